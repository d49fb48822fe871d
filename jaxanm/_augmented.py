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
a reverse-over-forward derivative of the residual (:func:`second_derivative`).

Everything is done in the scaled unknowns ``y = U / scale`` (so that a problem and its
rescaling locate alike), with the border ``b`` as large as R_u's entries: each Newton
iteration factorises the bordered matrix, its transpose and the Newton matrix (beside the
walk's factors, counted in the system's ``stats``).
"""

from __future__ import annotations

import functools
import typing

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

from ._problem import counted_solve, work
from .bordered import ExtendedSystem, bordered_matrix, joint_function, release

MAX_ITERATIONS = 12
"""Newton iterations allowed to locate a fold or a branch point."""

DIVERGED = 4.0
"""Newton is given up when a step is this many times its previous one: from a guess within its
basin it converges quadratically, so a growing step means the guess was not."""


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
    with work(system.stats, "jacobian"):
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


def _converged(size: float, point: float) -> bool:
    """Newton's step (scaled) is within sqrt(eps) of the point (its scaled norm ``point``, at
    least 1): the point it reached is then off by about the step's square (quadratic
    convergence), round-off of U."""
    return bool(size <= np.sqrt(np.finfo(float).eps) * max(point, 1.0))


class _Scaled(typing.NamedTuple):
    """R and its derivatives at U in the scaled unknowns y = U / scale: ``r``, ``ju`` (R_u
    times the u scales, dense or CSC), ``jl`` (R_lam times lam's scale), the size of their
    entries ``big`` (the borders' size)."""

    r: np.ndarray
    ju: object
    jl: np.ndarray
    big: float


def _scaled(system: ExtendedSystem, U, step: int) -> _Scaled:
    r, jac, dlam = system.tangent_parts(U, step=step)
    S = system.scale
    ju = jac @ scipy.sparse.diags(S[:-1]) if scipy.sparse.issparse(jac) else jac * S[:-1]
    ju = scipy.sparse.csc_matrix(ju) if scipy.sparse.issparse(jac) else ju
    big = float(abs(ju).max()) if scipy.sparse.issparse(ju) else float(np.max(np.abs(ju)))
    return _Scaled(r, ju, dlam * S[-1], max(big, float(np.max(np.abs(dlam * S[-1]))), np.finfo(float).tiny))


def _solve(system: ExtendedSystem, matrix, rhs, *, step: int, lam: float) -> np.ndarray:
    """``matrix^-1 rhs`` through a factorisation made aside (counted) and released."""
    fact = system.factorise(matrix, step=step, lam=lam, aside=True)
    x = np.asarray(counted_solve(fact, rhs, system.stats))
    release(fact)
    return x


def _transpose(M):
    return M.T.tocsc() if hasattr(M, "tocsc") else np.ascontiguousarray(M.T)


def _hessian_rows(system: ExtendedSystem, U, vectors, w) -> np.ndarray:
    """``w^T R_yy[v, .]`` for each scaled column v of ``vectors`` (rows, in y)."""
    S = system.scale
    return np.array([hessian_row(system, U, S * v, w) * S for v in np.atleast_2d(vectors.T)])


def locate_fold(system: ExtendedSystem, U, phi, *, step: int) -> Located:
    """Newton on the fold's augmented system from ``U``, ``phi`` (n,) an approximate null
    vector of R_u (the u-part of the branch's tangent near the fold)."""
    n, S, U = system.n, system.scale, np.array(U, dtype=np.float64)
    c = phi / S[:-1]
    c = psi = c / np.linalg.norm(c)  # psi: the left null vector's guess, phi's for a symmetric R_u
    last = np.zeros(n + 1)
    last[-1] = 1.0  # e_(n+1), not a row of an (n+1)^2 identity: n is 250,000 on large problems
    previous = size = np.inf
    for iteration in range(1, MAX_ITERATIONS + 1):
        at = _scaled(system, U, step)
        M = bordered_matrix(at.ju, psi[:, None] * at.big, c[None, :], corner=np.zeros((1, 1)))
        vg = _solve(system, M, last, step=step, lam=U[-1])
        w = _solve(system, _transpose(M), last, step=step, lam=U[-1])[:n]
        row = -_hessian_rows(system, U, np.append(vg[:n], 0.0)[:, None], w)[0]
        newton = bordered_matrix(at.ju, at.jl[:, None], row[None, :])
        dy = _solve(system, newton, -np.append(at.r, vg[n]), step=step, lam=U[-1])
        point, U, size = system.norm(U), U + S * dy, float(np.linalg.norm(dy))
        if not (np.isfinite(size) and np.all(np.isfinite(w)) and np.linalg.norm(w) > 0 and np.linalg.norm(vg[:n]) > 0):
            break
        psi, c = w / np.linalg.norm(w), vg[:n] / np.linalg.norm(vg[:n])
        if _converged(size, point):
            return Located(U, np.append(S[:-1] * c, 0.0)[:, None], psi, iteration, True, size)
        if size > DIVERGED * previous:
            break
        previous = size
    return Located(U, np.append(S[:-1] * c, 0.0)[:, None], psi, iteration, False, size)


def locate_branch_point(system: ExtendedSystem, U, t, phi, *, step: int) -> Located:
    """Newton on the branch point's augmented system from ``U``, with ``t`` (the branch's
    tangent) and ``phi`` (an approximate second null vector of R_U, (n+1,)) spanning the
    guess of R_U's null space."""
    n, S, U, mu = system.n, system.scale, np.array(U, dtype=np.float64), 0.0
    C = np.linalg.qr(np.column_stack([t, phi]) / S[:, None])[0]  # orthonormal, scaled
    b = phi[:n] / np.linalg.norm(phi[:n])
    units = np.zeros((n + 2, 3))
    units[n:, :2], units[n + 1, 2] = np.eye(2), 1.0
    previous = size = np.inf
    for iteration in range(1, MAX_ITERATIONS + 1):
        at = _scaled(system, U, step)
        border = b * at.big
        M = bordered_matrix(at.ju, np.column_stack([at.jl, border]), C[:n].T,
                            corner=np.column_stack([C[n], np.zeros(2)]))
        Z = _solve(system, M, units[:, :2], step=step, lam=U[-1])
        V, g = Z[: n + 1], Z[n + 1]
        w = _solve(system, _transpose(M), units[:, 2], step=step, lam=U[-1])[:n]
        rows = -_hessian_rows(system, U, V, w)
        newton = bordered_matrix(at.ju, np.column_stack([at.jl, border]), rows[:, :n],
                                 corner=np.column_stack([rows[:, n], np.zeros(2)]))
        dX = _solve(system, newton, -np.concatenate([at.r + mu * border, g]), step=step, lam=U[-1])
        point, U, mu, size = system.norm(U), U + S * dX[: n + 1], mu + dX[n + 1], float(np.linalg.norm(dX[: n + 1]))
        if not (np.isfinite(size) and np.all(np.isfinite(w)) and np.any(w)):
            break
        b, C = w / np.linalg.norm(w), np.linalg.qr(V)[0]
        if _converged(size, point):
            return Located(U, S[:, None] * C, b, iteration, True, size)
        if size > DIVERGED * previous:
            break
        previous = size
    return Located(U, S[:, None] * C, b, iteration, False, size)
