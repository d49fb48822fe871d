"""The extended system of a one-parameter family ``R(u, lam) = 0`` and its bordered matrix.

Path following (:mod:`jaxanm.continuation`) sees n equations in the n + 1 unknowns
``U = (u, lam)``.  At a point it factorises the bordered (n + 1) x (n + 1) matrix

    B = [[R_u, R_lam],
         [ w^T      ]]

(R_u by ``jax.jacfwd`` or the coloured :class:`~jaxanm.SparseJacobian`, R_lam by a ``jvp``,
``w`` a border row), through the one counted factorisation of the project
(:func:`jaxanm.factorize`, or a hook).  B stays regular at limit points, where R_u is
singular, as long as ``w`` is not orthogonal to the branch's tangent.  Its kernel vector
``z = B^-1 e_(n+1)`` spans the tangent (``R_U z = 0``, ``w.z = 1``), so any constraint
``<v, dU> = c`` is imposed afterwards on a solution of B by adding a multiple of ``z``:
the border used for factorising need not be the one a series or a correction wants, and
one factorisation per point serves the tangent, every series order and the correction.

Norms and inner products are on the scaled unknowns ``U / scale`` (``scale`` has n + 1
entries, lam's last), so that velocity-like and temperature-like unknowns and the
parameter count alike in the arclength.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

from . import _checks as checks
from ._acceptance import CHECK_LIMIT
from ._factorization import Factorization
from ._problem import Problem, compiled, counted_solve, work
from ._problem import factorize as counted_factorize
from ._run_inputs import jacobian_kind, on_device, params_float64
from ._series import AffinePath
from .errors import InputError, SingularMatrixError, StepFailure
from .errors import format_number as _number
from .jacobian import detect_sparsity
from .stats import Stats

START_ITERATIONS = 20
"""Newton iterations at fixed lam allowed to bring ``u0`` onto the branch (:func:`corrected_start`)."""


class ContinuationFailure(StepFailure):
    """Why a continuation step could not be completed: a :class:`~jaxanm.StepFailure` located
    by the step and the parameter ``lam`` there (also in ``t``, for code that handles time
    steps), with ``code``, the short reason a :class:`~jaxanm.Branch` ends with
    (:attr:`~jaxanm.Branch.stopped`).  The path followers catch it and return the branch they
    found; it is raised to the caller only for a starting point that cannot be used."""

    def __init__(self, reason: str, *, step: int, lam: float, amax=None, residual_norm=None,
                 code: str = "singular"):
        super().__init__(reason, step=step, t=lam, amax=amax, residual_norm=residual_norm)
        self.lam, self.code = float(lam), code
        self.args = (f"continuation step {step} (lam = {self.lam:.8g}): {reason}; a_max = {_number(self.amax)}, "
                     f"|R|_inf = {_number(self.residual_norm)}",)


@functools.lru_cache(maxsize=64)
def joint_function(residual):
    """``(U, params) -> residual(U[:-1], U[-1], params)``: the residual of the unknowns and the
    parameter together, the function the series expands (one object per residual, so that
    compiled jets are found again)."""
    return lambda U, params: residual(U[:-1], U[-1], params)


@functools.lru_cache(maxsize=64)
def _step_form(residual):
    """The residual in the step solvers' signature ``(x, x_old, t, dt, params)``, lam in ``t``:
    :class:`~jaxanm._problem.Problem` then builds R_u (dense or sparse) as it does for K*."""
    return lambda x, x_old, t, dt, params: residual(x, t, params)


@functools.lru_cache(maxsize=64)
def _value_and_dlam(residual):
    """Jitted ``(u, lam, params) -> (R, dR/dlam)``: one ``jvp`` gives both."""
    def value_and_dlam(u, lam, params):
        return jax.jvp(lambda at: residual(u, at, params), (lam,), (jnp.ones_like(lam),))

    return jax.jit(value_and_dlam)


def _scale_vector(scale, n: int) -> np.ndarray:
    """``scale`` as n + 1 positive entries (u's, then lam's)."""
    s = np.asarray(1.0 if scale is None else scale, dtype=np.float64)
    if s.ndim == 0:
        s = np.append(np.full(n, float(s)), 1.0)
    elif s.shape == (n,):
        s = np.append(s, 1.0)
    elif s.shape != (n + 1,):
        raise InputError(f"scale must be a float, an array of shape ({n},) (u) or ({n + 1},) (u, then lam), "
                         f"got shape {s.shape}")
    if not np.all(np.isfinite(s) & (s > 0)):
        raise InputError("scale must be positive and finite: a characteristic magnitude per unknown")
    return s


def _finite_number(name, value, fix):
    """``value`` as a float if it is a finite real scalar, else :class:`InputError`."""
    real = (np.ndim(value) == 0 and not isinstance(value, (bool, np.bool_, str, bytes))
            and np.isrealobj(value) and np.issubdtype(np.asarray(value).dtype, np.number))
    if not (real and math.isfinite(float(value))):
        raise InputError(f"{name} must be a finite real number, got {value!r}; {fix}")
    return float(value)


def check_inputs(residual, u0, lam0, params, *, lam_end, stop_at, max_steps, tol, scale, jacobian,
                 sparsity, direction, factorize):
    """Check what both path followers take, before any computation (:class:`InputError` naming
    the argument and the fix).  Returns ``(U0, scale (n + 1,), ends)``, ``ends`` the list of
    ``(index into U, value)`` where the branch stops."""
    if not callable(residual):
        raise InputError(f"residual must be a callable residual(u, lam, params) -> (n,), got {residual!r}")
    try:
        u0 = np.asarray(u0, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"u0 must be a non-empty 1-D array of real numbers ({exc})") from exc
    if u0.ndim != 1 or u0.size == 0:
        raise InputError(f"u0 must be a non-empty 1-D array of unknowns, got shape {u0.shape}; flatten it")
    if not np.all(np.isfinite(u0)):
        raise InputError(f"u0 has {int(np.sum(~np.isfinite(u0)))} non-finite entries; give a finite starting point")
    n = u0.size
    lam0 = _finite_number("lam0", lam0, "the parameter at the starting point")
    ends = []
    if lam_end is not None:
        lam_end = _finite_number("lam_end", lam_end, "or None to stop after max_steps")
        if lam_end == lam0:
            raise InputError(f"lam_end equals lam0 = {lam0!r}: the branch would stop where it starts")
        ends.append((n, lam_end))
    if stop_at is not None:
        if not (isinstance(stop_at, tuple) and len(stop_at) == 2):
            raise InputError(f"stop_at must be a pair (index of u in [0, {n}), value), got {stop_at!r}")
        index = checks.integer("stop_at[0]", stop_at[0], -n, n - 1, hint="the index of the monitored unknown") % n
        value = _finite_number("stop_at[1]", stop_at[1], "the value of u[index] where the branch stops")
        if value == u0[index]:
            raise InputError(f"stop_at: u0[{index}] already equals {value!r}; the branch would stop where it starts")
        ends.append((index, value))
    checks.integer("max_steps", max_steps, 1)
    checks.real("tol", tol, 0.0, 1.0, open_low=True, open_high=True, hint="e.g. tol=1e-8")
    checks.choice("jacobian", jacobian, ("auto", "dense", "sparse"))
    if sparsity is not None and not (callable(sparsity) or scipy.sparse.issparse(sparsity)):
        raise InputError("sparsity must be a scipy sparse (n, n) pattern of R_u, a callable params -> pattern, or None")
    if scipy.sparse.issparse(sparsity) and sparsity.shape != (n, n):
        raise InputError(f"sparsity must have the shape of R_u, ({n}, {n}), got {sparsity.shape}")
    if direction not in (1, -1):
        raise InputError(f"direction must be +1 (towards increasing lam) or -1, got {direction!r}")
    if factorize is not None and not callable(factorize):
        raise InputError("factorize must be None or a callable (matrix, stats) -> object with solve(rhs), "
                         f"got {factorize!r}")
    _check_output(residual, u0, lam0, params)
    return np.append(u0, lam0), _scale_vector(scale, n), ends


def _check_output(residual, u0, lam0, params):
    """The residual traces and returns shape (n,) (abstract evaluation: nothing is computed)."""
    with jax.enable_x64(True):
        try:
            out = jax.eval_shape(residual, jnp.asarray(u0), jnp.float64(lam0), params)
        except Exception as exc:  # noqa: BLE001 - any tracing error is a problem of the input
            raise InputError(f"residual(u0, lam0, params) could not be traced by JAX ({exc!r}); write it in "
                             "jax.numpy with signature residual(u, lam, params)") from exc
    if getattr(out, "shape", None) != u0.shape:
        raise InputError(f"residual(u, lam, params) must return an array of shape {u0.shape} (one equation per "
                         f"unknown of u), got {getattr(out, 'shape', type(out).__name__)}")


class Linearisation:
    """The bordered matrix factorised at ``point`` (border row ``row``), with the residual
    there (``residual``), the top block ``[R_u, R_lam]`` for products (``jacobian``, ``dlam``)
    and the kernel vector ``z`` (``B z = e_(n+1)``); its solves are counted in ``stats``."""

    def __init__(self, point, residual, jacobian, dlam, row, fact, stats: Stats):
        self.point, self.residual, self.jacobian, self.dlam, self.row = point, residual, jacobian, dlam, row
        self.fact, self.stats = fact, stats
        last = np.zeros(point.size)
        last[-1] = 1.0
        self.z = np.asarray(counted_solve(fact, last, stats))

    def solve(self, top, last: float = 0.0) -> np.ndarray:
        """``B^-1 [top; last]``."""
        return np.asarray(counted_solve(self.fact, np.append(top, last), self.stats))

    def constrained(self, top, v, value: float = 0.0) -> np.ndarray:
        """The solution ``x`` of ``R_U x = top`` with ``v . x = value`` (``v`` a row, e.g. a
        scaled tangent): a solution of B plus the multiple of ``z`` that meets the constraint."""
        y = self.solve(top)
        return y + ((value - v @ y) / (v @ self.z)) * self.z

    def times(self, x) -> np.ndarray:
        """``R_U x = R_u x[:-1] + R_lam x[-1]`` (host product with the assembled tangent)."""
        return self.jacobian @ x[:-1] + self.dlam * x[-1]

    def term_sizes(self) -> np.ndarray:
        """``|R_u| |u| + |R_lam| |lam|`` per equation: how large the terms of R that cancel at a
        solution are, each known to a relative round-off of eps (the state itself is stored to
        eps |U|), so that R is computed at best to eps times this."""
        jac = abs(self.jacobian)
        return np.asarray(jac @ np.abs(self.point[:-1])).ravel() + np.abs(self.dlam) * abs(self.point[-1])

    def slogdet(self) -> tuple[float, float] | None:
        """``(sign, log|det B|)`` from the factors (None if the factorisation object cannot
        tell: a ``factorize`` hook's without ``slogdet()``).  With ``z`` oriented by the border
        (``row . z = 1``) the sign is that of ``det [R_U; z^T]``, which changes along a branch
        only where R_U loses rank: at branch points, not at folds."""
        slogdet = getattr(self.fact, "slogdet", None)
        return None if slogdet is None else slogdet()


class ExtendedSystem:
    """``R(U) = 0`` for ``U = (u, lam)``: residuals, linearisations (bordered, factorised,
    counted in ``stats``) and the series of the residual along a path.  ``factorize``: the
    hook ``(matrix, stats) -> object with solve(rhs)`` (default :func:`jaxanm.factorize`).
    ``residual_function`` and ``params`` are the problem's (read by event location); ``sparsity``
    the sparse R_u's pattern, given or detected (None when dense)."""

    def __init__(self, residual, U0, params, scale, jacobian: str, sparsity, stats: Stats, factorize=None):
        n = U0.size - 1
        self.n, self.scale, self.stats = n, scale, stats
        self.params = on_device(params_float64(params))
        self._residual = residual
        self._factorize = counted_factorize if factorize is None else factorize
        self._fact: Factorization | None = None
        kind = jacobian_kind(jacobian, sparsity, n)
        if kind == "sparse" and sparsity is None:
            sparsity = self._detected_pattern(U0)
        self.kind, self.sparsity = kind, sparsity  # the pattern given or detected (None: dense)
        self._problem = Problem(_step_form(residual), scale[:-1], stats, kind, sparsity)

    def _detected_pattern(self, U0):
        """R_u's pattern from the residual's jaxpr (:func:`jaxanm.detect_sparsity`): it holds for
        every lam (lam's value is not read), an entry with a factor lam included at lam = 0."""
        return detect_sparsity(_step_form(self._residual), U0[:-1], None, np.float64(U0[-1]), None, self.params)

    @property
    def residual_function(self):
        """The residual ``(u, lam, params) -> R`` of the problem."""
        return self._residual

    def dot(self, a, b) -> float:
        """Inner product of the scaled unknowns."""
        return float(np.dot(a / self.scale, b / self.scale))

    def norm(self, v) -> float:
        """2-norm of the scaled unknowns."""
        return float(np.linalg.norm(v / self.scale))

    def tangent_row(self, t) -> np.ndarray:
        """The border row of the constraint ``<t, dU> = c`` in the scaled inner product."""
        return t / self.scale**2

    def axis_row(self, index: int, sign: float = 1.0) -> np.ndarray:
        """The border row fixing ``U[index]`` (``sign``: the direction its kernel vector takes)."""
        row = np.zeros(self.n + 1)
        row[index] = sign
        return row

    def residual(self, U) -> np.ndarray:
        """``R(u, lam)`` on the host (counted)."""
        with work(self.stats, "series", "residual_evaluations"):
            r = np.asarray(compiled(self.residual_function).residual(U[:-1], np.float64(U[-1]), self.params))
        return r

    def tangent_parts(self, U, *, step: int):
        """``(R, R_u, R_lam)`` at ``U`` (R_u dense or sparse, as the system's Jacobian);
        :class:`ContinuationFailure` (code ``"non_finite"``) when R or R_lam is not finite."""
        with work(self.stats, "jacobian", "residual_evaluations"):
            values = _value_and_dlam(self.residual_function)(U[:-1], np.float64(U[-1]), self.params)
            r, dlam = (np.asarray(v) for v in values)
        r_norm = float(np.max(np.abs(r)))
        if not (np.isfinite(r_norm) and np.all(np.isfinite(dlam))):
            raise ContinuationFailure("the residual or dR/dlam is not finite", step=step, lam=U[-1],
                                      residual_norm=r_norm, code="non_finite")
        return r, self._problem.tangent(U[:-1], None, np.float64(U[-1]), None, self.params), dlam

    def factorise(self, matrix, *, step: int, lam: float, aside: bool = False):
        """``matrix`` factorised through the system's hook, counted; the factors made before
        are released first (one LU alive), unless ``aside``: factors made beside the walk's
        (locating an event), which the caller releases (:func:`release`) when done.
        :class:`ContinuationFailure` (``"singular"``, or ``"non_finite"`` for non-finite
        entries) when it cannot be factorised."""
        if not aside:
            release(self._fact)
        try:
            fact = self._factorize(matrix, self.stats)
        except SingularMatrixError as exc:
            code = "non_finite" if "non-finite" in str(exc) else "singular"
            raise ContinuationFailure(f"the bordered matrix cannot be factorised ({exc})", step=step, lam=lam,
                                      code=code) from exc
        if not aside:
            self._fact = fact
        return fact

    def linearise(self, U, row, *, step: int, aside: bool = False) -> Linearisation:
        """R, R_u, R_lam at ``U``, the bordered matrix with ``row`` factorised
        (:meth:`factorise`, ``aside`` as there); :class:`ContinuationFailure` when R is not
        finite or B cannot be factorised."""
        r, jac, dlam = self.tangent_parts(U, step=step)
        fact = self.factorise(bordered_matrix(jac, dlam[:, None], row[None, :]), step=step, lam=U[-1], aside=aside)
        lin = Linearisation(U, r, jac, dlam, row, fact, self.stats)
        if not np.all(np.isfinite(lin.z)):
            if aside:
                release(fact)
            raise ContinuationFailure("the tangent is not finite (the bordered matrix is numerically singular)",
                                      step=step, lam=U[-1], residual_norm=float(np.max(np.abs(r))))
        return lin

    def round_off(self, lin: Linearisation, row) -> float:
        """A bound on how far from the branch round-off can leave a point, in the scaled norm:
        the correction ``B^-1 (eps s T)`` under the constraint ``row`` (one solve), T the sizes of
        R's terms (:meth:`Linearisation.term_sizes`), s signs drawn once per size (errors of
        the rows add like random ones).  It bounds what Newton's corrections stall at; they
        stall lower where R's differences of nearby values are exact (stencils on smooth
        states: measured 0.002 to 0.1 of it on the 1D Bratu problem)."""
        signs = np.random.default_rng(self.n).choice([-1.0, 1.0], self.n)
        return self.norm(lin.constrained(np.finfo(float).eps * signs * lin.term_sizes(), row))

    def path(self, point, max_terms: int) -> "PathSeries":
        """The residual's series along a path from ``point`` (:class:`PathSeries`)."""
        return PathSeries(self, point, max_terms)


def release(fact) -> None:
    """Free a factorisation's LU (if it can: a hook's object may not)."""
    if fact is not None and hasattr(fact, "release"):
        fact.release()


def bordered_matrix(top_left, right, bottom, corner=None):
    """``[[top_left, right], [bottom, corner]]`` (corner zeros by default): CSC when
    ``top_left`` is sparse, else a dense array.  ``right`` (n, k) and ``bottom`` (k, m + k)
    are dense, ``bottom``'s last k columns the corner's unless ``corner`` is given."""
    k = right.shape[1]
    if corner is None:
        bottom, corner = bottom[:, :-k], bottom[:, -k:]
    if scipy.sparse.issparse(top_left):
        blocks = [[top_left, scipy.sparse.csc_matrix(right)],
                  [scipy.sparse.csc_matrix(bottom), scipy.sparse.csc_matrix(corner)]]
        return scipy.sparse.bmat(blocks, format="csc")
    return np.block([[np.asarray(top_left), right], [bottom, corner]])


class PathSeries:
    """Right-hand sides of the series of ``R(U(a)) = 0``, ``U(a) = U_s + sum a^k U_k``: after
    :meth:`next` is given ``U_k``, it returns ``F_(k+1)``, the coefficient of ``a^(k+1)`` of R
    along the path truncated at k (so that order k + 1 reads ``R_U U_(k+1) = -F_(k+1)``).

    The coefficients come from :class:`~jaxanm._series.AffinePath` (the affine part by a linear
    map, the rest by incremental Taylor arithmetic, one compilation for every order, shared by
    every step of every branch with this residual and shapes): with ``lookahead`` it returns
    the coefficient of order k + 1 along the path with the provisional ``U_(k+1) = U_k``, which
    is ``F_(k+1) + R_U U_k``; the linear term is taken off by a product with the assembled
    tangent (exact, whatever solved for ``U_k``).  A residual that cannot be split gets a jet of
    the whole residual with a zero last term, compiled per number of terms.
    """

    def __init__(self, system: ExtendedSystem, point, max_terms: int):
        self._system, self._point = system, point
        self._terms: list[np.ndarray] = []
        joint = joint_function(system.residual_function)
        args = (system.params,)
        with work(system.stats, "series"):
            fns = compiled(joint).affine_functions(point, args)
            self._path = None if fns is None else AffinePath(fns, point, args, lookahead=True, max_terms=max_terms)
        self._whole = compiled(joint).series  # used without a split; compiled on first use only

    def next(self, U_k, linearisation: Linearisation) -> np.ndarray:
        """``F_(k+1)`` from the new coefficient ``U_k`` (counted in ``stats.series_orders``)."""
        with work(self._system.stats, "series", "series_orders"):
            if self._path is not None:
                f = self._path.next(U_k) - linearisation.times(U_k)
            else:
                self._terms.append(np.asarray(U_k))
                terms = np.stack(self._terms + [np.zeros_like(U_k)])
                f = np.asarray(self._whole(self._point, terms, self._system.params))[-1]
        return f


def settle(system: ExtendedSystem, lin: Linearisation, constraint, target: float, *, step: int,
           max_iterations: int = START_ITERATIONS):
    """Newton at ``lin.point`` (under ``constraint``, a border row: ``constraint . dU = 0``, and
    re-linearised with ``lin.row`` at each iterate, counted) until its correction is at most
    ``target`` (scaled): ``(linearisation at the point, last correction, iterations)``.

    Corrections that stop at least halving have reached the point's round-off floor: that
    floor is accepted within ``CHECK_LIMIT`` times ``target``; above, the walk cannot keep its
    promise there: :class:`ContinuationFailure` ``"round_off"`` when round-off of R's terms can
    give so large a correction (:meth:`ExtendedSystem.round_off`, a bound), else
    ``"corrector"`` (Newton does not converge), as after ``max_iterations``."""
    previous = np.inf
    for iteration in range(max_iterations + 1):
        dU = lin.constrained(-lin.residual, constraint)
        size = system.norm(dU)
        if size <= target:
            return lin, size, iteration
        if not (np.isfinite(size) and size <= 0.5 * previous) or iteration == max_iterations:
            if size <= CHECK_LIMIT * target:
                return lin, size, iteration
            raise _not_settled(system, lin, constraint, size, target, step, iteration)
        previous = size
        lin = system.linearise(lin.point + dU, lin.row, step=step)
    raise AssertionError("unreachable")


def _not_settled(system, lin, constraint, size, target, step, iterations) -> ContinuationFailure:
    """Why Newton's corrections stall at ``size`` above ``target``: round-off (when its bound
    reaches that far) or a corrector that does not converge."""
    bound = system.round_off(lin, constraint) if np.isfinite(size) else 0.0
    lam, norm = lin.point[-1], float(np.max(np.abs(lin.residual)))
    if size <= CHECK_LIMIT * bound:
        return ContinuationFailure(f"Newton's corrections stall at {size:.2g} (scaled) from the branch, within "
                                   f"round-off of R's terms ({bound:.2g}), above the accuracy the steps promise "
                                   f"({target:.2g})", step=step, lam=lam, residual_norm=norm, code="round_off")
    return ContinuationFailure(f"Newton does not bring the point onto the branch (correction {size:.3g} after "
                               f"{iterations} iterations)", step=step, lam=lam, residual_norm=norm, code="corrector")


def corrected_start(system: ExtendedSystem, U0, direction: int, tol: float):
    """The linearisation at the starting point, bordered by ``direction`` e_lam (its kernel
    vector points towards ``direction`` lam), its distance from the branch (Newton's last
    correction) and the Newton iterations it took: ``u0`` is
    first brought onto the branch by Newton at fixed lam0 while its correction exceeds
    ``tol`` (scaled norm; :func:`settle`).  A start that cannot be used is the caller's to
    change: :class:`InputError` saying why."""
    row = system.axis_row(system.n, float(direction))
    try:
        lin = system.linearise(np.array(U0, dtype=np.float64), row, step=0)
        lin, distance, iterations = settle(system, lin, system.axis_row(system.n), tol, step=0)
    except ContinuationFailure as failure:
        fix = {"non_finite": "the residual is not finite at (u0, lam0) or on Newton's way from it: give a point "
                             "inside its domain",
               "singular": "the bordered matrix is singular at (u0, lam0): a branch point or a degenerate R_lam; start "
                           "beside it (or from a branch-point event with start=)"}
        raise InputError(f"u0 is not a usable starting point at lam0 = {U0[-1]:.8g}: {failure.reason}; "
                         + fix.get(failure.code, "give a point on the branch (a solution at lam0)")) from failure
    return lin, distance, iterations
