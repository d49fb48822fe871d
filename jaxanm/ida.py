"""SUNDIALS IDA (variable-order BDF) on a jaxanm residual: the external adaptive baseline.

A residual in semi-discrete form, ``jaxanm.SemiDiscrete(F)`` with ``F(u, u_dot, t, params)``,
is IDA's DAE residual ``F(t, y, y')`` as it is.  jaxanm's problems are also written as the
implicit-Euler step residual ``R(x_new, x_old, t_new, dt, params)`` (:func:`jaxanm.integrate`;
given plain or as ``SemiDiscrete(step_residual=R)``).  When ``R`` depends on
``x_old`` only through the difference quotient ``(L x_new - L x_old) / dt`` of a *linear*
map ``L`` (values of the fields at the points), apart from row scalings that depend on ``dt``
alone, then for any fixed ``h0 > 0``::

    F(t, y, y') = R(y, y - h0 y', t, h0, params)

is an exact DAE residual ``F(t, y, y') = D(h0) G(t, y, y')``: since ``L`` is linear,
``(L y - L (y - h0 y')) / h0 = L y'``, and ``D(h0)`` is a constant positive diagonal row
scaling, which changes neither the solution nor IDA's Newton test (made on the corrections of
``y``, not on the residual).  The FSW residual (:mod:`jaxanm.fsw.physics`) is of this form on
fixed points (``tracers`` or no motion): ``x_old`` enters through ``_old_value`` in
``dT/dt`` and, with ``inertia``, ``dV/dt``, both MLS values (linear in the nodal parameters),
and ``dt`` further enters only the row scalings ``s_plate``, ``s_tool``, ``s_edge`` and the
momentum rows' ``stiff`` (constants for fixed ``h0``); ``t`` enters nowhere.
``tests/test_ida.py`` checks the claim on the FSW rows: ``R(y, y - h y', h) / R(y, y - h' y', h')``
is one row-wise ratio, the same for independent random ``(y, y')``.  A Lagrangian scene is
*not* of this form (its points move between steps and ``x_old`` is refitted by an
``after_step`` hook); IDA is not offered there.

IDA's Newton matrix is ``dF/dy + cj dF/dy' = R_x + (1 - cj h0) R_xold``.  It is computed by
the project's coloured compressed forward-mode Jacobian (:class:`jaxanm.SparseJacobian`)
of ``x -> R(x, x - h0 (y' + cj (x - y)), t, h0)`` at ``x = y`` (whose derivative is exactly
that matrix; for a semi-discrete ``F``, of ``x -> F(x, y' + cj (x - y), t)``), handed to
IDA's sparse direct solver (SuperLU_MT) in CSC order.  The pattern must contain the nonzeros
of both ``R_x`` and ``R_xold`` (the FSW model's ``sparsity`` does: each row couples to its
stencil, all fields).

Consistent initial values.  IDA needs ``F(t0, y0, y0') = 0``.  Unless ``yp0`` is given, the
run starts with two implicit-Euler steps of size ``ic_dt`` (jaxanm's modified Newton at ``ic_tol``):
from ``x1, x2`` the pair ``y0 = x2, y0' = (x2 - x1) / ic_dt`` is consistent *exactly*
(``F(y0, y0') = D(h0) / D(ic_dt) R(x2, x1, ic_dt) = 0`` to the Newton tolerance), and two
steps instead of one let fast transients (the FSW velocity relaxes in ~1e-9 s after the
impulsive start) settle before the difference quotient is taken.  IDA then starts at
``t0 + 2 ic_dt``; the error this start adds is implicit Euler's over ``2 ic_dt`` (default
``1e-6`` of the span).  IDA's own ``IDACalcIC`` is not used: its ``YA_YDP`` mode needs a
semi-explicit split into differential and algebraic *unknowns*, which MLS nodal parameters
do not have (every column of ``dF/dy'`` is nonzero), and its ``Y`` mode would solve for all
of ``y0`` given ``y0'``.

Outputs are taken at the requested times exactly: each internal step is one call of IDA's
``onestep`` mode with ``tstop`` at the next output time (so the steps are counted, and no
interpolation error is added at the outputs).  The wheel exposes the residual and Jacobian
counts only; steps are counted here, and linear solves equal the residual evaluations IDA
makes while stepping (its Newton iteration evaluates the residual once per linear solve; with
a user Jacobian it makes no difference-quotient evaluations).
"""

from __future__ import annotations

import dataclasses
import functools
import time
import warnings
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

from ._checks import integer, positive, real
from ._extras import require
from ._problem import count, work
from ._run_inputs import params_float64
from ._scheme import SemiDiscrete, stage_residual
from ._x64 import entry_point
from .errors import InputError
from .jacobian import SparseJacobian, detect_sparsity
from .stats import Stats

__all__ = ["IDAFailure", "IDASolution", "IDAStats", "dae_residual", "integrate_ida"]


class IDAFailure(RuntimeError):
    """IDA stopped before the last output time; ``status`` (IDA's flag), ``t`` (time reached),
    ``reason`` (IDA's message) and ``stats`` (:class:`IDAStats` so far) say why and where."""

    def __init__(self, reason: str, *, status: int, t: float, stats: "IDAStats"):
        self.reason, self.status, self.t, self.stats = reason, int(status), float(t), stats
        super().__init__(f"IDA failed at t = {self.t:.6g} (flag {self.status}): {reason}; "
                         f"{stats.time_steps} steps, {stats.jacobian_evaluations} Jacobians so far")


IDA_TIMERS = ("start", "residual", "jacobian", "ida")

_RENAMED = {"steps": "time_steps", "wall_s": "wall_time_s", "linear_solves": "newton_iterations"}
"""IDAStats' former field names -> the shared names (:class:`jaxanm.Stats`'s)."""


@dataclasses.dataclass
class IDAStats(Stats):
    """Counters and wall times of one :func:`integrate_ida` run: a :class:`jaxanm.Stats` (the
    same names for the same things), of which IDA fills these.

    ``time_steps``: IDA's internal (accepted) steps; ``residual_evaluations`` and
    ``jacobian_evaluations``: calls made by IDA (Jacobians are also its matrix setups: one
    SuperLU_MT factorisation each, counted in ``factorizations`` too); ``newton_iterations``:
    IDA's Newton iterations (one residual evaluation and one linear solve each, module
    docstring); ``ic_steps``: implicit-Euler steps of the consistent start (their Newton work is
    in ``ic_stats``, a :class:`jaxanm.Stats`).  ``wall_time_s``: the whole call; ``wall_time``
    splits it into ``start`` (consistent start, sparsity, checks), ``residual`` and
    ``jacobian`` (the JAX calls IDA made) and ``ida`` (the rest: IDA's own linear algebra and
    bookkeeping).  The former names ``steps``, ``wall_s`` and ``linear_solves`` still read
    (deprecated).
    """

    REMAINDER = "ida"
    ic_steps: int = 0
    ic_stats: object = None
    wall_time: dict = dataclasses.field(default_factory=lambda: dict.fromkeys(IDA_TIMERS, 0.0))

    def __getattr__(self, name: str):
        """The deprecated former field names (``steps``, ``wall_s``, ``linear_solves``), with a
        :class:`DeprecationWarning` naming the new one."""
        new = _RENAMED.get(name)
        if new is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        warnings.warn(f"IDAStats.{name} is deprecated: use IDAStats.{new} (the name jaxanm.Stats gives it)",
                      DeprecationWarning, stacklevel=2)
        return getattr(self, new)


@dataclasses.dataclass
class IDASolution:
    """Result of :func:`integrate_ida`: ``ts (S,)`` the output times, ``xs (S, n)`` the states
    and ``xps (S, n)`` their time derivatives there, ``t_start`` the time IDA started from
    (after the consistent start), ``stats`` an :class:`IDAStats`."""

    ts: np.ndarray
    xs: np.ndarray
    xps: np.ndarray
    t_start: float
    stats: IDAStats


def dae_residual(residual: Callable | SemiDiscrete) -> Callable:
    """Jitted ``(t, y, yp, h0, params) -> F(t, y, y')``: ``F(y, yp, t, params)`` of a
    ``SemiDiscrete(F)``, else ``R(y, y - h0 yp, t, h0, params)`` of a step residual of the
    contract above (module docstring; ``h0`` unused by ``F``)."""
    if isinstance(residual, SemiDiscrete) and residual.fn is not None:
        return _semi_discrete_dae(residual.fn)
    return _step_dae(stage_residual(residual))


@functools.lru_cache(maxsize=64)
def _semi_discrete_dae(fn: Callable) -> Callable:
    """One jitted function per ``fn`` (its compiled code shared by every run)."""
    return jax.jit(lambda t, y, yp, h0, params: fn(y, yp, t, params))


@functools.lru_cache(maxsize=64)
def _step_dae(residual: Callable) -> Callable:
    """One jitted function per step residual (its compiled code shared by every run)."""
    return jax.jit(lambda t, y, yp, h0, params: residual(y, y - h0 * yp, t, h0, params))


def _newton_matrix_residual(residual: Callable | SemiDiscrete) -> Callable:
    """``(x, (y, yp, cj), t, h0, params) -> F(t, x, yp + cj (x - y))`` (module docstring): its
    derivative in ``x`` at ``x = y`` is IDA's ``dF/dy + cj dF/dy'``."""
    if isinstance(residual, SemiDiscrete) and residual.fn is not None:
        return _semi_discrete_newton(residual.fn)
    return _step_newton(stage_residual(residual))


@functools.lru_cache(maxsize=64)
def _semi_discrete_newton(fn: Callable) -> Callable:
    """One function object per ``fn``, so the compressed Jacobian compiles once."""

    def g(x, aux, t, h0, params):
        y, yp, cj = aux
        return fn(x, yp + cj * (x - y), t, params)

    return g


@functools.lru_cache(maxsize=64)
def _step_newton(residual: Callable) -> Callable:
    """One function object per step residual, so the compressed Jacobian compiles once."""

    def g(x, aux, t, h0, params):
        y, yp, cj = aux
        return residual(x, x - h0 * (yp + cj * (x - y)), t, h0, params)

    return g


def _csc_pattern(pattern, n: int) -> scipy.sparse.csc_matrix:
    """Boolean CSC pattern, duplicates summed and indices sorted (the order SparseJacobian uses)."""
    coo = scipy.sparse.coo_matrix(pattern)
    if coo.shape != (n, n):
        raise InputError(f"sparsity must be an ({n}, {n}) pattern for {n} unknowns, got {coo.shape}")
    csc = scipy.sparse.csc_matrix((np.ones(coo.nnz, dtype=bool), (coo.row, coo.col)), shape=(n, n))
    csc.sum_duplicates()
    csc.sort_indices()
    return csc


def _check_inputs(x0, t0, t_out, rtol, atol, scale, h0, yp0, ic_dt, max_steps):
    """Validate the run's inputs before any computation; return them as float64 arrays."""
    x0 = np.asarray(x0, dtype=np.float64)
    if x0.ndim != 1 or x0.size == 0:
        raise InputError(f"x0 must be a non-empty 1-D array of unknowns, got shape {x0.shape}; flatten your state")
    if not np.all(np.isfinite(x0)):
        raise InputError(f"x0 has {int(np.sum(~np.isfinite(x0)))} non-finite entries; give a finite initial state")
    real("t0", t0)
    t_out = np.atleast_1d(np.asarray(t_out, dtype=np.float64))
    if t_out.ndim != 1 or t_out.size == 0 or not np.all(np.isfinite(t_out)):
        raise InputError(f"t_out must be a non-empty 1-D array of finite output times, got {t_out!r}")
    if not (np.all(np.diff(t_out) > 0) and t_out[0] > t0):
        raise InputError(f"t_out must increase strictly and start after t0 = {t0!r}; got {t_out!r}")
    real("rtol", rtol, 0.0, 1.0, open_low=True, open_high=True, hint="IDA recommends 1e-15 <= rtol <= 1e-3")
    atol_a = np.asarray(atol, dtype=np.float64)
    if (atol_a.ndim > 1 or (atol_a.ndim == 1 and atol_a.size != x0.size)
            or not np.all(np.isfinite(atol_a) & (atol_a >= 0))):
        raise InputError(f"atol must be a number >= 0 or an array of {x0.size} of them (relative to scale), "
                         f"got {atol!r}")
    if rtol == 0 and not np.any(atol_a > 0):
        raise InputError("rtol and atol are both zero: IDA's error weights 1/(rtol |y| + atol scale) would be infinite")
    scale = np.broadcast_to(np.asarray(1.0 if scale is None else scale, dtype=np.float64), x0.shape).copy()
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise InputError("scale must be positive and finite (a characteristic magnitude per unknown)")
    span = float(t_out[-1] - t0)
    h0 = 1e-3 * span if h0 is None else h0
    positive("h0", h0, hint="the dt of the DAE residual's row scalings")
    ic_dt = 1e-6 * span if ic_dt is None else ic_dt
    if yp0 is None:
        if not 2 * positive("ic_dt", ic_dt) < t_out[0] - t0:
            raise InputError(f"ic_dt must be positive with t0 + 2 ic_dt < the first output time {t_out[0]!r} "
                             f"(the consistent start takes two implicit-Euler steps of ic_dt), got {ic_dt!r}")
    else:
        yp0 = np.asarray(yp0, dtype=np.float64)
        if yp0.shape != x0.shape or not np.all(np.isfinite(yp0)):
            raise InputError(f"yp0 must be a finite array of the shape of x0 {x0.shape}, got shape {yp0.shape}")
    integer("max_steps", max_steps, 1)
    return x0, t_out, atol_a, scale, float(h0), yp0, ic_dt


def _consistent_start(residual, x0, params, t0, ic_dt, ic_tol, scale, pattern):
    """Two implicit-Euler steps of ``ic_dt``: ``(t0 + 2 ic_dt, x2, (x2 - x1) / ic_dt, stats)``."""
    from ._integrate import integrate
    from ._saveat import SaveAt
    from ._solver import Newton

    sol = integrate(residual, x0, params, t0=t0, t1=t0 + 2 * ic_dt, dt=ic_dt, solver=Newton(tol=ic_tol),
                    scale=scale, jacobian="sparse", sparsity=pattern, saveat=SaveAt(steps=1))
    x1, x2 = sol.xs[-2], sol.xs[-1]
    return float(sol.ts[-1]), x2, (x2 - x1) / ic_dt, sol.stats


def _check_start_residual(F, t0, x0, yp0, h0, params, consistency_tol):
    """Check the DAE residual at the start (:class:`InputError`): one finite row per unknown,
    and a given ``yp0`` consistent (``max |F(t0, x0, yp0)| <= consistency_tol``)."""
    n = x0.size
    f0 = np.asarray(F(t0, x0, np.zeros(n) if yp0 is None else yp0, h0, params))
    if f0.shape != (n,):
        raise InputError(f"residual returned shape {f0.shape} for {n} unknowns; it must return one row per unknown")
    if not np.all(np.isfinite(f0)):
        raise InputError(f"residual is not finite at x0 ({int(np.sum(~np.isfinite(f0)))} rows); check x0 and params")
    if yp0 is not None and np.max(np.abs(f0)) > consistency_tol:
        raise InputError(f"yp0 is not consistent: max |F(t0, x0, yp0)| = {np.max(np.abs(f0)):.3g} > consistency_tol = "
                         f"{consistency_tol:g}; give a consistent yp0, or none (then a consistent start is computed)")


def _newton_pattern(g, x0, sparsity, t0, h0, params) -> scipy.sparse.csc_matrix:
    """The CSC pattern of IDA's Newton matrix: the given ``sparsity`` (a pattern or a callable
    of ``params``), or detected from the jaxpr of ``g`` (:func:`_newton_matrix_residual`)."""
    n = x0.size
    if sparsity is None:
        pattern = detect_sparsity(g, x0, (x0, jnp.zeros(n), 0.37 / h0), t0, h0, params)
    else:
        pattern = sparsity(params) if callable(sparsity) else sparsity
    return _csc_pattern(pattern, n)


def _ida(ida_module, F, jac, h0, params, pattern, stats: IDAStats, **options):
    """SUNDIALS IDA (``ida_module`` = ``sksundae.ida``, sparse direct solver) on the DAE residual
    ``F`` and the Newton matrix ``jac``, whose calls are counted and timed in ``stats``;
    ``options`` go to IDA."""

    def resfn(t, y, yp, res):
        with work(stats, "residual", "residual_evaluations"):
            res[:] = np.asarray(F(t, y, yp, h0, params))

    def jacfn(t, y, yp, res, cj, JJ):
        with work(stats, "jacobian", "jacobian_evaluations"):
            J = jac(y, (y, yp, cj), t, h0, params)
            JJ[:] = J.data
        count(stats, "factorizations")  # IDA's matrix setup: one SuperLU_MT factorisation

    with warnings.catch_warnings():  # the wheel warns that its own sparse DQ Jacobian is unused: jacfn replaces it
        warnings.filterwarnings("ignore", message="Custom sparse Jacobian approximation")
        return ida_module.IDA(resfn, jacfn=jacfn, linsolver="sparse", sparsity=pattern.astype(np.float64), **options)


def _march(solver, t_start: float, t_out, max_steps: int, stats: IDAStats, wall0: float):
    """IDA's internal steps up to each output time in turn (stopping exactly on it): the lists
    of output times, states and derivatives.  An :class:`IDAFailure` when IDA fails, the state
    goes non-finite or ``max_steps`` is spent."""
    ts, xs, xps = [], [], []
    t = t_start
    for t_next in t_out:
        if t_next <= t_start:
            raise InputError(f"output time {t_next!r} is before IDA's start {t_start!r} (t0 + 2 ic_dt): "
                             "give a smaller ic_dt")
        while t < t_next:
            if stats.time_steps >= max_steps:
                stats.close(time.perf_counter() - wall0)
                raise IDAFailure(f"more than max_steps = {max_steps} steps; raise max_steps or loosen rtol/atol",
                                 status=-1, t=t, stats=stats)
            r = solver.step(float(t_next), method="onestep", tstop=float(t_next))
            if not r.success:
                stats.close(time.perf_counter() - wall0)
                raise IDAFailure(str(r.message), status=r.status, t=float(r.t), stats=stats)
            count(stats, "time_steps")
            t = float(r.t)
            if not np.all(np.isfinite(r.y)):
                stats.close(time.perf_counter() - wall0)
                raise IDAFailure("the state went non-finite", status=-99, t=t, stats=stats)
        ts.append(t)
        xs.append(np.array(r.y))
        xps.append(np.array(r.yp))
    return ts, xs, xps


@entry_point
def integrate_ida(residual: Callable | SemiDiscrete, x0, params=None, *, t0: float, t_out, rtol: float = 1e-6,
                  atol=1e-8, scale=None, sparsity=None, h0: float | None = None, yp0=None,
                  ic_dt: float | None = None, ic_tol: float = 1e-12, consistency_tol: float = 1e-8,
                  max_order: int = 5, first_step: float = 0.0, max_step: float = 0.0,
                  max_steps: int = 200_000, nthreads: int = 1) -> IDASolution:
    """Integrate the DAE ``F(y, y', t, params) = 0`` of a :class:`jaxanm.SemiDiscrete` residual,
    or ``R(y, y - h0 y', t, h0, params) = 0`` of a jaxanm step residual, with IDA.

    Parameters
    ----------
    residual : SemiDiscrete or callable
        ``jaxanm.SemiDiscrete(F)``, ``F(u, u_dot, t, params) -> (n,)``; or a step residual
        ``(x_new, x_old, t_new, dt, params) -> (n,)`` of the module docstring's form.
    x0, params, t0 : array (n,), pytree, float
        State at ``t0``; parameters of the residual (fixed for the run); the initial time.
    t_out : array of float
        Output times, strictly increasing, after ``t0`` (after ``t0 + 2 ic_dt`` without ``yp0``).
    rtol, atol : float
        IDA's tolerances: error weights ``1 / (rtol |y_i| + atol scale_i)``, so ``atol`` is
        relative to each unknown's ``scale`` (an array of ``n`` is accepted too).
    scale : float or array (n,)
        Characteristic magnitude of each unknown (as in :func:`jaxanm.integrate`).
    sparsity : scipy sparse matrix, callable ``params -> pattern``, or None
        Pattern of ``R_x`` and ``R_xold`` together (of ``F_u`` and ``F_u_dot``); None detects it
        (:func:`jaxanm.detect_sparsity`).
    h0 : float
        The ``dt`` of a step residual's row scalings (default ``1e-3`` of the span): the DAE does
        not depend on it, its rows' conditioning does; unused by a semi-discrete ``F``.
    yp0 : array (n,), optional
        A consistent ``y'(t0)``; checked (``max |F| <= consistency_tol``).  Without it, the
        consistent start of the module docstring.
    ic_dt, ic_tol : float
        Step and Newton tolerance of that start (default ``ic_dt`` = ``1e-6`` of the span).
    consistency_tol : float
        Largest ``max |F(t0, x0, yp0)|`` accepted for a given ``yp0`` (scaled rows).
    max_order, first_step, max_step : int, float, float
        IDA's options (BDF order 1-5; 0 lets IDA choose).
    max_steps : int
        Internal steps allowed in all (an :class:`IDAFailure` beyond).
    nthreads : int
        Threads of SuperLU_MT.

    Returns
    -------
    IDASolution

    Raises
    ------
    InputError
        Bad input, before any long computation, naming the fix (``pip install 'jaxanm[ida]'``).
    IDAFailure
        IDA stopped (error test or Newton failures, too many steps, non-finite residual).
    """
    wall0 = time.perf_counter()
    ida_module = require("sksundae.ida", "ida", "jaxanm.ida.integrate_ida (SUNDIALS IDA)")
    x0, t_out, atol_a, scale, h0, yp0, ic_dt = _check_inputs(x0, t0, t_out, rtol, atol, scale, h0, yp0, ic_dt,
                                                             max_steps)
    params = jax.device_put(params_float64(params))
    F = dae_residual(residual)
    _check_start_residual(F, t0, x0, yp0, h0, params, consistency_tol)
    g = _newton_matrix_residual(residual)
    pattern = _newton_pattern(g, x0, sparsity, t0, h0, params)
    jac = SparseJacobian(g, pattern)
    t_start, y0, ic_stats = float(t0), x0, None  # from the given yp0 at t0, else after the consistent start
    if yp0 is None:
        t_start, y0, yp0, ic_stats = _consistent_start(residual, x0, params, t0, ic_dt, ic_tol, scale, pattern)
    stats = IDAStats(ic_steps=0 if ic_stats is None else 2, ic_stats=ic_stats,
                     wall_time=dict(dict.fromkeys(IDA_TIMERS, 0.0), start=time.perf_counter() - wall0))
    solver = _ida(ida_module, F, jac, h0, params, pattern, stats, nthreads=nthreads, rtol=float(rtol),
                  atol=atol_a * scale, max_order=int(max_order), first_step=float(first_step), max_step=float(max_step))
    r = solver.init_step(t_start, y0, yp0)
    if not r.success:
        raise IDAFailure(str(r.message), status=r.status, t=t_start, stats=stats)
    ts, xs, xps = _march(solver, t_start, t_out, max_steps, stats, wall0)
    count(stats, "newton_iterations", stats.residual_evaluations)  # one residual per Newton iteration
    stats.close(time.perf_counter() - wall0)
    return IDASolution(np.array(ts), np.array(xs), np.array(xps), t_start, stats)
