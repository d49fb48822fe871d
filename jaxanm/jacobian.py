"""Tangent matrices by forward-mode autodiff: dense ``jacfwd`` or coloured compressed ``jacfwd``.

For the sparse meshless operators, columns that share no row get the same colour
(a distance-2 colouring of the column-intersection graph), all columns of one colour are
seeded together, and one ``jvp`` per colour recovers every nonzero: the cost is the number of
colours, not the number of unknowns.  The compressed product is computed on the device; the
(cheap) scatter into a scipy CSC matrix is done on the host, so a new sparsity pattern
(e.g. after a Lagrangian stencil rebuild) never forces a recompilation as long as the number
of colours stays within the same padded bucket.

Most of a meshless residual is linear maps of the unknowns (stencil sums) feeding pointwise
nonlinear terms, and the seeded ``jvp`` spends its time in the stencil sums.  Through the
affine frontier of :mod:`jaxanm._affine` the chain rule splits it: ``J S = J_rest(F(x)) (A S)``
with ``A`` the frontier's linear map, which does not depend on ``x``.  ``A S`` (one ``jvp`` of
the linear part per colour) depends only on the arguments the linear map reads, the stencil
weights of a fixed cloud, so :class:`SparseJacobian` keeps it while those stay the same
objects, and a tangent then costs one ``jvp`` of the cheap pointwise rest per colour (a cloud
that moves makes ``A S`` anew at each tangent, at about the plain ``jvp``'s cost).
"""

from __future__ import annotations

import collections
import functools
import os
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
from jax.extend import core as jex_core

from ._affine import split_affine
from ._jaxpr_sparsity import PATTERN_ENTRIES_MAX, jacobian_pattern
from ._x64 import entry_point
from .errors import InputError

_COLOR_BUCKET = 16  # colours are padded to a multiple of this: fewer recompiles
# Device memory one seeded jvp of a meshless residual holds, per nonzero of the Jacobian: its
# stencil intermediates are (N, m) arrays, about nnz / fields entries each, several alive at
# once.  Measured on fsw_tracers at dr/4 (13,173 points, nnz 3.1e6): 38 MB per colour, i.e.
# 12 B per nonzero; 16 B leaves room for residuals with more intermediates.
_BYTES_PER_NONZERO_AND_COLOR = 16
# Colours are seeded together up to this much memory, then in batches (lax.map): the
# fsw_paper Jacobian (144 padded colours, 0.2e6 nonzeros: 0.5 GB) stays one vmap, a cloud 4x
# finer per direction no longer needs 6.6 GB.
JACOBIAN_MEMORY_BYTES = 512 * 2**20
DENSE_BYTES_PER_ENTRY = 32
"""Bytes per entry of a dense (n, n) Jacobian while ``jacfwd`` makes it: the seeds, the
Jacobian and the residual's intermediates per seed, each n x n float64."""


def color_columns(pattern) -> np.ndarray:
    """Greedy colouring of the columns of a sparsity pattern.

    Two columns get different colours whenever they have a nonzero in a common row, so
    ``J @ seed(colour)`` holds each nonzero of ``J`` once.  Columns are visited by
    decreasing degree (largest-first greedy) on the column-intersection graph ``P^T P``, each
    taking the smallest colour its coloured neighbours do not have; the visit is one compiled
    loop (:func:`_greedy_colors`), linear in the graph's size.  Returns ``colors`` of shape ``(n,)``.
    """
    csc = scipy.sparse.csc_matrix(pattern, dtype=bool)
    n = csc.shape[1]
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    _few_enough_couplings(csc)
    structure = scipy.sparse.csc_matrix((np.ones(csc.nnz), csc.indices, csc.indptr), shape=csc.shape)
    graph = (structure.T @ structure).tocsr()  # columns sharing a row are neighbours
    order = np.argsort(-np.diff(csc.indptr), kind="stable").astype(np.int32)
    return np.asarray(_greedy_colors(graph.indptr.astype(np.int32), graph.indices.astype(np.int32), order),
                      dtype=np.int64)


def _few_enough_couplings(csc) -> None:
    """Refuse (:class:`~jaxanm.InputError`) a pattern whose colouring would not fit: a row that
    couples r unknowns makes a clique of r^2 edges in ``P^T P`` and needs r colours, r seeded
    columns of n entries each; :data:`~jaxanm._jaxpr_sparsity.PATTERN_ENTRIES_MAX` bounds r^2,
    and sixteen times it the work of forming ``P^T P`` (the sum of r^2 over the rows)."""
    per_row = np.bincount(csc.indices, minlength=csc.shape[0]).astype(np.float64)
    densest = int(np.argmax(per_row))
    if per_row[densest] ** 2 > PATTERN_ENTRIES_MAX or per_row @ per_row > 16 * PATTERN_ENTRIES_MAX:
        raise InputError(f"the sparsity pattern's row {densest} couples {int(per_row[densest])} of {csc.shape[1]} "
                         "unknowns (and its rows together too many for a colouring): a sparse Jacobian would seed "
                         "about as many columns as a dense one; give jacobian='dense' for a small problem, or "
                         "write the dense coupling apart from the residual (a bordered system)")


@jax.jit
def _greedy_colors(indptr, indices, order):
    """Sequential greedy colouring of a graph (CSR) in ``order``: each vertex stamps its
    neighbours' colours with its turn, then takes the first colour not stamped."""
    n = order.shape[0]

    def vertex(turn, state):
        colors, stamp = state
        j = order[turn]

        def mark(e, stamp):
            c = colors[indices[e]]
            return stamp.at[jnp.where(c >= 0, c, n)].set(turn)  # uncoloured: the spare slot n

        stamp = jax.lax.fori_loop(indptr[j], indptr[j + 1], mark, stamp)
        first_free = jax.lax.while_loop(lambda c: stamp[c] == turn, lambda c: c + 1, 0)
        return colors.at[j].set(first_free), stamp

    start = (jnp.full(n, -1, dtype=indices.dtype), jnp.full(n + 1, -1, dtype=indices.dtype))
    return jax.lax.fori_loop(0, n, vertex, start)[0]


def _step_function(residual, x_old, t, dt, params):
    return lambda x: residual(x, x_old, t, dt, params)


@functools.lru_cache(maxsize=64)
def dense_jacobian_function(residual):
    """Jitted ``(x, x_old, t, dt, params) -> dR/dx_new`` (dense, by ``jax.jacfwd``)."""
    return jax.jit(lambda x, x_old, t, dt, params: jax.jacfwd(_step_function(residual, x_old, t, dt, params))(x))


@functools.lru_cache(maxsize=64)
def compressed_jacobian_function(residual, batch: int | None = None):
    """Jitted ``(x, seeds, x_old, t, dt, params) -> (n_colors, n)``: rows are ``J @ seed``.

    ``batch``: seed at most this many colours at once (``lax.map`` over batches, which bounds
    the memory of the stencil intermediates); None: all colours in one ``vmap``.
    """

    def compressed(x, seeds, x_old, t, dt, params):
        f = _step_function(residual, x_old, t, dt, params)
        column = lambda s: jax.jvp(f, (x,), (s,))[1]  # noqa: E731
        if batch is None or batch >= seeds.shape[0]:
            return jax.vmap(column)(seeds)
        return jax.lax.map(column, seeds, batch_size=batch)

    return jax.jit(compressed)


def color_batch(nnz: int, n_colors: int, budget: int | None = None) -> int | None:
    """How many colours to seed at once so that one batch holds at most about ``budget`` bytes
    of intermediates: a power of two (so that a Lagrangian pattern whose nonzeros drift keeps
    its compiled batch), at least one colour; None when all ``n_colors`` fit.  ``budget``:
    :data:`JACOBIAN_MEMORY_BYTES` by default."""
    return _batch(_BYTES_PER_NONZERO_AND_COLOR * nnz, n_colors, budget)


def _batch(per_color: int, n_colors: int, budget: int | None = None) -> int | None:
    """The largest power of two of colours, at least one, whose ``per_color`` bytes each fit in
    ``budget`` (:data:`JACOBIAN_MEMORY_BYTES` by default); None when all ``n_colors`` fit."""
    budget = JACOBIAN_MEMORY_BYTES if budget is None else budget
    fit = budget // max(1, per_color)
    if fit >= n_colors:
        return None
    return 1 << max(0, int(fit).bit_length() - 1)


class SparseJacobian:
    """Coloured, compressed ``jacfwd`` of a step residual, returned as a scipy CSC matrix.

    ``pattern`` is a scipy sparse (n, n) matrix whose nonzeros include every structural
    nonzero of the Jacobian (a superset is safe; a missing entry would be silently lost,
    so :func:`detect_sparsity` or the model's own pattern must be complete).  Large patterns
    are seeded in batches of :attr:`batch` colours (:func:`color_batch`).
    """

    def __init__(self, residual, pattern):
        self._residual = residual
        self._chain = None  # _FrontierChain, or False where the residual cannot be split
        self.set_pattern(pattern)

    def set_pattern(self, pattern) -> None:
        """Install a (new) sparsity pattern: recolour and rebuild the seeds."""
        coo = scipy.sparse.coo_matrix(pattern)
        n = coo.shape[0]
        if coo.shape != (n, n):
            raise ValueError(f"sparsity pattern must be square (n, n), got {coo.shape}")
        csc = scipy.sparse.csc_matrix((np.ones(coo.nnz, dtype=bool), (coo.row, coo.col)), shape=(n, n))
        csc.sum_duplicates()
        csc.sort_indices()
        self.n = n
        self.colors = color_columns(csc)
        self.n_colors = int(self.colors.max()) + 1 if n else 0
        padded = -(-self.n_colors // _COLOR_BUCKET) * _COLOR_BUCKET
        _memory_fits(DENSE_BYTES_PER_ENTRY * float(padded) * n, f"the coloured Jacobian ({self.n_colors} colours of "
                     f"{n} columns, each seeded column holding n entries)", "give jacobian='dense' for a small problem")
        seeds = np.zeros((padded, n))
        seeds[self.colors, np.arange(n)] = 1.0
        self._seeds = seeds
        self.batch = color_batch(csc.nnz, padded)
        self._fn = compressed_jacobian_function(self._residual, self.batch)
        if self._chain:
            self._chain.forget()
        self._indptr = csc.indptr.copy()
        self._rows = csc.indices.copy()
        self._cols = np.repeat(np.arange(n), np.diff(csc.indptr))

    def __call__(self, x, x_old, t, dt, params) -> scipy.sparse.csc_matrix:
        """Jacobian ``dR/dx_new`` at ``x`` as a CSC matrix (host, float64)."""
        args = (x_old, t, dt, params)
        if self._chain is None:
            self._chain = _FrontierChain.make(self._residual, x, args, self._seeds.shape[0]) or False
        if self._chain:
            compressed = np.asarray(self._chain(self._seeds, x, args))
        else:
            compressed = np.asarray(self._fn(x, self._seeds, *args))
        data = compressed[self.colors[self._cols], self._rows]
        return scipy.sparse.csc_matrix((data, self._rows, self._indptr), shape=(self.n, self.n))


class _FrontierParts(NamedTuple):
    """What the chain rule through the affine frontier needs of one residual and argument
    layout, made once and shared by every :class:`SparseJacobian` of them (a path follower or a
    run makes a new one per call: its compiled functions are found again here)."""

    seeded_frontier: Callable  # jitted (batch, seeds, x, *args) -> A S, batch static
    chain: Callable  # jitted (A S, x, *args) -> J S
    used: list  # per flat argument leaf: read by the linear map's tangent
    frontier_size: int  # entries of the frontier values (A s has as many per colour)
    per_color: int  # bytes of one colour's intermediates in A S (:func:`_frontier_bytes`)

    @classmethod
    def make(cls, residual, x, args):
        """The parts, or None when the residual cannot be split or has no affine part."""
        try:
            split = split_affine(residual, jnp.asarray(x), *args, scalar_factors_affine=False)
        except Exception:  # noqa: BLE001 - not splittable: the plain compressed jacfwd is correct
            return None
        if split.n_affine_eqns == 0:
            return None

        def seeded_frontier(batch, seeds, x, *args):
            column = lambda s: jax.jvp(lambda y: split.linear(y, *args), (x,), (s,))[1]  # noqa: E731
            if batch is None or batch >= seeds.shape[0]:
                return jax.vmap(column)(seeds)
            return jax.lax.map(column, seeds, batch_size=batch)

        def chain(frontier_seeds, x, *args):
            values = split.linear(x, *args)
            return jax.vmap(lambda ts: jax.jvp(lambda f: split.rest(f, *args), (values,), (ts,))[1])(frontier_seeds)

        frontier = jax.eval_shape(split.linear, jnp.asarray(x), *args)
        return cls(jax.jit(seeded_frontier, static_argnums=0), jax.jit(chain),
                   _tangent_inputs(split.linear, x, args), sum(int(np.prod(f.shape)) for f in frontier),
                   _frontier_bytes(split.linear, x, args))


_PARTS: collections.OrderedDict = collections.OrderedDict()
_MAX_PARTS = 64  # residuals and layouts whose frontier parts are kept, the oldest dropped first


def _frontier_parts(residual, x, args) -> _FrontierParts | None:
    """The shared :class:`_FrontierParts` of ``residual`` for the layout (structure, shapes and
    dtypes) of ``(x, args)``."""
    leaves, tree = jax.tree_util.tree_flatten((x, args))
    key = (residual, tree, tuple((np.shape(v), str(getattr(v, "dtype", type(v).__name__))) for v in leaves))
    if key in _PARTS:
        _PARTS.move_to_end(key)
    else:
        if len(_PARTS) >= _MAX_PARTS:
            _PARTS.popitem(last=False)
        _PARTS[key] = _FrontierParts.make(residual, x, args)
    return _PARTS[key]


class _FrontierChain:
    """``J S`` by the chain rule through the affine frontier (module docstring), with ``A S``
    kept while the arguments the linear map reads are the same objects."""

    def __init__(self, parts: _FrontierParts, batch: int | None):
        self._parts = parts
        self._seeded_frontier = parts.seeded_frontier
        self._batch = batch  # colours seeded at once into A S (None: all)
        self._kept_leaves, self._kept = None, None

    @classmethod
    def make(cls, residual, x, args, n_colors: int):
        """The chain for ``residual`` at these arguments, or None when it would not pay: the
        residual cannot be split, has no affine part, or ``A S`` would exceed the memory
        budget of :data:`JACOBIAN_MEMORY_BYTES`."""
        parts = _frontier_parts(residual, x, args)
        if parts is None or parts.frontier_size * n_colors * 8 > JACOBIAN_MEMORY_BYTES:
            return None
        return cls(parts, _batch(parts.per_color, n_colors))

    def forget(self) -> None:
        """Drop the kept ``A S`` (the seeds changed)."""
        self._kept_leaves, self._kept = None, None

    def __call__(self, seeds, x, args):
        """``J S`` (n_colors, n) at ``x`` (``A S`` made :func:`_frontier_bytes`-bounded batches
        of colours at a time).

        ``A S`` is made anew whenever the arguments the linear map reads are new objects (a
        cloud that moves: then about the cost of the plain seeded ``jvp``), never taken from
        the plain path instead: the tangent is one function of its arguments, whatever came
        before, so that a run resumed from a checkpoint factorises bit for bit the matrices
        of an uninterrupted one."""
        leaves = [leaf for leaf, used in zip(jax.tree_util.tree_leaves(args), self._parts.used) if used]
        if self._kept is None or len(leaves) != len(self._kept_leaves) or any(
                a is not b for a, b in zip(leaves, self._kept_leaves)):
            self._kept = None  # freed before the new one is made
            self._kept = self._seeded_frontier(self._batch, seeds, jnp.asarray(x), *args)
            self._kept_leaves = leaves  # held, so that an identical id cannot be a new object
        return self._parts.chain(self._kept, jnp.asarray(x), *args)


def _frontier_bytes(linear, x, args) -> int:
    """Bytes of one colour's intermediates in ``A S``, bounded by the sum of every value its
    ``jvp`` computes (its jaxpr's outputs, as if all were alive at once).

    The linear map applies each derivative operator to the gathered stencil values separately,
    so these are many (N, m) arrays per colour, far more than the nonzeros per colour that
    :func:`color_batch` budgets for the whole residual."""
    xj = jnp.asarray(x)
    column = jax.make_jaxpr(lambda s: jax.jvp(lambda y: linear(y, *args), (xj,), (s,))[1])(xj)
    return sum(int(np.prod(v.aval.shape)) * v.aval.dtype.itemsize for eqn in column.jaxpr.eqns for v in eqn.outvars)


def _tangent_inputs(linear, x, args) -> list:
    """Per flat leaf of ``args``: whether the tangent of ``linear`` (its ``A s``) reads it."""
    flat, tree = jax.tree_util.tree_flatten(args)

    def tangent(s, *flat_args):
        rebuilt = jax.tree_util.tree_unflatten(tree, flat_args)
        return jax.jvp(lambda y: linear(y, *rebuilt), (jnp.asarray(x),), (s,))[1]

    with jax.disable_jit():
        closed = jax.make_jaxpr(tangent)(jnp.asarray(x), *flat)
    jaxpr = closed.jaxpr
    needed = {v for v in jaxpr.outvars if isinstance(v, jex_core.Var)}
    for eqn in reversed(jaxpr.eqns):
        if any(v in needed for v in eqn.outvars) or eqn.effects:
            needed.update(v for v in eqn.invars if isinstance(v, jex_core.Var))
    return [v in needed for v in jaxpr.invars[1:]]


def dense_jacobian_fits(n: int, argument: str, fix: str) -> None:
    """Refuse, with an :class:`~jaxanm.InputError` naming ``argument`` and ``fix``, a dense
    (n, n) Jacobian that would not fit in this machine's memory: ``jacfwd`` holds its seeds,
    the Jacobian and intermediates of that size (:data:`DENSE_BYTES_PER_ENTRY` per entry)."""
    _memory_fits(DENSE_BYTES_PER_ENTRY * float(n) ** 2, f"{argument} (dense {n} x {n} Jacobians, with their "
                 "intermediates)", fix)


def _memory_fits(need: float, what: str, fix: str) -> None:
    """Refuse (:class:`~jaxanm.InputError`) ``what`` when its ``need`` of bytes exceeds this
    machine's memory."""
    have = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    if need > have:
        raise InputError(f"{what} needs about {need / 2**30:.3g} GiB, more than this machine's "
                         f"{have / 2**30:.3g} GiB of memory; {fix}")


@entry_point
def detect_sparsity(residual, x, x_old, t, dt, params, probes: int = 3, seed: int = 0, method: str = "jaxpr"):
    """Sparsity pattern of ``dR/dx_new`` as a boolean scipy CSC matrix.

    ``method="jaxpr"`` (the default): from the residual's jaxpr, by index sets propagated
    primitive by primitive (:mod:`jaxanm._jaxpr_sparsity`), in memory and time O(nnz), never a
    dense Jacobian.  The pattern holds for every value of ``x``, ``x_old``, ``t`` and ``dt``
    (their values are not read); ``params`` are read where they decide which elements meet
    (gather and scatter indices, a ``where``'s condition, a constant matrix's zeros).  A
    residual that couples nearly every unknown to every other is refused with an
    :class:`~jaxanm.InputError` (use a dense Jacobian).

    ``method="probes"``: the nonzeros of ``probes`` dense Jacobians at random perturbations of
    ``x`` (seeded by ``seed``), for small problems only (a check of the above; refused when the
    dense Jacobians would not fit in memory).  An entry that vanishes at every probe (a factor
    zero at these ``t``, ``dt`` or ``x_old``) is missed.
    """
    if method == "jaxpr":
        return jacobian_pattern(residual, x, (x_old, t, dt), (params,))
    if method != "probes":
        raise InputError(f"method must be 'jaxpr' or 'probes', got {method!r}")
    dense_jacobian_fits(np.size(x), "detect_sparsity(method='probes')", "use method='jaxpr'")
    jac = dense_jacobian_function(residual)
    x = jnp.asarray(x, dtype=jnp.float64)
    rng = np.random.default_rng(seed)
    mask = None
    for _ in range(probes):
        xp = x + (1e-3 * (np.abs(np.asarray(x)) + 1.0)) * rng.standard_normal(x.shape)
        nz = np.asarray(jac(xp, x_old, t, dt, params)) != 0.0
        mask = nz if mask is None else (mask | nz)
    return scipy.sparse.csc_matrix(mask)
