"""MLS stencils at the points of a cloud (:func:`build_stencils`) or at arbitrary targets
(:func:`evaluate_at`), by one code path: the neighbour search, the checks of the inputs and of
each support, the kernel (on the host, or compiled for rebuilds), the condition screen."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
from scipy.spatial import cKDTree

from .._checks import flag, integer, positive
from .._x64 import entry_point
from ..errors import InputError
from ._condition import condition_screen
from ._kernel import run_kernel
from ._neighbours import M_MAX_MULTIPLE
from ._shape import N_BASIS, RCOND_MIN


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


def _build(nodes, centers, h, m_max, c, q, owner, same_cloud, neighbours=None, derivatives=True, compiled=False):
    """Shared code path of :func:`build_stencils` and :func:`evaluate_at`.

    ``same_cloud``: the evaluation points are the nodes themselves (``centers is nodes``);
    padding then repeats each point's own index and coinciding points are rejected.  Otherwise
    padding repeats the index of the nearest node.  ``neighbours``: a :class:`NeighbourList`
    to search instead of a new cKDTree (for the cloud itself, with a given ``m_max``).  Without
    ``derivatives`` only ``phi`` is computed (the derivative fields are None).  ``compiled``:
    the jitted kernel instead of the host's (:mod:`jaxanm.mls._kernel`).
    """
    positive("c", c, hint="the paper uses c = 0.2")
    integer("q", q, 1, hint="the weight exp(-(r/c)^(2q)) is then smooth at r = 0, as its second derivatives "
            "require; the paper uses q = 1")
    if m_max is not None:
        integer("m_max", m_max, N_BASIS, hint="or None: the largest neighbour count")
    compiled = flag("compiled", compiled, hint="True for stencils rebuilt at every step, False for those built once")
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
    node = np.where(mask, idx, pad[:, None])  # numpy's own index type: it gathers faster than int32
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
    phi, dx, dy, dxx, dxy, dyy, bound, finite = run_kernel(x, y, inside, h, float(c), int(q), derivatives, compiled)
    rcond = condition_screen(bound, x, y, inside, float(c), int(q))
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
    # on the device once, not at every call of a function that reads them
    weights = (None if w is None else jnp.asarray(w) for w in (phi, dx, dy, dxx, dxy, dyy))
    return Stencils(jnp.asarray(index), *weights)


@entry_point
def build_stencils(points, h, m_max=None, c=0.2, q=1, neighbours=None, compiled=False) -> Stencils:
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
    compiled : bool
        ``False``: the shape functions are computed by numpy on the host, nothing is compiled
        (a cloud built once).  ``True``: by the jitted kernel, compiled once per shape (over
        a second, kept in ``jaxanm run``'s compile cache) and then faster per build: for a
        cloud rebuilt at every step (``benchmarks/results/mls_host_kernel.md``).  The two
        differ by round-off.

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
    return _build(pts, pts, hh, m_max, c, q, "point", same_cloud=True, neighbours=neighbours, compiled=compiled)


@entry_point
def evaluate_at(points, h, targets, m_max=None, c=0.2, q=1, derivatives=True, neighbours=None,
                compiled=False) -> Stencils:
    """MLS stencils at arbitrary target locations (probes, sections), from the nodes ``points``.

    Same approximation and code path as :func:`build_stencils`; ``h`` is a scalar or one radius
    per target, and the returned ``(T, m)`` stencils gather from the N nodes: the value of a
    nodal-parameter field ``f`` (N,) at the targets is ``value(st, f)``.  Padding entries repeat
    the index of the target's nearest node, with zero weights.  ``m_max`` as in
    :func:`build_stencils` (default from the targets' neighbour counts).  ``derivatives=False``
    computes only ``phi`` (2x cheaper; the same values): the stencils' ``dx`` ... ``dyy`` are
    then None, for :func:`value` only.  ``neighbours``: a :class:`NeighbourList` kept for
    moving targets on a moving cloud (e.g. material points), used instead of a new cKDTree;
    ``compiled`` as for :func:`build_stencils`.
    """
    pts = _as_cloud("points", points)
    tgt = _as_cloud("targets", targets)
    hh = _as_radius(h, tgt.shape[0], "target")
    return _build(pts, tgt, hh, m_max, c, q, "target", same_cloud=False, derivatives=derivatives,
                  neighbours=neighbours, compiled=compiled)


def value_matrix(st: Stencils, n_nodes: int | None = None) -> scipy.sparse.csc_matrix:
    """The MLS value operator as a sparse (M, n_nodes) matrix: ``value_matrix(st) @ f == value(st, f)``.

    ``n_nodes`` defaults to M (stencils of a cloud at its own points).  MLS is not interpolating,
    so nodal parameters that reproduce given values solve ``value_matrix(st) @ f = values``.
    """
    index, phi = np.asarray(st.index), np.asarray(st.phi)
    M = index.shape[0]
    rows = np.repeat(np.arange(M), index.shape[1])
    return scipy.sparse.csc_matrix((phi.reshape(-1), (rows, index.reshape(-1))), shape=(M, n_nodes or M))

