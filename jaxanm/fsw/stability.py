"""Stability of the implicit-Euler heat step, and a guard that ends a run whose temperatures
leave the range the continuum keeps them in.

The heat rows of a step residual are, for fixed velocity, ``D(dt) [M (T - T_old) / dt + K T
+ f]``: ``M`` the value rows of the collocation points that carry a heat equation (zero rows
for the edge and boundary conditions), ``K`` the conduction (and transport) operator, ``D`` the
row scalings of :mod:`jaxanm.fsw.physics`.  The semi-discrete system ``M T' = -K T - f`` has
the modes ``K v = -mu M v``, which grow like ``exp(mu t)``; implicit Euler multiplies each by
``1 / (1 - dt mu)`` per step.  Both tangents of the residual, ``J_new = dR/dT = D (M / dt + K)``
and ``J_old = dR/dT_old = -D M / dt``, give the step's amplification matrix
``-J_new^-1 J_old = (M / dt + K)^-1 M / dt`` whatever ``D`` is; :func:`heat_modes` returns its
eigenpairs, each with its ``mu`` and where its values lie on the cloud.

The continuum has no growing mode (the heat equation with a Robin or flux boundary is
dissipative), and a symmetric Galerkin discretisation inherits that from its energy identity.
Strong-form collocation has no such identity: the collocated operator is not symmetric, and at
the tool/plate interface the edge pairs carry two conditions without storage (equal
temperature, equal flux, each with one-sided MLS derivatives), through which the edge
parameters follow the neighbouring rings and feed back into their heat equations with no
guaranteed sign.  Depending on the spacing, the weight c and the edge rows this gives modes
with ``mu > 0`` on the edge pairs (docs/notes/collocation_stability.md).  Implicit Euler hides
a mode with ``dt mu > 2`` (``|1 / (1 - dt mu)| < 1``) and amplifies one with ``0 < dt mu < 2``.
The step solvers cannot reject such steps: each is solved correctly, it is the discrete system
that diverges.

:class:`TemperatureGuard` is the run-time check: by the minimum principle the temperature never
falls below ``min(T0, Ta)`` (every source is a heating), and without dissipation it never rises
above ``max(T0, Ta)``.  A state outside those bounds by more than a margin ends the run with a
:class:`DivergenceError` that says where, by how much, how fast the changes grew, and which mode
of the initial heat step grows.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

import jaxanm

from ..internal import entry_point
from .discretisation import Model
from .geometry import PLATE, PLATE_EDGE, RING, TOOL, TOOL_EDGE

__all__ = ["DivergenceError", "HeatMode", "KIND_NAMES", "MARGIN", "TemperatureGuard", "heat_modes", "heat_tangents"]

KIND_NAMES = {TOOL: "TOOL", TOOL_EDGE: "TOOL_EDGE", PLATE_EDGE: "PLATE_EDGE", PLATE: "PLATE", RING: "RING"}
"""Names of the point kinds of :mod:`jaxanm.fsw.geometry`, for reports."""

MARGIN = 0.25
"""The guard's default overshoot, a fraction of the temperature scale.  Measured largest
undershoots of the nodal temperatures below min(T0, Ta), relative to the rise: 2.8 % on
fsw_small (0.01 s, one spacing from the tool centre in the first steps), 0.7 % on fsw_tracers
(0.01 s), 0.2 % on calibration_small; conduction_small stays inside [Ta, T0]
(docs/notes/collocation_stability.md)."""

ZERO_AMPLIFICATION = 1e-10
"""Eigenvalues of the amplification matrix below this are the algebraic rows' zeros (the
edge and boundary conditions carry no d/dt: their old values drop out), not modes."""


@dataclasses.dataclass(frozen=True)
class HeatMode:
    """One mode of the implicit-Euler heat step (see the module docstring).

    Attributes
    ----------
    mu : complex
        Growth rate (1/s) of the semi-discrete mode, ``K v = -mu M v``: it grows when
        ``mu.real > 0``.
    amplification : complex
        Factor ``1 / (1 - dt mu)`` by which one implicit-Euler step of size ``dt`` multiplies it.
    dt : float
        The step size of ``amplification`` (s).
    values : (N,) complex ndarray
        The mode's temperature values at the collocation points (MLS values of its nodal
        parameters), scaled to a largest modulus of 1.
    nodal : (N,) complex ndarray
        Its temperature nodal parameters, scaled as ``values``.
    share : dict
        Kind name (:data:`KIND_NAMES`) -> fraction of ``sum |values|^2`` at points of that kind.
    kind : str
        Kind of the point where ``|values|`` is largest.
    radius : float
        Radius (m) of that point.
    """

    mu: complex
    amplification: complex
    dt: float
    values: np.ndarray
    nodal: np.ndarray
    share: dict
    kind: str
    radius: float

    def describe(self) -> str:
        """One line: ``mu``, the amplification per step and where the mode lives."""
        where = ", ".join(f"{k} {s:.2f}" for k, s in sorted(self.share.items(), key=lambda kv: -kv[1]) if s >= 0.01)
        mu = f"{self.mu.real:+.4g}" + (f" {self.mu.imag:+.3g}i" if abs(self.mu.imag) > 1e-9 * abs(self.mu) else "")
        return (f"mu = {mu} 1/s, amplification {_complex(self.amplification)} per step of {self.dt:g} s, "
                f"largest at a {self.kind} point (r = {self.radius * 1e3:.4g} mm; shares {where})")


def _complex(z: complex) -> str:
    """``z`` for a message: its real part when it is real, else both parts and the modulus."""
    return f"{z.real:.4g}" if abs(z.imag) <= 1e-9 * abs(z) else f"{z.real:.4g}{z.imag:+.3g}i (|.| = {abs(z):.4g})"


COLUMN_BATCH = 64
"""Tangent columns computed at once (``lax.map`` batches bound the memory of the stencil
intermediates, ``64 N m`` floats)."""


@functools.partial(jax.jit, static_argnums=(0, 1))
def _columns(residual, old: bool, x, seeds, t, dt, params):
    """``dR/dx_new @ seed`` (or ``dR/dx_old @ seed`` with ``old``) at ``x_new = x_old = x``
    for each row of ``seeds``, by forward-mode products."""
    def f(y):
        return residual(x, y, t, dt, params) if old else residual(y, x, t, dt, params)

    return jax.lax.map(lambda s: jax.jvp(f, (x,), (s,))[1], seeds, batch_size=COLUMN_BATCH)


@entry_point
def heat_tangents(model: Model, params: dict, x, dt: float, t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """The temperature rows' tangents with respect to the temperature unknowns, dense.

    One forward-mode product per temperature unknown (no colouring: the analysis is dense
    anyway, and one compiled function per cloud size serves every call).

    Parameters
    ----------
    model : Model
        The discretised scene (needs the ``conduction`` effect).
    params : dict
        The residual's parameters (:meth:`Model.params`).
    x : (n,) array
        The state: the tangents are taken at ``x_new = x_old = x``, the other fields held.
    dt, t : float
        Step size and time passed to the residual.

    Returns
    -------
    tuple of (N, N) ndarray
        ``dR_T/dT_new`` and ``dR_T/dT_old``.
    """
    if "T" not in model.fields:
        raise jaxanm.InputError("the scene has no temperature unknowns (effect 'conduction'): no heat step to analyse")
    N = model.cloud.size
    first = model.fields.index("T") * N
    seeds = np.zeros((N, model.size))
    seeds[np.arange(N), first + np.arange(N)] = 1.0
    args = (jnp.asarray(x, dtype=jnp.float64), jnp.asarray(seeds), jnp.float64(t), jnp.float64(dt), params)
    new, old = (np.asarray(_columns(model.residual, o, *args))[:, first:first + N].T for o in (False, True))
    return new, old


@entry_point
def heat_modes(model: Model, params: dict, x, dt: float, count: int = 4, t: float = 0.0,
               by: str = "mu") -> list[HeatMode]:
    """The ``count`` rightmost modes (largest ``mu.real``) of the implicit-Euler heat step, or
    with ``by="amplification"`` those that one step of ``dt`` amplifies most.

    Parameters
    ----------
    model : Model
        The discretised scene (needs the ``conduction`` effect).
    params : dict
        The residual's parameters (:meth:`Model.params`): the cloud and its stencils.
    x : (n,) array
        The state at which the step is linearised (the heat rows of a pure conduction scene are
        linear: any state).
    dt : float
        Step size (s): the amplification ``1 / (1 - dt mu)`` is that of this step.
    count : int
        How many modes to return.
    t : float
        Time passed to the residual.
    by : str
        ``"mu"`` (the semi-discrete growth rate: what grows at some step size) or
        ``"amplification"`` (``|1 / (1 - dt mu)|``: what grows at this one).

    Returns
    -------
    list of HeatMode
        Largest first.  A dense eigen-decomposition of the N x N amplification matrix
        ``-J_new^-1 J_old`` (module docstring): meant for clouds of a few thousand points.
    """
    if by not in ("mu", "amplification"):
        raise jaxanm.InputError(f"by must be 'mu' or 'amplification', got {by!r}")
    new, old = heat_tangents(model, params, x, dt, t)
    lam, vectors = scipy.linalg.eig(-np.linalg.solve(new, old))
    keep = np.abs(lam) > ZERO_AMPLIFICATION
    lam, vectors = lam[keep], vectors[:, keep]
    mu = (1.0 - 1.0 / lam) / dt
    order = np.argsort(-mu.real if by == "mu" else -np.abs(lam))[:count]
    st = params["st"]
    index, phi = np.asarray(st.index), np.asarray(st.phi)
    kind = model.cloud.kind
    radius = np.hypot(*np.asarray(params["xy"]).T)
    modes = []
    for j in order:
        values = np.sum(phi * vectors[index, j], axis=1)
        top = values[np.argmax(np.abs(values))]
        values, nodal = values / top, vectors[:, j] / top
        weight = np.abs(values) ** 2
        share = {name: float(weight[kind == k].sum() / weight.sum()) for k, name in KIND_NAMES.items()}
        peak = int(np.argmax(weight))
        modes.append(HeatMode(mu=complex(mu[j]), amplification=complex(lam[j]), dt=float(dt), values=values,
                              nodal=nodal, share=share, kind=KIND_NAMES[int(kind[peak])], radius=float(radius[peak])))
    return modes


class DivergenceError(jaxanm.StepFailure):
    """A temperature left its physical range (:class:`TemperatureGuard`).

    A :class:`jaxanm.StepFailure` whose message says where, by how much and how fast; besides
    ``step``, ``t``, ``amax`` and ``residual_norm`` it carries:

    Attributes
    ----------
    value : float
        The temperature parameter (K) furthest outside the range.
    bound : float
        The bound it crossed (K): the range widened by the guard's margin.
    growth : float or None
        The largest change of a step over that of the step before (None at the first step).
    kind : str
        Kind (:data:`KIND_NAMES`) of the point ``value`` belongs to.
    radius : float
        That point's radius (m) in the initial cloud.
    modes : list of HeatMode
        The modes of the initial heat step that the step size amplifies most (empty if not
        computed).
    """

    def __init__(self, reason, *, value, bound, growth, kind, radius, modes, **where):
        super().__init__(reason, **where)
        self.value, self.bound, self.growth = float(value), float(bound), growth
        self.kind, self.radius, self.modes = kind, float(radius), list(modes)


class TemperatureGuard:
    """The run-time check of the temperatures against the range the continuum keeps them in.

    The heat equation with non-negative sources (dissipation), a Robin boundary at ``Ta`` and
    the initial ``T0`` keeps ``T >= min(T0, Ta)`` (minimum principle), and without sources also
    ``T <= max(T0, Ta)``.  The discrete solution may overshoot these a little (MLS is not
    monotone); a temperature parameter beyond them by more than ``margin`` times the
    temperature scale is a diverging mode, and :meth:`check` raises a :class:`DivergenceError`.
    The scale is ``|T0 - Ta|``, or with dissipation the largest rise above ``max(T0, Ta)`` so
    far (this step's included) if that is larger.  A spurious mode has lobes of both signs (it
    is orthogonal to the smooth physical decay), so its trough crosses the lower bound once it
    is deeper than ``margin`` times its own crest: a mode that heats much more than it cools,
    or that stays below the physical heating, is not caught.  Nodal parameters are checked, not
    values: they are what the step carries, and they differ from the values by a smoothing of
    condition number ~3.

    Parameters
    ----------
    model : Model
        The discretised scene (needs the ``conduction`` effect).
    params, x0 : dict and (n,) array, optional
        The initial parameters and state: when given (and the cloud has at most
        ``diagnose_max`` points) the error names the mode of the initial heat step that the
        step amplifies most (:func:`heat_modes`).
    margin : float
        Allowed overshoot, as a fraction of the temperature scale.
    diagnose_max : int
        Largest cloud for the dense eigen-analysis of the error message.
    """

    def __init__(self, model: Model, params: dict | None = None, x0=None, margin: float = MARGIN,
                 diagnose_max: int = 2000):
        if "T" not in model.fields:
            raise jaxanm.InputError("TemperatureGuard needs temperature unknowns (effect 'conduction')")
        th = model.scene.thermal
        self.model, self.params, self.x0 = model, params, x0
        self.margin, self.diagnose_max = float(margin), int(diagnose_max)
        self.lower, self.upper = min(th.T0, th.Ta), max(th.T0, th.Ta)
        self.heated = model.effects.any("heat source")  # dissipation, friction heat, ...
        self.rise = 0.0  # largest rise above ``upper`` so far (heated scenes)
        self.floor = 1e-6 * th.T0  # the scale of a scene whose T0 = Ta and that has no source
        self._previous, self._change = None, None

    @classmethod
    def for_model(cls, model: Model, params: dict, x0) -> "TemperatureGuard | None":
        """The guard of a run of ``model`` from ``x0`` with ``params`` (None when the model has
        no temperature unknowns)."""
        return cls(model, params, x0) if "T" in model.fields else None

    def temperatures(self, x) -> np.ndarray:
        """The temperature parameters (N,) of the unknowns ``x``."""
        N = self.model.cloud.size
        return np.asarray(x, dtype=np.float64).reshape(len(self.model.fields), N)[self.model.fields.index("T")]

    def bounds(self) -> tuple[float, float]:
        """The current ``(lowest, highest)`` temperatures allowed (K), margin included."""
        scale = max(abs(self.upper - self.lower), self.rise, self.floor)
        top = np.inf if self.heated else self.upper + self.margin * scale
        return self.lower - self.margin * scale, top

    def __call__(self, t, x, stats) -> None:
        """:meth:`check` as a :func:`jaxanm.integrate` ``callback(t, x, stats)`` (fixed clouds:
        ``x`` holds the nodal parameters of the cloud the guard's model describes)."""
        amax = stats.amax[-1] if stats.amax else None
        residual = stats.residual_norm[-1] if stats.residual_norm else None
        dt = stats.step_sizes[-1] if stats.step_sizes else self.model.scene.time.dt
        self.check(self.temperatures(x), step=stats.time_steps, t=t, dt=dt, amax=amax, residual_norm=residual)

    def check(self, T, *, step: int, t: float, dt: float, amax=None, residual_norm=None) -> None:
        """Check the temperature parameters ``T`` (N,) of accepted step ``step`` (ending at
        ``t``, of size ``dt``); raise :class:`DivergenceError` if one is out of bounds."""
        T = np.asarray(T, dtype=np.float64)
        if self.heated and np.all(np.isfinite(T)):
            self.rise = max(self.rise, float(T.max()) - self.upper)
        low, high = self.bounds()
        change = None if self._previous is None else float(np.abs(T - self._previous).max())
        growth = None if change is None or not self._change else change / self._change
        outside = np.maximum(low - T, T - high)
        worst = int(np.argmax(outside))
        if outside[worst] > 0 or not np.all(np.isfinite(T)):
            raise self._error(T, worst, low, high, (change, growth), step=step, t=t, dt=dt, amax=amax,
                              residual_norm=residual_norm)
        self._previous, self._change = T.copy(), change

    def _error(self, T, worst, low, high, changes, *, dt, **where) -> DivergenceError:
        """The :class:`DivergenceError` of parameter ``worst`` outside ``[low, high]``;
        ``changes``: this step's largest change and its ratio to the previous step's."""
        value = float(T[worst])
        bound = low if value < low else high
        kind = KIND_NAMES[int(self.model.cloud.kind[worst])]
        radius = float(np.hypot(*self.model.cloud.points[worst]))  # kinds keep their radius band
        side = "below" if value < low else "above"
        change, growth = changes
        grew = "" if growth is None else (f"; the largest change of a step grew {growth:.3g}-fold "
                                          f"({self._change:.3g} K, then {change:.3g} K)")
        reason = (f"temperature diverged: T = {value:.4g} K at a {kind} point (r = {radius * 1e3:.4g} mm), "
                  f"{side} the physical range {self.lower:g}-{'inf' if self.heated else f'{self.upper:g}'} K "
                  f"(margin {self.margin:g} of the scale: bound {bound:.4g} K){grew}")
        modes = self._diagnosis(dt)
        if modes:
            reason += f"; the initial heat step's most amplified mode: {modes[0].describe()}"
        return DivergenceError(reason, value=value, bound=bound, growth=growth, kind=kind, radius=radius,
                               modes=modes, **where)

    def _diagnosis(self, dt: float) -> list:
        """The most amplified modes of the initial heat step at ``dt``, if affordable, else []."""
        if self.params is None or self.x0 is None or self.model.cloud.size > self.diagnose_max:
            return []
        return heat_modes(self.model, self.params, self.x0, dt, count=2, by="amplification")
