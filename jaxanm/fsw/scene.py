"""FSW scenes: typed, validated, loaded from TOML or built in Python, overridable by key.

A :class:`Scene` holds everything a friction-stir-welding run needs, in SI units: geometry and
point layout, plate material, tool, thermal boundary data, the penalty factor, time stepping,
the nonlinear solver, registration points (probes), registration sections and the list of
*effects* (which residual terms and unknowns the model assembles, see :data:`EFFECTS`).

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
from .scene_sections import (  # noqa: F401 - re-exported: the sections are part of this module's API
    _NAME_CHARS,
    EDGE_ROWS,
    EDGE_SOURCES,
    LAYOUTS,
    MAX_ORDER,
    MAX_POINTS,
    MAX_SAMPLES,
    MAX_STEPS,
    SOLVER_KINDS,
    SOLVER_NAMES,
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
    _as_str,
    _as_strs,
    _check,
)

__all__ = [
    "EDGE_ROWS",
    "EDGE_SOURCES",
    "EFFECTS",
    "EFFECT_REQUIRES",
    "Geometry",
    "Material",
    "Mechanics",
    "Probe",
    "SOLVER_KINDS",
    "SOLVER_NAMES",
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

EFFECTS = (
    "inertia",
    "viscous",
    "softening",
    "conduction",
    "tool_conduction",
    "dissipation",
    "robin",
    "lagrangian",
    "tracers",
    "slip",
    "traverse",
)
"""Effect names a scene may list (a contract with the CLI and the model):

- ``viscous``: momentum balance of the power-law fluid with penalised incompressibility
  (creates the velocity unknowns u, v; the tool turns rigidly, the ring r = R2 is fixed);
- ``inertia``: ``rho dV/dt`` in the momentum balance;
- ``softening``: viscosity depends on temperature through ``T^A`` (else ``T0^A``);
- ``conduction``: heat equation in the plate (creates the temperature unknowns T);
- ``tool_conduction``: heat equation in the tool, T and heat flux continuous at r = R1 (else the
  plate edge r = R1 is insulated and the tool stays at T0);
- ``dissipation``: heat source ``q = 3 beta mu epsbar^2``;
- ``robin``: ``-k dT/dN = h (T - Ta)`` at r = R2 (else that edge is insulated);
- ``lagrangian``: points move with the material (``x <- x + dt V``, tool points rotate rigidly),
  stencils are rebuilt after every step;
- ``tracers``: fixed (Eulerian) points, ``V . grad`` transport terms, passive tracer particles
  advected for the mixing picture;
- ``slip``: partial sliding at the tool (Schmidt-Hattel's contact state delta =
  ``tool.contact_state``): the plate's velocity at the tool edge is ``delta omega (-y, x)``
  (the tool turns at omega), and the interface shear ``tau(R1)`` sliding at ``(1 - delta)
  omega R1`` releases ``(1 - delta) omega R1 tau(R1)`` W/m^2 of frictional heat at the
  interface, all of it heat, split between tool and plate by the interface's flux condition
  (delta = 1, sticking, is the paper's condition and gives its residual exactly);
- ``traverse``: the tool travels along +x at ``U = tool.traverse_speed``, seen from the tool:
  the ring r = R2 moves at (-U, 0) (the plate streams in on the leading side x > 0 and out on
  the trailing side), the inflow part of the ring lets the plate carry T0 in (the Robin row
  plus ``rho Cp max(-V.N, 0) (T - T0)``), the outflow part keeps the Robin row, and the
  transport terms ``V . grad`` of the heat equation and the inertia carry the through-flow;
  the tracers leave across the trailing side and re-enter on the leading side.  Needs fixed
  points (``tracers``).  U = 0 gives the scene without it exactly.
"""

EFFECT_REQUIRES = {
    "inertia": ("viscous",),
    "softening": ("viscous", "conduction"),
    "tool_conduction": ("conduction",),
    "dissipation": ("viscous", "conduction"),
    "robin": ("conduction",),
    "lagrangian": ("viscous",),
    "tracers": ("viscous",),
    "slip": ("viscous",),
    "traverse": ("viscous", "tracers"),
}
"""Effects that need other effects (the field they act on)."""



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
        object.__setattr__(self, "name", _as_str("name", self.name))
        _check("name", self.name, 0 < len(self.name) <= 100 and set(self.name) <= _NAME_CHARS
               and not self.name.startswith("."),
               "must be 1-100 letters, digits or _-.+ not starting with '.' (it names the output directory)")
        effects = _as_strs("effects", self.effects)
        object.__setattr__(self, "effects", effects)
        for key, cls in _SECTIONS.items():
            _check(key, getattr(self, key), isinstance(getattr(self, key), cls),
                   f"expected a jaxanm.fsw.scene.{cls.__name__}")
        for key, cls in (("probes", Probe), ("sections", Section)):
            _check(key, getattr(self, key), isinstance(getattr(self, key), (list, tuple)),
                   f"expected a list of jaxanm.fsw.scene.{cls.__name__}")
            items = tuple(getattr(self, key))
            for i, item in enumerate(items):
                _check(f"{key}[{i}]", item, isinstance(item, cls), f"expected a {cls.__name__}")
            object.__setattr__(self, key, items)
        self._validate_effects()
        self._validate_places()

    def _validate_effects(self):
        _check("effects", self.effects, len(self.effects) > 0,
               f"list at least one effect of {EFFECTS}")
        for e in self.effects:
            _check("effects", e, e in EFFECTS, f"unknown effect; known effects are {EFFECTS}")
        _check("effects", self.effects, len(set(self.effects)) == len(self.effects),
               "an effect is listed twice")
        have = set(self.effects)
        _check("effects", self.effects, bool(have & {"viscous", "conduction"}),
               "list 'viscous' (velocity) and/or 'conduction' (temperature): without them the "
               "scene has no unknowns")
        _check("effects", self.effects, not {"traverse", "lagrangian"} <= have,
               "'traverse' with 'lagrangian' is not supported: the plate streaming through the disc "
               "would carry the moving cloud out of it; use 'tracers' (fixed points, the plate's "
               "material points enter and leave) instead of 'lagrangian'")
        for e in self.effects:
            missing = [r for r in EFFECT_REQUIRES.get(e, ()) if r not in have]
            _check("effects", self.effects, not missing,
                   f"effect {e!r} needs {missing} (add them or drop {e!r})")
        _check("mechanics.start", self.mechanics.start, self.mechanics.start == "rest" or "viscous" in have,
               "a start other than 'rest' needs the 'viscous' effect (the flow it solves); use 'rest'")
        _check("effects", self.effects, not {"lagrangian", "tracers"} <= have,
               "'lagrangian' (moving points) and 'tracers' (fixed points) exclude each other")
        _check("effects", self.effects, not ("lagrangian" in have and self.geometry.layout == "graded"),
               "'lagrangian' on geometry.layout = 'graded' is not supported yet: the graded cloud is "
               "validated on fixed points only (its rezoning and the tool edge sliding past the fine "
               "rings are untested); use 'tracers' instead of 'lagrangian', or layout 'polar'")
        self._validate_contact(have)

    def _validate_contact(self, have: set):
        """The tool's contact state and travel need their effects, and fixed points."""
        tl = self.tool
        _check("tool.contact_state", tl.contact_state, tl.contact_state == 1.0 or "slip" in have,
               "differs from 1 (sticking) but the scene does not list the 'slip' effect: add 'slip' to "
               "effects, or leave tool.contact_state = 1")
        _check("tool.traverse_speed", tl.traverse_speed, tl.traverse_speed == 0.0 or "traverse" in have,
               "differs from 0 but the scene does not list the 'traverse' effect: add 'traverse' (and "
               "'tracers') to effects, or leave tool.traverse_speed = 0")
        _check("effects", self.effects, not ("slip" in have and "lagrangian" in have),
               "'slip' with 'lagrangian' is not supported: the plate edge would turn slower than the "
               "tool edge, separating the coincident interface pairs the moving cloud needs; use "
               "'tracers' (fixed points) instead of 'lagrangian'")

    def _validate_places(self):
        g = self.geometry
        names = [p.name for p in self.probes]
        _check("probes", names, len(set(names)) == len(names), "probe names must be unique")
        for i, p in enumerate(self.probes):
            r = math.hypot(p.x, p.y)
            where = "inside the tool" if r < g.R1 else "on the tool edge" if r == g.R1 else "outside the plate"
            _check(f"probes[{i}] ({p.name}).x, y", (p.x, p.y), g.R1 < r < g.R2,
                   f"must lie in the plate, geometry.R1 = {g.R1} < r < geometry.R2 = {g.R2}, but r = "
                   f"sqrt(x^2 + y^2) = {r:.6g} is {where}: move the registration point into the plate")
        names = [s.name for s in self.sections]
        _check("sections", names, len(set(names)) == len(names), "section names must be unique")
        for i, s in enumerate(self.sections):
            for key in ("start", "end"):
                pt = getattr(s, key)
                _check(f"sections[{i}].{key}", pt, math.hypot(*pt) <= g.R2 * (1 + 1e-12),
                       f"must lie in the disc r <= geometry.R2 = {g.R2}")

    def has(self, effect: str) -> bool:
        """Whether the scene lists ``effect``."""
        return effect in self.effects

    def with_overrides(self, overrides: dict) -> "Scene":
        """A new scene with ``{"section.field": value}`` replaced (values may be strings).

        Keys are :func:`override_keys` (e.g. ``material.K``, ``time.dt``, ``effects``); string
        values are parsed to the field's type (``"2e16"``, ``"conduction,robin"``).  The result
        is validated as a whole; an unknown key or bad value raises :class:`SceneError`.
        """
        _check("overrides", overrides, isinstance(overrides, dict), "expected a dict {'section.field': value}")
        top: dict = {}
        per_section: dict = {}
        allowed = override_keys()
        for key, value in overrides.items():
            _check("override key", key, key in allowed, f"known keys are {', '.join(allowed)}")
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
        d = {"name": self.name, "effects": list(self.effects)}
        for key in _SECTIONS:
            d[key] = _section_dict(getattr(self, key))
        d["probes"] = [_section_dict(p) for p in self.probes]
        d["sections"] = [_section_dict(s) for s in self.sections]
        return d

    @classmethod
    def from_dict(cls, data: dict, source: str = "scene") -> "Scene":
        """Scene from a dictionary in the TOML layout; unknown tables or keys raise :class:`SceneError`."""
        _check(source, data, isinstance(data, dict), "expected a table (dict) of scene sections")
        known = {"name", "effects", "probes", "sections", *_SECTIONS}
        for key in data:
            _check(f"{source}: top-level key", key, key in known, f"known keys are {sorted(known)}")
        kwargs = {k: data[k] for k in ("name", "effects") if k in data}
        for key, sec in _SECTIONS.items():
            if key in data:
                kwargs[key] = _section_from(sec, data[key], f"{source}: [{key}]")
        for key, sec in (("probes", Probe), ("sections", Section)):
            if key in data:
                items = data[key]
                _check(f"{source}: {key}", items, isinstance(items, list), f"expected [[{key}]] tables")
                kwargs[key] = tuple(_section_from(sec, it, f"{source}: [[{key}]] #{i}")
                                    for i, it in enumerate(items))
        return cls(**kwargs)


def _section_dict(obj) -> dict:
    return {f.name: (list(v) if isinstance(v := getattr(obj, f.name), tuple) else v)
            for f in dataclasses.fields(obj)}


def _section_from(cls, table, where: str):
    _check(where, table, isinstance(table, dict), "expected a table of key = value")
    names = {f.name for f in dataclasses.fields(cls)}
    for key in table:
        _check(f"{where} key", key, key in names, f"known keys are {sorted(names)}")
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
    _check(f"{path}: base", base, isinstance(base, str), "must be a scene name or a path to a .toml file")
    base_path = _scene_path(base, relative_to=path)
    _check(f"{path}: base", base, base_path.resolve() not in chain + (path.resolve(),),
           "makes a cycle of scenes built on each other")
    merged = _scene_table(base_path, chain + (path.resolve(),))
    for key, value in data.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = {**merged[key], **value}
        else:
            merged[key] = value
    return merged
