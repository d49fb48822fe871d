"""The ANM's walk along a branch: one factorisation and one series per step.

Each step starts from a point on the branch with the bordered matrix factorised there: its
series (orders 1..p by :class:`~jaxanm.bordered.PathSeries`), its length (eq. 26's validity
range, shortened to an end condition), its end point checked and corrected with the same
factors (a chord-Newton correction whose size is the end point's distance from the branch),
then the next point factorised and, if the correction left it farther from the branch than
the step promised, brought back by Newton (:func:`~jaxanm.bordered.settle`).  A step that
cannot be completed ends the walk with its reason; what came before is kept.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from ._acceptance import CHECK_LIMIT, evaluate_series, validity_range
from ._real_roots import real_roots
from ._walk import Walk, orient
from .bordered import ContinuationFailure, ExtendedSystem, Linearisation, settle

MAX_HALVINGS = 10
"""Times a step's length is halved when its end point misses the accuracy the series promised."""

MIN_STEP = 16 * np.finfo(float).eps
"""A step shorter than this times the state (scaled norms) would not move it: the walk stops
(``"min_step"``)."""


@dataclasses.dataclass(frozen=True)
class Options:
    """The ANM walk's options (checked by :func:`jaxanm.continuation`)."""

    tol: float
    ends: list
    max_steps: int
    order: int
    max_step: float = np.inf
    correct: bool = True


class EndPoint(NamedTuple):
    """A step's end on its series at ``a``: the point, R there, the chord correction and its
    scaled size (the end point's distance from the branch)."""

    U: np.ndarray
    residual: np.ndarray
    correction: np.ndarray
    distance: float


def walk_anm(system: ExtendedSystem, lin: Linearisation, start_distance: float, opts: Options, walk: Walk) -> None:
    """ANM steps from ``lin`` (on the branch within ``start_distance``, its point recorded)
    until an end condition, ``max_steps`` or a step that cannot be completed; recorded in
    ``walk`` with the reason it stopped."""
    for step in range(len(walk.a) + 1, opts.max_steps + 1):
        try:
            lin, start_distance, end = _step(system, lin, opts, walk, step, start_distance)
        except ContinuationFailure as failure:
            walk.fail(failure)
            return
        if end is not None:
            walk.stop("lam_end" if end[0] == system.n else "stop_at")
            return
    walk.stop("max_steps")


def _step(system, lin, opts: Options, walk: Walk, step: int, start_distance: float):
    """One step: ``(linearisation at its end point, that point's distance, end condition met)``."""
    coeffs = series(system, lin, opts.order, step)
    amax = validity_range(coeffs, system.scale, opts.tol)
    a, end = _length(system, lin, coeffs, amax, opts, walk, step)
    found, a, end, halvings = _accepted_end(system, lin, coeffs, a, end, opts, step, start_distance)
    U_next = found.U + found.correction if opts.correct else found.U.copy()
    if end is not None:
        U_next[end[0]] = end[1]
    powers = a ** np.arange(coeffs.shape[0])
    derivative = (np.arange(1, coeffs.shape[0] + 1) * powers) @ coeffs
    row = system.tangent_row(derivative / system.norm(derivative))
    lin_next = system.linearise(U_next, row, step=step)
    constraint = row if end is None else system.axis_row(end[0])
    distance, iterations = found.distance, 0
    if opts.correct:
        lin_next, distance, iterations = settle(system, lin_next, constraint, opts.tol * a, step=step)
    walk.add(lin_next, orient(system, lin_next), a, coeffs, correction=found.distance, distance=distance,
             amax=amax, halvings=halvings, iterations=iterations)
    return lin_next, distance, end


def series(system: ExtendedSystem, lin: Linearisation, order: int, step: int) -> np.ndarray:
    """``U_1 .. U_p`` at ``lin.point``: the unit tangent (oriented by the border, i.e. along the
    previous tangent), then orders 2..p from the jet right-hand sides, each orthogonal to U_1."""
    coeffs = np.zeros((order, system.n + 1))
    coeffs[0] = orient(system, lin)
    v = system.tangent_row(coeffs[0])
    path = system.path(lin.point, max_terms=order - 1)
    for k in range(2, order + 1):
        coeffs[k - 1] = lin.constrained(-path.next(coeffs[k - 2], lin), v)
    if not np.all(np.isfinite(coeffs)):
        raise ContinuationFailure("the series coefficients are not finite", step=step, lam=lin.point[-1], amax=0.0,
                                  residual_norm=float(np.max(np.abs(lin.residual))), code="non_finite")
    return coeffs


def _length(system, lin, coeffs, amax: float, opts: Options, walk: Walk, step: int):
    """``(a, end)``: the validity range, capped at ``max_step``, shortened to the first end
    condition met (``end``, else None).  An exact series (``a_max = inf``, e.g. on a trivial
    branch) with no end condition ahead takes ``max_step``, or the previous step's length, or
    1 (scaled) at the first step."""
    a, end = _first_end(coeffs, lin.point, min(amax, opts.max_step), opts.ends)
    if not np.isfinite(a):
        a = walk.a[-1] if walk.a else 1.0
    if not a > MIN_STEP * system.norm(lin.point):
        raise ContinuationFailure(f"the series' validity range ({amax:.3g}) cannot move the point", step=step,
                                  lam=lin.point[-1], amax=amax, residual_norm=float(np.max(np.abs(lin.residual))),
                                  code="min_step")
    return a, end


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


def _accepted_end(system, lin, coeffs, a, end, opts: Options, step: int, start_distance: float):
    """The step's end point: ``(EndPoint, a, end, halvings)``.  Accepted when its distance from
    the branch is within ``CHECK_LIMIT`` times what the step promised: eq. 26's ``tol a`` plus
    the start's own distance, plus the round-off floor (:meth:`ExtendedSystem.round_off`, made
    only once a distance does not fall).  Otherwise the step is halved (same series): a
    distance that does not at least halve with it is no truncation error (that falls as
    a^(p+1)) but a floor; when round-off accounts for it, the longer step is kept."""
    previous, floor = None, 0.0
    for halvings in range(MAX_HALVINGS + 1):
        found = _end_point(system, lin, coeffs, a, end)
        if found is not None:
            if found.distance <= CHECK_LIMIT * (opts.tol * a + start_distance + floor):
                return found, a, end, halvings
            if previous is not None and found.distance > 0.5 * previous[0].distance:
                floor = floor or system.round_off(lin, system.tangent_row(coeffs[0]))
                if previous[0].distance <= CHECK_LIMIT * (opts.tol * previous[1] + start_distance + floor):
                    return (*previous, halvings - 1)
                raise ContinuationFailure(f"the end point stays {found.distance:.3g} (scaled) from the branch however "
                                          f"short the step, more than round-off of R's terms explains "
                                          f"({floor:.2g})", step=step, lam=lin.point[-1],
                                          residual_norm=float(np.max(np.abs(found.residual))), code="round_off")
        previous = None if found is None else (found, a, end)
        a, end = 0.5 * a, None
    raise ContinuationFailure(f"the end point misses the accuracy of eq. 26 after {MAX_HALVINGS} halvings of the step "
                              f"(a = {2 * a:.3g})", step=step, lam=lin.point[-1], code="min_step"
                              if found is not None else "non_finite")


def _end_point(system, lin, coeffs, a, end) -> EndPoint | None:
    """The series' end at ``a`` with its chord correction (None when R is not finite there)."""
    U_end = lin.point + evaluate_series(coeffs, a)
    r_end = system.residual(U_end)
    if not np.all(np.isfinite(r_end)):
        return None
    dU = _correction(system, lin, coeffs[0], r_end, U_end, end)
    return EndPoint(U_end, r_end, dU, system.norm(dU))


def _correction(system, lin, U_1, r_end, U_end, end) -> np.ndarray:
    """Chord-Newton correction of ``U_end`` with the step's factorisation: ``<U_1, dU> = 0``, or
    with ``end = (index, value)`` the stopping unknown brought to its value."""
    if end is not None:
        index, value = end
        if abs(lin.z[index]) > 1e-12 * np.max(np.abs(lin.z)):
            return lin.constrained(-r_end, system.axis_row(index), value - U_end[index])
    return lin.constrained(-r_end, system.tangent_row(U_1))
