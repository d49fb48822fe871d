"""Branch switching at a simple branch point: the two tangents from the algebraic bifurcation
equation, and the first point of the bifurcated branch.

At a simple branch point ``U*`` the n x (n+1) matrix R_U has a two-dimensional null space
(basis ``v_1, v_2``) and a left null vector ``psi``.  A branch through ``U*`` leaves along
``t = alpha_1 v_1 + alpha_2 v_2`` only if the second-order term of ``R(U* + e t + ...)`` can be
solved for, i.e. if it is orthogonal to ``psi``: the algebraic bifurcation equation (ABE)

    sum_jk alpha_j alpha_k Q_jk = 0,    Q_jk = psi^T R_UU[v_j, v_k],

a quadratic form with two real directions at a simple branch point (Keller 1977; the
second derivatives come from ``jax``: :func:`jaxanm._augmented.hessian_row`).  One direction
is the tangent of the branch followed; the other is the bifurcated branch's.

The bifurcated branch is entered off the singular point: a predictor ``U* + delta t_2`` and
Newton with ``<t_2, U - U*> = delta`` held (the bordered matrix with ``t_2`` is regular there),
``delta`` shortened while Newton fails or lands on the branch followed.  That point starts
the new branch, after the branch point itself and a first step whose series is the
second-order path through both.
"""

from __future__ import annotations

import numpy as np

from ._augmented import Located, hessian_row
from .bordered import ContinuationFailure, ExtendedSystem, settle

SWITCH_DISTANCE = 1e-2
"""The first distance ``delta`` from the branch point (scaled, times ``max(1, |U*|)``) at which
the bifurcated branch is entered; quartered while that fails (at most ``SWITCH_ATTEMPTS``)."""

SWITCH_ATTEMPTS = 6


def branch_tangents(system: ExtendedSystem, found: Located, along) -> tuple[np.ndarray, np.ndarray]:
    """The unit tangents (scaled) of the two branches through a located branch point,
    ``(2, n+1)``: the one nearer ``along`` first (oriented with it), the bifurcated one second
    (:func:`oriented` in the scaled unknowns); and the ABE's matrix Q (2, 2) in ``found.null``."""
    V, psi = found.null, found.psi
    rows = np.array([hessian_row(system, found.U, V[:, j], psi) for j in range(2)])
    Q = rows @ V
    Q = 0.5 * (Q + Q.T)
    q, R = np.linalg.eigh(Q)
    if q[0] * q[1] < 0:  # two real directions: q0 b0^2 + q1 b1^2 = 0
        betas = [np.array([np.sqrt(abs(q[1])), sign * np.sqrt(abs(q[0]))]) for sign in (1.0, -1.0)]
        directions = [V @ (R @ beta) for beta in betas]
    else:  # degenerate form: the branch followed and its complement in the null space
        alpha = V.T @ (along / system.scale**2)  # along's coordinates in the (scaled-orthonormal) basis
        directions = [V @ alpha, V @ np.array([-alpha[1], alpha[0]])]
    directions = [d / system.norm(d) for d in directions]
    first = int(np.argmax([abs(system.dot(d, along)) for d in directions]))
    t1, t2 = directions[first], directions[1 - first]
    t1 = t1 if system.dot(t1, along) > 0 else -t1
    return np.stack([t1, oriented(t2 / system.scale) * system.scale]), Q


def oriented(t) -> np.ndarray:
    """``t`` or ``-t``: the one whose first entry of largest magnitude (within 1 %, so that
    round-off does not choose between equal entries of a symmetric mode) is positive."""
    first = int(np.argmax(np.abs(t) >= 0.99 * np.max(np.abs(t))))
    return t if t[first] > 0 else -t


def switched_start(system: ExtendedSystem, event, direction: int, tol: float):
    """The first point of the branch that leaves the branch-point ``event`` along
    ``direction`` times its second tangent: ``(linearisation at the point, its series from
    U* (2, n+1), delta, its distance from the branch (Newton's last correction), Newton
    iterations)``; :class:`ContinuationFailure` (``"corrector"``) when no ``delta`` works."""
    t1, t2 = (np.asarray(t, dtype=np.float64) for t in event.data["tangents"])
    t2 = direction * t2
    U_star = np.append(np.asarray(event.u, dtype=np.float64), event.lam)
    row, apart = system.tangent_row(t2), abs(system.dot(t1, t2))
    delta, spent = SWITCH_DISTANCE * max(1.0, system.norm(U_star)), 0
    for _ in range(SWITCH_ATTEMPTS):
        try:
            lin = system.linearise(U_star + delta * t2, row, step=1)
            lin, distance, iterations = settle(system, lin, row, tol, step=1)
        except ContinuationFailure:
            delta, spent = 0.25 * delta, spent + 1
            continue
        offset = lin.point - U_star
        if system.dot(offset, t2) > 0.5 * (1.0 + apart) * system.norm(offset):  # nearer t2's ray than t1's
            series = np.stack([t2, (offset - delta * t2) / delta**2])
            return lin, series, delta, distance, iterations + spent
        delta, spent = 0.25 * delta, spent + iterations + 1
    raise ContinuationFailure(f"Newton does not reach the bifurcated branch from {SWITCH_ATTEMPTS} distances down to "
                              f"{4 * delta:.2g} (scaled) along its tangent", step=1, lam=event.lam, code="corrector")

