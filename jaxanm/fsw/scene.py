"""FSW scenes: typed, validated, loaded from TOML or built in Python, overridable by key.

A :class:`Scene` holds everything a friction-stir-welding run needs, in SI units: geometry and
point layout, plate material, tool, thermal boundary data, the penalty factor, time stepping,
the nonlinear solver, registration points (probes), registration sections and the list of
*effects* (which residual terms and unknowns the model assembles: :data:`EFFECTS`, each described
by its record in :data:`jaxanm.fsw.effects.REGISTRY`).

Every value is checked when the scene is built (from Python, from TOML or by
:meth:`Scene.with_overrides`), before any computation: a bad value, or a combination of
options the model cannot take, raises :class:`SceneError` (a :class:`jaxanm.InputError`, hence
a ``ValueError``) naming the field, the value and what is allowed.

Shipped scenes live in ``jaxanm/fsw/scenes/*.toml``; :func:`load_scene` takes their name
(``"fsw_paper"``) or a path to a TOML file of the same layout::

    name = "my_scene"
    effects = ["viscous", "conduction", "robin"]
    [geometry]   R1 = 1.5e-3  ...          # one table per section, keys = field names
    [[probes]]   name = "1"  x = 1.875e-3  y = 0.0
    [[sections]] name = "A-A"  start = [-6e-3, 0.0]  end = [6e-3, 0.0]  samples = 161
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import tomllib
from pathlib import Path

from ..errors import did_you_mean
from .effects import EFFECTS, REGISTRY, scene_value
from .scene_sections import (  # noqa: F401 - re-exported: the sections are part of this module's API
    EDGE_ROWS,
    EDGE_SOURCES,
    KIND_ALIASES,
    LAYOUTS,
    MAX_ORDER,
    MAX_POINTS,
    MAX_SAMPLES,
    MAX_STEPS,
    NAME_CHARS,
    SOLVER_KINDS,
    SOLVER_OPTIONS,
    STARTS,
    Geometry,
    Material,
    Mechanics,
    Probe,
    SceneError,
    Section,
    SolverSpec,
    Thermal,
    Time,
    Tool,
    as_str,
    as_strs,
    check,
)

__all__ = [
    "EDGE_ROWS",
    "EDGE_SOURCES",
    "EFFECTS",
    "EFFECT_REQUIRES",
    "Geometry",
    "KIND_ALIASES",
    "Material",
    "Mechanics",
    "Probe",
    "SOLVER_KINDS",
    "SOLVER_OPTIONS",
    "Scene",
    "SceneError",
    "Section",
    "SolverSpec",
    "Thermal",
    "Time",
    "Tool",
    "load_scene",
    "override_keys",
    "shipped_scenes",
]

log = logging.getLogger(__name__)

SCENES_DIR = Path(__file__).with_name("scenes")
"""Directory of the shipped scene files."""

EFFECT_REQUIRES = {name: effect.requires for name, effect in REGISTRY.items() if effect.requires}
"""Effects that need other effects (the fields they act on): :attr:`Effect.requires` of the
records of :data:`jaxanm.fsw.effects.REGISTRY`, by name."""

_SECTIONS = {"geometry": Geometry, "material": Material, "tool": Tool, "thermal": Thermal,
             "mechanics": Mechanics, "time": Time, "solver": SolverSpec}


@dataclasses.dataclass(frozen=True)
class Scene:
    """A complete, validated FSW scene (SI units).

    Build it from Python (``Scene(effects=("viscous",), material=Material(n=0.3))``), from TOML
    (:func:`load_scene`) or from another scene (:meth:`with_overrides`).  Cross-field checks
    (effect names and dependencies, probes inside the plate, sections inside the disc) run on
    creation and raise :class:`SceneError`.
    """

    name: str = "scene"
    effects: tuple[str, ...] = ("viscous",)
    geometry: Geometry = dataclasses.field(default_factory=Geometry)
    material: Material = dataclasses.field(default_factory=Material)
    tool: Tool = dataclasses.field(default_factory=Tool)
    thermal: Thermal = dataclasses.field(default_factory=Thermal)
    mechanics: Mechanics = dataclasses.field(default_factory=Mechanics)
    time: Time = dataclasses.field(default_factory=Time)
    solver: SolverSpec = dataclasses.field(default_factory=SolverSpec)
    probes: tuple[Probe, ...] = ()
    sections: tuple[Section, ...] = ()

    def __post_init__(self):
        object.__setattr__(self, "name", as_str("name", self.name))
        check("name", self.name, 0 < len(self.name) <= 100 and set(self.name) <= NAME_CHARS
               and not self.name.startswith("."),
               "must be 1-100 letters, digits or _-.+ not starting with '.' (it names the output directory)")
        effects = as_strs("effects", self.effects)
        object.__setattr__(self, "effects", effects)
        for key, cls in _SECTIONS.items():
            check(key, getattr(self, key), isinstance(getattr(self, key), cls),
                   f"expected a jaxanm.fsw.scene.{cls.__name__}")
        for key, cls in (("probes", Probe), ("sections", Section)):
            check(key, getattr(self, key), isinstance(getattr(self, key), (list, tuple)),
                   f"expected a list of jaxanm.fsw.scene.{cls.__name__}")
            items = tuple(getattr(self, key))
            for i, item in enumerate(items):
                check(f"{key}[{i}]", item, isinstance(item, cls), f"expected a {cls.__name__}")
            object.__setattr__(self, key, items)
        self._validate_effects()
        self._validate_places()

    def _validate_effects(self):
        """Names, exclusions and requirements of the listed effects, their parameters, their checks
        (all read from their records, :data:`jaxanm.fsw.effects.REGISTRY`)."""
        check("effects", self.effects, len(self.effects) > 0,
               f"list at least one effect of {EFFECTS}")
        for e in self.effects:
            check("effects", e, e in EFFECTS, f"unknown effect; known effects are {EFFECTS}")
        check("effects", self.effects, len(set(self.effects)) == len(self.effects),
               "an effect is listed twice")
        have = set(self.effects)
        creating = [e for e in EFFECTS if "unknowns" in REGISTRY[e].roles]
        made = ", ".join(f"{e!r} {REGISTRY[e].fields}" for e in creating)
        check("effects", self.effects, bool(have & set(creating)),
               f"list one of {creating} (they create the unknowns: {made}): without them the scene has no unknowns")
        for e in self.effects:
            for other, why in REGISTRY[e].excludes:
                check("effects", self.effects, other not in have, why)
        for e in self.effects:
            missing = [r for r in REGISTRY[e].requires if r not in have]
            check("effects", self.effects, not missing,
                   f"effect {e!r} needs {missing} (add them or drop {e!r})")
        check("mechanics.start", self.mechanics.start, self.mechanics.start == "rest" or "viscous" in have,
               "a start other than 'rest' needs the 'viscous' effect (the flow it solves); use 'rest'")
        self._validate_parameters(have)
        for e in self.effects:
            for key, value, allowed in (REGISTRY[e].check(self) if REGISTRY[e].check else ()):
                check(key, value, False, allowed)

    def _validate_parameters(self, have: set):
        """Each effect's parameters within their ranges, and at their defaults unless the effect is listed."""
        for name, effect in REGISTRY.items():
            for par in effect.parameters:
                value, default = scene_value(self, par.key), _default(par.key)
                check(par.key, value, par.low <= value <= par.high,
                       f"must be in [{par.low:g}, {par.high:g}] ({par.unit}): {par.doc}")
                check(par.key, value, value == default or name in have,
                       f"differs from its default {default!r} but the scene does not list the {name!r} effect: add "
                       f"{name!r} to effects{_and_requirements(name)}, or leave {par.key} = {default!r}")

    def _validate_places(self):
        g = self.geometry
        names = [p.name for p in self.probes]
        check("probes", names, len(set(names)) == len(names), "probe names must be unique")
        for i, p in enumerate(self.probes):
            r = math.hypot(p.x, p.y)
            where = "inside the tool" if r < g.R1 else "on the tool edge" if r == g.R1 else "outside the plate"
            check(f"probes[{i}] ({p.name}).x, y", (p.x, p.y), g.R1 < r < g.R2,
                   f"must lie in the plate, geometry.R1 = {g.R1} < r < geometry.R2 = {g.R2}, but r = "
                   f"sqrt(x^2 + y^2) = {r:.6g} is {where}: move the registration point into the plate")
        names = [s.name for s in self.sections]
        check("sections", names, len(set(names)) == len(names), "section names must be unique")
        for i, s in enumerate(self.sections):
            for key in ("start", "end"):
                pt = getattr(s, key)
                check(f"sections[{i}].{key}", pt, math.hypot(*pt) <= g.R2 * (1 + 1e-12),
                       f"must lie in the disc r <= geometry.R2 = {g.R2}")

    @property
    def eps0(self) -> float:
        """The strain-rate regularisation the model uses (1/s): ``material.eps0``, or
        ``material.eps0_relative * tool.omega`` when that is set (:class:`Material`)."""
        m = self.material
        return m.eps0_relative * self.tool.omega if m.eps0_relative > 0 else m.eps0

    def has(self, effect: str) -> bool:
        """Whether the scene lists ``effect``."""
        return effect in self.effects

    def restricted_to(self, effects) -> "Scene":
        """This scene with only ``effects`` (in this scene's order), the parameters of the
        effects dropped back at their defaults (validated as any scene)."""
        keep = [e for e in self.effects if e in set(effects)]
        dropped = {p.key: _default(p.key) for e in self.effects if e not in keep for p in REGISTRY[e].parameters}
        return self.with_overrides({"effects": ",".join(keep), **dropped})

    def with_overrides(self, overrides: dict) -> "Scene":
        """A new scene with ``{"section.field": value}`` replaced (values may be strings).

        Keys are :func:`override_keys` (e.g. ``material.K``, ``time.dt``, ``effects``); string
        values are parsed to the field's type (``"2e16"``, ``"conduction,robin"``).  The result
        is validated as a whole; an unknown key or bad value raises :class:`SceneError`.
        """
        check("overrides", overrides, isinstance(overrides, dict), "expected a dict {'section.field': value}")
        top: dict = {}
        per_section: dict = {}
        allowed = override_keys()
        for key, value in overrides.items():
            check("override key", key, key in allowed, f"known keys are {', '.join(allowed)}")
            if "." in key:
                sec, fld = key.split(".", 1)
                per_section.setdefault(sec, {})[fld] = value
            else:
                top[key] = value
        changes = {sec: dataclasses.replace(getattr(self, sec), **fields)
                   for sec, fields in per_section.items()}
        return dataclasses.replace(self, **top, **changes)

    def to_dict(self) -> dict:
        """Plain dictionary in the TOML layout (round-trips through :meth:`from_dict`)."""
        d: dict[str, object] = {"name": self.name, "effects": list(self.effects)}
        for key in _SECTIONS:
            d[key] = _section_dict(getattr(self, key))
        d["probes"] = [_section_dict(p) for p in self.probes]
        d["sections"] = [_section_dict(s) for s in self.sections]
        return d

    @classmethod
    def from_dict(cls, data: dict, source: str = "scene") -> "Scene":
        """Scene from a dictionary in the TOML layout; unknown tables or keys raise :class:`SceneError`."""
        check(source, data, isinstance(data, dict), "expected a table (dict) of scene sections")
        known = {"name", "effects", "probes", "sections", *_SECTIONS}
        for key in data:
            check(f"{source}: top-level key", key, key in known, f"known keys are {sorted(known)}")
        kwargs = {k: data[k] for k in ("name", "effects") if k in data}
        for key, sec in _SECTIONS.items():
            if key in data:
                kwargs[key] = _section_from(sec, data[key], f"{source}: [{key}]")
        for key, sec in (("probes", Probe), ("sections", Section)):
            if key in data:
                items = data[key]
                check(f"{source}: {key}", items, isinstance(items, list), f"expected [[{key}]] tables")
                kwargs[key] = tuple(_section_from(sec, it, f"{source}: [[{key}]] #{i}")
                                    for i, it in enumerate(items))
        return cls(**kwargs)


def _default(key: str):
    """The default of the scene field ``"section.field"`` (its section class's)."""
    section, field = key.split(".", 1)
    return next(f.default for f in dataclasses.fields(_SECTIONS[section]) if f.name == field)


def _and_requirements(name: str) -> str:
    requires = REGISTRY[name].requires
    return f" (with {', '.join(repr(r) for r in requires)})" if requires else ""


def _section_dict(obj) -> dict:
    """A section's keys in the TOML layout; an unset one (None: its owner's default) is left out."""
    return {f.name: (list(v) if isinstance(v, tuple) else v)
            for f in dataclasses.fields(obj) if (v := getattr(obj, f.name)) is not None}


def _section_from(cls, table, where: str):
    check(where, table, isinstance(table, dict), "expected a table of key = value")
    names = {f.name for f in dataclasses.fields(cls)}
    for key in table:
        check(f"{where} key", key, key in names, f"known keys are {sorted(names)}")
    return cls(**table)


def override_keys() -> tuple:
    """Every key :meth:`Scene.with_overrides` accepts: ``effects``, ``name`` and ``section.field``."""
    keys = ["effects", "name"]
    for sec, cls in _SECTIONS.items():
        keys += [f"{sec}.{f.name}" for f in dataclasses.fields(cls)]
    return tuple(keys)


def shipped_scenes() -> tuple:
    """Names of the scenes shipped in ``jaxanm/fsw/scenes``."""
    return tuple(sorted(p.stem for p in SCENES_DIR.glob("*.toml")))


def load_scene(name_or_path) -> Scene:
    """Load a shipped scene by name (``"fsw_paper"``) or a scene TOML file by path.

    A file may start from another scene: ``base = "fsw_graded"`` (a shipped scene's name, or a
    path relative to the file) takes that scene's tables, and the file's own keys replace
    theirs one by one (a list, such as ``[[probes]]``, replaces the base's list whole).

    Raises :class:`SceneError` if the name is unknown, the file is not valid TOML, or a value
    is invalid (the message names the field).
    """
    path = _scene_path(name_or_path)
    return Scene.from_dict(_scene_table(path, ()), source=str(path))


def _scene_path(name_or_path, relative_to: Path | None = None) -> Path:
    """The TOML file of a shipped scene's name or of a path (relative to ``relative_to``'s folder).

    A shipped scene's name (``"fsw"``) is that scene, whatever the current folder holds: a folder
    of that name (e.g. the results of ``jaxanm run --out fsw``) is never a scene file, and a *file*
    of that name, or of that name plus ``.toml``, only gets a warning naming the way to run it
    (``./fsw``).  Anything else is a path.
    """
    text = str(name_or_path)
    path = Path(name_or_path)
    if relative_to is not None and not path.is_absolute():
        path = relative_to.parent / path
    if text in shipped_scenes():
        shipped = SCENES_DIR / f"{text}.toml"
        shadowed = [p for p in (path, path.with_name(path.name + ".toml"))
                    if p.is_file() and p.resolve() != shipped.resolve()]
        if shadowed:
            log.warning("%r is a shipped scene and %s is a file: running the shipped scene; to run the file, "
                        "give its path, e.g. %s", text, shadowed[0], _explicit_path(shadowed[0], relative_to))
        return shipped
    if path.is_dir():
        raise SceneError(f"scene {text!r} is a folder, not a scene file: give a .toml file or one of the "
                         f"shipped scenes {shipped_scenes()}")
    if not path.is_file():
        if path.suffix != ".toml" and "/" not in text and "\\" not in text:
            hint = did_you_mean(text, shipped_scenes())
            raise SceneError(f"unknown scene {text!r}" + (f" ({hint})" if hint else "")
                             + f": give a path to a .toml file or one of the shipped scenes {shipped_scenes()}")
        named = f"; the shipped scene is {path.stem!r}" if path.stem in shipped_scenes() else ""
        raise SceneError(f"scene file {str(path)!r} does not exist{named}")
    return path


def _explicit_path(path: Path, relative_to: Path | None) -> str:
    """``path`` spelt so that it cannot be read as a scene name (``./fsw``)."""
    if path.is_absolute() or relative_to is not None:
        return str(path)
    return f".{os.sep}{path}"


def _scene_table(path: Path, chain: tuple) -> dict:
    """The TOML table of the scene file ``path`` with its ``base`` scenes' tables under it."""
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"scene file {str(path)!r} is not valid TOML: {exc}") from exc
    if "base" not in data:
        return data
    base = data.pop("base")
    check(f"{path}: base", base, isinstance(base, str), "must be a scene name or a path to a .toml file")
    base_path = _scene_path(base, relative_to=path)
    check(f"{path}: base", base, base_path.resolve() not in chain + (path.resolve(),),
           "makes a cycle of scenes built on each other")
    merged = _scene_table(base_path, chain + (path.resolve(),))
    for key, value in data.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = {**merged[key], **value}
        else:
            merged[key] = value
    return merged
