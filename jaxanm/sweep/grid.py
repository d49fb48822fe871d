"""Sweep grid files: a base scene, scene overrides and solver settings, expanded into tasks.

A grid file is TOML::

    scene = "conduction_small"      # a shipped scene, or a scene TOML file (relative to the grid file)
    reference = "dt=0.025-newton-tol=1e-10"  # optional: the task the errors are measured against

    [overrides]                     # optional: scene fields by the dotted keys of `jaxanm run --set`
    "time.t_end" = 0.2              # a value: the same in every task
    "time.dt" = [0.05, 0.025]       # a list: one task per value (an axis of a cartesian product)

    [[solvers]]                     # solver settings; each entry is the product of its own lists
    kind = "anm"                    # anm | newton | mnewton | ida (default: the scene's solver.kind)
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

**Scene overrides in a solver entry.**  A ``[[solvers]]`` entry may also hold dotted scene keys
(``"time.dt" = [1e-3, 1e-4]``): they are crossed with that entry's solver settings only, so
a grid that is no product (modified Newton over six steps, the ANM over three, IDA over its
tolerances and no step) is one file.  A key may be in ``[overrides]`` or in solver entries,
not both.

**IDA** (``kind = "ida"``, :mod:`jaxanm.fsw.ida_scene`): SUNDIALS IDA on the scene's residual,
fixed-point scenes only; settings ``rtol, atol, max_order`` (defaults
:data:`jaxanm.fsw.ida_scene.IDA_DEFAULTS`, ``atol`` = ``rtol`` unless given; they appear as
``solver.rtol`` etc. in the task's overrides and the table).  The scene's ``time.dt`` and
``solver.*`` do not enter an IDA task; its outputs are the scene's save times.

**A Richardson reference** instead of a reference task::

    [reference.richardson]
    dt = 5e-5                       # implicit Euler at dt, dt/2 and dt/4 ...
    kind = "mnewton"                # ... with this solver and its settings
    tol = 1e-10

adds three tasks (``richardson-dt=...``) that run the base scene with the grid's top-level
``[overrides]`` (single values then: the reference must be one scene) at fixed steps dt, dt/2,
dt/4; the sweep then extrapolates them (:mod:`jaxanm.sweep.richardson`).  Every save time of
that scene must be a multiple of dt, so that all three runs end a step there.

``warmup = true`` makes each task first run its configuration briefly (two steps; IDA to a
tenth of its first output time), untimed, so that ``wall_s`` excludes the JIT compilation
(:mod:`jaxanm.sweep.task`); without it the first task of each solver on each worker pays it.

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

from jaxanm.errors import InputError
from jaxanm.fsw.scene import (
    KIND_ALIASES,
    SOLVER_KINDS,
    SOLVER_OPTIONS,
    Scene,
    SceneError,
    load_scene,
    override_keys,
)
from jaxanm.internal import flag, integer, positive, real

__all__ = ["IDA", "RICHARDSON", "SOLVER_KEYS", "Grid", "GridError", "Richardson", "Task", "grid_from_dict",
           "read_grid"]

IDA = "ida"
"""The grid kind of IDA tasks (no scene solver: :mod:`jaxanm.fsw.ida_scene`)."""

SOLVER_KEYS = {**SOLVER_OPTIONS, IDA: ("rtol", "atol", "max_order")}
"""Solver settings that apply to each kind (``solver.*`` scene fields besides ``kind``, those the
kind's solver takes; IDA's own)."""
RICHARDSON = "richardson"
"""Prefix of the ids of a Richardson reference's tasks."""
TOP_KEYS = ("scene", "reference", "warmup", "overrides", "solvers")
"""Keys a grid file may have at its top level."""


class GridError(InputError):
    """A bad grid file; the message names the file, the entry or task, and what to change."""


@dataclasses.dataclass(frozen=True)
class Task:
    """One grid point: its id, its overrides (dotted scene keys, as in the grid), its scene and,
    for an IDA task, IDA's settings."""

    id: str
    overrides: dict
    scene: Scene
    ida: dict | None = None
    """IDA settings (``rtol, atol, max_order``) of an IDA task; None for an implicit-Euler run."""


@dataclasses.dataclass(frozen=True)
class Grid:
    """A read grid: its name (the file's stem), base scene, override keys in column order,
    tasks in grid order and the reference task id (or None), or a Richardson reference, and
    whether each task first makes an untimed compiling run (``warmup``)."""

    name: str
    base: Scene
    keys: tuple
    tasks: tuple
    reference: str | None = None
    richardson: Richardson | None = None
    warmup: bool = False


@dataclasses.dataclass(frozen=True)
class Richardson:
    """A Richardson reference: its coarsest step ``dt`` and its three tasks at dt, dt/2, dt/4."""

    dt: float
    tasks: tuple


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
    override_points = _override_points(data.get("overrides", {}), base, source)
    solver_points = _solver_points(data.get("solvers", {}), base, source)
    shared = {k for p in override_points for k in p} & {k for p in solver_points for k in p}
    if shared:
        raise GridError(f"{source}: {sorted(shared)[0]!r} is both in [overrides] and in a [[solvers]] entry; give "
                        "it in one place (in each solver entry, if it differs between them)")
    points = [{**o, **s} for o, s in itertools.product(override_points, solver_points)]
    keys = tuple(dict.fromkeys(k for p in points for k in p))
    keys = tuple(sorted(keys, key=lambda k: k.startswith("solver.")))  # scene fields first, stable
    ids = _task_ids(points, keys)
    tasks: list[Task] = []
    seen: dict[str, Task] = {}
    for task_id, overrides in zip(ids, points):
        task = _task(task_id, overrides, base, f"{source}: task {task_id!r}")
        same = next((i for i, t in seen.items() if (t.scene, t.ida) == (task.scene, task.ida)), None)
        if same is not None:
            raise GridError(f"{source}: tasks {same!r} and {task_id!r} are the same run; list each value "
                            "once (an axis value repeated, or two entries that overlap)")
        if task_id in seen:
            raise GridError(f"{source}: two tasks get the id {task_id!r} (their values differ only in characters "
                            "an id cannot hold); write the values differently")
        seen[task_id] = task
        tasks.append(task)
    reference, richardson = data.get("reference"), None
    if isinstance(reference, dict):
        richardson, reference = _richardson(reference, override_points, base, set(seen), source), None
    elif reference is not None and reference not in seen:
        listed = ", ".join(repr(i) for i in ids[:20]) + (", ..." if len(ids) > 20 else "")
        raise GridError(f"{source}: reference = {reference!r} is not a task of this grid; its tasks are {listed} "
                        "(or give a Richardson reference: [reference.richardson] with dt and a solver)")
    warmup = flag(f"{source}: warmup", data.get("warmup", False), hint="true: an untimed compiling run first",
                  error=GridError)
    return Grid(name=name, base=base, keys=keys, tasks=tuple(tasks), reference=reference, richardson=richardson,
                warmup=warmup)


def _task(task_id: str, overrides: dict, base: Scene, where: str) -> Task:
    """The :class:`Task` of one grid point: its scene, and IDA's settings for an IDA point."""
    ida = None
    scene_overrides = overrides
    if overrides.get("solver.kind") == IDA:
        from jaxanm.fsw.ida_scene import IDA_DEFAULTS

        ida = {**IDA_DEFAULTS, **{k.split(".", 1)[1]: v for k, v in overrides.items() if k.startswith("solver.")}}
        del ida["kind"]
        ida.setdefault("atol", ida["rtol"])
        scene_overrides = {k: v for k, v in overrides.items() if not k.startswith("solver.")}
        _check_ida(ida, where)
    try:
        scene = base.with_overrides(scene_overrides)
    except SceneError as exc:
        raise GridError(f"{where}: {exc}") from exc
    if ida is not None and scene.has("lagrangian"):
        raise GridError(f"{where}: IDA needs fixed points and scene {scene.name!r} is Lagrangian (its points move "
                        "between steps, so its step residual is no DAE); use the fixed-point scene (fsw_tracers "
                        "for fsw_paper) or an implicit-Euler kind")
    return Task(task_id, overrides, scene, ida)


def _check_ida(ida: dict, where: str) -> None:
    """IDA's settings, checked as :func:`jaxanm.ida.integrate_ida` will (before any run)."""
    real(f"{where}: rtol", ida["rtol"], 0.0, 1.0, open_low=True, open_high=True,
         hint="IDA's useful range is 1e-15 <= rtol <= 1e-3", error=GridError)
    real(f"{where}: atol", ida["atol"], 0.0, hint="relative to each unknown's scale", error=GridError)
    integer(f"{where}: max_order", ida["max_order"], 1, 5, hint="the orders of IDA's BDF formulas", error=GridError)


def _richardson(table: dict, override_points: list, base: Scene, ids: set, source: str) -> Richardson:
    """The three tasks of a ``[reference.richardson]`` table (module docstring)."""
    where = f"{source}: [reference.richardson]"
    spec = table.get("richardson") if set(table) == {"richardson"} else None
    if not isinstance(spec, dict):
        raise GridError(f"{source}: reference must be a task id (reference = \"ID\") or a table "
                        "[reference.richardson] with dt and a solver (kind, tol, ...)")
    dt = positive(f"{where}: dt", spec.get("dt"), hint="the coarsest of dt, dt/2, dt/4", error=GridError)
    if len(override_points) != 1:
        raise GridError(f"{where}: the reference runs the grid's [overrides], which must then be single values "
                        "(one scene); put axes such as time.dt in the [[solvers]] entries")
    solver = _solver_points({k: v for k, v in spec.items() if k != "dt"}, base, where)
    if len(solver) != 1 or solver[0].get("solver.kind") == IDA or any(not k.startswith("solver.") for k in solver[0]):
        raise GridError(f"{where}: give one implicit-Euler solver (kind = \"mnewton\", tol = 1e-10: single values, "
                        "no scene keys)")
    tasks = []
    for level in range(3):
        step = dt / 2 ** level
        task_id = f"{RICHARDSON}-dt={_format(float(step))}"
        if task_id in ids:
            raise GridError(f"{where}: the grid already has a task {task_id!r}; rename it")
        overrides = {**override_points[0], "time.dt": step, "time.adaptive": False, **solver[0]}
        tasks.append(_task(task_id, overrides, base, where))
    scene = tasks[0].scene
    off = [t for t in scene.time.save_times if t > 0 and abs(t / dt - round(t / dt)) > 1e-9 * t / dt]
    if off:
        raise GridError(f"{where}: save time {off[0]!r} s is no multiple of dt = {dt!r}: all three runs must end a "
                        "step at every save time (time.save and time.t_end in [overrides]); choose dt dividing them")
    return Richardson(dt=float(dt), tasks=tuple(tasks))


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
    points = []
    for i, entry in enumerate(_entries(value, "overrides", source)):
        where = f"{source}: [overrides]" if isinstance(value, dict) else f"{source}: [[overrides]] #{i + 1}"
        flat = _flatten(entry)
        _check_scene_keys(flat, where)
        points += _product(flat, _list_valued(flat, base), where)
    return points


def _check_scene_keys(flat: dict, where: str) -> None:
    """Every key of ``flat`` is a scene key of ``jaxanm run --set`` (solver settings excepted)."""
    allowed = set(override_keys())
    for key in flat:
        if key.startswith("solver."):
            raise GridError(f"{where}: {key!r} is a solver setting; give it under [[solvers]] as "
                            f"{key.split('.', 1)[1]} = ...")
        if key not in allowed:
            raise GridError(f"{where}: unknown scene key {key!r}; the keys of `jaxanm run --set` are "
                            f"{', '.join(k for k in override_keys() if not k.startswith('solver.'))}")


def _list_valued(flat: dict, base: Scene) -> set:
    """The keys of ``flat`` whose scene field is itself a list (``effects``, ``time.save``)."""
    return {k for k in flat if isinstance(_scene_value(base, k), tuple)}


def _solver_points(value, base: Scene, source: str) -> list[dict]:
    """Every point of the ``solvers`` entries: ``{"solver.<key>": value}`` (kind as the scene names
    it, or ``ida``) and the entry's own scene overrides (dotted keys)."""
    kinds_text = ", ".join([*SOLVER_KINDS, IDA])
    points = []
    for i, raw in enumerate(_entries(value, "solvers", source)):
        where = f"{source}: [solvers]" if isinstance(value, dict) else f"{source}: [[solvers]] #{i + 1}"
        entry = _flatten(raw)
        scene_part = {k: v for k, v in entry.items() if "." in k}
        _check_scene_keys(scene_part, where)
        kinds = entry.get("kind", base.solver.kind)
        for kind in kinds if isinstance(kinds, list) else [kinds]:
            if isinstance(kind, str) and kind in KIND_ALIASES:  # a former spelling: the scene warns of it
                kind = KIND_ALIASES[kind]
            if not isinstance(kind, str) or kind not in SOLVER_KEYS:
                raise GridError(f"{where}: kind = {kind!r} is unknown; use one of {kinds_text}")
            short = kind
            for key in entry:
                if key == "kind" or key in scene_part:
                    continue
                if key not in SOLVER_KEYS[short]:
                    known = key in {k for keys in SOLVER_KEYS.values() for k in keys}
                    why = (f"it does not apply to kind = {short!r}" if known
                           else "it is not a solver setting")
                    raise GridError(f"{where}: {key!r}: {why}; kind {short!r} takes "
                                    f"{', '.join(SOLVER_KEYS[short])} (put other kinds in their own [[solvers]] entry)")
            fixed = {"solver.kind": short} if "kind" in entry else {}
            settings = {f"solver.{k}": v for k, v in entry.items() if k != "kind" and k not in scene_part}
            solver = _product(settings, set(), where)
            scenes = _product(scene_part, _list_valued(scene_part, base), where)
            points += [{**sc, **fixed, **p} for sc in scenes for p in solver]
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
                parts.append(p[key])
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
