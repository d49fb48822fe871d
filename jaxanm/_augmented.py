"""Folds and simple branch points of ``R(u, lam) = 0`` located by Newton on their minimally
augmented systems (Govaerts, *Numerical methods for bifurcations of dynamical equilibria*,
SIAM 2000, ch. 4 and 7), through the path follower's counted factorisations.

A **fold** (limit point) is a regular solution of ``G(U) = [R(U); g(U)] = 0``, ``U = (u, lam)``,
where ``g`` is the last unknown of the bordered solve

    [[R_u, b], [c^T, 0]] [v; g] = [0; 1]        (b, c: approximate null vectors of R_u^T, R_u),

zero exactly where R_u is singular.  A **simple branch point** is where the n x (n+1) matrix
R_U = [R_u, R_lam] loses rank: a regular solution of ``[R(U) + mu b; g_1(U); g_2(U)] = 0``
(``mu``: an unfolding unknown, zero at the solution), ``g_j`` from

    [[R_U, b], [C^T, 0]] [v_j; g_j] = [0; e_j]   (C: two columns spanning R_U's null space),

so that at the solution ``v_1, v_2`` span R_U's null space and the left solution ``w`` of the
transposed system is its left null vector.  The derivatives of ``g`` are ``-w^T R_UU[., v]``,
a reverse-over-forward derivative of the residual (:func:`second_derivative`).  Each Newton
iteration factorises the bordered matrix and its transpose (counted in the system's
``stats``); the Newton matrix differs from the bordered one by a rank-2 term, solved by the
Sherman-Morrison-Woodbury formula with the same factors.
"""

from __future__ import annotations

import functools
import typing

import jax
import jax.numpy as jnp
import numpy as np

from ._factorization import counted_solve
from .bordered import ExtendedSystem, bordered_matrix, joint_function, release

MAX_ITERATIONS = 12
"""Newton iterations allowed to locate a fold or a branch point."""

CONVERGED = 64 * np.finfo(float).eps
"""Newton has converged when its step is this small relative to the point (scaled norms): a
few ulps of U, where quadratic convergence leaves nothing to gain."""


@functools.lru_cache(maxsize=64)
def second_derivative(residual):
    """Jitted ``(U, x, w, params) -> grad_U (w . R_U(U) x)``: the row ``w^T R_UU[x, .]`` (one
    compilation per residual)."""
    joint = joint_function(residual)

    def row(U, x, w, params):
        return jax.grad(lambda X: jnp.vdot(w, jax.jvp(lambda Y: joint(Y, params), (X,), (x,))[1]))(U)

    return jax.jit(row)


def hessian_row(system: ExtendedSystem, U, x, w) -> np.ndarray:
    """``w^T R_UU(U)[x, .]`` on the host (timed as a Jacobian evaluation)."""
    with system.stats.timer("jacobian"):
        return np.asarray(second_derivative(system.residual_function)(U, x, w, system.params))


class Located(typing.NamedTuple):
    """A located fold or branch point: the point ``U``, the right null vectors of R_u (fold:
    (n+1, 1) as ``(phi, 0)``) or of R_U (branch point: (n+1, 2)), the left null vector ``psi``
    (n,), the Newton iterations, whether Newton converged, and its last step (scaled)."""

    U: np.ndarray
    null: np.ndarray
    psi: np.ndarray
    iterations: int
    converged: bool
    last_step: float


def woodbury(Z, V, y) -> np.ndarray:
    """``(M + U V^T)^-1 r`` from ``y = M^-1 r`` and ``Z = M^-1 U`` (Sherman-Morrison-Woodbury:
    a rank-k change of a factorised matrix costs k solves and a k x k system)."""
    small = np.eye(Z.shape[1]) + V.T @ Z
    return y - Z @ np.linalg.solve(small, V.T @ y)


def _converged(size: float, previous: float, U_norm: float) -> bool:
    """Newton's step is at round-off of U, or it stalls (no longer halves) after coming within
    sqrt(eps) of U, where quadratic convergence had already reached round-off."""
    scale = max(U_norm, 1.0)
    stalled = size > 0.5 * previous and previous <= np.sqrt(np.finfo(float).eps) * scale
    return bool(size <= CONVERGED * scale or stalled)


def locate_fold(system: ExtendedSystem, U, phi, *, step: int) -> Located:
    """Newton on the fold's augmented system from ``U``, ``phi`` (n,) an approximate null
    vector of R_u (the u-part of the branch's tangent near the fold)."""
    n, U, st = system.n, np.array(U, dtype=np.float64), system.stats
    b = c = phi / np.linalg.norm(phi)
    last = np.zeros(n + 1)
    last[-1] = 1.0
    previous, size, w, v = np.inf, np.inf, b, c
    for iteration in range(1, MAX_ITERATIONS + 1):
        r, jac, dlam = system.tangent_parts(U, step=step)
        M = bordered_matrix(jac, b[:, None], c[None, :], corner=np.zeros((1, 1)))
        fact = system.factorise(M, step=step, lam=U[-1], aside=True)
        column = np.append(dlam - b, 0.0)  # the Newton matrix's last column minus M's
        Z = np.asarray(counted_solve(fact, np.column_stack([column, last]), st))
        v, g = Z[:n, 1], Z[n, 1]
        y = np.asarray(counted_solve(fact, -np.append(r, g), st))
        release(fact)
        w = _left_solution(system, M, last, step, U[-1])[:n]
        row = -hessian_row(system, U, np.append(v, 0.0), w) - np.append(c, 0.0)  # last row minus M's
        dU = woodbury(Z, np.column_stack([last, row]), y)
        U, size = U + dU, system.norm(dU)
        b, c = w / np.linalg.norm(w), v / np.linalg.norm(v)
        if _converged(size, previous, system.norm(U)):
            return Located(U, np.append(c, 0.0)[:, None], b, iteration, True, size)
        previous = size
    return Located(U, np.append(c, 0.0)[:, None], b, MAX_ITERATIONS, False, size)


def locate_branch_point(system: ExtendedSystem, U, t, phi, *, step: int) -> Located:
    """Newton on the branch point's augmented system from ``U``, with ``t`` (the branch's
    tangent) and ``phi`` (an approximate second null vector of R_U, (n+1,)) spanning the
    guess of R_U's null space."""
    n, U, mu, st = system.n, np.array(U, dtype=np.float64), 0.0, system.stats
    C = _orthonormal(np.column_stack([t, phi]), system.scale)
    b = phi[:n] / np.linalg.norm(phi[:n])
    units = np.zeros((n + 2, 3))
    units[n:, :2], units[n + 1, 2] = np.eye(2), 1.0
    previous, size = np.inf, np.inf
    for iteration in range(1, MAX_ITERATIONS + 1):
        r, jac, dlam = system.tangent_parts(U, step=step)
        corner = np.column_stack([C[n], np.zeros(2)])
        M = bordered_matrix(jac, np.column_stack([dlam, b]), C[:n].T, corner=corner)
        fact = system.factorise(M, step=step, lam=U[-1], aside=True)
        Z = np.asarray(counted_solve(fact, units[:, :2], st))
        V, g = Z[: n + 1], Z[n + 1]
        y = np.asarray(counted_solve(fact, -np.concatenate([r + mu * b, g]), st))
        release(fact)
        w = _left_solution(system, M, units[:, 2], step, U[-1])[:n]
        rows = np.array([-hessian_row(system, U, V[:, j], w) for j in range(2)]) - C.T  # minus M's rows
        dX = woodbury(Z, np.column_stack([rows, np.zeros(2)]).T, y)
        U, mu, size = U + dX[: n + 1], mu + dX[n + 1], system.norm(dX[: n + 1])
        b, C = w / np.linalg.norm(w), _orthonormal(V, system.scale)
        if _converged(size, previous, system.norm(U)):
            return Located(U, C, b, iteration, True, size)
        previous = size
    return Located(U, C, b, MAX_ITERATIONS, False, size)


def _left_solution(system: ExtendedSystem, M, rhs, step: int, lam: float) -> np.ndarray:
    """``M^-T rhs``: ``M^T`` (in M's format, CSC or dense) factorised aside, counted, released."""
    transposed = M.T.tocsc() if hasattr(M, "tocsc") else np.ascontiguousarray(M.T)
    fact = system.factorise(transposed, step=step, lam=lam, aside=True)
    x = np.asarray(counted_solve(fact, rhs, system.stats))
    release(fact)
    return x


def _orthonormal(vectors, scale) -> np.ndarray:
    """The columns of ``vectors`` orthonormalised in the scaled inner product (their span)."""
    q, _ = np.linalg.qr(vectors / scale[:, None])
    return q * scale[:, None]
