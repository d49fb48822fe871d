"""Path following of ``R(u, lam) = 0``: the ANM (series in the pseudo-arclength) and, for
comparison, the classical pseudo-arclength Newton continuation, both returning a :class:`Branch`.

The ANM (Cochelin, Damil and Potier-Ferry 1994) expands the unknowns ``U = (u, lam)`` in the
pseudo-arclength ``a = <U - U_s, U_1>`` (scaled inner product, ``|U_1| = 1``) from the start
``U_s`` of each step: ``U(a) = U_s + sum_k a^k U_k``.  Order 1 is the unit tangent; order
k >= 2 solves ``R_U U_k = -F_k`` and ``<U_1, U_k> = 0``, with ``F_k`` the coefficient of
``a^k`` of R along the path truncated at k - 1 (by ``jet``, :class:`~jaxanm.bordered.PathSeries`).
Every order solves with the one bordered matrix factorised at ``U_s``
(:mod:`jaxanm.bordered`: the border is the previous tangent, so limit points pass).  The
step ends at the validity range ``a_max = (tol |U_1| / |U_p|)^(1/(p-1))`` (eq. 26 of the paper,
:func:`jaxanm.validity_range`), and the next step starts there.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable, NamedTuple

import numpy as np

from ._acceptance import CHECK_LIMIT, CHECK_ROUND_OFF, evaluate_series, validity_range
from ._x64 import entry_point
from .bordered import ContinuationFailure, ExtendedSystem, Linearisation, check_inputs, corrected_start
from .errors import InputError
from .stats import Stats

MAX_HALVINGS = 10
"""Times a step's length is halved when its end point misses the accuracy the series promised."""

MIN_STEP = 1e-12
"""A step shorter than this (scaled arclength) cannot advance the branch: the step fails."""


class BranchPoints(NamedTuple):
    """Points of a branch found on its series: ``lam (k,)``, ``u (k, n)``, and their arclength
    ``s (k,)`` along the branch (:attr:`Branch.s`)."""

    lam: np.ndarray
    u: np.ndarray
    s: np.ndarray


@dataclasses.dataclass(frozen=True)
class Branch:
    """A branch of solutions of ``R(u, lam) = 0`` from :func:`continuation` or
    :func:`newton_continuation`: its points at the step ends, the start first, and a series
    per step to evaluate it between them.

    Attributes
    ----------
    lam : ndarray (S,)
        The parameter at the points.
    u : ndarray (S, n)
        The unknowns at the points.
    a : ndarray (S-1,)
        Length of each step in the scaled pseudo-arclength, ``<U_(i+1) - U_i, t_i>`` (:attr:`s`
        is their running sum).
    amax : ndarray (S-1,) or None
        The ANM's validity range of each step (eq. 26); ``a`` is shorter where the branch
        stopped at ``lam_end`` / ``stop_at`` or the end-point check halved it.  None for Newton.
    residual_norm : ndarray (S,)
        ``|R|_inf`` at the points.
    correction : ndarray (S-1,)
        Scaled norm of each step's end correction: for the ANM, the end point's distance from
        the branch before it was corrected; for Newton, the last Newton correction.
    tangent : ndarray (S, n+1)
        Unit tangent (scaled norm) at the points, oriented along the branch.
    series : ndarray (S-1, q, n+1) or None
        ``U(a) = U_i + sum_k a^k series[i, k-1]`` on step i, ``a`` in ``[0, a[i]]``: the ANM's own
        series (q = order; the next point is its corrected end), Newton's chord-length cubic
        Hermite interpolant of the points and tangents (q = 3).  None with ``keep_series=False``.
    scale : ndarray (n+1,)
        The scale of the unknowns (u's, then lam's).
    stats : Stats
        Factorisations, series orders, solves, Newton iterations, ``amax``, ``orders``,
        ``step_sizes``, ``rejected_steps`` (steps halved or refused), the wall-time split.
    method : str
        ``"anm"`` or ``"newton"``.
    stopped : str
        Why the branch ends: ``"lam_end"``, ``"stop_at"`` or ``"max_steps"``.
    """

    lam: np.ndarray
    u: np.ndarray
    a: np.ndarray
    amax: np.ndarray | None
    residual_norm: np.ndarray
    correction: np.ndarray
    tangent: np.ndarray
    series: np.ndarray | None
    scale: np.ndarray
    stats: Stats
    method: str
    stopped: str

    @property
    def s(self) -> np.ndarray:
        """Arclength at the points (S,): the running sum of ``a``, from 0."""
        return np.concatenate([[0.0], np.cumsum(self.a)])

    def _points(self) -> np.ndarray:
        return np.column_stack([self.u, self.lam])

    def _kept_series(self) -> np.ndarray:
        """:attr:`series`, or an error saying how to keep it."""
        if self.series is None:
            raise InputError("this branch kept no series (keep_series=False): run it with keep_series=True")
        return self.series

    def evaluate(self, s) -> tuple[np.ndarray, np.ndarray]:
        """``(lam (m,), u (m, n))`` on the branch at arclengths ``s`` (m,) in ``[0, s[-1]]``,
        from each step's series."""
        series = self._kept_series()
        s = np.atleast_1d(np.asarray(s, dtype=np.float64))
        starts = self.s
        steps = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, self.a.size - 1)
        local = s - starts[steps]
        values = self._points()[steps].copy()
        power = np.ones_like(local)
        for k in range(series.shape[1]):
            power = power * local
            values += power[:, None] * series[steps, k]
        return values[:, -1], values[:, :-1]

    def crossings(self, value: float, index: int | None = None) -> BranchPoints:
        """The points where ``lam`` (``index`` None) or ``u[index]`` equals ``value``, found as
        real roots of each step's series (every crossing, in branch order)."""
        series = self._kept_series()
        j = self.u.shape[1] if index is None else int(index)
        points = self._points()
        return self._roots(lambda i: np.concatenate([[points[i, j] - value], series[i, :, j]]))

    def limit_points(self) -> BranchPoints:
        """The limit points (folds) in ``lam``: where ``d lam / d a`` of a step's series vanishes."""
        series = self._kept_series()
        orders = np.arange(1, series.shape[1] + 1)
        return self._roots(lambda i: orders * series[i, :, -1])

    def _roots(self, polynomial: Callable) -> BranchPoints:
        """Points at the real roots of ``polynomial(i)`` (ascending coefficients in a) on each
        step i: in ``[0, a_i)``, the last step's end included."""
        found = []
        last = self.a.size - 1
        for i, a in enumerate(self.a):
            found += [self.s[i] + r for r in real_roots(polynomial(i), a, closed=(i == last))]
        s = np.array(found)
        lam, u = self.evaluate(s) if s.size else (np.zeros(0), np.zeros((0, self.u.shape[1])))
        return BranchPoints(lam, u, s)


def real_roots(c, hi: float, closed: bool = True) -> np.ndarray:
    """Real roots in ``[0, hi]`` (``[0, hi)`` if not ``closed``; ``hi`` may be inf) of
    ``sum_k c[k] a^k``, sorted: companion-matrix roots of the polynomial in ``a / hi``,
    polished by Newton iterations, kept where the polynomial is zero to round-off."""
    c = np.asarray(c, dtype=np.float64)
    width = hi if np.isfinite(hi) else 1.0
    ct = c * width ** np.arange(c.size)
    nonzero = np.flatnonzero(ct)
    if nonzero.size == 0 or nonzero[-1] == 0:
        return np.zeros(0)
    ct = ct[: nonzero[-1] + 1]
    roots = np.polynomial.polynomial.polyroots(ct)
    t = roots[np.abs(roots.imag) <= 1e-6 * np.maximum(1.0, np.abs(roots))].real
    dt = np.polynomial.polynomial.polyder(ct)
    for _ in range(4):
        slope = np.polynomial.polynomial.polyval(t, dt)
        t = t - np.divide(np.polynomial.polynomial.polyval(t, ct), slope, out=np.zeros_like(t), where=slope != 0)
    size = np.polynomial.polynomial.polyval(np.abs(t), np.abs(ct))
    upper = 1.0 if np.isfinite(hi) else np.inf
    keep = (np.abs(np.polynomial.polynomial.polyval(t, ct)) <= 1e-9 * size) & (t >= -1e-12)
    keep &= (t <= upper + 1e-12) if closed else (t < upper - 1e-12)
    return np.unique(np.clip(t[keep], 0.0, upper)) * width


def _first_end(coeffs, U_s, a: float, ends) -> tuple[float, tuple | None]:
    """The step length: ``a``, or the first ``a' in (0, a]`` where the series meets an end
    condition ``(index, value)`` (then that condition)."""
    best, hit = a, None
    for index, value in ends:
        roots = real_roots(np.concatenate([[U_s[index] - value], coeffs[:, index]]), a)
        roots = roots[roots > 0]
        if roots.size and roots[0] <= best:
            best, hit = roots[0], (index, value)
    return best, hit


@dataclasses.dataclass
class _Walk:
    """What a path follower records, point by point (turned into a :class:`Branch`)."""

    points: list
    tangents: list
    residual_norms: list
    a: list = dataclasses.field(default_factory=list)
    amax: list = dataclasses.field(default_factory=list)
    corrections: list = dataclasses.field(default_factory=list)
    series: list = dataclasses.field(default_factory=list)

    def add(self, point, tangent, a, correction, residual_norm):
        """Record a step: its end ``point``, a unit tangent (the ANM records its step's start's,
        one point behind; Newton the new point's), its length, the size of its end correction
        and the residual norm at ``point`` (NaN: known later)."""
        self.points.append(point)
        self.tangents.append(tangent)
        self.a.append(a)
        self.corrections.append(correction)
        self.residual_norms.append(residual_norm)

    def branch(self, system: ExtendedSystem, stats: Stats, method: str, stopped: str, series, start: float):
        """The :class:`Branch` of these points (``series``: per step, or None)."""
        stats.close(time.perf_counter() - start)
        points = np.array(self.points)
        return Branch(lam=points[:, -1].copy(), u=points[:, :-1].copy(), a=np.array(self.a),
                      amax=np.array(self.amax) if method == "anm" else None,
                      residual_norm=np.array(self.residual_norms), correction=np.array(self.corrections),
                      tangent=np.array(self.tangents), series=series, scale=system.scale, stats=stats,
                      method=method, stopped=stopped)


def _check_anm(order, max_step, correct, keep_series):
    if not (isinstance(order, (int, np.integer)) and not isinstance(order, bool) and order >= 2):
        raise InputError(f"order must be an integer >= 2, got {order!r}: eq. 26 compares U_1 with U_p "
                         "(e.g. order=15)")
    if not (isinstance(max_step, (int, float)) and max_step > 0):
        raise InputError(f"max_step must be a positive number (np.inf: no cap), got {max_step!r}")
    for name, flag in (("correct", correct), ("keep_series", keep_series)):
        if not isinstance(flag, (bool, np.bool_)):
            raise InputError(f"{name} must be True or False, got {flag!r}")


@dataclasses.dataclass(frozen=True)
class _Options:
    """The step options of a path follower (checked by its public function)."""

    tol: float
    ends: list
    max_steps: int
    order: int = 0
    max_step: float = np.inf
    correct: bool = True
    keep_series: bool = True
    ds: float = 0.0
    ds_max: float = 0.0
    ds_min: float = 0.0
    max_iter: int = 0
    target_iter: int = 0


@entry_point
def continuation(residual: Callable, u0, lam0, params=None, *, lam_end=None, stop_at=None, max_steps: int = 50,
                 order: int = 15, tol: float = 1e-8, scale=None, jacobian: str = "auto", sparsity=None,
                 direction: int = 1, max_step: float = np.inf, correct: bool = True, keep_series: bool = True,
                 factorize: Callable | None = None) -> Branch:
    """Follow the branch of ``residual(u, lam, params) = 0`` from ``(u0, lam0)`` by the ANM.

    Parameters
    ----------
    residual : callable
        ``residual(u, lam, params) -> (n,)`` in ``jax.numpy``, jet-compatible (no
        ``custom_jvp``, ``while`` or linear solves inside).
    u0, lam0 : array (n,), float
        The starting point.  If ``u0`` is not on the branch (its Newton correction at fixed lam0
        exceeds ``tol``) it is first corrected by Newton at fixed lam0, each iteration a counted
        factorisation (``stats.newton_iterations``); the branch starts at the corrected point.
    params : pytree of arrays
        Parameters of the residual, held constant (float64, put on the device once).
    lam_end, stop_at : float, ``(index, value)``
        Stop exactly where lam = ``lam_end``, or where ``u[index] = value`` (a monitored
        unknown: a fold in lam is no end there), at the first ``a > 0`` where a step's series
        meets it; the point is then corrected with that unknown held fixed.
    max_steps : int
        Otherwise stop after this many steps.
    order, tol : int, float
        Series order p and eta of eq. 26: each step ends at ``a_max = (tol / |U_p|)^(1/(p-1))``.
    scale : float, (n,) or (n+1,) array
        Characteristic magnitude of each unknown (u's; then lam's, default 1): the arclength and
        every norm are on ``U / scale``.
    jacobian, sparsity :
        R_u dense (``jax.jacfwd``) or coloured sparse (:class:`~jaxanm.SparseJacobian`), as in
        :func:`jaxanm.integrate`: ``"auto"`` is sparse when ``sparsity`` (an (n, n) pattern of
        R_u, or a callable ``params -> pattern``) is given or n > 400.
    direction : +1 or -1
        The first step goes towards increasing (+1) or decreasing lam; later ones never turn
        back (each tangent has a positive product with the previous one).
    max_step : float
        Longest step (scaled arclength); np.inf: the validity range alone decides.
    correct : bool
        Move each step's end point by one chord-Newton correction with the step's factorisation
        (one residual, one solve), ``<U_1, dU> = 0`` (or the stopping unknown held fixed), so
        that errors do not build up along the branch.  Its size (``Branch.correction``) is the
        end point's distance from the branch, checked in any case: above ``CHECK_LIMIT`` times
        what eq. 26 promised there (``tol a``, round-off floor ``CHECK_ROUND_OFF |U|``;
        :class:`jaxanm.ANM`) the step is halved (same series, no factorisation; counted in
        ``stats.rejected_steps``), at most ``MAX_HALVINGS`` times.
    keep_series : bool
        Keep each step's series, ``(steps, order, n+1)`` floats, in the :class:`Branch`.
    factorize : callable ``(matrix, stats) -> object with solve(rhs)``, optional
        How the bordered matrix (dense array or scipy CSC, (n+1, n+1)) is factorised; default
        :func:`jaxanm.factorize`.  The series needs solves with the exact tangent at
        each step's start: a hook that reuses factors across steps must iterate to that
        accuracy (e.g. GMRES preconditioned by an earlier LU) and count what it does in
        ``stats``.  An object with ``release()`` has it called before the next factorisation.

    Returns
    -------
    Branch
        The points, each step's series (``evaluate``, ``crossings``, ``limit_points``), stats.

    Raises
    ------
    InputError
        On invalid arguments, before any computation.
    StepFailure
        A :class:`~jaxanm.ContinuationFailure` (step, lam, a_max, residual) when a step fails:
        non-finite values, a singular bordered matrix, a series that cannot advance, an end
        point that misses its accuracy after ``MAX_HALVINGS`` halvings, or a starting point
        that Newton cannot bring onto the branch.
    """
    U0, scale, ends = check_inputs(residual, u0, lam0, params, lam_end=lam_end, stop_at=stop_at,
                                   max_steps=max_steps, tol=tol, scale=scale, jacobian=jacobian, sparsity=sparsity,
                                   direction=direction, factorize=factorize)
    _check_anm(order, max_step, correct, keep_series)
    opts = _Options(tol=float(tol), ends=ends, max_steps=int(max_steps), order=int(order), max_step=float(max_step),
                    correct=bool(correct), keep_series=bool(keep_series))
    start, stats = time.perf_counter(), Stats()
    system = ExtendedSystem(residual, U0, params, scale, jacobian, sparsity, stats, factorize)
    lin = corrected_start(system, U0, direction, tol)
    walk, stopped = _follow_anm(system, lin, opts)
    return walk.branch(system, stats, "anm", stopped, np.array(walk.series) if keep_series else None, start)


def _follow_anm(system: ExtendedSystem, lin: Linearisation, opts: _Options):
    """The ANM steps from the linearisation at the start: ``(walk, why it stopped)``."""
    stats = system.stats
    walk = _Walk([lin.point], [], [float(np.max(np.abs(lin.residual)))])
    for step in range(1, opts.max_steps + 1):
        coeffs = _series(system, lin, opts.order, step)
        a, end, amax = _step_length(system, lin, coeffs, opts, step)
        U_next, t_next, a, end, distance = _step_end(system, lin, coeffs, a, end, opts, step, amax)
        stats.time_steps += 1
        stats.amax.append(amax)
        stats.orders.append(opts.order)
        stats.step_sizes.append(a)
        walk.add(U_next, coeffs[0], a, distance, np.nan)
        walk.amax.append(amax)
        if opts.keep_series:
            walk.series.append(coeffs)
        if end is not None:
            break
        if step < opts.max_steps:  # the next step starts from this one's corrected end
            lin = system.linearise(U_next, system.tangent_row(t_next), step=step + 1)
            walk.residual_norms[-1] = float(np.max(np.abs(lin.residual)))
    walk.residual_norms[-1] = float(np.max(np.abs(system.residual(walk.points[-1]))))
    walk.tangents.append(t_next)
    return walk, _stopped(system, end)


def _stopped(system, end) -> str:
    """Why a branch stopped, from the end condition met last (None: max_steps)."""
    return "max_steps" if end is None else ("lam_end" if end[0] == system.n else "stop_at")


def _series(system: ExtendedSystem, lin: Linearisation, order: int, step: int) -> np.ndarray:
    """``U_1 .. U_p`` at ``lin.point``: the unit tangent (oriented by the border, i.e. along the
    previous tangent), then orders 2..p from the jet right-hand sides, each orthogonal to U_1."""
    coeffs = np.zeros((order, system.n + 1))
    z_norm = system.norm(lin.z)
    coeffs[0] = lin.z / z_norm
    if not (np.isfinite(z_norm) and z_norm > 0):
        raise ContinuationFailure("tangent not finite (bordered matrix near singular)", step=step, lam=lin.point[-1],
                                  residual_norm=float(np.max(np.abs(lin.residual))))
    v = system.tangent_row(coeffs[0])
    path = system.path(lin.point, max_terms=order - 1)
    for k in range(2, order + 1):
        f = path.next(coeffs[k - 2], lin)
        coeffs[k - 1] = lin.constrained(-f, v)
    if not np.all(np.isfinite(coeffs)):
        raise ContinuationFailure("series coefficients not finite", step=step, lam=lin.point[-1], amax=0.0,
                                  residual_norm=float(np.max(np.abs(lin.residual))))
    return coeffs


def _step_length(system, lin, coeffs, opts: _Options, step):
    """``(a, end, a_max)``: the validity range (eq. 26 on the scaled unknowns), capped at
    ``max_step``, shortened to the first end condition met (``end``, else None)."""
    amax = validity_range(coeffs, system.scale, opts.tol)
    a, end = _first_end(coeffs, lin.point, min(amax, opts.max_step), opts.ends)
    if not np.isfinite(a):
        raise ContinuationFailure("the series is exact (a_max = inf) and no lam_end or stop_at lies ahead: "
                                  "give max_step", step=step, lam=lin.point[-1], amax=amax)
    if not a > MIN_STEP:
        raise ContinuationFailure("the series cannot advance (validity range below MIN_STEP)", step=step,
                                  lam=lin.point[-1], amax=amax, residual_norm=float(np.max(np.abs(lin.residual))))
    return a, end, amax


def _step_end(system, lin, coeffs, a, end, opts: _Options, step, amax):
    """The step's end: ``(U_next, unit tangent there, a, end, distance)``.  Its end point is
    checked by one chord-Newton correction with the step's factorisation (its scaled size is
    the distance from the branch).  A distance above what the series promised halves ``a``.
    If halving does not at least halve the distance, the excess is no truncation error (that
    falls as a^(p+1)) but a floor (round-off in R and in the solve, or the start's own
    distance): the longer step is kept when that floor is within ``CHECK_LIMIT tol`` of the
    state (``ANM(criterion="state")``'s yardstick), else the step fails."""
    previous = None
    for _ in range(MAX_HALVINGS + 1):
        attempt = _end_point(system, lin, coeffs, a, end)
        if attempt is not None:
            promised = max(opts.tol * a, CHECK_ROUND_OFF * system.norm(attempt[0]), np.finfo(float).tiny)
            if attempt[3] <= CHECK_LIMIT * promised:
                break
            if previous is not None and attempt[3] > 0.5 * previous[0][3]:
                (attempt, a, end), floor = previous, previous[0][3]
                if floor > CHECK_LIMIT * opts.tol * max(1.0, system.norm(attempt[0])):
                    raise ContinuationFailure(f"the end point's distance from the branch does not fall with the "
                                              f"step: a floor of {floor:.3g} (scaled), above tol times the state; "
                                              "the problem is too ill-conditioned here for this tol", step=step,
                                              lam=lin.point[-1], amax=amax,
                                              residual_norm=float(np.max(np.abs(attempt[1]))))
                system.stats.rejected_steps -= 1
                break
        previous = None if attempt is None else (attempt, a, end)
        a, end = 0.5 * a, None
        system.stats.rejected_steps += 1
    else:
        residual = np.nan if attempt is None else float(np.max(np.abs(attempt[1])))
        raise ContinuationFailure(f"end point misses the accuracy of eq. 26 after {MAX_HALVINGS} halvings of the "
                                  f"step", step=step, lam=lin.point[-1], amax=amax, residual_norm=residual)
    U_end, _, dU, distance = attempt
    U_next = U_end + dU if opts.correct else U_end
    if end is not None:
        U_next[end[0]] = end[1]
    derivative = np.arange(1, coeffs.shape[0] + 1) @ (coeffs * a ** np.arange(coeffs.shape[0])[:, None])
    return U_next, derivative / system.norm(derivative), a, end, distance


def _end_point(system, lin, coeffs, a, end):
    """The series' end point at ``a``, the residual there, its chord correction and that
    correction's scaled size: ``(U_end, R, dU, distance)``, or None when R is not finite."""
    U_end = lin.point + evaluate_series(coeffs, a)
    r_end = system.residual(U_end)
    if not np.all(np.isfinite(r_end)):
        return None
    dU = _correction(system, lin, coeffs[0], r_end, U_end, end)
    return U_end, r_end, dU, system.norm(dU)


def _correction(system, lin, U_1, r_end, U_end, end) -> np.ndarray:
    """Chord-Newton correction of ``U_end`` with the step's factorisation: ``<U_1, dU> = 0``, or
    with ``end = (index, value)`` the stopping unknown brought to its value."""
    if end is not None:
        index, value = end
        if abs(lin.z[index]) > 1e-12 * np.max(np.abs(lin.z)):
            return lin.constrained(-r_end, system.axis_row(index), value - U_end[index])
    return lin.constrained(-r_end, system.tangent_row(U_1))


def _check_newton(ds, ds_max, ds_min, max_iter, target_iter):
    for name, value in (("ds", ds), ("ds_max", ds_max), ("ds_min", ds_min)):
        if not (isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < value
                and (value < np.inf or name == "ds_max")):
            raise InputError(f"{name} must be a positive finite number (scaled arclength; ds_max may be np.inf), "
                             f"got {value!r}")
    if not ds_min <= ds <= ds_max:
        raise InputError(f"need ds_min <= ds <= ds_max, got ds_min={ds_min!r}, ds={ds!r}, ds_max={ds_max!r}")
    for name, value in (("max_iter", max_iter), ("target_iter", target_iter)):
        if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= 1):
            raise InputError(f"{name} must be an integer >= 1, got {value!r}")


@entry_point
def newton_continuation(residual: Callable, u0, lam0, params=None, *, lam_end=None, stop_at=None,
                        max_steps: int = 200, tol: float = 1e-8, scale=None, jacobian: str = "auto", sparsity=None,
                        direction: int = 1, ds: float = 0.1, ds_max: float = np.inf, ds_min: float = 1e-8,
                        max_iter: int = 8, target_iter: int = 4, factorize: Callable | None = None) -> Branch:
    """Follow the same branch as :func:`continuation` by Keller's pseudo-arclength continuation.

    Each step predicts along the unit tangent ``t`` (scaled norm), ``U + ds t``, and corrects
    by Newton on ``R(U) = 0``, ``<t, U - U_prev> = ds`` (the bordered matrix of
    :mod:`jaxanm.bordered` with the border ``t``, factorised at every iterate and counted),
    until the scaled correction is below ``tol``; the last factorisation also gives the
    tangent at the new point (a solve with its kernel vector).  Step-length control by Newton
    iterations: ``ds`` is multiplied by ``target_iter / iterations`` (between 0.5 and 2, at
    most ``ds_max``); a corrector that does not converge in ``max_iter`` iterations or whose
    corrections grow is refused and ``ds`` halved (``stats.rejected_steps``), down to ``ds_min``.
    A step that passes ``lam_end`` / ``stop_at`` is followed by Newton with that unknown fixed
    at its value, from the linear interpolation of the two points.

    Parameters
    ----------
    ds, ds_max, ds_min : float
        First, largest and smallest step length (scaled pseudo-arclength).  ``ds_max`` is no
        fixed bound by default (np.inf): the steps grow with the Newton iteration count's
        control as far as the branch lets them, so they scale with the branch (a long branch,
        e.g. a fine grid's with unscaled unknowns, is not crawled at a fixed length).
    max_iter, target_iter : int
        Newton iterations allowed per step, and the number the step-length control aims at.
    residual, u0, lam0, params, lam_end, stop_at, max_steps, tol, scale, jacobian, sparsity, direction, factorize :
        As for :func:`continuation`; ``tol`` bounds the last Newton correction (scaled norm),
        and ``u0`` is corrected the same way.

    Returns
    -------
    Branch
        ``series`` is the chord-length cubic Hermite interpolant of the points and tangents of
        each step (parameter in ``[0, a_i]``; limit points and crossings found on it are as
        accurate as that interpolation), ``amax`` None, ``correction`` the last Newton
        correction of each step.

    Raises
    ------
    InputError
        On invalid arguments, before any computation.
    StepFailure
        A :class:`~jaxanm.ContinuationFailure` when the corrector fails down to ``ds_min``, or
        Newton at a stopping value does not converge.
    """
    U0, scale, ends = check_inputs(residual, u0, lam0, params, lam_end=lam_end, stop_at=stop_at,
                                   max_steps=max_steps, tol=tol, scale=scale, jacobian=jacobian, sparsity=sparsity,
                                   direction=direction, factorize=factorize)
    _check_newton(ds, ds_max, ds_min, max_iter, target_iter)
    opts = _Options(tol=float(tol), ends=ends, max_steps=int(max_steps), ds=float(ds), ds_max=float(ds_max),
                    ds_min=float(ds_min), max_iter=int(max_iter), target_iter=int(target_iter))
    start, stats = time.perf_counter(), Stats()
    system = ExtendedSystem(residual, U0, params, scale, jacobian, sparsity, stats, factorize)
    lin = corrected_start(system, U0, direction, tol)
    walk = _Walk([lin.point], [lin.z / system.norm(lin.z)], [float(np.max(np.abs(lin.residual)))])
    stopped = _follow_newton(system, walk, opts)
    return walk.branch(system, stats, "newton", stopped, _hermite(system, walk), start)


def _follow_newton(system: ExtendedSystem, walk: _Walk, opts: _Options) -> str:
    """Pseudo-arclength steps from the walk's first point; returns why they stopped."""
    ds, end = opts.ds, None
    for step in range(1, opts.max_steps + 1):
        U, t = walk.points[-1], walk.tangents[-1]
        U_new, lin, iterations, size, ds = _arclength_step(system, U, t, ds, opts, step)
        end = _crossed(U, U_new, opts.ends)
        if end is not None:
            U_pred = U + end[2] * (U_new - U)
            found = _newton(system, U_pred, system.axis_row(end[0]), end[1], opts, step)
            if found is None:
                raise ContinuationFailure(f"Newton at fixed U[{end[0]}] = {end[1]:.6g} did not converge",
                                          step=step, lam=U_pred[-1])
            U_new, lin, _, size = found
            U_new[end[0]] = end[1]
        z = lin.z if system.dot(lin.z, t) > 0 else -lin.z
        residual_norm = float(np.max(np.abs(system.residual(U_new))))
        walk.add(U_new, z / system.norm(z), system.dot(t, U_new - U), size, residual_norm)
        system.stats.time_steps += 1
        system.stats.step_sizes.append(walk.a[-1])
        if end is not None:
            break
        ds = min(opts.ds_max, ds * min(2.0, max(0.5, opts.target_iter / iterations)))
    return _stopped(system, end)


def _arclength_step(system, U, t, ds, opts: _Options, step):
    """Predictor ``U + ds t`` and Newton corrector on the arclength constraint, ``ds`` halved
    while the corrector fails: ``(U_new, linearisation, iterations, last correction, ds)``."""
    while True:
        row = system.tangent_row(t)
        found = _newton(system, U + ds * t, row, float(row @ U) + ds, opts, step)
        if found is not None:
            return (*found, ds)
        system.stats.rejected_steps += 1
        ds *= 0.5
        if ds < opts.ds_min:
            raise ContinuationFailure(f"the corrector fails down to ds_min = {opts.ds_min:g}", step=step, lam=U[-1])


def _newton(system, U, row, target, opts: _Options, step):
    """Newton on ``R(U) = 0``, ``row . U = target`` from ``U``: ``(U, linearisation at the last
    iterate, iterations, last correction)``, or None when it diverges or does not converge."""
    previous = np.inf
    for iteration in range(1, opts.max_iter + 1):
        try:
            lin = system.linearise(U, row, step=step)
        except ContinuationFailure:
            return None  # a predictor where R is not finite or B singular: a shorter step may do
        dU = lin.solve(-lin.residual, target - row @ U)
        size = system.norm(dU)
        if not (np.isfinite(size) and size < previous):
            return None
        U = U + dU
        system.stats.newton_iterations += 1
        if size <= opts.tol:
            return U, lin, iteration, size
        previous = size
    return None


def _crossed(U, U_new, ends):
    """The first end condition ``(index, value)`` passed between ``U`` and ``U_new``, with the
    fraction of the way where the straight line meets it: ``(index, value, theta)`` or None."""
    best = None
    for index, value in ends:
        before, after = U[index] - value, U_new[index] - value
        if before * after <= 0 and before != after:
            theta = before / (before - after)
            if best is None or theta < best[2]:
                best = (index, value, theta)
    return best


def _hermite(system: ExtendedSystem, walk: _Walk) -> np.ndarray:
    """The chord-length cubic Hermite interpolant of each step (end tangents times the scaled
    chord ``c``, the standard choice that follows a turning branch), its parameter stretched
    to ``[0, a_i]``: ``(steps, 3, n+1)`` coefficients of ``a, a^2, a^3``.  (In the pseudo-arclength
    itself the end derivative ``t_(i+1) / <t_i, t_(i+1)>`` grows without bound as the branch
    turns within a step, and the cubic overshoots at folds.)"""
    series = []
    for i, a in enumerate(walk.a):
        chord = walk.points[i + 1] - walk.points[i]
        stretch = system.norm(chord) / a
        d0, d1, mean = walk.tangents[i] * stretch, walk.tangents[i + 1] * stretch, chord / a
        series.append([d0, (3 * mean - 2 * d0 - d1) / a, (d0 + d1 - 2 * mean) / a**2])
    return np.array(series).reshape(len(walk.a), 3, system.n + 1)
