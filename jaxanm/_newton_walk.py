"""Keller's pseudo-arclength Newton continuation, walked like the ANM's branch: a predictor
along the unit tangent, Newton on ``R(U) = 0`` with the arclength constraint (a factorisation
per iteration), the step length controlled by the iteration count.  Each step's "series" is
the chord-length cubic Hermite interpolant of its end points and tangents.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._acceptance import CHECK_LIMIT
from ._hermite import hermite_terms
from ._walk import Walk
from .bordered import ContinuationFailure, ExtendedSystem


@dataclasses.dataclass(frozen=True)
class Options:
    """Keller's options (checked by :func:`jaxanm.newton_continuation`)."""

    tol: float
    ends: list
    max_steps: int
    ds: float
    ds_max: float
    ds_min: float
    max_iter: int
    target_iter: int


def walk_newton(system: ExtendedSystem, walk: Walk, opts: Options) -> None:
    """Pseudo-arclength steps from the walk's last point until an end condition, ``max_steps``
    or a step that cannot be completed (the walk records why)."""
    ds = opts.ds
    for step in range(len(walk.a) + 1, opts.max_steps + 1):
        U, t = walk.points[-1], walk.tangents[-1]
        try:
            U_new, lin, iterations, size, ds, halvings = _arclength_step(system, U, t, ds, opts, step)
            end = _crossed(U, U_new, opts.ends)
            if end is not None:
                U_pred = U + end[2] * (U_new - U)
                found, more, _ = _newton(system, U_pred, system.axis_row(end[0]), end[1], opts, step)
                iterations += more
                if found is None:
                    raise ContinuationFailure(f"Newton at fixed U[{end[0]}] = {end[1]:.6g} did not converge",
                                              step=step, lam=U_pred[-1], code="corrector")
                U_new, lin, size = found
                U_new[end[0]] = end[1]
        except ContinuationFailure as failure:
            walk.fail(failure)
            return
        z = lin.z if system.dot(lin.z, t) > 0 else -lin.z
        t_new = z / system.norm(z)
        a = system.dot(t, U_new - U)
        walk.add(lin, t_new, a, hermite(system, U, U_new, t, t_new, a), correction=size, distance=size,
                 halvings=halvings,
                 iterations=iterations, residual_norm=float(np.max(np.abs(system.residual(U_new)))), point=U_new)
        if end is not None:
            walk.stop("lam_end" if end[0] == system.n else "stop_at")
            return
        ds = min(opts.ds_max, ds * min(2.0, max(0.5, opts.target_iter / iterations)))
    walk.stop("max_steps")


def _arclength_step(system, U, t, ds, opts: Options, step):
    """Predictor ``U + ds t`` and Newton corrector on the arclength constraint, ``ds`` halved
    while the corrector fails: ``(U_new, linearisation, iterations, last correction, ds,
    halvings)``."""
    halvings, iterations = 0, 0
    while True:
        row = system.tangent_row(t)
        found, used, refused = _newton(system, U + ds * t, row, float(row @ U) + ds, opts, step)
        iterations += used
        if found is not None:
            U_new, lin, size = found
            return U_new, lin, iterations, size, ds, halvings
        halvings += 1
        ds *= 0.5
        if ds < opts.ds_min:
            if refused is not None and refused.code == "non_finite":  # no step, however short, stays finite
                raise ContinuationFailure(f"{refused.reason} at every predictor down to ds_min = {opts.ds_min:g}",
                                          step=step, lam=U[-1], code="non_finite")
            raise ContinuationFailure(f"the corrector fails down to ds_min = {opts.ds_min:g}", step=step, lam=U[-1],
                                      code="min_step")


def _newton(system, U, row, target, opts: Options, step):
    """Newton on ``R(U) = 0``, ``row . U = target`` from ``U``: ``((U, linearisation at the last
    iterate, last correction) or None when it diverges or does not converge, the updates
    made, the failure that refused an iterate (R not finite, B singular) or None)``.
    Corrections that stall (at the point's round-off floor) within ``CHECK_LIMIT tol`` are
    accepted; above, within round-off's bound (:meth:`ExtendedSystem.round_off`):
    :class:`ContinuationFailure` ``"round_off"``."""
    previous = np.inf
    for iteration in range(opts.max_iter):
        try:
            lin = system.linearise(U, row, step=step)
        except ContinuationFailure as refused:
            return None, iteration, refused  # R not finite or B singular at this iterate: a shorter step may do
        dU = lin.solve(-lin.residual, target - row @ U)
        size = system.norm(dU)
        if not (np.isfinite(size) and size < previous):
            if size <= CHECK_LIMIT * opts.tol:  # stalled at round-off within the leeway: as converged as can be
                return (U + dU, lin, size), iteration + 1, None
            if np.isfinite(size) and size <= CHECK_LIMIT * system.round_off(lin, row):
                raise ContinuationFailure(f"Newton's corrections stall at {size:.2g} (scaled) from the branch, "
                                          f"within round-off of R's terms, above tol = {opts.tol:g}", step=step,
                                          lam=U[-1], code="round_off")
            return None, iteration, None
        U = U + dU
        if size <= opts.tol:
            return (U, lin, size), iteration + 1, None
        previous = size
    return None, opts.max_iter, None


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


def hermite(system: ExtendedSystem, U0, U1, t0, t1, a: float) -> np.ndarray:
    """The chord-length cubic Hermite interpolant of a step (end tangents times the scaled
    chord ``c``, the standard choice that follows a turning branch), its parameter stretched
    to ``[0, a]``: ``(3, n+1)`` coefficients of ``a, a^2, a^3``.  (In the pseudo-arclength
    itself the end derivative ``t_1 / <t_0, t_1>`` grows without bound as the branch turns
    within a step, and the cubic overshoots at folds.)"""
    chord = U1 - U0
    stretch = system.norm(chord) / a
    return hermite_terms(chord, t0 * stretch, t1 * stretch, a)
