"""The typed sections of an FSW scene (:class:`Geometry`, :class:`Material`, :class:`Tool`,
:class:`Thermal`, :class:`Mechanics`, :class:`Time`, :class:`SolverSpec`, :class:`Probe`,
:class:`Section`), the value conversions and range checks they run on creation, and the
limits they enforce.

Each section converts its fields to their declared types and checks their ranges when it is
built; a bad value raises :class:`SceneError` naming the field, the value and what is
allowed.  :mod:`jaxanm.fsw.scene` assembles them into a :class:`~jaxanm.fsw.scene.Scene`
(and re-exports them, so ``from jaxanm.fsw.scene import Geometry`` works).
"""

from __future__ import annotations

import dataclasses
import math
import warnings

from .. import scheme_names
from ..errors import InputError
from ..internal import make_solver, solver_kinds

__all__ = [
    "EDGE_ROWS",
    "EDGE_SOURCES",
    "Geometry",
    "KIND_ALIASES",
    "LAYOUTS",
    "MAX_ORDER",
    "MAX_POINTS",
    "MAX_SAMPLES",
    "MAX_STEPS",
    "Material",
    "OMEGA_MAX",
    "Mechanics",
    "Probe",
    "SOLVER_KINDS",
    "SOLVER_OPTIONS",
    "STARTS",
    "SceneError",
    "Section",
    "SolverSpec",
    "Thermal",
    "Time",
    "Tool",
]

LAYOUTS = ("polar", "grid", "graded")
EDGE_ROWS = ("flux", "half_cell")
EDGE_SOURCES = ("point", "exponential")
"""Temperature rows of the plate-edge points (:class:`Thermal`)."""
SOLVER_KINDS = solver_kinds()
"""The ``solver.kind`` values a scene accepts: the registered kinds (:func:`jaxanm.solver_kinds`),
the names the CLI's ``--solver`` and a sweep grid's ``kind`` take too.  A solver added to
``jaxanm/_solver/`` appears here by its kind."""
KIND_ALIASES = {"modified_newton": "mnewton"}
"""Former spellings of a ``solver.kind``, still read (with a :class:`DeprecationWarning`) -> the kind."""
STARTS = ("rest", "quasi_static", "continuation")
"""Flows at t = 0 (:class:`Mechanics`)."""
MAX_POINTS = 200_000
"""Largest point cloud a scene may ask for (about ``pi (R2 / dr)^2`` points): checked on load,
so that a typo in ``dr`` or ``R2`` fails at once instead of exhausting memory."""
MAX_STEPS = 10_000_000
"""Largest number of time steps ``t_end / dt`` a scene may ask for."""
MAX_ORDER = 30
"""Largest ANM series order a scene may ask for (the jet series compiles in a time that grows
steeply with the order: benchmarks/results/hard_cases.md)."""
OMEGA_MAX = 1000.0
"""Fastest tool rotation a scene may ask for (rad/s)."""
MAX_SAMPLES = 100_000
"""Largest number of samples of a registration section."""
NAME_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-.+")
"""Characters allowed in a scene's name and in the names it gives (effects, probes, sections)."""
_COLUMN_CHARS = NAME_CHARS - set("-.+")
"""Characters of a probe name: a CSV column name that readers (numpy's ``genfromtxt(names=True)``
in :mod:`jaxanm.fsw.compare`) keep as it is."""


class SceneError(InputError):
    """An invalid scene value or combination of options, found before any computation; the
    message names the field, the bad value and what is allowed (a :class:`jaxanm.InputError`)."""


def _fail(field: str, value, allowed: str):
    raise SceneError(f"scene field {field!r} = {value!r} is invalid: {allowed}")


def check(field: str, value, ok: bool, allowed: str) -> None:
    """Raise :class:`SceneError` naming ``field``, ``value`` and what is ``allowed`` unless ``ok``."""
    if not ok:
        _fail(field, value, allowed)


def _as_float(field: str, value) -> float:
    """A finite float from an int/float (or, for overrides, its string form)."""
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            _fail(field, value, "expected a real number, e.g. 2.69e16")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        _fail(field, value, "expected a real number")
    try:
        value = float(value)
    except OverflowError:
        _fail(field, value, "expected a finite real number (this integer is too large for a float)")
    check(field, value, math.isfinite(value), "expected a finite real number")
    return value


def _as_int(field: str, value) -> int:
    if isinstance(value, str):
        try:
            value = int(value)
        except ValueError:
            _fail(field, value, "expected an integer")
    if isinstance(value, bool) or not isinstance(value, int):
        _fail(field, value, "expected an integer")
    return int(value)


def as_str(field: str, value) -> str:
    """``value`` if it is a string, else :class:`SceneError` naming ``field``."""
    check(field, value, isinstance(value, str), "expected a string")
    return value


def _as_floats(field: str, value) -> tuple:
    """A tuple of floats from a list/tuple (or a comma-separated string)."""
    if isinstance(value, str):
        value = [v for v in (s.strip() for s in value.split(",")) if v]
    check(field, value, isinstance(value, (list, tuple)), "expected a list of real numbers")
    return tuple(_as_float(f"{field}[{i}]", v) for i, v in enumerate(value))


def as_strs(field: str, value) -> tuple:
    """A tuple of strings from a list/tuple (or a comma-separated string)."""
    if isinstance(value, str):
        value = [v for v in (s.strip() for s in value.split(",")) if v]
    check(field, value, isinstance(value, (list, tuple)), "expected a list of names")
    return tuple(as_str(f"{field}[{i}]", v) for i, v in enumerate(value))


def _as_bool(field: str, value) -> bool:
    """A bool from a bool (or, for overrides, ``true``/``false``)."""
    if isinstance(value, str) and value.strip().lower() in ("true", "false"):
        value = value.strip().lower() == "true"
    check(field, value, isinstance(value, bool), "expected true or false")
    return value


def _unset_or(convert):
    """``convert`` that keeps None (a setting left to its owner's default)."""
    return lambda field, value: None if value is None else convert(field, value)


_CONVERTERS = {"float": _as_float, "int": _as_int, "str": as_str, "bool": _as_bool,
               "tuple[float, ...]": _as_floats, "tuple[str, ...]": as_strs}
_CONVERTERS.update({f"{name} | None": _unset_or(conv) for name, conv in list(_CONVERTERS.items())})


class _Section:
    """Base of the scene's sections: converts every field to its declared type on creation."""

    _name = ""

    def __post_init__(self):
        for f in dataclasses.fields(self):
            conv = _CONVERTERS[f.type]
            object.__setattr__(self, f.name, conv(f"{self._name}.{f.name}", getattr(self, f.name)))
        self._validate()

    def _validate(self) -> None:
        """Range checks of the section's own fields (overridden per section)."""

    def _positive(self, *names: str) -> None:
        for name in names:
            value = getattr(self, name)
            check(f"{self._name}.{name}", value, value > 0, "must be > 0")


@dataclasses.dataclass(frozen=True)
class Geometry(_Section):
    """Disc of radius R2 around a tool of radius R1, covered by points ``dr`` apart (metres).

    ``layout``: ``"polar"`` (concentric rings ``dr`` apart, about ``2 pi r / dr`` points each,
    an even number so that no point lies on y = 0) or ``"grid"`` (a square grid of spacing
    ``dr`` clipped ``dr/2`` away from r = R1 and r = R2, plus the same boundary rings).
    Both put points on r = R2 and a pair of coincident points on r = R1 (one on the tool side,
    one on the plate side, see :mod:`jaxanm.fsw.geometry`).  The isothermal Couette
    validation converges on ``polar``; on ``grid`` its error stalls (about 3e-2 omega R1 at
    the grid points nearest the tool edge, from dr = (R2 - R1)/6 to /16).  The MLS influence radius is
    ``h_factor * dr``; ``c`` and ``q`` are the weight parameters of paper eq. 30.

    ``"graded"``: rings whose spacing follows the physics, fine across the shear
    band at the tool edge (about ``n R1 / 2`` wide, 0.1 mm at the paper's n = 0.1324) and
    coarse in the far field: ``dr`` is the spacing at the tool edge and across the plate's
    fine zone ``band`` (m) beyond R1; outwards from it (and inwards from R1 into the tool, at
    once) each ring gap is ``grading`` times the previous up to ``dr_far``; every ring holds
    about ``2 pi r`` over its spacing points, and each point's MLS influence radius is
    ``h_factor`` times its ring's spacing (``band``, ``dr_far`` and ``grading`` are used by
    this layout only).  fsw_tracers' physics on 1603 graded points (dr = 0.085 mm, band 0.17
    mm, dr_far 0.375 mm; scene ``fsw_graded``) errs in the temperature rise by 1.1-1.7 % over
    0.05-0.3 s with ``thermal.edge_source = "exponential"`` (4.4-4.7 % with the one-point
    source), against 12-14 % on 1727 and 9-11 % on 3369 uniform points
    (docs/notes/spatial_accuracy.md); it is validated on fixed points only, and a scene with
    ``lagrangian`` on it is refused.

    ``rezone`` (used by the ``lagrangian`` effect only; 0 = never): the plate points are
    re-seeded at their initial layout, and the state refitted there, once some plate point's
    nearest neighbour comes closer than ``rezone`` times its distance at the last seeding
    (the shear at the tool edge bunches the first rings; see :mod:`jaxanm.fsw.lagrangian`).

    ``thickness`` (m, used by the ``shoulder`` effect only): the plate's thickness, through which
    the shoulder's heat input per area spreads (the 2-D model's fields are uniform through it).
    """

    _name = "geometry"
    R1: float = 1.5e-3
    R2: float = 6e-3
    dr: float = 3.75e-4
    h_factor: float = 3.0
    layout: str = "polar"
    c: float = 0.2
    q: int = 1
    rezone: float = 0.0
    band: float = 0.0
    dr_far: float = 0.0
    grading: float = 1.25
    thickness: float = 3e-3

    def _validate(self):
        self._positive("R1", "R2", "dr", "c")
        check("geometry.R2", self.R2, self.R2 > self.R1, f"must exceed geometry.R1 = {self.R1}")
        check("geometry.dr", self.dr, self.dr <= (self.R2 - self.R1) / 2,
               f"must be <= (R2 - R1) / 2 = {(self.R2 - self.R1) / 2:.6g} (at least one ring of "
               f"points between tool and outer edge)")
        smallest = self.R2 * math.sqrt(math.pi / MAX_POINTS)  # about MAX_POINTS points (no overflow)
        check("geometry.dr", self.dr, self.dr >= smallest,
               f"with geometry.R2 = {self.R2} it asks for more than {MAX_POINTS} points (about "
               f"pi (R2/dr)^2): use dr >= {smallest:.3g}")
        check("geometry.h_factor", self.h_factor, 1.5 <= self.h_factor <= 6.0,
               "must be in [1.5, 6] (the paper uses 3)")
        check("geometry.layout", self.layout, self.layout in LAYOUTS, f"must be one of {LAYOUTS}")
        check("geometry.c", self.c, self.c <= 10.0, "must be in (0, 10] (weight exp(-(r/c)^(2q)), the paper uses 0.2)")
        check("geometry.q", self.q, 1 <= self.q <= 10, "must be an integer in [1, 10] (the paper uses 1)")
        if self.layout == "graded":
            check("geometry.dr_far", self.dr_far, self.dr <= self.dr_far <= (self.R2 - self.R1) / 2,
                   f"the graded layout's far-field spacing must be in [geometry.dr = {self.dr:.6g}, "
                   f"(R2 - R1) / 2 = {(self.R2 - self.R1) / 2:.6g}]")
            check("geometry.band", self.band, 0.0 <= self.band <= min(self.R1, self.R2 - self.R1) / 2,
                   f"the graded layout's fine zone on each side of R1 must be in [0, "
                   f"{min(self.R1, self.R2 - self.R1) / 2:.6g}] (m)")
            check("geometry.grading", self.grading, 1.0 < self.grading <= 2.0,
                   "must be in (1, 2]: the ratio of successive ring spacings of the graded layout")
        check("geometry.rezone", self.rezone, 0.0 <= self.rezone < 1.0,
               "must be in [0, 1): the fraction of a plate point's seeded nearest-neighbour distance "
               "below which the Lagrangian cloud is re-seeded (0: never; e.g. 0.9)")


@dataclasses.dataclass(frozen=True)
class Material(_Section):
    """Plate material (SI): ``mu = K T^A epsbar_reg^(n-1) / 3``, ``epsbar_reg = sqrt(epsbar^2 + eps0^2)``.

    K in Pa s^n K^-A (the paper's 2.69e10 N/mm^2 is 2.69e16 Pa), density ``rho``, heat
    capacity ``Cp``, conductivity ``k``, dissipated fraction ``beta`` of the mechanical power.

    ``eps0_relative`` (0: unused): when > 0, the regularisation follows the tool's rotation,
    ``eps0 = eps0_relative * omega`` (and ``eps0`` is unused), so that it stays the same
    fraction of the flow's strain rates at every rotation speed (the flow of the regularised
    law depends on ``eps0 / omega`` only); :meth:`jaxanm.fsw.scene.Scene.eps0` is the value used.
    """

    _name = "material"
    K: float = 2.69e16
    A: float = -3.3155
    n: float = 0.1324
    eps0: float = 0.1
    rho: float = 2780.0
    Cp: float = 920.0
    k: float = 140.0
    beta: float = 0.9
    eps0_relative: float = 0.0

    def _validate(self):
        self._positive("K", "n", "eps0", "rho", "Cp", "k")
        check("material.eps0_relative", self.eps0_relative, 0.0 <= self.eps0_relative <= 1.0,
               "must be in [0, 1] (0: material.eps0 is used as it is; e.g. 0.005, the paper's scenes' "
               "0.1 1/s at omega = 20 rad/s)")
        check("material.n", self.n, self.n <= 2.0, "must be in (0, 2] (power-law index)")
        check("material.A", self.A, -20.0 <= self.A <= 20.0, "must be in [-20, 20]")
        check("material.beta", self.beta, 0.0 <= self.beta <= 1.0, "must be in [0, 1]")


@dataclasses.dataclass(frozen=True)
class Tool(_Section):
    """Tool (steel): density, heat capacity, conductivity (SI), rotation speed ``omega`` (rad/s,
    at most :data:`OMEGA_MAX`), contact state and travel speed.

    ``contact_state`` (the ``slip`` effect): Schmidt-Hattel's delta in [0, 1], the plate's
    tangential velocity at the tool edge over the tool's, ``delta omega R1``; 1 is sticking
    (the paper's condition), 0 full sliding.  ``traverse_speed`` (the ``traverse`` effect):
    the tool's travel speed U >= 0 (m/s) along +x; the plate streams past it at (-U, 0).
    ``shoulder_flux`` (W/m^2) and ``shoulder_radius`` (m, the ``shoulder`` effect): the heat
    input per area of the plate under the shoulder, R1 < r <= shoulder_radius.  Each must keep
    its default unless the scene lists its effect; their ranges are those of their effects'
    records (:data:`jaxanm.fsw.effects.REGISTRY`), checked with the scene.
    """

    _name = "tool"
    rho: float = 7800.0
    Cp: float = 450.0
    k: float = 36.0
    omega: float = 20.0
    contact_state: float = 1.0
    traverse_speed: float = 0.0
    shoulder_flux: float = 0.0
    shoulder_radius: float = 4.5e-3

    def _validate(self):
        self._positive("rho", "Cp", "k", "omega")
        check("tool.omega", self.omega, self.omega <= OMEGA_MAX,
               f"must be in (0, {OMEGA_MAX:g}] rad/s ({OMEGA_MAX * 30 / math.pi:.0f} rpm, beyond friction stir "
               "welding practice, 30-300 rad/s)")


@dataclasses.dataclass(frozen=True)
class Thermal(_Section):
    """Robin coefficient ``h`` (W/m^2/K), ambient ``Ta`` and initial ``T0`` temperatures (K).

    ``edge_rows``: the temperature rows of the plate-edge points at r = R1, one of
    :data:`EDGE_ROWS`.  ``"flux"`` collocates the flux condition alone there (the heat
    dissipated within half a spacing of the tool edge then never enters the discrete balance);
    ``"half_cell"`` collocates the heat balance of the edge cell, flux condition folded in
    (:mod:`jaxanm.fsw.physics`, docs/notes/energy_balance.md).

    ``edge_source`` (``"half_cell"`` only): how that balance counts the dissipation in the plate
    half cell ``[R1, R1 + dr/2]``, one of :data:`EDGE_SOURCES`.  ``"point"`` takes ``q(R1) dr/2``;
    ``"exponential"`` integrates ``q`` along its local decay, measured by the MLS gradient at the
    edge point (the source falls by e within about 0.09 mm of the tool at the paper's n, so the
    point value over-counts once the edge spacing resolves that; docs/notes/spatial_accuracy.md).
    """

    _name = "thermal"
    h: float = 1000.0
    Ta: float = 300.0
    T0: float = 300.0
    edge_rows: str = "flux"
    edge_source: str = "point"

    def _validate(self):
        check("thermal.h", self.h, self.h >= 0, "must be >= 0")
        self._positive("Ta", "T0")
        check("thermal.edge_rows", self.edge_rows, self.edge_rows in EDGE_ROWS, f"must be one of {EDGE_ROWS}")
        check("thermal.edge_source", self.edge_source, self.edge_source in EDGE_SOURCES,
               f"must be one of {EDGE_SOURCES}")
        check("thermal.edge_source", self.edge_source,
               self.edge_source == "point" or self.edge_rows == "half_cell",
               'integrates the source of the edge half cell: needs thermal.edge_rows = "half_cell"')


@dataclasses.dataclass(frozen=True)
class Mechanics(_Section):
    """Penalty factor ``lambda`` (Pa s) of ``p = -lambda tr(epsdot)`` (paper eq. 9), and the flow at t = 0.

    ``pressure_stabilisation`` (the ``incompressible`` effect, whose record gives its range): the
    ``alpha`` of the continuity rows ``div V = alpha h^2 / mu_ref Lap p``; the penalty is then 0.

    ``start``: ``"rest"`` (the default: the plate at rest, the tool turning; the first step's
    iteration starts there), ``"quasi_static"`` (the stationary flow the momentum rows hold
    at T0, solved on the run's cloud before the first step by damped Newton,
    :mod:`jaxanm.fsw.start`) or ``"continuation"`` (the same flow by the ANM's path following
    in the strain-rate regularisation).  The
    momentum rows are quasi-static (their inertia spins the plate up in ~1e-8 s), so both
    describe the same physics; from rest Newton's first step does not converge on graded
    clouds finer than 0.085 mm at the tool edge (docs/notes/start_from_rest.md).  Needs the
    ``viscous`` effect.
    """

    _name = "mechanics"
    penalty: float = 0.0
    start: str = "rest"
    pressure_stabilisation: float = 0.01

    def _validate(self):
        check("mechanics.penalty", self.penalty, self.penalty >= 0, "must be >= 0 (Pa s)")
        check("mechanics.start", self.start, self.start in STARTS,
               f"must be one of {STARTS}: the plate at rest at t = 0, or the quasi-static flow at T0 "
               "(by damped Newton or by continuation)")


@dataclasses.dataclass(frozen=True)
class Time(_Section):
    """Time ``scheme``, step ``dt``, end time ``t_end`` (s) and the times at which fields are saved.

    ``scheme``: ``"euler"`` (implicit Euler, the paper's), ``"bdf2"``, ``"esdirk3"`` or
    ``"esdirk4"`` (:func:`jaxanm.make_scheme`); the stages of the last three are built from the
    scene's residual in semi-discrete form, so they need fixed points (the scene refuses them
    with the ``lagrangian`` effect).

    Save times after ``t_end`` are ignored (so a shortened run keeps the scene's list);
    t = 0 and t = t_end are always saved.  ``adaptive = true``: step sizes from a local error
    estimate (:class:`jaxanm.StepController`), ``dt`` the first step's, the local error of the
    field values at the points below ``atol`` times their scale (omega R1 for u and v, T0 for
    T) plus ``rtol`` times their size; a Lagrangian scene also bounds the steps by the point
    motion (:func:`jaxanm.fsw.lagrangian.motion_dt_max`), and ``dt_max > 0`` bounds them
    (0: no bound of the scene's own).  Both tolerances are finite, in ``[0, 1)`` with
    ``adaptive`` and not both 0 (always ``>= 0``; unused without ``adaptive``).

    ``probe_dt > 0`` samples the probes every ``probe_dt`` (and at ``t_end``, the one sample
    of a run shorter than ``probe_dt``) from the time
    scheme's dense output between the steps' ends (:attr:`jaxanm.SaveAt.fn_ts`), so their
    histories do not depend on the steps the controller takes; 0: at every step.  It needs
    fixed points (a Lagrangian scene's probes are material points, recorded where each step
    takes them).
    """

    _name = "time"
    scheme: str = "euler"
    dt: float = 1e-4
    t_end: float = 0.7
    save: tuple[float, ...] = ()
    adaptive: bool = False
    rtol: float = 0.0
    atol: float = 1e-5
    dt_max: float = 0.0
    probe_dt: float = 0.0

    def _validate(self):
        check("time.scheme", self.scheme, self.scheme in scheme_names(),
               f"must be one of {', '.join(scheme_names())} (implicit Euler, BDF2, Kværnø's ESDIRKs of order 3 "
               "and 4)")
        self._positive("dt", "t_end")
        check("time.dt_max", self.dt_max, self.dt_max >= 0,
               "must be >= 0 (s): the largest adaptive step, 0 for no bound of the scene's own")
        for name in ("rtol", "atol"):
            value = getattr(self, name)
            check(f"time.{name}", value, value >= 0, "must be >= 0 (0 leaves its part out of the error test)")
            check(f"time.{name}", value, value < 1 or not self.adaptive,
                   "must be < 1 with time.adaptive = true: the tolerances are relative (atol to the fields' "
                   "scales omega R1 and T0, rtol to their values), and 1 accepts an error the size of the "
                   "field itself; e.g. 1e-5")
        check("time.atol", self.atol, self.rtol > 0 or self.atol > 0 or not self.adaptive,
               "time.rtol or time.atol must be > 0 with time.adaptive = true (with both 0 the error test "
               "accepts no step): set e.g. time.atol = 1e-5, or time.adaptive = false")
        check("time.dt", self.dt, self.dt <= self.t_end, f"must be <= time.t_end = {self.t_end}")
        check("time.dt", self.dt, self.dt * MAX_STEPS >= self.t_end,
               f"time.t_end / time.dt asks for more than {MAX_STEPS} steps: use dt >= "
               f"{self.t_end / MAX_STEPS:.3g} or a shorter t_end")
        check("time.probe_dt", self.probe_dt, self.probe_dt >= 0,
               "must be >= 0 (s): the probes' sampling interval, 0 to record them at every step")
        check("time.probe_dt", self.probe_dt, self.probe_dt == 0 or self.probe_dt * MAX_STEPS >= self.t_end,
               f"time.t_end / time.probe_dt asks for more than {MAX_STEPS} probe samples: use probe_dt >= "
               f"{self.t_end / MAX_STEPS:.3g}")
        for i, s in enumerate(self.save):
            check(f"time.save[{i}]", s, s >= 0, "save times must be >= 0")

    @property
    def save_times(self) -> tuple:
        """Sorted save times within [0, t_end], with 0 and t_end included."""
        return tuple(sorted({0.0, self.t_end, *(s for s in self.save if s <= self.t_end)}))

    @property
    def probe_times(self) -> tuple:
        """The times the probes are sampled at after t = 0 with ``probe_dt > 0`` (multiples of
        it, and ``t_end``); empty with ``probe_dt = 0`` (at every step)."""
        if self.probe_dt == 0:
            return ()
        count = math.floor(self.t_end / self.probe_dt * (1 + 1e-12))
        return tuple(sorted({*(k * self.probe_dt for k in range(1, count + 1) if k * self.probe_dt < self.t_end),
                             self.t_end}))


@dataclasses.dataclass(frozen=True)
class SolverSpec(_Section):
    """Nonlinear step solver: ``kind`` (a registered kind, ``anm | newton | mnewton``; the former
    ``modified_newton`` is read as ``mnewton``, with a :class:`DeprecationWarning`) and
    the settings of that kind's solver, handed as they are to :func:`jaxanm.make_solver`, which
    validates them.  A setting the scene does not give (None) is the solver's own default
    (:class:`jaxanm.ANM`, :class:`jaxanm.Newton`, :class:`jaxanm.ModifiedNewton`): the defaults
    live in the solvers alone.  The keys are the solvers' options (their dataclass fields,
    :data:`SOLVER_OPTIONS`): ``tol``; ANM ``order``, ``criterion``, ``max_substeps``,
    ``adaptive``, ``homotopy``, ``pade``; the Newton solvers' ``max_iter`` (0: the solver's own
    default, as unset) and ``max_rate`` (the ANM's and modified Newton's).  A setting is passed
    on only to a solver that takes it.  The scene adds one rule of its own: ``order`` at most
    :data:`MAX_ORDER`."""

    _name = "solver"
    kind: str = "anm"
    order: int | None = None
    tol: float | None = None
    criterion: str | None = None
    max_substeps: int | None = None
    adaptive: bool | None = None
    homotopy: str | None = None
    pade: bool | None = None
    max_iter: int | None = None
    max_rate: float | None = None

    def _validate(self):
        if self.kind in KIND_ALIASES:
            warnings.warn(f"solver.kind = {self.kind!r} is deprecated: write {KIND_ALIASES[self.kind]!r}",
                          DeprecationWarning, stacklevel=5)
            object.__setattr__(self, "kind", KIND_ALIASES[self.kind])
        check("solver.kind", self.kind, self.kind in SOLVER_KINDS, f"must be one of {SOLVER_KINDS}")
        if self.order is not None:
            check("solver.order", self.order, self.order <= MAX_ORDER,
                  f"must be at most {MAX_ORDER}: the jet series compiles in a time that grows steeply with the order")
        try:
            self.make()
        except InputError as exc:  # the solver's own check, under the scene keys it came from
            names = self._refused_settings()
            if len(names) == 1:
                _fail(f"solver.{names[0]}", getattr(self, names[0]), str(exc))
            _fail(" and ".join(f"solver.{n}" for n in names) or "solver",
                  {n: getattr(self, n) for n in names} if names else self.options(), str(exc))

    def _refused_settings(self) -> list:
        """The settings the kind's solver refuses: the first refused alone (each tried on the
        solver's defaults), else those without which the rest is accepted (a refused
        combination, e.g. ``pade`` with a low ``order``)."""
        kind, given = self.kind, self.options()

        def refused(options: dict) -> bool:
            try:
                make_solver(kind, **options)
            except InputError:
                return True
            return False

        alone = [name for name, value in given.items() if refused({name: value})]
        if alone:
            return alone[:1]
        return [name for name in given if not refused({k: v for k, v in given.items() if k != name})]

    def options(self) -> dict:
        """The settings the scene gives that the kind's solver takes, as its keyword arguments
        (unset ones, and ``max_iter`` = 0, left out: the solver's defaults)."""
        opts = {name: getattr(self, name) for name in SOLVER_OPTIONS[self.kind]}
        return {k: v for k, v in opts.items() if v is not None and not (k == "max_iter" and v == 0)}

    def setting(self, name: str):
        """The value of option ``name`` the scene's solver runs with: the scene's, else the
        solver's default (None when the kind takes no such option)."""
        return getattr(self.make(), name, None)

    @staticmethod
    def defaults(name: str) -> dict:
        """The default of option ``name`` per kind whose solver takes it (the solver's own:
        what an unset ``solver.<name>`` means)."""
        return {kind: fields[name].default for kind in SOLVER_KINDS if name in (fields := _solver_fields(kind))}

    def make(self):
        """The :mod:`jaxanm` solver of this kind with these settings (e.g. ``jaxanm.ANM``), built by
        :func:`jaxanm.make_solver`, which validates them."""
        return make_solver(self.kind, **self.options())


def _solver_fields(kind: str) -> dict:
    """The options of the registered solver ``kind``: name -> dataclass field (every step solver
    is a dataclass: its fields are its options)."""
    solver = make_solver(kind)
    assert dataclasses.is_dataclass(solver)
    return {f.name: f for f in dataclasses.fields(solver) if f.init}


def _scene_options(kind: str) -> tuple:
    """The ``solver.*`` fields the registered solver ``kind`` takes, in the scene's order."""
    takes = _solver_fields(kind)
    return tuple(f.name for f in dataclasses.fields(SolverSpec) if f.name in takes)


SOLVER_OPTIONS = {kind: _scene_options(kind) for kind in SOLVER_KINDS}
"""For each registered solver kind, the ``solver.*`` fields of a scene its solver takes (in the
scene's order): what :meth:`SolverSpec.make` passes on, and the settings a sweep's ``[[solvers]]``
entry may give for that kind."""


@dataclasses.dataclass(frozen=True)
class Probe(_Section):
    """A registration point ``(x, y)`` (m) in the plate, ``R1 < r < R2``, whose u, v and T a run
    records at every step.

    In a fixed-point scene (no ``lagrangian`` effect) the fields are taken at ``(x, y)``
    itself (MLS values there, :class:`jaxanm.fsw.record.ProbeSites`): the same quantity on
    every cloud.  In a Lagrangian scene the probe is a material point: the plate point nearest
    ``(x, y)`` at t = 0, followed as it moves, with its own values (the paper's registration
    points; :func:`jaxanm.fsw.record.probe_points`).  ``summary.json`` (``probe_positions``)
    says where each probe was.  ``name``: letters, digits and ``_`` (it names the columns
    ``<name>_u, <name>_v, <name>_T`` of ``probes.csv``), not ``t``.
    """

    _name = "probes"
    name: str = ""
    x: float = 0.0
    y: float = 0.0

    def _validate(self):
        check("probes.name", self.name, 0 < len(self.name) <= 50 and set(self.name) <= _COLUMN_CHARS
               and self.name != "t",
               "must be 1-50 letters, digits or '_' other than 't' (it names the probes.csv columns "
               "<name>_u, <name>_v, <name>_T)")


@dataclasses.dataclass(frozen=True)
class Section(_Section):
    """A registration section: ``samples`` points on the segment from ``start`` to ``end`` (m)."""

    _name = "sections"
    name: str = ""
    start: tuple[float, ...] = (0.0, 0.0)
    end: tuple[float, ...] = (0.0, 0.0)
    samples: int = 161

    def _validate(self):
        check("sections.name", self.name, bool(self.name), "must be a non-empty name")
        for key in ("start", "end"):
            check(f"sections.{key}", getattr(self, key), len(getattr(self, key)) == 2,
                   "must be a point [x, y]")
        check("sections.samples", self.samples, 2 <= self.samples <= MAX_SAMPLES,
               f"must be an integer in [2, {MAX_SAMPLES}]")
