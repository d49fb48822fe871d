"""The effects a scene may list, one record each (:data:`REGISTRY`).

An effect is a part of the physics a scene switches on by name (``effects = [...]``).  Its
:class:`Effect` record is the one place that says what it is: its name and meaning, the effects
it requires and those it excludes (with the reason), its scene parameters with their ranges
(:class:`Parameter`: each becomes a constant of the residual's ``params["c"]``), the unknown
fields it creates, what it adds (:data:`ROLES`: momentum rows, heat rows, a heat source, a
moving boundary, the start flow, moving points) and the checks across scene fields that it
needs.  Everything else reads the records:

- scene validation (:mod:`jaxanm.fsw.scene`): names, requirements, exclusions, parameter ranges,
  a parameter off its default only with its effect listed, the effects' own checks;
- the residual's flags (:class:`Effects`, read by :mod:`jaxanm.fsw.physics`) and its constants
  (:data:`CONSTANTS`, filled by :meth:`jaxanm.fsw.discretisation.Model.constants`);
- the quasi-static start flow (:func:`jaxanm.fsw.start.flow_scene`: the effects with the role
  ``"start flow"``), the temperature guard (:mod:`jaxanm.fsw.stability`: ``"heat source"``)
  and the host hook (:mod:`jaxanm.fsw.lagrangian`: ``"moving points"``, the flags).

A new effect is a record here, its rows in :mod:`jaxanm.fsw.physics` and, if it has
parameters, their fields in :mod:`jaxanm.fsw.scene_sections`; ``tests/test_fsw_effects.py``
fails when one of them is missing.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Iterable

from ..errors import InputError

__all__ = ["BASE_CONSTANTS", "CONSTANTS", "EFFECTS", "Effect", "Effects", "FIELDS", "PECLET_MAX", "Parameter",
           "REGISTRY", "ROLES", "scene_value"]

ROLES = {
    "unknowns": "creates unknown fields (its entry in `fields`)",
    "momentum rows": "adds terms to the momentum rows, or rows of their own",
    "heat rows": "adds terms to the heat rows, or rows of their own",
    "heat source": "heats the material: the temperature guard leaves the upper bound open",
    "moving boundary": "moves a boundary of the flow (the plate at the tool edge, the ring r = R2)",
    "start flow": "kept by the quasi-static start flow (it changes the stationary momentum rows or their boundary "
                  "values)",
    "moving points": "moves the points of the cloud after every step (the host hook)",
    "tracers": "advects passive tracer particles after every step (the host hook)",
}
"""What an effect may add (:attr:`Effect.roles`), and what each means."""

FIELDS = ("u", "v", "T", "p")
"""Unknown fields in layout order (the unknowns are ``[u (N), v (N), T (N), p (N)]``, those of
the scene's effects only)."""

BASE_CONSTANTS = ("K", "A", "n", "eps0", "rho", "Cp", "k", "beta", "rho_t", "Cp_t", "k_t", "omega",
                  "h", "Ta", "T0", "lam", "dr", "U", "Ts", "mu_ref")
"""Scalars of ``params["c"]`` every scene has: material, tool, thermal data, the penalty, the
spacing at the tool edge and the scales (``U = omega R1``, ``Ts = T0``, ``mu_ref``)."""


@dataclasses.dataclass(frozen=True)
class Parameter:
    """A scene field that belongs to one effect.

    Attributes
    ----------
    key : str
        The scene key, ``"section.field"`` (e.g. ``"tool.traverse_speed"``).
    constant : str
        Its name in the residual's ``params["c"]``.
    low, high : float
        The closed range of its values.
    unit : str
        Its SI unit (``"1"``: a ratio).
    doc : str
        What it is.

    A scene whose effects do not list the parameter's effect must leave it at its default
    (the field's default in :mod:`jaxanm.fsw.scene_sections`): a value that would do nothing
    is refused rather than ignored.
    """

    key: str
    constant: str
    low: float
    high: float
    unit: str
    doc: str


Check = Callable[[object], list]
"""An effect's check across scene fields: ``check(scene) -> [(key, value, allowed), ...]``, the
fields whose values the effect cannot take, each with what is allowed (empty when none)."""


@dataclasses.dataclass(frozen=True)
class Effect:
    """One effect: its name, what it requires and excludes, its parameters and what it adds.

    Attributes
    ----------
    name : str
        The name a scene lists.
    doc : str
        What the effect does (one paragraph; its equations are in :mod:`jaxanm.fsw.physics`).
    roles : frozenset of str
        What it adds, among :data:`ROLES`.
    requires : tuple of str
        Effects it needs (the fields it acts on, the points it needs).
    excludes : tuple of (str, str)
        Effects it cannot be combined with, each with the reason and the alternative.
    parameters : tuple of Parameter
        Its scene fields.
    fields : tuple of str
        The unknown fields it creates (among :data:`FIELDS`).
    check : callable or None
        Its rules across scene fields (:data:`Check`).
    """

    name: str
    doc: str
    roles: frozenset = frozenset()
    requires: tuple = ()
    excludes: tuple = ()
    parameters: tuple = ()
    fields: tuple = ()
    check: Check | None = None

    def __post_init__(self):
        unknown = set(self.roles) - set(ROLES)
        if unknown:
            raise ValueError(f"effect {self.name!r}: unknown roles {sorted(unknown)}; known: {sorted(ROLES)}")
        if bool(self.fields) != ("unknowns" in self.roles):
            raise ValueError(f"effect {self.name!r}: the role 'unknowns' goes with fields, and only with them")


def scene_value(scene, key: str):
    """The value of the scene field ``"section.field"``."""
    section, field = key.split(".", 1)
    return getattr(getattr(scene, section), field)


def _lagrangian_check(scene) -> list:
    g = scene.geometry
    refused = []
    if g.layout == "graded":
        refused.append(("geometry.layout", g.layout,
                        "'lagrangian' on geometry.layout = 'graded' is not supported yet: the graded cloud is "
                        "validated on fixed points only (its rezoning and the tool edge sliding past the fine rings "
                        "are untested); use 'tracers' instead of 'lagrangian', or layout 'polar'"))
    if scene.time.scheme != "euler":
        refused.append(("time.scheme", scene.time.scheme,
                        "is invalid with the 'lagrangian' effect: the points move after every step and the state is "
                        "refitted on the rebuilt stencils, so the state a step starts from belongs to another "
                        "discretisation and the residual has no semi-discrete form (a multistep or Runge-Kutta "
                        "scheme would restart at every step); use time.scheme = 'euler', or 'tracers' instead of "
                        "'lagrangian'"))
    if scene.time.probe_dt > 0:
        refused.append(("time.probe_dt", scene.time.probe_dt,
                        "is invalid with the 'lagrangian' effect: its probes are material points, recorded where "
                        "each step takes them, and a step's dense output lives on the cloud the step started on; "
                        "use time.probe_dt = 0 (at every step), or 'tracers' instead of 'lagrangian'"))
    return refused


_LAGRANGIAN = (
    "'{e}' with 'lagrangian' is not supported: {why}; use 'tracers' (fixed points) instead of 'lagrangian'")

REGISTRY: dict = {}
"""Every effect's :class:`Effect`, by name, in the order the documentation lists them."""


def _register(*effects: Effect) -> None:
    for effect in effects:
        REGISTRY[effect.name] = effect


_register(
    Effect("viscous",
           "Momentum balance of the power-law fluid, incompressibility by the penalty `mechanics.penalty` (or "
           "by `incompressible`); creates the velocity unknowns u, v; the tool turns rigidly, the ring r = R2 "
           "is fixed.",
           frozenset({"unknowns", "momentum rows"}), fields=("u", "v")),
    Effect("inertia", "`rho dV/dt` in the momentum balance.", frozenset({"momentum rows"}), requires=("viscous",)),
    Effect("softening", "The viscosity depends on the temperature through `T^A` (else `T0^A`).",
           frozenset({"momentum rows"}), requires=("viscous", "conduction")),
    Effect("conduction", "The heat equation in the plate; creates the temperature unknowns T.",
           frozenset({"unknowns", "heat rows"}), fields=("T",)),
    Effect("tool_conduction",
           "The heat equation in the tool, T and heat flux continuous at r = R1 (else the plate edge r = R1 is "
           "insulated and the tool stays at T0).",
           frozenset({"heat rows"}), requires=("conduction",)),
    Effect("dissipation", "The heat source `q = 3 beta mu epsbar^2` of the plastic work.",
           frozenset({"heat rows", "heat source"}), requires=("viscous", "conduction")),
    Effect("robin", "`-k dT/dN = h (T - Ta)` at r = R2 (else that edge is insulated).",
           frozenset({"heat rows"}), requires=("conduction",)),
    Effect("lagrangian",
           "The points move with the material (`x <- x + dt V`, tool points rotate rigidly), stencils are "
           "rebuilt after every step, the cloud is re-seeded when sheared (`geometry.rezone`).",
           frozenset({"moving points"}), requires=("viscous",),
           excludes=(("tracers", "'lagrangian' (moving points) and 'tracers' (fixed points) exclude each other"),),
           check=_lagrangian_check),
    Effect("tracers",
           "Fixed (Eulerian) points: the transport terms `V . grad` in the heat and momentum rows, passive tracer "
           "particles advected for the mixing picture.",
           frozenset({"momentum rows", "heat rows", "tracers"}), requires=("viscous",)),
)


_SLIP = ("Partial sliding at the tool (Schmidt-Hattel's contact state delta = `tool.contact_state`): the "
         "plate at the tool edge moves at `delta omega (-y, x)` (the tool turns at omega), and the interface "
         "shear `tau(R1)` sliding at `(1 - delta) omega R1` releases `(1 - delta) omega R1 tau(R1)` W/m^2 of "
         "frictional heat at the interface, all of it heat, split between tool and plate by the interface's "
         "flux condition (delta = 1, sticking, is the paper's condition and gives its residual exactly).")

_TRAVERSE = ("The tool travels along +x at `U = tool.traverse_speed`; seen from the tool the ring r = R2 moves at "
             "(-U, 0) (the plate streams in on the leading side x > 0 and out on the trailing side), the inflow part "
             "of the ring lets the plate carry T0 in (the Robin row plus `rho Cp max(-V.N, 0) (T - T0)`), the "
             "outflow part keeps the Robin row, the transport terms `V . grad` carry the through-flow; tracers leave "
             "across the trailing side and re-enter on the leading side.  U = 0 gives the scene without it exactly.")


PECLET_MAX = 11.0
"""The largest cell Peclet number ``(omega R1 + U) dr / alpha`` at the tool edge (``dr`` its
spacing, ``alpha`` the plate's diffusivity) a travelling tool may ask for: the heat step's
transport term is collocated without upwinding, and on the weld's cloud under a uniform stream
it has no growing mode up to a cell Peclet number of 11 there and growing modes at the plate
edge at 33 (benchmarks/results/heat_peclet.md).  The window's speeds on the weld scenes' cloud
stay below 0.4."""


def _traverse_check(scene) -> list:
    t, g, m = scene.tool, scene.geometry, scene.material
    peclet = (t.omega * g.R1 + t.traverse_speed) * g.dr * m.rho * m.Cp / m.k
    if peclet > PECLET_MAX:
        return [("geometry.dr", g.dr,
                 f"gives the cell Peclet number (omega R1 + U) dr / alpha = {peclet:.3g} at the tool edge "
                 f"(tool.omega = {t.omega:g} rad/s, tool.traverse_speed = {t.traverse_speed:g} m/s), beyond "
                 f"{PECLET_MAX:g}, the largest at which the heat step's transport term was measured free of "
                 "growing modes (benchmarks/results/heat_peclet.md); refine geometry.dr or lower tool.omega")]
    return []


_register(
    Effect("slip", _SLIP,
           frozenset({"momentum rows", "heat rows", "heat source", "moving boundary", "start flow"}),
           requires=("viscous",),
           excludes=(("lagrangian", _LAGRANGIAN.format(
               e="slip", why="the plate edge would turn slower than the tool edge, separating the coincident "
                             "interface pairs the moving cloud needs")),),
           parameters=(Parameter("tool.contact_state", "delta", 0.0, 1.0, "1",
                                 "the plate's speed at the tool edge over the tool's (1 sticking, 0 full sliding)"),)),
    Effect("traverse", _TRAVERSE,
           frozenset({"momentum rows", "heat rows", "moving boundary", "start flow"}),
           requires=("viscous", "tracers"),
           excludes=(("lagrangian", _LAGRANGIAN.format(
               e="traverse", why="the plate streaming through the disc would carry the moving cloud out of it")),),
           parameters=(Parameter("tool.traverse_speed", "U_tr", 0.0, 0.1, "m/s",
                                 "the tool's travel speed along +x (travel along -x gives the same fields turned "
                                 "by 180 degrees)"),),
           check=_traverse_check),
)

def _incompressible_check(scene) -> list:
    penalty = scene.mechanics.penalty
    if penalty != 0.0:
        return [("mechanics.penalty", penalty,
                 "must be 0 with 'incompressible': the pressure holds div V = 0 at the points, and a penalty "
                 "would add lambda grad(div V) on top of it; set mechanics.penalty = 0")]
    return []


_register(
    Effect("incompressible",
           "Mass conservation by a pressure: the unknown field p, `-grad p` in the momentum rows (the penalty "
           "`mechanics.penalty` must be 0) and the continuity rows `div V = alpha h^2 / mu_ref Lap p` at the plate "
           "points (`alpha` the small pressure stabilisation of equal-order collocation), `p = 0` in the tool "
           "and at the leading point of the ring.  The through-flow of a travelling tool then passes the pin "
           "instead of compressing ahead of it.",
           frozenset({"unknowns", "momentum rows", "start flow"}), requires=("viscous",),
           excludes=(("lagrangian", _LAGRANGIAN.format(
               e="incompressible", why="a moving cloud's refit of the pressure is not validated (its circular "
                                       "flow is divergence-free by symmetry: the penalty suffices there)")),),
           parameters=(Parameter("mechanics.pressure_stabilisation", "alpha_p", 1e-3, 1.0, "1",
                                 "alpha of the continuity rows' pressure stabilisation div V = alpha h^2 / mu_ref "
                                 "Lap p (h the local spacing)"),),
           fields=("p",), check=_incompressible_check),
)

def _shoulder_check(scene) -> list:
    g, radius = scene.geometry, scene.tool.shoulder_radius
    if not g.R1 < radius <= g.R2:
        return [("tool.shoulder_radius", radius,
                 f"must be in (geometry.R1, geometry.R2] = ({g.R1:g}, {g.R2:g}] m: the shoulder covers the plate "
                 "from the pin outwards")]
    return []


_register(
    Effect("shoulder",
           "The tool's shoulder heats the plate's face under it: a heat input per area `tool.shoulder_flux` "
           "(W/m^2) over R1 < r <= `tool.shoulder_radius`, spread through the plate's thickness "
           "`geometry.thickness` (the source `q / H` in the plate's heat equation).",
           frozenset({"heat rows", "heat source"}), requires=("conduction",),
           parameters=(Parameter("tool.shoulder_flux", "q_sh", 0.0, 1e8, "W/m^2",
                                 "heat input per area of the plate's face under the shoulder"),
                       Parameter("tool.shoulder_radius", "R_sh", 1e-4, 0.1, "m", "the shoulder's radius"),
                       Parameter("geometry.thickness", "H", 1e-4, 0.1, "m",
                                 "the plate's thickness, through which the shoulder's heat spreads")),
           check=_shoulder_check),
)

EFFECTS = tuple(REGISTRY)
"""Effect names a scene may list, in the order of :data:`REGISTRY`."""

CONSTANTS = BASE_CONSTANTS + tuple(p.constant for e in REGISTRY.values() for p in e.parameters)
"""Scalars of ``params["c"]``: :data:`BASE_CONSTANTS` and every effect parameter's constant."""


class Effects:
    """The effect flags of a model: ``flags.slip`` is whether the scene lists ``slip``, one
    attribute per registered effect (hashable: one residual is compiled per combination).

    Parameters
    ----------
    names : iterable of str
        The effects switched on (registered names).
    """

    __slots__ = ("names",)
    names: frozenset[str]

    def __init__(self, names: Iterable[str] = ()):
        names = frozenset(names)
        unknown = sorted(names - set(REGISTRY))
        if unknown:
            raise InputError(f"unknown effects {unknown}; known effects are {EFFECTS}")
        object.__setattr__(self, "names", names)

    @classmethod
    def of(cls, scene) -> "Effects":
        """The effect flags of a scene."""
        return cls(scene.effects)

    def __getattr__(self, name: str) -> bool:
        if name in REGISTRY:
            return name in self.names
        raise AttributeError(f"{name!r} is no effect (known effects are {EFFECTS})")

    def __setattr__(self, name, value):
        raise AttributeError("Effects are immutable")

    def __eq__(self, other) -> bool:
        return isinstance(other, Effects) and self.names == other.names

    def __hash__(self) -> int:
        return hash(self.names)

    def __repr__(self) -> str:
        return f"Effects({sorted(self.names)})"

    def __reduce__(self):
        return Effects, (tuple(sorted(self.names)),)

    def any(self, role: str) -> bool:
        """Whether some effect switched on has ``role`` (one of :data:`ROLES`)."""
        if role not in ROLES:
            raise InputError(f"unknown role {role!r}; known: {sorted(ROLES)}")
        return any(role in REGISTRY[name].roles for name in self.names)

    @property
    def fields(self) -> tuple:
        """Unknown fields, in layout order (:data:`FIELDS`)."""
        made = {f for name in self.names for f in REGISTRY[name].fields}
        return tuple(f for f in FIELDS if f in made)

