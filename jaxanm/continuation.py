"""Path following of ``R(u, lam) = 0``: the ANM (series in the pseudo-arclength) and, for
comparison, the classical pseudo-arclength Newton continuation, both returning a
:class:`~jaxanm.Branch` with the events found on it.

The ANM (Cochelin, Damil and Potier-Ferry 1994) expands the unknowns ``U = (u, lam)`` in the
pseudo-arclength ``a = <U - U_s, U_1>`` (scaled inner product, ``|U_1| = 1``) from the start
``U_s`` of each step: ``U(a) = U_s + sum_k a^k U_k``.  Order 1 is the unit tangent; order
k >= 2 solves ``R_U U_k = -F_k`` and ``<U_1, U_k> = 0``, with ``F_k`` the coefficient of
``a^k`` of R along the path truncated at k - 1 (by ``jet``, :class:`~jaxanm.bordered.PathSeries`).
Every order solves with the one bordered matrix factorised at ``U_s``
(:mod:`jaxanm.bordered`: the border is the previous tangent, so limit points pass).  The
step ends at the validity range ``a_max = (tol |U_1| / |U_p|)^(1/(p-1))`` (eq. 26 of the paper,
:func:`jaxanm.validity_range`), and the next step starts there (:mod:`jaxanm._anm_walk`).
"""

from __future__ import annotations

import time
from typing import Callable

import numpy as np

from . import _anm_walk, _newton_walk
from . import _checks as checks
from ._walk import Walk, orient
from ._x64 import entry_point
from .bordered import ContinuationFailure, ExtendedSystem, check_inputs, corrected_start
from .branch import Branch, Source
from .errors import InputError
from .events import DETECTORS, Event, detectors
from .stats import Stats
from .switching import switched_start


@entry_point
def continuation(residual: Callable, u0=None, lam0=None, params=None, *, lam_end=None, stop_at=None,
                 max_steps: int = 50, order: int = 15, tol: float = 1e-8, scale=None, jacobian: str = "auto",
                 sparsity=None, direction: int = 1, max_step: float = np.inf, correct: bool = True,
                 keep_series: bool = True, factorize: Callable | None = None, events=("fold", "branch_point"),
                 on_step: Callable | None = None, start: Event | None = None) -> Branch:
    """Follow the branch of ``residual(u, lam, params) = 0`` from ``(u0, lam0)`` by the ANM.

    Parameters
    ----------
    residual : callable
        ``residual(u, lam, params) -> (n,)`` in ``jax.numpy``, jet-compatible (no
        ``custom_jvp``, ``while`` or linear solves inside).
    u0, lam0 : array (n,), float
        The starting point (none with ``start``).  If ``u0`` is not on the branch (its Newton
        correction at fixed lam0 exceeds ``tol``) it is first corrected by Newton at fixed lam0
        (``stats.newton_iterations``); the branch starts at the corrected point.
    params : pytree of arrays
        Parameters of the residual, held constant (float64).
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
        back (each tangent has a positive product with the previous one).  With ``start``: along
        (+1) or against (-1) the bifurcated tangent ``start.data["tangents"][1]``.
    max_step : float
        Longest step (scaled arclength); np.inf: the validity range alone decides (an exact
        series, as on a trivial branch ``u = 0``, then takes the previous step's length, 1 at
        first: give ``max_step`` there, below the distance between branch points).
    correct : bool
        Correct each step's end point: one chord-Newton correction with the step's factors,
        then Newton with the next point's while it is farther than ``tol a`` from the branch
        (``stats.newton_iterations``).  Its distance (``Branch.correction``) is checked in any
        case: above ``CHECK_LIMIT`` times what the step promised the step is halved
        (``stats.rejected_steps``; :mod:`jaxanm._anm_walk`).
    keep_series : bool
        Keep each step's series, ``(steps, order, n+1)`` floats, in the :class:`Branch`.
    factorize : callable ``(matrix, stats) -> object with solve(rhs)``, optional
        How bordered matrices (dense or scipy CSC) are factorised; default
        :func:`jaxanm.factorize`.  Solves must be exact (a hook reusing factors iterates to
        that accuracy and counts in ``stats``); ``release()``, if there, is called before the
        next factorisation; without ``slogdet()`` no branch points are detected.
    events : sequence of str
        Keys of :data:`jaxanm.events.DETECTORS`: ``"fold"``, ``"branch_point"``, ``"stability"``
        (of ``u' = R``: :attr:`Branch.unstable`, Hopf points, :mod:`jaxanm.stability`); or ``()``.
    on_step : callable ``StepEnd -> list of Event``, optional
        Called at every point with the factorisation held there (:class:`jaxanm.events.StepEnd`);
        the events it returns join :attr:`Branch.events`.
    start : Event, optional
        A ``"branch_point"`` event of this problem: follow the bifurcated branch from it
        (:mod:`jaxanm.switching`; :meth:`Branch.switch` does this with the branch's options).

    Returns
    -------
    Branch
        Points, series, events, ``stopped``, ``message``, stats: a step that cannot be completed
        ends the branch, what was found kept.

    Raises
    ------
    InputError
        On invalid arguments, before any computation, or a starting point that cannot be used.
    """
    _check_anm(order, max_step, correct, keep_series)
    shared = dict(lam_end=lam_end, stop_at=stop_at, max_steps=max_steps, tol=tol, scale=scale, jacobian=jacobian,
                  sparsity=sparsity, direction=direction, factorize=factorize, events=events, on_step=on_step)
    own = dict(order=order, max_step=max_step, correct=correct, keep_series=keep_series)
    return _follow(continuation, residual, u0, lam0, params, start, shared, own)


START_RESIDUAL = 1e-6
"""A ``start`` event must be a branch point of this problem: R and R_U times its null vectors
vanish there to this fraction of what R_U makes of the scale (times the state's or the
vectors' size in it).  A branch point located on this problem meets it to round-off (1e-14
and below); another problem's point (other params, another residual) misses by O(1)."""


def _inputs(residual, u0, lam0, params, start, *, lam_end, stop_at, max_steps, tol, scale, jacobian, sparsity,
            direction, factorize, events, on_step):
    """The checks both path followers share (:class:`InputError` naming the argument), and
    ``(U0, scale (n+1,), ends)``."""
    if start is not None:
        if not isinstance(start, Event):
            raise InputError(f"start must be an Event (a branch point of a Branch's events), got {start!r}")
        if start.kind != "branch_point" or "tangents" not in start.data:
            raise InputError(f"start must be a located branch-point event (kind 'branch_point' with its tangents), "
                             f"got a {start.kind!r} event: to follow its branch from there, give u0=event.u, "
                             "lam0=event.lam")
        if u0 is not None or lam0 is not None:
            raise InputError("give either u0 and lam0 or start (a branch-point event), not both")
        u0, lam0 = start.u, start.lam
    elif u0 is None or lam0 is None:
        raise InputError("u0 and lam0 are required (the starting point), unless start= gives a branch-point event")
    if isinstance(events, str) or not all(kind in DETECTORS for kind in events):
        raise InputError(f"events must be a sequence of event kinds among {sorted(DETECTORS)}, got {events!r}")
    if on_step is not None and not callable(on_step):
        raise InputError(f"on_step must be None or a callable StepEnd -> list of Event, got {on_step!r}")
    return check_inputs(residual, u0, lam0, params, lam_end=lam_end, stop_at=stop_at, max_steps=max_steps, tol=tol,
                        scale=scale, jacobian=jacobian, sparsity=sparsity, direction=direction, factorize=factorize)


def _begin(walk: Walk, system: ExtendedSystem, U0, start, direction: int, tol: float, rows: int):
    """The walk's first point (and, from a branch point, its first step): ``(linearisation,
    its distance from the branch)`` to go on from, or None when the walk already ended."""
    if start is None:
        lin, distance, iterations = corrected_start(system, U0, direction, tol)
        walk.start(lin.point, orient(system, lin), float(np.max(np.abs(lin.residual))), lin, iterations, distance)
        return lin, distance
    r = _check_start_event(system, U0, start)
    walk.start(U0, direction * np.asarray(start.data["tangents"][1]), float(np.max(np.abs(r))), None)
    try:
        lin, series, delta, distance, iterations = switched_start(system, start, direction, tol)
    except ContinuationFailure as failure:
        walk.fail(failure)
        return None
    padded = np.zeros((rows, system.n + 1))
    padded[:2] = series
    walk.add(lin, orient(system, lin), delta, padded, correction=distance, distance=distance, amax=delta,
             iterations=iterations)
    return lin, distance


def _check_start_event(system: ExtendedSystem, U0, start: Event) -> np.ndarray:
    """R at a ``start`` event, checked to be a branch point of this problem (:data:`START_RESIDUAL`):
    R = 0, and R_U v = 0 for its null vectors v."""
    try:
        r, jac, dlam = system.tangent_parts(U0, step=0)
    except ContinuationFailure as failure:
        raise InputError(f"start: the residual is not finite at the event ({failure.reason})") from failure
    V = np.asarray(start.data.get("null_vectors", np.zeros((U0.size, 0))))
    if V.shape != (U0.size, 2):
        raise InputError(f"start: the event's null vectors have shape {V.shape}, not ({U0.size}, 2): it is another "
                         "problem's, or its location did not converge")
    unit = float(np.max(abs(jac) @ system.scale[:-1] + np.abs(dlam) * system.scale[-1]))  # R_U on the scale
    sizes = np.max(np.abs(np.column_stack([U0, V]) / system.scale[:, None]), axis=0)
    misses = np.max(np.abs(np.column_stack([r, jac @ V[:-1] + dlam[:, None] * V[-1]])), axis=0)
    if not np.all(misses <= START_RESIDUAL * unit * np.maximum(sizes, [1.0, 0.0, 0.0])):
        raise InputError(f"start: the event is not a branch point of this problem (R and R_U times its null vectors "
                         f"miss zero by {np.max(misses / unit / np.maximum(sizes, 1e-300)):.2g} of R_U's size): it "
                         "was found with another residual or params")
    return r


def _check_anm(order, max_step, correct, keep_series):
    checks.integer("order", order, 2, hint="eq. 26 compares U_1 with U_p (e.g. order=15)")
    checks.real("max_step", max_step, 0.0, open_low=True, finite=False, hint="np.inf: no cap")
    checks.flag("correct", correct)
    checks.flag("keep_series", keep_series)


def _check_newton(ds, ds_max, ds_min, max_iter, target_iter):
    for name, value in (("ds", ds), ("ds_max", ds_max), ("ds_min", ds_min)):
        checks.real(name, value, 0.0, open_low=True, finite=name != "ds_max",
                    hint="a scaled arclength; ds_max may be np.inf")
    if not ds_min <= ds <= ds_max:
        raise InputError(f"need ds_min <= ds <= ds_max, got ds_min={ds_min!r}, ds={ds!r}, ds_max={ds_max!r}")
    checks.integer("max_iter", max_iter, 1)
    checks.integer("target_iter", target_iter, 1)


@entry_point
def newton_continuation(residual: Callable, u0=None, lam0=None, params=None, *, lam_end=None, stop_at=None,
                        max_steps: int = 200, tol: float = 1e-8, scale=None, jacobian: str = "auto", sparsity=None,
                        direction: int = 1, ds: float = 0.1, ds_max: float = np.inf, ds_min: float = 1e-8,
                        max_iter: int = 8, target_iter: int = 4, factorize: Callable | None = None,
                        events=("fold", "branch_point"), on_step: Callable | None = None,
                        start: Event | None = None) -> Branch:
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
    at its value, from the linear interpolation of the two points.  Folds and branch points
    are detected as by :func:`continuation` (the tangent's turn, ``det B``'s sign) and located
    by Newton on their augmented systems.

    Parameters
    ----------
    ds, ds_max, ds_min : float
        First, largest and smallest step length (scaled pseudo-arclength).  ``ds_max`` is no
        fixed bound by default (np.inf): the steps grow with the Newton iteration count's
        control as far as the branch lets them, so they scale with the branch (a long branch,
        e.g. a fine grid's with unscaled unknowns, is not crawled at a fixed length).
    max_iter, target_iter : int
        Newton iterations allowed per step, and the number the step-length control aims at.
    residual, u0, lam0, params, lam_end, stop_at, max_steps, tol, scale :
        As for :func:`continuation`; ``tol`` bounds the last Newton correction (scaled norm),
        and ``u0`` is corrected the same way.
    jacobian, sparsity, direction, factorize, events, on_step, start :
        As for :func:`continuation`.

    Returns
    -------
    Branch
        ``series`` is the chord-length cubic Hermite interpolant of the points and tangents of
        each step (parameter in ``[0, a_i]``; crossings found on it are as accurate as that
        interpolation; folds are located on the augmented system), ``amax`` None,
        ``correction`` the last Newton correction of each step.  A step whose corrector fails
        down to ``ds_min``, or a value of ``lam_end`` / ``stop_at`` Newton cannot reach, ends
        the branch there (:attr:`Branch.stopped`, :attr:`Branch.message`).

    Raises
    ------
    InputError
        On invalid arguments, before any computation, or a starting point that cannot be used.
    """
    _check_newton(ds, ds_max, ds_min, max_iter, target_iter)
    shared = dict(lam_end=lam_end, stop_at=stop_at, max_steps=max_steps, tol=tol, scale=scale, jacobian=jacobian,
                  sparsity=sparsity, direction=direction, factorize=factorize, events=events, on_step=on_step)
    own = dict(ds=ds, ds_max=ds_max, ds_min=ds_min, max_iter=max_iter, target_iter=target_iter)
    return _follow(newton_continuation, residual, u0, lam0, params, start, shared, own)


def _follow(follow: Callable, residual, u0, lam0, params, start, shared: dict, own: dict) -> Branch:
    """The walk of ``follow`` (:func:`continuation` or :func:`newton_continuation`) on checked
    inputs: ``shared``, the options both take, and ``own``, the method's."""
    method = "anm" if follow is continuation else "newton"
    U0, scale, ends = _inputs(residual, u0, lam0, params, start, **shared)
    tol = float(shared["tol"])
    began, stats = time.perf_counter(), Stats()
    system = ExtendedSystem(residual, U0, params, scale, shared["jacobian"], shared["sparsity"], stats,
                            shared["factorize"])
    walk = Walk(system, detectors(shared["events"], system, tol, method, shared["on_step"]))
    begun = _begin(walk, system, U0, start, shared["direction"], tol, int(own.get("order", 3)))
    if begun is not None and method == "anm":
        opts = _anm_walk.Options(tol=tol, ends=ends, max_steps=int(shared["max_steps"]), order=int(own["order"]),
                                 max_step=float(own["max_step"]), correct=bool(own["correct"]))
        _anm_walk.walk_anm(system, begun[0], begun[1], opts, walk)
    elif begun is not None:
        opts_newton = _newton_walk.Options(tol=tol, ends=ends, max_steps=int(shared["max_steps"]),
                                           **{k: float(v) for k, v in own.items() if k.startswith("ds")},
                                           max_iter=int(own["max_iter"]), target_iter=int(own["target_iter"]))
        _newton_walk.walk_newton(system, walk, opts_newton)
    carried = {k: v for k, v in {**shared, **own}.items() if k not in ("lam_end", "stop_at", "direction")}
    return walk.branch(stats, method, bool(own.get("keep_series", True)), began,
                       Source(follow, residual, params, carried))
