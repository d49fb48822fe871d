"""Which stencils are too ill-conditioned: the kernel's cheap lower bound of each moment
matrix's reciprocal condition number, and an exact eigenvalue check where it is low."""

from __future__ import annotations

import numpy as np

from ._shape import RCOND_MIN


def equilibrated_moments(x, y, mask, c, q):
    """The equilibrated moment matrices ``S P^T W P S`` (n, 6, 6) of n stencils (scaled local
    coordinates ``x, y`` and support ``mask`` (n, m), as for the kernel), in numpy: for the
    few stencils whose condition :func:`condition_screen` computes exactly."""
    w = np.where(mask, np.exp(-(((x * x + y * y) / c**2) ** q)), 0.0)
    P = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)
    A = np.einsum("nmi,nm,nmj->nij", P, w, P)
    with np.errstate(divide="ignore", invalid="ignore"):  # an empty support: non-finite, refused
        s = 1.0 / np.sqrt(np.einsum("nii->ni", A))
    return A * s[:, :, None] * s[:, None, :]


def reciprocal_condition(moments):
    """Reciprocal 2-norm condition numbers of symmetric matrices (n, k, k); NaN if non-finite."""
    rcond = np.full(moments.shape[0], np.nan)
    ok = np.isfinite(moments).all(axis=(1, 2))
    eig = np.linalg.eigvalsh(moments[ok])
    rcond[ok] = np.maximum(eig[:, 0], 0.0) / eig[:, -1]  # round-off can make eig[:, 0] < 0
    return rcond


def condition_screen(bound, x, y, mask, c, q):
    """Reciprocal condition numbers where they matter: exact below a cheap lower bound only.

    For a symmetric positive definite k x k matrix with eigenvalues ``l_1 <= ... <= l_k``,
    the product of the k - 1 largest is at most their mean to the power k - 1 (AM-GM), and
    their sum is below the trace, so ``l_1 >= det ((k - 1) / trace)^(k - 1)``; and ``l_k`` is
    at most the Frobenius norm.  So ``rcond >= det ((k - 1) / trace)^(k - 1) / |A|_F``.  The
    kernel returns that ``bound`` (its Cholesky factors give the determinant to a few eps
    relative to the smallest eigenvalue); rows where it clears :data:`RCOND_MIN` by 1e3 keep
    it, the others (and non-finite ones) get :func:`reciprocal_condition` of their moment
    matrices (:func:`equilibrated_moments` of the kernel's inputs ``x, y, mask, c, q``).
    Which rows pass the check does not depend on the bound.

    It is much tighter than ``det / trace^k`` (3e3 to 8e3 times for an equilibrated 6 x 6
    matrix: trace 6, Frobenius norm between sqrt 6 and 6), so that the one-sided supports at
    the disc's edges (rcond ~ 1e-5) pass without the eigenvalue check in numpy.
    """
    bound = np.array(bound)
    # 1e3 x RCOND_MIN: a margin far above the determinant's round-off
    low = np.flatnonzero(~(bound >= 1e3 * RCOND_MIN))
    if low.size:
        bound[low] = reciprocal_condition(equilibrated_moments(x[low], y[low], mask[low], c, q))
    return bound

