"""The closed-form MLS shape functions of one evaluation point's stencil, for n stencils at once.

The MLS approximation with quadratic basis ``p = [1, x, y, x^2, xy, y^2]`` and weight
(paper eq. 30) ``w(r) = exp(-(r/c)^(2q))`` for ``r <= 1``, 0 otherwise, ``r = |x - x_j| / h``,
gives ``phi_j(x) = p(x)^T A(x)^{-1} B(x)`` with ``A = sum_j w_j p(x_j) p(x_j)^T`` and
``B[:, j] = w_j p(x_j)``.  Coordinates are local to each evaluation point and scaled by its
``h``.  ``phi`` and its first and second derivatives (including the derivatives of the moving
weight) come in closed form from differentiating ``A gamma = p`` (see
:func:`shape_functions`), solved through one QR factorisation of ``sqrt(W) P`` with
equilibrated columns instead of through ``A``: the derivatives lose about
``log10(1 / rcond) / 2`` digits instead of the ``log10(1 / rcond)`` of an elimination on ``A``
(tests/test_mls.py checks them against a 50-digit reference; the comparison with the
elimination this replaced is in ``benchmarks/results/profile_host_step.md``).  Written in
an array namespace ``xp``: ``jax.numpy`` for the jitted kernel, ``numpy`` for the host
(:mod:`jaxanm.mls._kernel` says which runs when); its results are not differentiated with
respect to the points: nothing in jaxanm does.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

N_BASIS = 6
"""Number of quadratic basis functions: the minimum number of nodes in a support."""

RCOND_MIN = 1e-10
"""Smallest accepted reciprocal condition number of the equilibrated moment matrix.

The closed-form kernel loses about ``log10(1 / rcond) / 2`` digits (errors measured below
``4 eps / sqrt(rcond)`` of ``sum |phi|``, and likewise for each derivative); its QR
factorisation (CholeskyQR2) needs ``rcond`` well above eps, which this bound keeps, and below
it the nodes are so nearly collinear (or on a conic) that the approximation is meaningless.  With the
paper's weight (c = 0.2) and h = 3 dr, interior points have rcond ~ 0.4 (regular cloud) or
> 0.05 (jittered by +-dr/4); points on the edge of the disc, whose supports are one-sided under
the narrow Gaussian, have rcond ~ 5e-5 (regular) down to ~ 1e-6 (jittered)."""


def _barrier(xp, value):
    """``value`` behind an XLA optimisation barrier when traced by ``jax.numpy`` (see
    :func:`shape_functions`), as it is with numpy."""
    return jax.lax.optimization_barrier(value) if xp is jnp else value


def _weight(x, y, mask, c, q, xp):
    """Weight ``w = exp(-g)``, ``g = (r^2 / c^2)^q``, at ``xi = 0`` from the nodes' local
    coordinates ``x, y``, and the derivatives of ``g`` with respect to ``xi``:
    ``(g_x, g_y)`` and ``(g_xx, g_xy, g_yy)`` (arrays shaped like ``x``).

    ``r^2 = |xi - x_j|^2`` gives ``r^2_,i = -2 x_ji`` and ``r^2_,ij = 2 delta_ij`` at ``xi = 0``;
    with ``t = r^2 / c^2``, ``g_,i = q t^(q-1) t_,i`` and
    ``g_,ij = q (q-1) t^(q-2) t_,i t_,j + q t^(q-1) t_,ij``.  Integer powers of r^2: smooth at
    r = 0 (the node under xi).  ``w`` is 0 where ``mask`` is False: padding, and nodes outside
    the support r^2 <= 1, which the caller decides (:func:`jaxanm.mls.build_stencils`).
    """
    t = (x * x + y * y) / c**2
    w = xp.where(mask, xp.exp(-(t**q)), 0.0)
    tx, ty, tii = -2.0 * x / c**2, -2.0 * y / c**2, 2.0 / c**2
    d1 = q * t ** (q - 1) if q > 1 else 1.0
    d2 = q * (q - 1) * t ** (q - 2) if q > 1 else 0.0
    return w, (d1 * tx, d1 * ty), (d2 * tx * tx + d1 * tii, d2 * tx * ty, d2 * ty * ty + d1 * tii)


def _cholesky_inverse(G, xp):
    """``R^{-1}`` for the upper-triangular ``R`` with ``R^T R = G``, for n symmetric positive
    definite k x k matrices given entrywise: ``G[i][j]`` (n,) for ``i <= j``; ``R^{-1}`` the
    same way (nested lists, upper triangle).

    Written out on the entries (k = 6: a few hundred operations on (n,) arrays).  Cholesky is
    backward stable without pivoting; an indefinite or singular ``G`` gives non-finite results,
    which the caller checks.
    """
    k = len(G)
    R = [[None] * k for _ in range(k)]
    for j in range(k):
        R[j][j] = xp.sqrt(G[j][j] - sum(R[i][j] * R[i][j] for i in range(j)))
        for col in range(j + 1, k):
            R[j][col] = (G[j][col] - sum(R[i][j] * R[i][col] for i in range(j))) / R[j][j]
    X = [[None] * k for _ in range(k)]
    for j in range(k):
        X[j][j] = 1.0 / R[j][j]
        for i in range(j - 1, -1, -1):
            X[i][j] = -sum(R[i][col] * X[col][j] for col in range(i + 1, j + 1)) / R[i][i]
    return X


def _gram(V, xp):
    """Upper triangle of ``V^T V`` for n matrices given by their columns ``V[i]`` (n, m)."""
    return [[xp.sum(V[i] * V[j], axis=1) if j >= i else None for j in range(len(V))] for i in range(len(V))]


def _times_upper(V, X):
    """Columns of ``V X`` for columns ``V[i]`` (n, m) and an upper-triangular ``X[i][j]`` (n,)."""
    return [sum(V[i] * X[i][j][:, None] for i in range(j + 1)) for j in range(len(V))]


def _cholesky_qr2(v, P, xp):
    """The QR factorisation ``V S = Q R`` of the equilibrated ``V = sqrt(W) P`` (columns
    ``v * P[i]``, (n, m) each) for n stencils at once, by CholeskyQR2 (Fukaya, Nakatsukasa,
    Yanagisawa, Yamamoto, 2014; error analysis: Yamamoto et al., ETNA 44, 2015):
    ``Q1 = V S R1^{-1}`` with ``R1^T R1 = S V^T V S``, then the same once more on ``Q1``:
    ``Q = Q1 R2^{-1}``, ``R = R2 R1``.  For ``cond(V) < eps^(-1/2)`` (here
    ``cond(V) = rcond^(-1/2) <= 1e5``, by :data:`RCOND_MIN`) Q is orthonormal to a few eps and
    ``V S - Q R`` is a few eps of ``|V S|``, as with Householder reflections.

    Returns the equilibration ``s = 1 / sqrt(diag A)`` (list of (n,)), the columns of ``Q1``,
    ``R2^{-1}`` and ``R^{-1}`` (upper triangles, (n,) entries), and a lower bound (n,) of the
    reciprocal condition number of the equilibrated ``A = P^T W P``.
    """
    A0 = _gram([v * p for p in P], xp)  # P^T W P
    s = [1.0 / xp.sqrt(A0[i][i]) for i in range(N_BASIS)]
    G1 = [[A0[i][j] * s[i] * s[j] if j >= i else None for j in range(N_BASIS)] for i in range(N_BASIS)]
    R1inv = _cholesky_inverse(G1, xp)
    # a lower bound of rcond(G1) (see jaxanm.mls._condition.condition_screen), det G1 = prod R1_jj^2
    det = 1.0 / functools.reduce(xp.multiply, [R1inv[j][j] for j in range(N_BASIS)]) ** 2
    trace = sum(G1[j][j] for j in range(N_BASIS))
    frobenius = xp.sqrt(sum(G1[i][j] ** 2 * (1.0 if i == j else 2.0)
                             for i in range(N_BASIS) for j in range(i, N_BASIS)))
    bound = det * ((N_BASIS - 1) / trace) ** (N_BASIS - 1) / frobenius
    Q1 = _barrier(xp, _times_upper([v * p * si[:, None] for p, si in zip(P, s)], R1inv))
    R2inv = _cholesky_inverse(_gram(Q1, xp), xp)
    # R^{-1} = R1^{-1} R2^{-1} (upper triangular); column j of R^{-T} is row j of R^{-1}
    Rinv = [[sum(R1inv[i][k] * R2inv[k][j] for k in range(i, j + 1)) if j >= i else None
             for j in range(N_BASIS)] for i in range(N_BASIS)]
    return s, Q1, R2inv, Rinv, bound


# Derivatives of the basis at xi = 0, in the order value, x, y, xx, xy, yy: p(0) = e_0,
# p_,x = e_1, p_,y = e_2, p_,xx = 2 e_3, p_,xy = e_4, p_,yy = 2 e_5.
_BASIS_DERIVATIVES = (1.0, 1.0, 1.0, 2.0, 1.0, 2.0)


def shape_functions(x, y, mask, c, q, derivatives=True, xp=jnp):
    """MLS shape functions at ``xi = 0`` and, with ``derivatives``, their first ``(x, y)`` and
    second ``(xx, xy, yy)`` derivatives with respect to xi, for n stencils at once: node local
    coordinates ``x, y`` and ``mask`` (n, m).  Returns those (n, m) arrays followed by a lower
    bound (n,) of the reciprocal condition numbers of the equilibrated moment matrices, from
    their Cholesky factors (for :func:`jaxanm.mls._condition.condition_screen`).

    With ``A = P^T W P``, ``gamma = A^{-1} p(xi)`` and ``phi = W P gamma``, differentiating
    ``A gamma = p`` gives ``A gamma_,i = p_,i - A_,i gamma`` and
    ``A gamma_,ij = p_,ij - A_,i gamma_,j - A_,j gamma_,i - A_,ij gamma``, where only the
    weights depend on xi: ``w_,i = -w g_,i``, ``w_,ij = w (g_,i g_,j - g_,ij)``.  These are
    solved through a QR factorisation ``sqrt(W) P S = Q R`` (``S`` the equilibration
    ``1 / sqrt(diag A)``) rather than through ``A``: with ``z = R S^{-1} gamma`` and
    ``u = Q z``, ``A_,i gamma = -S^{-1} R^T Q^T (g_,i u)`` and so on, so that

        z       = R^{-T} S p,                 phi       = sqrt(w) u,
        z_,i    = R^{-T} S p_,i + Q^T (g_,i u),            phi_,i  = sqrt(w) (Q z_,i - g_,i u),
        z_,ij   = R^{-T} S p_,ij + Q^T (g_,i Q z_,j + g_,j Q z_,i - (g_,i g_,j - g_,ij) u),
        phi_,ij = sqrt(w) (Q z_,ij - g_,i Q z_,j - g_,j Q z_,i + (g_,i g_,j - g_,ij) u).

    One factorisation and 6 right-hand sides ``S p_,..`` (``R^{-T} S diag(p_,..)`` is a column
    scaling of ``R^{-T}``); the only inverse is that of R, whose condition number is the square
    root of A's.  (Solving with A itself, the normal equations, squares it: the derivatives
    then lose up to ``log10(1 / rcond)`` digits.)  The QR factorisation is
    :func:`_cholesky_qr2`.  Everything is written out on the 6 basis indices -- elementwise
    products and sums over the stencil of (n, m) arrays, and (n,) arrays for the 6 x 6
    matrices -- not as batched matrix products (XLA runs those as one tiny product per
    stencil, several times slower) nor ``jnp.linalg`` (batched LAPACK calls inside this kernel
    intermittently deadlocked the XLA CPU runtime, jaxlib 0.10.2, under load).

    ``xp`` is the array namespace the formulas run on: ``jax.numpy`` (traced into the jitted
    kernel) or ``numpy`` (on the host, no compilation); the two differ by round-off.
    """
    # optimization_barrier: arrays used by many later sums are computed once; without it XLA
    # fuses their producers (exp, the products with R^{-1}) into every consumer and recomputes
    # them there, which doubles the kernel's time
    w, (gx, gy), (gxx, gxy, gyy) = _weight(x, y, mask, c, q, xp)
    v = xp.sqrt(w)
    v, gx, gy, gxx, gxy, gyy = _barrier(xp, (v, gx, gy, gxx, gxy, gyy))
    P = [xp.ones_like(x), x, y, x * x, x * y, y * y]
    s, Q1, R2inv, Rinv, bound = _cholesky_qr2(v, P, xp)

    def Qz(j, f=None):
        """``Q (z_j + Q^T f)`` (n, m) for ``z_j = R^{-T} S p_,j`` and ``f`` (n, m).

        ``Q = Q1 R2^{-1}`` is applied, not formed: ``Q^T f = R2^{-T} (Q1^T f)`` and
        ``Q z = Q1 (R2^{-1} z)``, 6 x 6 triangular products on (n,) arrays in place of 21
        products of (n, m) arrays.  (``R2`` is within a few eps of orthogonal-factor
        conditioning 1, so this changes the results by round-off only.)
        """
        z = {k: Rinv[j][k] * (s[j] * _BASIS_DERIVATIVES[j]) for k in range(j, N_BASIS)}
        if f is not None:
            d = [xp.sum(Q1[i] * f, axis=1) for i in range(N_BASIS)]
            z = {k: z.get(k, 0.0) + sum(R2inv[i][k] * d[i] for i in range(k + 1)) for k in range(N_BASIS)}
        y = [sum(R2inv[i][k] * z[k] for k in range(i, N_BASIS) if k in z) for i in range(N_BASIS)]
        return sum(Q1[i] * y[i][:, None] for i in range(N_BASIS))

    u = _barrier(xp, Qz(0))
    if not derivatives:
        return v * u, bound
    ux, uy = _barrier(xp, (Qz(1, gx * u), Qz(2, gy * u)))
    cxx, cxy, cyy = gx * gx - gxx, gx * gy - gxy, gy * gy - gyy
    uxx = Qz(3, 2.0 * gx * ux - cxx * u)
    uxy = Qz(4, gx * uy + gy * ux - cxy * u)
    uyy = Qz(5, 2.0 * gy * uy - cyy * u)
    return (v * u, v * (ux - gx * u), v * (uy - gy * u), v * (uxx - 2.0 * gx * ux + cxx * u),
            v * (uxy - gx * uy - gy * ux + cxy * u), v * (uyy - 2.0 * gy * uy + cyy * u), bound)

