"""Moving-least-squares (MLS) shape functions as padded gather stencils.

This module holds the meshless spatial discretisation of jaxanm (paper section 3.2):

- :class:`Stencils`, a JAX pytree of ``(N, m)`` neighbour indices and MLS shape-function
  weights (value, first and second derivatives) at N evaluation points;
- :func:`build_stencils` (every point of the cloud is both an MLS node and a collocation
  point) and :func:`evaluate_at` (stencils at arbitrary targets, e.g. probes and sections),
  which share one code path;
- :func:`value`, :func:`grad`, :func:`hessian`, :func:`laplacian`: pure gathers and sums,
  safe inside ``jax.jit``, ``jax.jacfwd`` and ``jax.experimental.jet`` (trace those inside
  ``jax.enable_x64(True)``, as jaxanm's entry points do, or inputs are cast to float32).

The MLS approximation with quadratic basis ``p = [1, x, y, x^2, xy, y^2]`` and weight
(paper eq. 30) ``w(r) = exp(-(r/c)^(2q))`` for ``r <= 1``, 0 otherwise, ``r = |x - x_j| / h``,
gives ``phi_j(x) = p(x)^T A(x)^{-1} B(x)`` with ``A = sum_j w_j p(x_j) p(x_j)^T`` and
``B[:, j] = w_j p(x_j)``.  Coordinates are local to each evaluation point and scaled by its
``h``.  ``phi`` and its first and second derivatives (including the derivatives of the moving
weight) come in closed form from differentiating ``A gamma = p`` (see
:func:`_shape_functions`), solved through one QR factorisation of ``sqrt(W) P`` with
equilibrated columns instead of through ``A``: the derivatives lose about
``log10(1 / rcond) / 2`` digits instead of the ``log10(1 / rcond)`` of an elimination on ``A``
(tests/test_mls.py checks them against a 50-digit reference; the comparison with the
elimination this replaced is in ``benchmarks/results/profile_host_step.md``).  The kernel is
jitted ``jax.numpy`` (its results are not differentiated with respect to the points: nothing in
jaxanm does).

Neighbours come from ``scipy.spatial.cKDTree``, or for a moving cloud from the candidate
lists of a :class:`NeighbourList` (remade only when some point has moved far).  The compiled
kernel runs on all evaluation points at once (in calls of up to ``CALL_MAX``, padded to a
multiple of ``CHUNK``) and depends only on that padded size and the stencil width m (and q):
rebuilding stencils for a moved cloud with the same ``m_max`` does not recompile.

Accuracy (quadratic basis, tests/test_mls.py): quadratic fields are reproduced to round-off;
for smooth fields the errors decrease as dr^3 (value), dr^2 (first derivatives) and dr
(second derivatives) on irregular clouds; at the nodes of a regular grid symmetry raises the
value and second-derivative orders to 4 and 2.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
from scipy.spatial import cKDTree

from ._compile_ahead import compile_ahead, wait
from ._x64 import entry_point
from .errors import InputError

__all__ = [
    "NeighbourList",
    "Stencils",
    "build_stencils",
    "evaluate_at",
    "value_matrix",
    "value",
    "grad",
    "hessian",
    "laplacian",
]

N_BASIS = 6
"""Number of quadratic basis functions: the minimum number of nodes in a support."""

M_MAX_MULTIPLE = 8
"""The default stencil width is the largest neighbour count rounded up to a multiple of this."""

CHUNK = 128
"""Granularity of the compiled kernel's calls: each takes a multiple of this many evaluation
points (the last call of a build is padded up to one), so that few shapes compile.  A
multiple of :data:`INNER`."""

CALL_MAX = 1024
"""Most evaluation points per call of the compiled kernel (larger builds make several calls).

A call has a fixed cost (its dispatch, and a start for each of its ~200 XLA fusions), so one
call over a whole paper-sized cloud beats several small ones (measured in
``benchmarks/results/profile_host_step.md``).  The compiled shapes are the multiples of :data:`CHUNK` up to
this: at most 8 per (m, q) and kernel, each compiled once."""

INNER = 64
"""Evaluation points per iteration of the loop (``lax.map``) inside each kernel call.

The kernel's ~200 fusions then each work on (64, m) arrays that stay in the L1/L2 caches
instead of streaming whole-cloud (n, m) arrays, which is faster than one pass and than blocks
of 32 or 128 (measured in ``benchmarks/results/profile_host_step.md``); results change by round-off only.
The loop costs compile time, once per shape (``jaxanm run`` keeps it in its compile cache)."""

RCOND_MIN = 1e-10
"""Smallest accepted reciprocal condition number of the equilibrated moment matrix.

The closed-form kernel loses about ``log10(1 / rcond) / 2`` digits (errors measured below
``4 eps / sqrt(rcond)`` of ``sum |phi|``, and likewise for each derivative); its QR
factorisation (CholeskyQR2) needs ``rcond`` well above eps, which this bound keeps, and below
it the nodes are so nearly collinear (or on a conic) that the approximation is meaningless.  With the
paper's weight (c = 0.2) and h = 3 dr, interior points have rcond ~ 0.4 (regular cloud) or
> 0.05 (jittered by +-dr/4); points on the edge of the disc, whose supports are one-sided under
the narrow Gaussian, have rcond ~ 5e-5 (regular) down to ~ 1e-6 (jittered)."""


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Stencils:
    """MLS stencils at N evaluation points, as padded gathers (a JAX pytree).

    Attributes
    ----------
    index : (N, m) int32
        Node indices of each stencil, nearest first.  Padding entries repeat the evaluation
        point's own index (for :func:`evaluate_at`: the nearest node's index).
    phi, dx, dy, dxx, dxy, dyy : (N, m) float64
        Shape functions and their derivatives at the evaluation points; padding entries are 0.
        The approximation of a nodal-parameter field ``f`` (N_nodes,) at evaluation point i is
        ``sum_k phi[i, k] * f[index[i, k]]``, and likewise for the derivatives.
    """

    index: jax.Array
    phi: jax.Array
    dx: jax.Array
    dy: jax.Array
    dxx: jax.Array
    dxy: jax.Array
    dyy: jax.Array


def _weight(x, y, mask, c, q):
    """Weight ``w = exp(-g)``, ``g = (r^2 / c^2)^q``, at ``xi = 0`` from the nodes' local
    coordinates ``x, y``, and the derivatives of ``g`` with respect to ``xi``:
    ``(g_x, g_y)`` and ``(g_xx, g_xy, g_yy)`` (arrays shaped like ``x``).

    ``r^2 = |xi - x_j|^2`` gives ``r^2_,i = -2 x_ji`` and ``r^2_,ij = 2 delta_ij`` at ``xi = 0``;
    with ``t = r^2 / c^2``, ``g_,i = q t^(q-1) t_,i`` and
    ``g_,ij = q (q-1) t^(q-2) t_,i t_,j + q t^(q-1) t_,ij``.  Integer powers of r^2: smooth at
    r = 0 (the node under xi).  ``w`` is 0 where ``mask`` is False: padding, and nodes outside
    the support r^2 <= 1, which the caller decides (:func:`_stencils`).
    """
    t = (x * x + y * y) / c**2
    w = jnp.where(mask, jnp.exp(-(t**q)), 0.0)
    tx, ty, tii = -2.0 * x / c**2, -2.0 * y / c**2, 2.0 / c**2
    d1 = q * t ** (q - 1) if q > 1 else 1.0
    d2 = q * (q - 1) * t ** (q - 2) if q > 1 else 0.0
    return w, (d1 * tx, d1 * ty), (d2 * tx * tx + d1 * tii, d2 * tx * ty, d2 * ty * ty + d1 * tii)


def _cholesky_inverse(G):
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
        R[j][j] = jnp.sqrt(G[j][j] - sum(R[i][j] * R[i][j] for i in range(j)))
        for col in range(j + 1, k):
            R[j][col] = (G[j][col] - sum(R[i][j] * R[i][col] for i in range(j))) / R[j][j]
    X = [[None] * k for _ in range(k)]
    for j in range(k):
        X[j][j] = 1.0 / R[j][j]
        for i in range(j - 1, -1, -1):
            X[i][j] = -sum(R[i][col] * X[col][j] for col in range(i + 1, j + 1)) / R[i][i]
    return X


def _gram(V):
    """Upper triangle of ``V^T V`` for n matrices given by their columns ``V[i]`` (n, m)."""
    return [[jnp.sum(V[i] * V[j], axis=1) if j >= i else None for j in range(len(V))] for i in range(len(V))]


def _times_upper(V, X):
    """Columns of ``V X`` for columns ``V[i]`` (n, m) and an upper-triangular ``X[i][j]`` (n,)."""
    return [sum(V[i] * X[i][j][:, None] for i in range(j + 1)) for j in range(len(V))]


def _cholesky_qr2(v, P):
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
    A0 = _gram([v * p for p in P])  # P^T W P
    s = [1.0 / jnp.sqrt(A0[i][i]) for i in range(N_BASIS)]
    G1 = [[A0[i][j] * s[i] * s[j] if j >= i else None for j in range(N_BASIS)] for i in range(N_BASIS)]
    R1inv = _cholesky_inverse(G1)
    # a lower bound of rcond(G1) (see _condition_screen), det G1 = prod R1_jj^2
    det = 1.0 / functools.reduce(jnp.multiply, [R1inv[j][j] for j in range(N_BASIS)]) ** 2
    trace = sum(G1[j][j] for j in range(N_BASIS))
    frobenius = jnp.sqrt(sum(G1[i][j] ** 2 * (1.0 if i == j else 2.0)
                             for i in range(N_BASIS) for j in range(i, N_BASIS)))
    bound = det * ((N_BASIS - 1) / trace) ** (N_BASIS - 1) / frobenius
    Q1 = jax.lax.optimization_barrier(_times_upper([v * p * si[:, None] for p, si in zip(P, s)], R1inv))
    R2inv = _cholesky_inverse(_gram(Q1))
    # R^{-1} = R1^{-1} R2^{-1} (upper triangular); column j of R^{-T} is row j of R^{-1}
    Rinv = [[sum(R1inv[i][k] * R2inv[k][j] for k in range(i, j + 1)) if j >= i else None
             for j in range(N_BASIS)] for i in range(N_BASIS)]
    return s, Q1, R2inv, Rinv, bound


# Derivatives of the basis at xi = 0, in the order value, x, y, xx, xy, yy: p(0) = e_0,
# p_,x = e_1, p_,y = e_2, p_,xx = 2 e_3, p_,xy = e_4, p_,yy = 2 e_5.
_BASIS_DERIVATIVES = (1.0, 1.0, 1.0, 2.0, 1.0, 2.0)


def _shape_functions(x, y, mask, c, q, derivatives=True):
    """MLS shape functions at ``xi = 0`` and, with ``derivatives``, their first ``(x, y)`` and
    second ``(xx, xy, yy)`` derivatives with respect to xi, for n stencils at once: node local
    coordinates ``x, y`` and ``mask`` (n, m).  Returns those (n, m) arrays followed by a lower
    bound (n,) of the reciprocal condition numbers of the equilibrated moment matrices, from
    their Cholesky factors (for :func:`_condition_screen`).

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
    """
    # optimization_barrier: arrays used by many later sums are computed once; without it XLA
    # fuses their producers (exp, the products with R^{-1}) into every consumer and recomputes
    # them there, which doubles the kernel's time
    w, (gx, gy), (gxx, gxy, gyy) = _weight(x, y, mask, c, q)
    v = jnp.sqrt(w)
    v, gx, gy, gxx, gxy, gyy = jax.lax.optimization_barrier((v, gx, gy, gxx, gxy, gyy))
    P = [jnp.ones_like(x), x, y, x * x, x * y, y * y]
    s, Q1, R2inv, Rinv, bound = _cholesky_qr2(v, P)

    def Qz(j, f=None):
        """``Q (z_j + Q^T f)`` (n, m) for ``z_j = R^{-T} S p_,j`` and ``f`` (n, m).

        ``Q = Q1 R2^{-1}`` is applied, not formed: ``Q^T f = R2^{-T} (Q1^T f)`` and
        ``Q z = Q1 (R2^{-1} z)``, 6 x 6 triangular products on (n,) arrays in place of 21
        products of (n, m) arrays.  (``R2`` is within a few eps of orthogonal-factor
        conditioning 1, so this changes the results by round-off only.)
        """
        z = {k: Rinv[j][k] * (s[j] * _BASIS_DERIVATIVES[j]) for k in range(j, N_BASIS)}
        if f is not None:
            d = [jnp.sum(Q1[i] * f, axis=1) for i in range(N_BASIS)]
            z = {k: z.get(k, 0.0) + sum(R2inv[i][k] * d[i] for i in range(k + 1)) for k in range(N_BASIS)}
        y = [sum(R2inv[i][k] * z[k] for k in range(i, N_BASIS) if k in z) for i in range(N_BASIS)]
        return sum(Q1[i] * y[i][:, None] for i in range(N_BASIS))

    u = jax.lax.optimization_barrier(Qz(0))
    if not derivatives:
        return v * u, bound
    ux, uy = jax.lax.optimization_barrier((Qz(1, gx * u), Qz(2, gy * u)))
    cxx, cxy, cyy = gx * gx - gxx, gx * gy - gxy, gy * gy - gyy
    uxx = Qz(3, 2.0 * gx * ux - cxx * u)
    uxy = Qz(4, gx * uy + gy * ux - cxy * u)
    uyy = Qz(5, 2.0 * gy * uy - cyy * u)
    return (v * u, v * (ux - gx * u), v * (uy - gy * u), v * (uxx - 2.0 * gx * ux + cxx * u),
            v * (uxy - gx * uy - gy * ux + cxy * u), v * (uyy - 2.0 * gy * uy + cyy * u), bound)


def _blocks(fn, *arrays):
    """``fn`` applied to blocks of :data:`INNER` rows of the (n, ...) ``arrays`` (n a multiple
    of it) by ``lax.map``, inside the jitted kernels; its results joined back to n rows."""
    k = arrays[0].shape[0] // INNER
    out = jax.lax.map(lambda a: fn(*a), tuple(a.reshape((k, INNER) + a.shape[1:]) for a in arrays))
    return tuple(o.reshape((-1,) + o.shape[2:]) for o in out)


@functools.partial(jax.jit, static_argnames=("q",))
def _kernel(x, y, mask, h, c, q):
    """Shape functions and derivatives for n stencils: ``(phi, dx, dy, dxx, dxy, dyy)`` (n, m),
    lower bounds of the moment matrices' rcond (n,) and a finite flag (n,).

    ``x, y`` (n, m): node coordinates relative to each evaluation point, divided by its ``h``
    (n,); ``mask`` (n, m): real (not padding) entries within the support (r <= 1).  Called by
    :func:`_run_kernel` with n a multiple of :data:`CHUNK`, in blocks of :data:`INNER`.
    """
    phi, px, py, pxx, pxy, pyy, bound = _blocks(lambda *a: _shape_functions(*a, c, q), x, y, mask)
    h1 = h[:, None]
    h2 = h1 * h1
    # the barrier: the finite test reads the outputs instead of fusing (recomputing) them
    out = jax.lax.optimization_barrier((phi, px / h1, py / h1, pxx / h2, pxy / h2, pyy / h2))
    # a * 0 is 0 for finite a and NaN otherwise: one sum instead of six boolean reductions
    finite = jnp.isfinite(jnp.sum(sum(a * 0.0 for a in out), axis=1))
    return (*out, bound, finite)


@functools.partial(jax.jit, static_argnames=("q",))
def _value_kernel(x, y, mask, h, c, q):
    """Value-only counterpart of :func:`_kernel`: ``(phi, bound, finite)`` for n stencils (phi
    by the same operations, without the derivatives)."""
    phi, bound = _blocks(lambda *a: _shape_functions(*a, c, q, derivatives=False), x, y, mask)
    phi = jax.lax.optimization_barrier(phi)
    return phi, bound, jnp.isfinite(phi).all(1)


@functools.partial(jax.jit, static_argnames=("n",))
def _joined(parts, n):
    """The first n rows of the concatenation of each array's ``parts`` (a tuple per call), on
    the device: the weights stay jax arrays, for the Stencils, without a copy through numpy
    (a copy per rebuild saved).  Compiled per (n, calls): a concatenation and a slice."""
    return tuple(jnp.concatenate(p)[:n] if len(p) > 1 else p[0][:n] for p in zip(*parts))


_COMPILED: set = set()
"""(kernel, rows, m, q) of the kernel calls made in this process (:func:`_run_kernel`)."""


def _run_kernel(x, y, mask, h, c, q, derivatives=True):
    """Run :func:`_kernel` on all evaluation points, in calls of at most :data:`CALL_MAX`:
    ``(phi, dx, dy, dxx, dxy, dyy)`` (n, m) as jax arrays, ``bound, finite`` (n,) in numpy.

    The points are padded (with copies of the first stencil) to a multiple of :data:`CHUNK`,
    so that the compiled shapes do not depend on N itself.  The numpy inputs go to the jitted
    kernel as they are (no separate ``jnp.asarray`` dispatches), and every call is dispatched
    before any result is read.  Without ``derivatives``, :func:`_value_kernel` runs instead
    and the five derivative arrays are None.
    """
    n = x.shape[0]
    n_pad = -(-n // CHUNK) * CHUNK

    def padded(a):
        return np.concatenate([a, np.repeat(a[:1], n_pad - n, axis=0)]) if n_pad > n else a

    x, y, mask, h = padded(x), padded(y), padded(mask), padded(h)
    kernel = _kernel if derivatives else _value_kernel
    starts = range(0, n_pad, CALL_MAX)
    # the calls' distinct shapes (a full call and the rest), new to this process, compile side by
    # side in the background rather than one after the other at their calls
    ahead = {(kernel, min(CALL_MAX, n_pad - i), x.shape[1], q): i for i in starts}
    if len(ahead) > 1 and not set(ahead) <= _COMPILED:
        for future in [compile_ahead(kernel, x[i:i + CALL_MAX], y[i:i + CALL_MAX], mask[i:i + CALL_MAX],
                                     h[i:i + CALL_MAX], c, q) for i in ahead.values()]:
            wait(future)
    _COMPILED.update(ahead)
    calls = [kernel(x[i:i + CALL_MAX], y[i:i + CALL_MAX], mask[i:i + CALL_MAX], h[i:i + CALL_MAX], c, q)
             for i in starts]
    weights = _joined(tuple(res[:-2] for res in calls), n)
    bound, finite = (np.concatenate([np.asarray(res[k]) for res in calls])[:n] for k in (-2, -1))
    return (*weights, bound, finite) if derivatives else (*weights, None, None, None, None, None, bound, finite)


def _as_cloud(name, points):
    """Validated (n, 2) float64 numpy array."""
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{name} must be an (N, 2) array of coordinates, got shape {arr.shape}.")
    bad = np.flatnonzero(~np.isfinite(arr).all(axis=1))
    if bad.size:
        raise InputError(
            f"{name} must be finite: row {bad[0]} is {arr[bad[0]].tolist()} "
            f"({bad.size} non-finite rows in all); remove or fix these points."
        )
    return arr


def _as_radius(h, n, owner):
    """Validated influence radius per evaluation point, (n,) float64."""
    arr = np.asarray(h, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    elif arr.shape != (n,):
        raise InputError(
            f"h must be a scalar or have shape ({n},) (one per {owner}), got {arr.shape}."
        )
    bad = np.flatnonzero(~(np.isfinite(arr) & (arr > 0)))
    if bad.size:
        raise InputError(
            f"h must be finite and > 0: h[{bad[0]}] = {arr[bad[0]]}; the paper uses h = 3 dr "
            f"(dr the point spacing)."
        )
    return arr


def _check_weight(c, q):
    """Validate the weight parameters of eq. 30."""
    if not (np.isfinite(c) and c > 0):
        raise InputError(f"c must be finite and > 0 (the paper uses c = 0.2), got {c}.")
    if isinstance(q, bool) or not isinstance(q, (int, np.integer)) or q < 1:
        raise InputError(
            f"q must be a positive integer (the weight exp(-(r/c)^(2q)) is then smooth at r = 0, "
            f"as its second derivatives require); the paper uses q = 1, got {q!r}."
        )


def _equilibrated_moments(x, y, mask, c, q):
    """The equilibrated moment matrices ``S P^T W P S`` (n, 6, 6) of n stencils (scaled local
    coordinates ``x, y`` and support ``mask`` (n, m), as for the kernel), in numpy: for the
    few stencils whose condition :func:`_condition_screen` computes exactly."""
    w = np.where(mask, np.exp(-(((x * x + y * y) / c**2) ** q)), 0.0)
    P = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)
    A = np.einsum("nmi,nm,nmj->nij", P, w, P)
    with np.errstate(divide="ignore", invalid="ignore"):  # an empty support: non-finite, refused
        s = 1.0 / np.sqrt(np.einsum("nii->ni", A))
    return A * s[:, :, None] * s[:, None, :]


def _reciprocal_condition(moments):
    """Reciprocal 2-norm condition numbers of symmetric matrices (n, k, k); NaN if non-finite."""
    rcond = np.full(moments.shape[0], np.nan)
    ok = np.isfinite(moments).all(axis=(1, 2))
    eig = np.linalg.eigvalsh(moments[ok])
    rcond[ok] = np.maximum(eig[:, 0], 0.0) / eig[:, -1]  # round-off can make eig[:, 0] < 0
    return rcond


def _condition_screen(bound, x, y, mask, c, q):
    """Reciprocal condition numbers where they matter: exact below a cheap lower bound only.

    For a symmetric positive definite k x k matrix with eigenvalues ``l_1 <= ... <= l_k``,
    the product of the k - 1 largest is at most their mean to the power k - 1 (AM-GM), and
    their sum is below the trace, so ``l_1 >= det ((k - 1) / trace)^(k - 1)``; and ``l_k`` is
    at most the Frobenius norm.  So ``rcond >= det ((k - 1) / trace)^(k - 1) / |A|_F``.  The
    kernel returns that ``bound`` (its Cholesky factors give the determinant to a few eps
    relative to the smallest eigenvalue); rows where it clears :data:`RCOND_MIN` by 1e3 keep
    it, the others (and non-finite ones) get :func:`_reciprocal_condition` of their moment
    matrices (:func:`_equilibrated_moments` of the kernel's inputs ``x, y, mask, c, q``).
    Which rows pass the check does not depend on the bound.

    It is much tighter than ``det / trace^k`` (3e3 to 8e3 times for an equilibrated 6 x 6
    matrix: trace 6, Frobenius norm between sqrt 6 and 6), so that the one-sided supports at
    the disc's edges (rcond ~ 1e-5) pass without the eigenvalue check in numpy.
    """
    bound = np.array(bound)
    # 1e3 x RCOND_MIN: a margin far above the determinant's round-off
    low = np.flatnonzero(~(bound >= 1e3 * RCOND_MIN))
    if low.size:
        bound[low] = _reciprocal_condition(_equilibrated_moments(x[low], y[low], mask[low], c, q))
    return bound


def _check_m_max(m_max):
    """Validate an explicit stencil width."""
    if m_max is not None and (isinstance(m_max, bool) or not isinstance(m_max, (int, np.integer))
                              or m_max < N_BASIS):
        raise InputError(f"m_max must be an integer >= {N_BASIS} (or None), got {m_max!r}.")


class NeighbourList:
    """Neighbour candidates of a moving cloud (a Verlet list), for rebuilding its stencils.

    One cKDTree query collects, for every evaluation point (the nodes themselves, or moving
    targets such as material points), the nodes within its own ``h + skin`` (on a graded cloud
    h varies tenfold: a common radius would give the fine zone's points a hundred times the
    candidates they need).  Until the nodes and the targets have together moved more than
    the ``skin`` left above each point's present h (the largest node move plus that target's
    move; for the nodes themselves twice the largest move), every pair now within ``h`` is
    among those candidates, so the nearest ``m`` within ``h`` are found by sorting the
    candidates' exact distances; beyond that, or for other sizes, the list is remade.  The result is what
    ``cKDTree.query(targets, k=m, distance_upper_bound=h)`` returns (distances computed the
    same way, ``inf`` where fewer than ``m`` are within ``h``; rows with a candidate at ``h``
    to round-off are left to cKDTree), up to the order of equidistant points.  Plain numpy
    state: it pickles into checkpoints as it is.

    Parameters
    ----------
    skin : float
        Extra search radius (same units as the points).
    """

    def __init__(self, skin: float):
        self.skin = float(skin)
        self.reference: np.ndarray | None = None   # (N, 2) node positions when the list was made
        self.targets: np.ndarray | None = None     # (T, 2) target positions then (None: the nodes themselves)
        self.reach: np.ndarray | None = None       # (T,) the radius each target's candidates cover
        self.candidates: np.ndarray | None = None  # (T, K) node indices, N where absent
        self.rebuilds = 0
        self.width = 0          # the widest stencil it has given (m=None): widths only grow

    @staticmethod
    def _moved(now, then) -> float:
        return float(np.sqrt(np.max(np.sum((now - then) ** 2, axis=1))))

    def _stale(self, points, targets, h) -> bool:
        reference, reach, then = self.reference, self.reach, self.targets
        if (reference is None or reach is None or reference.shape != points.shape or reach.shape != h.shape
                or (targets is None) != (then is None)):
            return True
        moved = self._moved(points, reference)
        if targets is None or then is None:
            moved = 2.0 * moved
        elif targets.shape != then.shape:
            return True
        else:
            moved = moved + np.sqrt(np.sum((targets - then) ** 2, axis=1))
        return not np.all(h + moved <= reach)

    def query(self, points: np.ndarray, h: np.ndarray, m: int | None, targets: np.ndarray | None = None):
        """``(dist, idx, m)``: the ``m`` nearest nodes closer than ``nextafter(h.max())`` to each
        target (default: to each node, itself first).  ``h`` (T,): radius per target; ``m=None``:
        the largest count within ``h``, rounded up to a multiple of :data:`M_MAX_MULTIPLE`, and
        at least the widest this list has given before (targets that move in and out of a
        denser zone would otherwise change the width, and the compiled kernel, back and forth;
        the extra columns are padding, outside every support)."""
        hmax = float(np.nextafter(h.max(), np.inf))
        centers = points if targets is None else targets
        h_at = np.nextafter(np.broadcast_to(np.asarray(h, dtype=np.float64), (len(centers),)), np.inf)
        if self._stale(points, targets, h_at):
            tree = cKDTree(points)
            reach = h_at + self.skin
            k = int(tree.query_ball_point(centers, r=reach, return_length=True).max())
            dist, cand = tree.query(centers, k=max(k, 1), distance_upper_bound=float(reach.max()))
            dist, cand = dist.reshape(len(centers), -1), cand.reshape(len(centers), -1)
            cand[~(dist <= reach[:, None])] = points.shape[0]  # beyond this target's own reach
            self.candidates, self.reference, self.reach = cand, points.copy(), reach
            self.targets = None if targets is None else targets.copy()
            self.rebuilds += 1
        n, cand = points.shape[0], self.candidates
        assert cand is not None  # made by the first query, which is always stale
        # coordinates gathered one axis at a time (a 1-D take is 4x faster than rows of 2)
        dx = np.append(points[:, 0], np.inf)[cand] - centers[:, :1]  # index n: absent candidate
        dy = np.append(points[:, 1], np.inf)[cand] - centers[:, 1:]
        d = np.sqrt(dx * dx + dy * dy)
        # A node at the radius to round-off (the polar cloud has them: the tool's third ring
        # is 3 dr = h from its centre) is in or out by round-off, and cKDTree's pruning of
        # its boxes (rounded box distances, off by ulps of h) decides it its own way:
        # let cKDTree decide those rows, so that the stencils are the ones it gives (the
        # weight there, exp(-1/c^2), is not negligible).
        band = 1e-12 * (hmax + np.abs(points).max() + np.abs(centers).max())
        rows = np.flatnonzero(((np.abs(d - hmax) <= band) | (np.abs(d - h[:, None]) <= band)).any(axis=1))
        tree = cKDTree(points) if rows.size else None
        if m is None:
            counts = (d <= h[:, None]).sum(axis=1)
            if tree is not None:
                counts[rows] = tree.query_ball_point(centers[rows], r=h[rows], return_length=True)
            m = max(M_MAX_MULTIPLE * max(1, math.ceil(int(counts.max()) / M_MAX_MULTIPLE)), self.width)
            self.width = m  # never narrower than before: a new width recompiles the MLS kernel
        flat = (np.argsort(d, axis=1, kind="stable")[:, :m]
                + cand.shape[1] * np.arange(len(centers))[:, None])
        dist, idx = d.reshape(-1)[flat], cand.reshape(-1)[flat]
        out = ~(dist < hmax)  # strict, as cKDTree's distance_upper_bound
        dist[out], idx[out] = np.inf, n
        if dist.shape[1] < m:  # fewer candidates than the stencil width
            pad = m - dist.shape[1]
            dist = np.concatenate([dist, np.full((len(centers), pad), np.inf)], axis=1)
            idx = np.concatenate([idx, np.full((len(centers), pad), n)], axis=1)
        if tree is not None:
            dist[rows], idx[rows] = (a.reshape(rows.size, m) for a in
                                     tree.query(centers[rows], k=m, distance_upper_bound=hmax))
        return dist, idx, m


def _stencils(nodes, centers, h, m_max, c, q, owner, same_cloud, neighbours=None, derivatives=True):
    """Shared code path of :func:`build_stencils` and :func:`evaluate_at`.

    ``same_cloud``: the evaluation points are the nodes themselves (``centers is nodes``);
    padding then repeats each point's own index and coinciding points are rejected.  Otherwise
    padding repeats the index of the nearest node.  ``neighbours``: a :class:`NeighbourList`
    to search instead of a new cKDTree (for the cloud itself, with a given ``m_max``).  Without
    ``derivatives`` only ``phi`` is computed (the derivative fields are None).
    """
    _check_weight(c, q)
    _check_m_max(m_max)
    if neighbours is not None and (m_max is not None or not same_cloud):
        dist, idx, m = neighbours.query(nodes, h, None if m_max is None else int(m_max),
                                        None if same_cloud else centers)
    else:
        tree = cKDTree(nodes)
        if m_max is None:
            counts = tree.query_ball_point(centers, r=h, return_length=True)
            m = M_MAX_MULTIPLE * max(1, math.ceil(int(counts.max()) / M_MAX_MULTIPLE))
        else:
            m = int(m_max)
        dist, idx = tree.query(centers, k=m, distance_upper_bound=float(np.nextafter(h.max(), np.inf)))
    mask = dist <= h[:, None]
    counts = mask.sum(axis=1)  # min(true count, m): exact wherever it is below 6 <= m
    few = np.flatnonzero(counts < N_BASIS)
    if few.size:
        i = few[0]
        raise InputError(
            f"{owner} {i} at {centers[i].tolist()} has {counts[i]} node(s) within h = {h[i]:.6g}"
            f"{' (itself included)' if same_cloud else ''}; the quadratic MLS basis needs at "
            f"least {N_BASIS} ({few.size} {owner}s have too few): increase h (the paper uses "
            f"h = 3 dr)."
        )
    pad = np.arange(len(centers)) if same_cloud else idx[:, 0]
    node = np.where(mask, idx, pad[:, None])  # numpy's own index type: gathers 2x faster than int32
    index = node.astype(np.int32)
    if same_cloud:
        dup = np.flatnonzero(mask[:, 1] & (dist[:, 1] == 0.0))
        if dup.size:
            i = dup[0]
            raise InputError(
                f"points {idx[i, 0]} and {idx[i, 1]} coincide at {centers[i].tolist()} "
                f"({dup.size} points have a duplicate); remove duplicate points."
            )

    # scaled local coordinates, one axis at a time (a 1-D take is faster than rows of 2)
    x = (nodes[:, 0][node] - centers[:, :1]) / h[:, None]
    y = (nodes[:, 1][node] - centers[:, 1:]) / h[:, None]
    # The support r <= 1 in the scaled coordinates is decided here, in numpy (two roundings,
    # no fused multiply-add): inside the jitted kernel XLA may contract x*x + y*y into an FMA,
    # and for nodes at h to round-off (the polar cloud's rings) the two roundings disagree.
    inside = mask & (x * x + y * y <= 1.0)
    phi, dx, dy, dxx, dxy, dyy, bound, finite = _run_kernel(x, y, inside, h, float(c), int(q), derivatives)
    rcond = _condition_screen(bound, x, y, inside, float(c), int(q))
    bad = np.flatnonzero(~(finite & (rcond >= RCOND_MIN)))
    if bad.size:
        i = bad[0]
        raise InputError(
            f"MLS moment matrix at {owner} {i} ({centers[i].tolist()}) is singular or "
            f"ill-conditioned (reciprocal condition number {rcond[i]:.3g} < {RCOND_MIN:g}, "
            f"finite shape functions: {bool(finite[i])}; {int(mask[i].sum())} nodes within "
            f"h = {h[i]:.6g}; {bad.size} {owner}s affected): the nodes carrying weight are too "
            f"few or (nearly) collinear; increase h (the paper uses h = 3 dr) so that the support "
            f"spans both directions, or add points."
        )
    return Stencils(jnp.asarray(index), phi, dx, dy, dxx, dxy, dyy)


@entry_point
def build_stencils(points, h, m_max=None, c=0.2, q=1, neighbours=None) -> Stencils:
    """MLS stencils at the points of a cloud, each point being both node and collocation point.

    Parameters
    ----------
    points : (N, 2) array
        Point coordinates (finite, no duplicates).
    h : float or (N,) array
        Influence radius h_I of each collocation point (> 0); the paper uses ``3 dr``.
        A node j belongs to the stencil of point i if ``|x_i - x_j| <= h_i``.
    m_max : int, optional
        Stencil width m.  Default: the largest neighbour count of the cloud, rounded up to a
        multiple of 8.  If a point has more than ``m_max`` neighbours, its ``m_max`` nearest are
        kept (the dropped ones are the farthest, whose weights are the smallest).  To rebuild
        stencils of a moved cloud without changing shapes (and without recompiling), pass
        ``m_max=st.index.shape[1]`` from the first build.
    c, q : float, int
        Weight parameters of ``w(r) = exp(-(r/c)^(2q))``, ``r = distance / h`` (paper eq. 30:
        c = 0.2, q = 1).  ``q`` must be a positive integer.
    neighbours : NeighbourList, optional
        Candidate lists kept from the previous build of a moving cloud (used with ``m_max``):
        the neighbour search then sorts those candidates instead of building a cKDTree.

    Returns
    -------
    Stencils
        ``(N, m)`` arrays; padding entries repeat the point's own index with zero weights.

    Raises
    ------
    InputError (a ValueError)
        Malformed or non-finite points, ``h <= 0``, coinciding points, a point with fewer than
        6 nodes within h, or a singular / ill-conditioned moment matrix.
    """
    pts = _as_cloud("points", points)
    hh = _as_radius(h, pts.shape[0], "point")
    return _stencils(pts, pts, hh, m_max, c, q, "point", same_cloud=True, neighbours=neighbours)


@entry_point
def evaluate_at(points, h, targets, m_max=None, c=0.2, q=1, derivatives=True, neighbours=None) -> Stencils:
    """MLS stencils at arbitrary target locations (probes, sections), from the nodes ``points``.

    Same approximation and code path as :func:`build_stencils`; ``h`` is a scalar or one radius
    per target, and the returned ``(T, m)`` stencils gather from the N nodes: the value of a
    nodal-parameter field ``f`` (N,) at the targets is ``value(st, f)``.  Padding entries repeat
    the index of the target's nearest node, with zero weights.  ``m_max`` as in
    :func:`build_stencils` (default from the targets' neighbour counts).  ``derivatives=False``
    computes only ``phi`` (2x cheaper; the same values): the stencils' ``dx`` ... ``dyy`` are
    then None, for :func:`value` only.  ``neighbours``: a :class:`NeighbourList` kept for
    moving targets on a moving cloud (e.g. material points), used instead of a new cKDTree.
    """
    pts = _as_cloud("points", points)
    tgt = _as_cloud("targets", targets)
    hh = _as_radius(h, tgt.shape[0], "target")
    return _stencils(pts, tgt, hh, m_max, c, q, "target", same_cloud=False, derivatives=derivatives,
                     neighbours=neighbours)


def value_matrix(st: Stencils, n_nodes: int | None = None) -> scipy.sparse.csc_matrix:
    """The MLS value operator as a sparse (M, n_nodes) matrix: ``value_matrix(st) @ f == value(st, f)``.

    ``n_nodes`` defaults to M (stencils of a cloud at its own points).  MLS is not interpolating,
    so nodal parameters that reproduce given values solve ``value_matrix(st) @ f = values``.
    """
    index, phi = np.asarray(st.index), np.asarray(st.phi)
    M = index.shape[0]
    rows = np.repeat(np.arange(M), index.shape[1])
    return scipy.sparse.csc_matrix((phi.reshape(-1), (rows, index.reshape(-1))), shape=(M, n_nodes or M))


def _contract(w, st, f):
    """``sum_k w[i, k] * f[index[i, k], ...]`` for a field f of shape (N_nodes, ...)."""
    g = jnp.asarray(f)[st.index]
    return jnp.sum(w.reshape(w.shape + (1,) * (g.ndim - 2)) * g, axis=1)


@entry_point
def value(st: Stencils, f):
    """MLS approximation of nodal parameters ``f`` (N_nodes, ...) at the stencils' points."""
    return _contract(st.phi, st, f)


@entry_point
def grad(st: Stencils, f):
    """Gradient ``(N, 2, ...)`` (last axis of size 2 for a scalar field: ``(N, 2)``)."""
    return jnp.stack([_contract(st.dx, st, f), _contract(st.dy, st, f)], axis=1)


@entry_point
def hessian(st: Stencils, f):
    """Second derivatives ``(N, 2, 2, ...)``: ``[[f_xx, f_xy], [f_xy, f_yy]]`` per point."""
    fxx, fxy, fyy = (_contract(w, st, f) for w in (st.dxx, st.dxy, st.dyy))
    return jnp.stack([jnp.stack([fxx, fxy], axis=1), jnp.stack([fxy, fyy], axis=1)], axis=1)


@entry_point
def laplacian(st: Stencils, f):
    """Laplacian ``f_xx + f_yy`` (N, ...) of nodal parameters ``f`` at the stencils' points."""
    return _contract(st.dxx + st.dyy, st, f)
