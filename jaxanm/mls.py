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
``B[:, j] = w_j p(x_j)``.  ``phi`` is written once in ``jax.numpy`` as a function of the
evaluation point; its first and second derivatives (including the derivatives of the moving
weight) are obtained by forward-mode autodiff.  Coordinates are local to each evaluation
point and scaled by its ``h``; the moment matrix is equilibrated (symmetric diagonal scaling)
before the solve.

Neighbours come from ``scipy.spatial.cKDTree``, or for a moving cloud from the candidate
lists of a :class:`NeighbourList` (remade only when some point has moved far).  The compiled kernel runs on chunks of
``CHUNK`` evaluation points and depends only on the stencil width m (and q): rebuilding
stencils for a moved cloud with the same ``m_max`` -- or for any N -- does not recompile.

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
"""Evaluation points per call of the compiled kernel (the last call is padded).

128 keeps a call's working set in the L2 cache: on fsw_paper (881 points, m = 32) the kernel
executes in 9 ms with 128 per call against 15 ms with 512 and 18 ms with 1024 (one core,
issue 14)."""

RCOND_MIN = 1e-10
"""Smallest accepted reciprocal condition number of the equilibrated moment matrix.

Shape functions and their derivatives lose about ``log10(1 / rcond)`` digits.  With the
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


def _basis(X):
    """Quadratic basis ``[1, x, y, x^2, xy, y^2]`` at local coordinates ``X`` (..., 2)."""
    x, y = X[..., 0], X[..., 1]
    return jnp.stack([jnp.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)


def _moments(xi, nodes, mask, c, q):
    """Moment matrix A (6, 6) and weighted basis B (6, m) at local evaluation point ``xi``."""
    d = xi - nodes
    r2 = jnp.sum(d * d, axis=-1)
    # (r/c)^(2q) written on r^2 with an integer power: smooth at r = 0 (the node under xi).
    w = jnp.where(mask & (r2 <= 1.0), jnp.exp(-((r2 / c**2) ** q)), 0.0)
    P = _basis(nodes)
    B = P.T * w
    return B @ P, B


def _equilibration(A):
    """Symmetric diagonal scaling ``s`` making ``s A s`` unit-diagonal."""
    return 1.0 / jnp.sqrt(jnp.diagonal(A))


def _spd_solve(A, b):
    """Solve ``A x = b`` for a small symmetric positive definite ``A`` (Gauss-Jordan, no pivoting).

    Elimination without pivoting is backward stable for symmetric positive definite matrices,
    and ``A`` is equilibrated by the caller.  Written in jnp array operations rather than
    ``jnp.linalg.solve``: batched LAPACK solves inside this kernel intermittently deadlocked the
    XLA CPU runtime (jaxlib 0.10.2, under load); the elimination runs as fast.  A singular or
    indefinite ``A`` gives non-finite or huge results, which the caller checks.
    """
    M = jnp.concatenate([A, b[:, None]], axis=1)
    for k in range(A.shape[0]):
        pivot_row = M[k] / M[k, k]
        M = (M - jnp.outer(M[:, k], pivot_row)).at[k].set(pivot_row)
    return M[:, -1]


def _shape_functions(xi, nodes, mask, c, q, s):
    """MLS shape functions ``phi_j(xi)`` (m,) at local scaled point ``xi`` (2,).

    ``s`` is a fixed equilibration of the moment matrix: ``s (s A s)^{-1} s = A^{-1}`` for any
    ``s``, so holding it constant does not change the derivatives.
    """
    A, B = _moments(xi, nodes, mask, c, q)
    gamma = s * _spd_solve(A * s[:, None] * s[None, :], s * _basis(xi))
    return gamma @ B


def _stencil_row(nodes, mask, c, q):
    """Shape functions at ``xi = 0``: value (m,), gradient (m, 2), Hessian (m, 2, 2).

    Also returns the equilibrated moment matrix at ``xi = 0`` (6, 6) for the conditioning check.
    """
    xi0 = jnp.zeros(2, dtype=nodes.dtype)
    A0, _ = _moments(xi0, nodes, mask, c, q)
    s = _equilibration(A0)

    def shape(xi):
        return _shape_functions(xi, nodes, mask, c, q, s)

    def first(xi):
        jac, phi = jax.jacfwd(lambda z: (shape(z), shape(z)), has_aux=True)(xi)
        return jac, (jac, phi)

    hess, (jac, phi) = jax.jacfwd(first, has_aux=True)(xi0)
    return phi, jac, hess, A0 * s[:, None] * s[None, :]


@functools.partial(jax.jit, static_argnames=("q",))
def _kernel(local, mask, h, c, q):
    """Shape functions and derivatives for n stencils.

    ``local`` (n, m, 2): node coordinates relative to each evaluation point, divided by its
    ``h`` (n,); ``mask`` (n, m): real (not padding) entries.  Called by :func:`_run_kernel`
    with n = ``CHUNK``.
    """
    phi, jac, hess, moments = jax.vmap(_stencil_row, in_axes=(0, 0, None, None))(local, mask, c, q)
    h1 = h[:, None]
    h2 = h1 * h1
    finite = (jnp.isfinite(phi).all(1) & jnp.isfinite(jac).all((1, 2))
              & jnp.isfinite(hess).all((1, 2, 3)))
    return (phi, jac[..., 0] / h1, jac[..., 1] / h1,
            hess[..., 0, 0] / h2, hess[..., 0, 1] / h2, hess[..., 1, 1] / h2, moments, finite)


def _value_row(nodes, mask, c, q):
    """Shape function values at ``xi = 0`` (m,) and the equilibrated moment matrix (6, 6).

    The primal part of :func:`_stencil_row` (the same calls, hence the same values, measured
    bit-identical), without the forward-mode derivatives that cost 10x as much.
    """
    xi0 = jnp.zeros(2, dtype=nodes.dtype)
    A0, _ = _moments(xi0, nodes, mask, c, q)
    s = _equilibration(A0)
    return _shape_functions(xi0, nodes, mask, c, q, s), A0 * s[:, None] * s[None, :]


@functools.partial(jax.jit, static_argnames=("q",))
def _value_kernel(local, mask, h, c, q):
    """Value-only counterpart of :func:`_kernel`: ``(phi, moments, finite)`` for n stencils."""
    phi, moments = jax.vmap(_value_row, in_axes=(0, 0, None, None))(local, mask, c, q)
    return phi, moments, jnp.isfinite(phi).all(1)


def _run_kernel(local, mask, h, c, q, derivatives=True):
    """Run :func:`_kernel` on fixed-size chunks of evaluation points; numpy results.

    Chunks keep the working set in cache and make the compiled shape independent of N: one
    compilation per (m, q).  The last chunk is padded with copies of the first stencil.  The
    numpy chunks go to the jitted kernel as they are (no separate ``jnp.asarray`` dispatches),
    and every chunk is dispatched before any result is read, so the host never waits between
    chunks.  Without ``derivatives``, :func:`_value_kernel` runs instead and the five
    derivative arrays are None.
    """
    n = local.shape[0]
    n_pad = -(-n // CHUNK) * CHUNK

    def padded(a):
        return np.concatenate([a, np.repeat(a[:1], n_pad - n, axis=0)])

    local, mask, h = padded(local), padded(mask), padded(h)
    kernel = _kernel if derivatives else _value_kernel
    chunks = [kernel(local[i:i + CHUNK], mask[i:i + CHUNK], h[i:i + CHUNK], c, q)
              for i in range(0, n_pad, CHUNK)]
    out = [np.concatenate([np.asarray(res[k]) for res in chunks])[:n] for k in range(len(chunks[0]))]
    return out if derivatives else [out[0], None, None, None, None, None, out[1], out[2]]


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


def _reciprocal_condition(moments):
    """Reciprocal 2-norm condition numbers of symmetric matrices (n, k, k); NaN if non-finite."""
    rcond = np.full(moments.shape[0], np.nan)
    ok = np.isfinite(moments).all(axis=(1, 2))
    eig = np.linalg.eigvalsh(moments[ok])
    rcond[ok] = np.maximum(eig[:, 0], 0.0) / eig[:, -1]  # round-off can make eig[:, 0] < 0
    return rcond


def _condition_screen(moments):
    """Reciprocal condition numbers where they matter: exact below a cheap lower bound only.

    For a symmetric positive definite k x k matrix, ``lambda_max <= trace`` and the other
    eigenvalues are at most ``lambda_max``, so ``lambda_min >= det / lambda_max^(k-1)`` and
    ``rcond >= det / trace^k``.  Rows whose bound already clears :data:`RCOND_MIN` (a batched
    LU determinant, 6x cheaper than the eigenvalues) get the bound; the others, and any
    non-finite row, get :func:`_reciprocal_condition`.  Which rows pass the check is unchanged.
    """
    k = moments.shape[-1]
    bound = np.full(moments.shape[0], -np.inf)
    ok = np.isfinite(moments).all(axis=(1, 2))
    trace = np.trace(moments[ok], axis1=1, axis2=2)
    bound[ok] = np.linalg.det(moments[ok]) / trace ** k
    # 1e3 x RCOND_MIN: a margin far above the determinant's round-off
    low = np.flatnonzero(~(bound >= 1e3 * RCOND_MIN))
    if low.size:
        bound[low] = _reciprocal_condition(moments[low])
    return bound


def _check_m_max(m_max):
    """Validate an explicit stencil width."""
    if m_max is not None and (isinstance(m_max, bool) or not isinstance(m_max, (int, np.integer))
                              or m_max < N_BASIS):
        raise InputError(f"m_max must be an integer >= {N_BASIS} (or None), got {m_max!r}.")


class NeighbourList:
    """Neighbour candidates of a moving cloud (a Verlet list), for rebuilding its stencils.

    One cKDTree query collects, for every evaluation point (the nodes themselves, or moving
    targets such as material points), the nodes within ``h + skin``.  Until the nodes and the
    targets have together moved more than ``skin`` from where the list was made (the largest
    node move plus the largest target move; for the nodes themselves twice the largest move),
    every pair now within ``h`` is among those candidates, so the nearest ``m`` within ``h``
    are found by sorting the candidates' exact distances; beyond that, or for other sizes or
    another radius, the list is remade.  The result is what
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
        self.reference = None   # (N, 2) node positions when the list was made
        self.targets = None     # (T, 2) target positions then (None: the nodes themselves)
        self.radius = None      # the h it was made for
        self.candidates = None  # (T, K) node indices, N where absent
        self.rebuilds = 0

    @staticmethod
    def _moved(now, then) -> float:
        return float(np.sqrt(np.max(np.sum((now - then) ** 2, axis=1))))

    def _stale(self, points, targets, h) -> bool:
        if (self.reference is None or self.reference.shape != points.shape or self.radius != h
                or (targets is None) != (self.targets is None)
                or (targets is not None and targets.shape != self.targets.shape)):
            return True
        moved = self._moved(points, self.reference)
        moved += moved if targets is None else self._moved(targets, self.targets)
        return not moved <= self.skin

    def query(self, points: np.ndarray, h: np.ndarray, m: int | None, targets: np.ndarray | None = None):
        """``(dist, idx, m)``: the ``m`` nearest nodes closer than ``nextafter(h.max())`` to each
        target (default: to each node, itself first).  ``h`` (T,): radius per target; ``m=None``:
        the largest count within ``h``, rounded up to a multiple of :data:`M_MAX_MULTIPLE`."""
        hmax = float(np.nextafter(h.max(), np.inf))
        centers = points if targets is None else targets
        if self._stale(points, targets, hmax):
            tree = cKDTree(points)
            reach = hmax + self.skin
            k = int(tree.query_ball_point(centers, r=reach, return_length=True).max())
            self.candidates = tree.query(centers, k=max(k, 1), distance_upper_bound=reach)[1].reshape(len(centers), -1)
            self.reference, self.radius = points.copy(), hmax
            self.targets = None if targets is None else targets.copy()
            self.rebuilds += 1
        n, cand = points.shape[0], self.candidates
        # coordinates gathered one axis at a time (a 1-D take is 4x faster than rows of 2)
        dx = np.append(points[:, 0], np.inf)[cand] - centers[:, :1]  # index n: absent candidate
        dy = np.append(points[:, 1], np.inf)[cand] - centers[:, 1:]
        d = np.sqrt(dx * dx + dy * dy)
        # A node at the radius to round-off (the polar cloud has them: the tool's third ring
        # is 3 dr = h from its centre) is in or out by round-off, and cKDTree's pruning of
        # its boxes (rounded box distances, measured: 11 ulps of h) decides it its own way:
        # let cKDTree decide those rows, so that the stencils are the ones it gives (the
        # weight there, exp(-1/c^2), is not negligible).
        band = 1e-12 * (hmax + np.abs(points).max() + np.abs(centers).max())
        rows = np.flatnonzero(((np.abs(d - hmax) <= band) | (np.abs(d - h[:, None]) <= band)).any(axis=1))
        tree = cKDTree(points) if rows.size else None
        if m is None:
            counts = (d <= h[:, None]).sum(axis=1)
            if rows.size:
                counts[rows] = tree.query_ball_point(centers[rows], r=h[rows], return_length=True)
            m = M_MAX_MULTIPLE * max(1, math.ceil(int(counts.max()) / M_MAX_MULTIPLE))
        flat = (np.argsort(d, axis=1, kind="stable")[:, :m]
                + cand.shape[1] * np.arange(len(centers))[:, None])
        dist, idx = d.reshape(-1)[flat], cand.reshape(-1)[flat]
        out = ~(dist < hmax)  # strict, as cKDTree's distance_upper_bound
        dist[out], idx[out] = np.inf, n
        if dist.shape[1] < m:  # fewer candidates than the stencil width
            pad = m - dist.shape[1]
            dist = np.concatenate([dist, np.full((len(centers), pad), np.inf)], axis=1)
            idx = np.concatenate([idx, np.full((len(centers), pad), n)], axis=1)
        if rows.size:
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
    index = np.where(mask, idx, pad[:, None]).astype(np.int32)
    if same_cloud:
        dup = np.flatnonzero(mask[:, 1] & (dist[:, 1] == 0.0))
        if dup.size:
            i = dup[0]
            raise InputError(
                f"points {idx[i, 0]} and {idx[i, 1]} coincide at {centers[i].tolist()} "
                f"({dup.size} points have a duplicate); remove duplicate points."
            )

    local = (nodes[index] - centers[:, None, :]) / h[:, None, None]
    phi, dx, dy, dxx, dxy, dyy, moments, finite = _run_kernel(local, mask, h, float(c), int(q), derivatives)
    rcond = _condition_screen(moments)
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
    return Stencils(*(None if a is None else jnp.asarray(a) for a in (index, phi, dx, dy, dxx, dxy, dyy)))


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
    computes only ``phi`` (10x cheaper; the same values): the stencils' ``dx`` ... ``dyy`` are
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
