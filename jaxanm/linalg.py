"""The host boundary: the only place where tangent matrices are factorised (and counted).

A solver receives a :class:`Factorization` ("a factorised K*") and applies it as often as it
likes; factorising is what the ANM saves, so every factorisation goes through
:func:`factorize`, which counts it in the run's :class:`~jaxanm.stats.Stats`, and every solve
with its factors counts and times itself there.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from ._extras import require
from .errors import SingularMatrixError
from .stats import Stats


# SuperLU's column ordering and pivoting.  The fsw_paper tangent (2643 unknowns, 198 693
# non-zeros, MLS stencils) has a structurally symmetric pattern, and its diagonal entries make
# acceptable pivots: minimum degree on A + A^T in symmetric mode, which takes the diagonal
# pivot unless it is below 0.1 of its column's largest entry (threshold partial pivoting, as
# UMFPACK's default), gives 0.91e6 non-zeros in L + U against 1.13e6 for MMD_ATA with partial
# pivoting, factorises in 38 ms against 88 ms and solves 7 right-hand sides in 4.3 ms against
# 6.4 ms, with the same relative residual (3.5e-20 against 3.3e-20).  COLAMD: 1.89e6, 195 ms;
# MMD_AT_PLUS_A with partial pivoting: 2.0e6 (its pivots leave the diagonal), 160 ms; KLU and
# MKL's PARDISO (PyPI wheels): 124 and 70 ms (PARDISO's 7 solves 38 ms); a reverse
# Cuthill-McKee renumbering of the points gains at most 1-2 ms more (benchmarks/results/lu_orderings.md,
# medians back to back).  The MLS value matrix of the Lagrangian refit
# factorises faster too (0.93e5 non-zeros against 1.21e5).  An exactly singular factor raises.
#
# On finer clouds the symmetric mode loses: the eliminated diagonals fall below the threshold
# and every pivot taken off the diagonal spoils the symmetric ordering.  fsw_tracers near rest
# (docs/notes/sparse_lu_at_scale.md), non-zeros of L + U, symmetric mode against MMD_ATA:
# 1.27e6 / 1.22e6 at dr (2643 unknowns), 15.8e6 / 8.7e6 at dr/2 (10 107), 246e6 / 58e6 and
# 918 s / 9 s at dr/4 (39 519).  So the symmetric mode is used up to SYMMETRIC_MAX_UNKNOWNS,
# between the sizes where it was measured to win and to lose, and a nested-dissection ordering
# above (below).
#
# Nested dissection is the standard fill-reducing ordering for matrices of 2D meshes (fill
# O(N log N), factorisation O(N^1.5), against minimum degree's worse growth), and a point cloud
# with MLS stencils is one.  METIS (pymetis wheel) orders the graph of A + A^T; SuperLU then
# factorises the symmetrically permuted matrix in symmetric mode, keeping the diagonal pivot
# unless it is below LARGE_DIAG_PIVOT_THRESH of its column.  fsw_tracers near rest and
# fsw_paper's first tangent, non-zeros of L + U (docs/notes/sparse_lu_at_scale.md):
# dr/2: 6.8e6 against 8.7e6 for MMD_ATA with partial pivoting; dr/4: 48.5e6 / 50.8e6 against
# 58.1e6 / 57.3e6.  Threshold 0.01 (HSL MA57's default): 0.1 keeps more diagonal pivots off
# and fills more than MMD_ATA (71e6 at dr/4), 0.001 fills least (35e6) but its relative
# residuals grow to 1e-15 (1e-16 at 0.01, 1e-18 with partial pivoting): element growth.
SYMMETRIC_MAX_UNKNOWNS = 5000
PERMC_SPEC = "MMD_AT_PLUS_A"
DIAG_PIVOT_THRESH = 0.1
SUPERLU_OPTIONS = {"SymmetricMode": True}
LARGE_DIAG_PIVOT_THRESH = 0.01


def sparse_lu(matrix):
    """SuperLU factors of a square sparse matrix, an object with ``solve(b)`` (``b`` of shape
    (n,) or (n, k)) and the factors' ``L``, ``U``: up to :data:`SYMMETRIC_MAX_UNKNOWNS` unknowns,
    ordering :data:`PERMC_SPEC` with threshold :data:`DIAG_PIVOT_THRESH` and options
    :data:`SUPERLU_OPTIONS`; above, a nested-dissection ordering (:class:`NestedDissectionLU`)."""
    matrix = scipy.sparse.csc_matrix(matrix)
    if matrix.shape[0] > SYMMETRIC_MAX_UNKNOWNS:
        return NestedDissectionLU(matrix)
    return scipy.sparse.linalg.splu(matrix, permc_spec=PERMC_SPEC,
                                    diag_pivot_thresh=DIAG_PIVOT_THRESH, options=dict(SUPERLU_OPTIONS))


def nested_dissection(matrix) -> np.ndarray:
    """METIS nested-dissection ordering of the graph of ``matrix + matrix^T``: ``perm`` such
    that ``matrix[perm][:, perm]`` has little fill in its LU factors."""
    # imported here: only matrices above SYMMETRIC_MAX_UNKNOWNS unknowns need it (the metis extra)
    pymetis = require("pymetis", "metis",
                      f"the nested-dissection LU of matrices above {SYMMETRIC_MAX_UNKNOWNS} unknowns")

    graph = scipy.sparse.csr_matrix(abs(matrix) + abs(matrix.T))
    graph.setdiag(0)
    graph.eliminate_zeros()
    # METIS_NodeND: row i of the permuted matrix is row perm[i] of the original (its iperm,
    # the other array returned, is the inverse: gathering by it fills 12x more at dr/2)
    perm, _ = pymetis.nested_dissection(pymetis.CSRAdjacency(graph.indptr, graph.indices))
    return np.asarray(perm, dtype=np.int64)


class NestedDissectionLU:
    """SuperLU factors of ``P A P^T``, P a :func:`nested_dissection` ordering, in symmetric mode
    with diagonal pivot threshold :data:`LARGE_DIAG_PIVOT_THRESH`; solves ``A x = b``."""

    def __init__(self, matrix):
        self.perm = nested_dissection(matrix)
        permuted = scipy.sparse.csc_matrix(matrix[self.perm][:, self.perm])
        self._lu = scipy.sparse.linalg.splu(permuted, permc_spec="NATURAL",
                                           diag_pivot_thresh=LARGE_DIAG_PIVOT_THRESH,
                                           options={"SymmetricMode": True})
        self.shape = matrix.shape

    @property
    def L(self):
        """The unit lower-triangular factor of ``P A P^T`` (made on each access, as SuperLU's:
        kept, a copy doubled the memory of the factors, about 0.6 GB for the 48e6 non-zeros
        at dr/4)."""
        return self._lu.L

    @property
    def U(self):
        """The upper-triangular factor of ``P A P^T`` (made on each access, as SuperLU's)."""
        return self._lu.U

    def solve(self, rhs) -> np.ndarray:
        """``A^-1 rhs`` for ``rhs`` of shape (n,) or (n, k)."""
        rhs = np.asarray(rhs, dtype=np.float64)
        x = np.empty_like(rhs)
        x[self.perm] = self._lu.solve(rhs[self.perm])
        return x


class Factorization:
    """LU factors of a square matrix: ``splu`` for sparse input, ``lu_factor`` for dense.

    With ``stats`` (a run's :class:`~jaxanm.stats.Stats`) every :meth:`solve` is timed there
    as ``solve`` and counted in ``stats.solves``; making the factors is not counted here
    (:func:`factorize` counts it), but making them again after :meth:`release` is.
    """

    def __init__(self, matrix, stats: Stats | None = None):
        if scipy.sparse.issparse(matrix):
            matrix = scipy.sparse.csc_matrix(matrix, dtype=np.float64)
            if not np.all(np.isfinite(matrix.data)):
                raise SingularMatrixError("tangent matrix has non-finite entries")
        else:
            matrix = np.asarray(matrix, dtype=np.float64)
            if not np.all(np.isfinite(matrix)):
                raise SingularMatrixError("tangent matrix has non-finite entries")
        self.matrix = matrix  # kept so that a checkpoint (or a released one) can re-create these exact factors
        self.shape = matrix.shape
        self.stats = stats
        self._solve = self._factors(matrix)

    @staticmethod
    def _factors(matrix):
        """The solve function of the LU factors of ``matrix`` (validated, finite)."""
        if scipy.sparse.issparse(matrix):
            try:
                return sparse_lu(matrix).solve
            except RuntimeError as exc:  # "Factor is exactly singular"
                raise SingularMatrixError(f"sparse LU failed: {exc}") from exc
        with warnings.catch_warnings():
            warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
            try:
                lu_piv = scipy.linalg.lu_factor(matrix, check_finite=False)
            except scipy.linalg.LinAlgWarning as exc:
                raise SingularMatrixError(f"dense LU: {exc}") from exc
        if np.any(np.diag(lu_piv[0]) == 0.0):
            raise SingularMatrixError("dense LU: matrix is exactly singular")
        return lambda b: scipy.linalg.lu_solve(lu_piv, b, check_finite=False)

    def release(self) -> None:
        """Free the factors, keeping the matrix.

        A solver that replaces this K* calls it before factorising the next one, so that two
        LUs are never alive at once (at dr/4 each takes about 0.8 GB).  It may still be held
        elsewhere (the state a step started from, which a user may step from again): a later
        :meth:`solve` then factorises the same matrix again, to the same factors, and counts
        that factorisation in ``stats``.
        """
        self._solve = None

    def solve(self, rhs) -> np.ndarray:
        """Solve ``K* x = rhs`` with the stored factors (host, float64); ``rhs`` of shape (n,)
        or (n, k), counted as 1 or k solves."""
        rhs = np.asarray(rhs, dtype=np.float64)
        if self._solve is None:  # released: factorise again (counted, as any factorisation)
            self._solve = _counted(self.stats, lambda: self._factors(self.matrix))
        if self.stats is None:
            return self._solve(rhs)
        with self.stats.timer("solve"):
            x = self._solve(rhs)
        self.stats.solves += 1 if rhs.ndim == 1 else rhs.shape[1]
        return x


def _counted(stats: Stats | None, make):
    """``make()``, a factorisation, timed as ``factorize`` and counted in ``stats`` if given."""
    if stats is None:
        return make()
    with stats.timer("factorize"):
        made = make()
    stats.factorizations += 1
    return made


def factorize(matrix, stats: Stats) -> Factorization:
    """Factorise ``matrix`` on the host, counting and timing it in ``stats`` (where its
    solves are then counted and timed too)."""
    return _counted(stats, lambda: Factorization(matrix, stats))
