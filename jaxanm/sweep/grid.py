"""Sweep grid files: a base scene, scene overrides and solver settings, expanded into tasks.

A grid file is TOML::

    scene = "conduction_small"      # a shipped scene, or a scene TOML file (relative to the grid file)
    reference = "dt=0.025-newton-tol=1e-10"  # optional: the task the errors are measured against

    [overrides]                     # optional: scene fields by the dotted keys of `jaxanm run --set`
    "time.t_end" = 0.2              # a value: the same in every task
    "time.dt" = [0.05, 0.025]       # a list: one task per value (an axis of a cartesian product)

    [[solvers]]                     # solver settings; each entry is the product of its own lists
    kind = "anm"                    # anm | newton | mnewton (default: the scene's solver.kind)
    order = [5, 7]
    tol = 1e-6
    [[solvers]]
    kind = "newton"
    tol = [1e-6, 1e-10]

The tasks are every overrides point times every solver point (here 2 x 4).  ``[overrides]`` may
also be an array ``[[overrides]]`` (the union of its entries' products) and ``[solvers]`` a
single table.  Unquoted dotted keys (``time.dt = ...``) and sub-tables (``[overrides.time]``)
mean the same as quoted ones.  A field whose value is itself a list (``effects``,
``time.save``) takes a list as one value and a list of lists as an axis.  Solver keys are the
scene's ``solver.*`` fields that apply to the kind: ``anm`` takes ``order, tol, criterion,
max_substeps, adaptive, homotopy, pade``; ``newton`` ``tol``; ``mnewton`` ``tol, max_rate``.

Each task's id names the values that vary across the grid, the solver kind by itself
(``anm-order=5``, ``dt=0.05-newton-tol=1e-10``; ``run`` when nothing varies).  Every task's
scene is built and validated when the grid is read, so a bad grid fails before any
computation, with a :class:`GridError` naming the file, the entry or task and the fix.
"""

from __future__ import annotations

import dataclasses
import itertools
import re
import tomllib
from pathlib import Path

from jaxanm.fsw.scene import Scene, SceneError, load_scene, override_keys

__all__ = ["SOLVER_KEYS", "Grid", "GridError", "Task", "grid_from_dict", "read_grid"]

SOLVER_KINDS = {"anm": "anm", "newton": "newton", "mnewton": "modified_newton"}
"""Solver kinds of a grid (those of ``jaxanm run --solver``) -> ``solver.kind`` of the scene."""
SOLVER_KEYS = {
    "anm": ("order", "tol", "criterion", "max_substeps", "adaptive", "homotopy", "pade"),
    "newton": ("tol",),
    "mnewton": ("tol", "max_rate"),
}
"""Solver settings (``solver.*`` scene fields besides ``kind``) that apply to each kind."""
TOP_KEYS = ("scene", "reference", "overrides", "solvers")
"""Keys a grid file may have at its top level."""


class GridError(ValueError):
    """A bad grid file; the message names the file, the entry or task, and what to change."""


@dataclasses.dataclass(frozen=True)
class Task:
    """One grid point: its id, its overrides (dotted scene keys, as in the grid) and its scene."""

    id: str
    overrides: dict
    scene: Scene


@dataclasses.dataclass(frozen=True)
class Grid:
    """A read grid: its name (the file's stem), base scene, override keys in column order,
    tasks in grid order and the reference task id (or None)."""

    name: str
    base: Scene
    keys: tuple
    tasks: tuple
    reference: str | None = None


def read_grid(path) -> Grid:
    """Read and validate the grid file at ``path`` (see the module docstring); raise :class:`GridError`."""
    path = Path(path)
    if not path.is_file():
        raise GridError(f"grid file {str(path)!r} does not exist")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise GridError(f"grid file {str(path)!r} is not valid TOML: {exc}") from exc
    return grid_from_dict(data, name=path.stem, base_dir=path.parent, source=f"grid file {str(path)!r}")


def grid_from_dict(data: dict, name: str = "grid", base_dir=".", source: str = "grid") -> Grid:
    """A :class:`Grid` from the grid file's TOML layout (``base_dir``: where a scene path is relative to).

    ``source`` starts every error message (the file name, for :func:`read_grid`).
    """
    unknown = [k for k in data if k not in TOP_KEYS]
    if unknown:
        raise GridError(f"{source}: unknown top-level key {unknown[0]!r}; the keys are {', '.join(TOP_KEYS)} "
                        "(scene fields go under [overrides], solver settings under [[solvers]])")
    base = _base_scene(data.get("scene"), Path(base_dir), source)
    points = [{**o, **s} for o, s in itertools.product(_override_points(data.get("overrides", {}), base, source),
                                                      _solver_points(data.get("solvers", {}), base, source))]
    keys = tuple(dict.fromkeys(k for p in points for k in p))
    keys = tuple(sorted(keys, key=lambda k: k.startswith("solver.")))  # scene fields first, stable
    ids = _task_ids(points, keys)
    tasks, seen = [], {}
    for task_id, overrides in zip(ids, points):
        try:
            scene = base.with_overrides(overrides)
        except SceneError as exc:
            raise GridError(f"{source}: task {task_id!r}: {exc}") from exc
        same = next((i for i, s in seen.items() if s == scene), None)
        if same is not None:
            raise GridError(f"{source}: tasks {same!r} and {task_id!r} are the same run; list each value "
                            "once (an axis value repeated, or two entries that overlap)")
        if task_id in seen:
            raise GridError(f"{source}: two tasks get the id {task_id!r} (their values differ only in characters "
                            "an id cannot hold); write the values differently")
        seen[task_id] = scene
        tasks.append(Task(task_id, overrides, scene))
    reference = data.get("reference")
    if reference is not None and reference not in seen:
        listed = ", ".join(repr(i) for i in ids[:20]) + (", ..." if len(ids) > 20 else "")
        raise GridError(f"{source}: reference = {reference!r} is not a task of this grid; its tasks are {listed}")
    return Grid(name=name, base=base, keys=keys, tasks=tuple(tasks), reference=reference)


def _base_scene(value, base_dir: Path, source: str) -> Scene:
    """The scene named by the grid's ``scene`` key (a shipped name, or a path relative to ``base_dir``)."""
    if not isinstance(value, str) or not value:
        raise GridError(f"{source}: give the base scene as scene = \"NAME\" (a shipped scene such as "
                        "\"fsw_paper\", or a scene TOML file relative to the grid file)")
    target = base_dir / value if value.endswith(".toml") else value
    try:
        return load_scene(target)
    except SceneError as exc:
        raise GridError(f"{source}: scene = {value!r}: {exc}") from exc


def _entries(value, table: str, source: str) -> list[dict]:
    """The entries of ``[table]`` (one) or ``[[table]]`` (several); ``{}`` when absent."""
    entries = value if isinstance(value, list) else [value]
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise GridError(f"{source}: {table} must be a table [{table}] or an array of tables [[{table}]], "
                            f"got {entry!r}")
        if isinstance(value, list) and not entry:
            raise GridError(f"{source}: [[{table}]] #{i + 1} is empty; give it at least one key or remove it")
    return entries or [{}]


def _override_points(value, base: Scene, source: str) -> list[dict]:
    """Every point of the ``overrides`` entries: ``{dotted key: value}``."""
    allowed = set(override_keys())
    points = []
    for i, entry in enumerate(_entries(value, "overrides", source)):
        where = f"{source}: [overrides]" if isinstance(value, dict) else f"{source}: [[overrides]] #{i + 1}"
        flat = _flatten(entry)
        for key in flat:
            if key.startswith("solver."):
                raise GridError(f"{where}: {key!r} is a solver setting; give it under [[solvers]] as "
                                f"{key.split('.', 1)[1]} = ...")
            if key not in allowed:
                raise GridError(f"{where}: unknown scene key {key!r}; the keys of `jaxanm run --set` are "
                                f"{', '.join(k for k in override_keys() if not k.startswith('solver.'))}")
        points += _product(flat, {k for k in flat if isinstance(_scene_value(base, k), tuple)}, where)
    return points


def _solver_points(value, base: Scene, source: str) -> list[dict]:
    """Every point of the ``solvers`` entries: ``{"solver.<key>": value}`` (kind as the scene names it)."""
    scene_kinds = {v: k for k, v in SOLVER_KINDS.items()}
    points = []
    for i, entry in enumerate(_entries(value, "solvers", source)):
        where = f"{source}: [solvers]" if isinstance(value, dict) else f"{source}: [[solvers]] #{i + 1}"
        kinds = entry.get("kind", scene_kinds[base.solver.kind])
        for kind in kinds if isinstance(kinds, list) else [kinds]:
            if not isinstance(kind, str) or (kind not in SOLVER_KINDS and kind not in scene_kinds):
                raise GridError(f"{where}: kind = {kind!r} is unknown; use one of {', '.join(SOLVER_KINDS)}")
            short = scene_kinds.get(kind, kind)
            for key, setting in entry.items():
                if key == "kind":
                    continue
                if key not in SOLVER_KEYS[short]:
                    known = key in {k for keys in SOLVER_KEYS.values() for k in keys}
                    why = (f"it does not apply to kind = {short!r}" if known
                           else "it is not a solver setting")
                    raise GridError(f"{where}: {key!r}: {why}; kind {short!r} takes "
                                    f"{', '.join(SOLVER_KEYS[short])} (put other kinds in their own [[solvers]] entry)")
                if isinstance(setting, dict):
                    raise GridError(f"{where}: {key!r} must be a value or a list of values, got a table")
            fixed = {"solver.kind": SOLVER_KINDS[short]} if "kind" in entry else {}
            settings = {f"solver.{k}": v for k, v in entry.items() if k != "kind"}
            points += [{**fixed, **p} for p in _product(settings, set(), where)]
    return points


def _flatten(table: dict, prefix: str = "") -> dict:
    """``{"time": {"dt": 1}}`` -> ``{"time.dt": 1}`` (TOML's unquoted dotted keys make nested tables)."""
    flat = {}
    for key, value in table.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def _scene_value(scene: Scene, key: str):
    """The value of dotted ``key`` in ``scene``."""
    obj = scene
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


def _product(settings: dict, list_valued: set, where: str) -> list[dict]:
    """The cartesian product of ``settings``: a list is an axis, except for a ``list_valued`` key,
    whose axis is a list of lists."""
    axes = {}
    for key, value in settings.items():
        is_axis = isinstance(value, list) and (key not in list_valued or any(isinstance(v, list) for v in value))
        if is_axis and not value:
            raise GridError(f"{where}: {key} = [] gives no task; list at least one value")
        if is_axis and key in list_valued and not all(isinstance(v, list) for v in value):
            raise GridError(f"{where}: {key} is a list field: give one list ({key} = [\"a\", \"b\"]) or a list "
                            f"of lists for an axis ({key} = [[\"a\"], [\"a\", \"b\"]]), not a mix")
        if is_axis and len({repr(v) for v in value}) < len(value):
            raise GridError(f"{where}: {key} = {value!r} lists a value twice; list each value once")
        axes[key] = value if is_axis else [value]
    return [dict(zip(axes, combo)) for combo in itertools.product(*axes.values())]


def _task_ids(points: list[dict], keys: tuple) -> list[str]:
    """One id per point from the values that vary across ``points`` (``"run"`` if none does)."""
    missing = object()
    varying = [k for k in keys if len({repr(p.get(k, missing)) for p in points}) > 1]
    ends = [k.rsplit(".", 1)[-1] for k in varying]
    ids = []
    for p in points:
        parts = []
        for key, end in zip(varying, ends):
            if key not in p:
                continue
            if key == "solver.kind":
                parts.append({v: k for k, v in SOLVER_KINDS.items()}[p[key]])
            else:
                parts.append(f"{end if ends.count(end) == 1 else key}={_format(p[key])}")
        ids.append(re.sub(r"[^A-Za-z0-9_.+=-]", "_", "-".join(parts)) or "run")
    return ids


def _format(value) -> str:
    """A value as it appears in a task id (floats as Python writes them: 1e-06, 0.0001)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list):
        return "+".join(_format(v) for v in value)
    return repr(value) if isinstance(value, float) else str(value)
