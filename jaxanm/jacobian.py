"""Tangent matrices by forward-mode autodiff: dense ``jacfwd`` or coloured compressed ``jacfwd``.

For the sparse meshless operators, columns that share no row get the same colour
(a distance-2 colouring of the column-intersection graph), all columns of one colour are
seeded together, and one ``jvp`` per colour recovers every nonzero: the cost is the number of
colours, not the number of unknowns.  The compressed product is computed on the device; the
(cheap) scatter into a scipy CSC matrix is done on the host, so a new sparsity pattern
(e.g. after a Lagrangian stencil rebuild) never forces a recompilation as long as the number
of colours stays within the same padded bucket.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

from ._x64 import entry_point

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


def color_columns(pattern) -> np.ndarray:
    """Greedy colouring of the columns of a sparsity pattern.

    Two columns get different colours whenever they have a nonzero in a common row, so
    ``J @ seed(colour)`` holds each nonzero of ``J`` once.  Columns are visited by
    decreasing degree (largest-first greedy) on the column-intersection graph ``P^T P``.
    Returns ``colors`` of shape ``(n,)``.
    """
    csc = scipy.sparse.csc_matrix(pattern, dtype=bool)
    n = csc.shape[1]
    structure = scipy.sparse.csc_matrix((np.ones(csc.nnz), csc.indices, csc.indptr), shape=csc.shape)
    graph = (structure.T @ structure).tocsr()  # columns sharing a row are neighbours
    degree = np.diff(csc.indptr)
    colors = np.full(n, -1, dtype=np.int64)
    stamp = np.full(n + 1, -1, dtype=np.int64)  # stamp[c] == j: colour c is taken near column j
    for j in np.argsort(-degree, kind="stable"):
        used = colors[graph.indices[graph.indptr[j] : graph.indptr[j + 1]]]
        stamp[used[used >= 0]] = j
        colors[j] = int(np.argmax(stamp != j))  # smallest colour not taken
    return colors


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
    budget = JACOBIAN_MEMORY_BYTES if budget is None else budget
    fit = budget // max(1, _BYTES_PER_NONZERO_AND_COLOR * nnz)
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
        seeds = np.zeros((padded, n))
        seeds[self.colors, np.arange(n)] = 1.0
        self._seeds = seeds
        self.batch = color_batch(csc.nnz, padded)
        self._fn = compressed_jacobian_function(self._residual, self.batch)
        self._indptr = csc.indptr.copy()
        self._rows = csc.indices.copy()
        self._cols = np.repeat(np.arange(n), np.diff(csc.indptr))

    def __call__(self, x, x_old, t, dt, params) -> scipy.sparse.csc_matrix:
        """Jacobian ``dR/dx_new`` at ``x`` as a CSC matrix (host, float64)."""
        compressed = np.asarray(self._fn(x, self._seeds, x_old, t, dt, params))
        data = compressed[self.colors[self._cols], self._rows]
        return scipy.sparse.csc_matrix((data, self._rows, self._indptr), shape=(self.n, self.n))


@entry_point
def detect_sparsity(residual, x, x_old, t, dt, params, probes: int = 3, seed: int = 0):
    """Sparsity pattern of ``dR/dx_new`` from dense Jacobians at randomly perturbed points.

    For small and moderate problems only (it forms ``probes`` dense n x n Jacobians).  An entry
    is kept if it is nonzero at any probe; random perturbations of ``x`` make accidental zeros
    (an entry that vanishes at one particular state) vanishingly unlikely.
    Returns a boolean scipy CSC matrix.
    """
    jac = dense_jacobian_function(residual)
    x = jnp.asarray(x, dtype=jnp.float64)
    rng = np.random.default_rng(seed)
    mask = None
    for _ in range(probes):
        xp = x + (1e-3 * (np.abs(np.asarray(x)) + 1.0)) * rng.standard_normal(x.shape)
        nz = np.asarray(jac(xp, x_old, t, dt, params)) != 0.0
        mask = nz if mask is None else (mask | nz)
    return scipy.sparse.csc_matrix(mask)
