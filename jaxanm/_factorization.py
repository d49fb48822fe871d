"""Host LU factorisations of tangent matrices: :class:`Factorization` factors and solves.

A solver receives a :class:`Factorization` ("a factorised K*") and applies it as often as it
likes.  Factorising is what the ANM saves, so the callers count it: :func:`jaxanm._problem.factorize`
and :func:`jaxanm._problem.counted_solve` time and count in a run's
:class:`~jaxanm.stats.Stats` (the problem is the one writer of work counters); the object
itself keeps no statistics.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from ._extras import require
from .errors import SingularMatrixError

# Why these SuperLU settings (the measurements: benchmarks/results/lu_orderings.md,
# benchmarks/results/lu_at_size.md and docs/notes/sparse_lu_at_scale.md).  The FSW tangents
# have a structurally symmetric pattern whose diagonal entries make acceptable pivots, so
# minimum degree on A + A^T in symmetric mode, keeping the diagonal pivot unless it is below
# DIAG_PIVOT_THRESH of its column (threshold partial pivoting, as UMFPACK's default), fills
# little and factorises fastest of SuperLU's orderings, with residuals as small as partial
# pivoting's; an exactly singular factor raises.  Where elimination pushes diagonals below the
# threshold, each pivot taken off the diagonal spoils the symmetric ordering and the fill
# grows: so above GUARDED_ABOVE unknowns a pattern whose factors took more than
# OFF_DIAGONAL_PIVOTS_MAX of their pivots off the diagonal is ordered by nested dissection from
# then on, and above SYMMETRIC_MAX_UNKNOWNS every matrix is (where its smaller fill catches up
# with the minimum degree's faster supernodes).  Nested dissection is the standard
# fill-reducing ordering of 2D meshes (a point cloud with MLS stencils is one): METIS orders
# the graph of A + A^T and SuperLU factorises the permuted matrix in symmetric mode with the
# smaller threshold LARGE_DIAG_PIVOT_THRESH (HSL MA57's default: a larger one keeps fewer
# diagonal pivots and fills more, a smaller one lets the elements grow).
SYMMETRIC_MAX_UNKNOWNS = 20000
GUARDED_ABOVE = 5000
OFF_DIAGONAL_PIVOTS_MAX = 0.01
PERMC_SPEC = "MMD_AT_PLUS_A"
DIAG_PIVOT_THRESH = 0.1
SUPERLU_OPTIONS = {"SymmetricMode": True}
LARGE_DIAG_PIVOT_THRESH = 0.01


def sparse_lu(matrix):
    """SuperLU factors of a square sparse matrix, an object with ``solve(b)`` (``b`` of shape
    (n,) or (n, k)) and the factors' ``L``, ``U``: up to :data:`SYMMETRIC_MAX_UNKNOWNS` unknowns,
    ordering :data:`PERMC_SPEC` with threshold :data:`DIAG_PIVOT_THRESH` and options
    :data:`SUPERLU_OPTIONS`; above, or for a pattern above :data:`GUARDED_ABOVE` whose factors
    took more than :data:`OFF_DIAGONAL_PIVOTS_MAX` of their pivots off the diagonal, a
    nested-dissection ordering (:class:`NestedDissectionLU`)."""
    matrix = scipy.sparse.csc_matrix(matrix)
    n = matrix.shape[0]
    guarded = n > GUARDED_ABOVE
    if n > SYMMETRIC_MAX_UNKNOWNS or (guarded and _known(_OFF_DIAGONAL, matrix.indptr, matrix.indices)):
        return NestedDissectionLU(matrix)
    lu = scipy.sparse.linalg.splu(matrix, permc_spec=PERMC_SPEC,
                                  diag_pivot_thresh=DIAG_PIVOT_THRESH, options=dict(SUPERLU_OPTIONS))
    if guarded and np.count_nonzero(lu.perm_r != lu.perm_c) > OFF_DIAGONAL_PIVOTS_MAX * n:
        _remember(_OFF_DIAGONAL, (matrix.indptr.copy(), matrix.indices.copy()))
    return lu


def _known(patterns: list, indptr, indices):
    """The entry of ``patterns`` (``(indptr, indices, ...)`` tuples) with this pattern, else None."""
    for entry in patterns:
        if np.array_equal(entry[0], indptr) and np.array_equal(entry[1], indices):
            return entry
    return None


def _remember(patterns: list, entry: tuple) -> None:
    """Keep ``entry`` as the newest of ``patterns``, at most :data:`ORDERINGS_KEPT` of them."""
    patterns.append(entry)
    del patterns[:-ORDERINGS_KEPT]


def nested_dissection(matrix) -> np.ndarray:
    """METIS nested-dissection ordering of the graph of ``matrix + matrix^T``: ``perm`` such
    that ``matrix[perm][:, perm]`` has little fill in its LU factors."""
    # imported here: only large matrices need it (the metis extra)
    pymetis = require("pymetis", "metis",
                      f"the nested-dissection LU of matrices above {SYMMETRIC_MAX_UNKNOWNS} unknowns (and above "
                      f"{GUARDED_ABOVE} whose pivots leave the diagonal)")

    graph = scipy.sparse.csr_matrix(abs(matrix) + abs(matrix.T))
    graph.setdiag(0)
    graph.eliminate_zeros()
    graph.sort_indices()
    known = _known(_ORDERINGS, graph.indptr, graph.indices)
    if known is not None:  # a pattern met again: its ordering (METIS is deterministic)
        return known[2]
    # METIS_NodeND: row i of the permuted matrix is row perm[i] of the original (its iperm,
    # the other array returned, is the inverse: gathering by it fills far more)
    perm, _ = pymetis.nested_dissection(pymetis.CSRAdjacency(graph.indptr, graph.indices))
    perm = np.asarray(perm, dtype=np.int64)
    perm.setflags(write=False)
    _remember(_ORDERINGS, (graph.indptr, graph.indices, perm))
    return perm


ORDERINGS_KEPT = 4
"""Nested-dissection orderings kept for the patterns met last: Newton iterations and path
following factorise matrices of one pattern over and over, and METIS takes about as long as
SuperLU's numeric factorisation (the 2D Bratu's bordered matrix at 250,000 unknowns)."""
_ORDERINGS: list = []  # (indptr, indices, perm) of the graphs ordered last, the newest last
_OFF_DIAGONAL: list = []  # (indptr, indices) of matrices whose symmetric-mode factors left the diagonal


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
        kept, a copy would double the memory of the factors)."""
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

    It factors and solves, nothing else: the caller counts and times (:func:`~jaxanm._problem.factorize`,
    :func:`~jaxanm._problem.counted_solve`).  The matrix is kept, so that a checkpoint, or a solve after
    :meth:`release`, re-creates these exact factors.  A matrix with non-finite entries, or an
    exactly singular one, raises :class:`~jaxanm.SingularMatrixError`.
    """

    def __init__(self, matrix):
        if scipy.sparse.issparse(matrix):
            matrix = scipy.sparse.csc_matrix(matrix, dtype=np.float64)
            if not np.all(np.isfinite(matrix.data)):
                raise SingularMatrixError("tangent matrix has non-finite entries")
        else:
            matrix = np.asarray(matrix, dtype=np.float64)
            if not np.all(np.isfinite(matrix)):
                raise SingularMatrixError("tangent matrix has non-finite entries")
        self.matrix = matrix
        self.shape = matrix.shape
        self._solve, self._lu = self._factors(matrix)

    @staticmethod
    def _factors(matrix):
        """The solve function of the LU factors of ``matrix`` (validated, finite), and the factors."""
        if scipy.sparse.issparse(matrix):
            try:
                lu = sparse_lu(matrix)
            except RuntimeError as exc:  # "Factor is exactly singular"
                raise SingularMatrixError(f"sparse LU failed: {exc}") from exc
            return lu.solve, lu
        with warnings.catch_warnings():
            warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
            try:
                lu_piv = scipy.linalg.lu_factor(matrix, check_finite=False)
            except scipy.linalg.LinAlgWarning as exc:
                raise SingularMatrixError(f"dense LU: {exc}") from exc
        if np.any(np.diag(lu_piv[0]) == 0.0):
            raise SingularMatrixError("dense LU: matrix is exactly singular")
        return (lambda b: scipy.linalg.lu_solve(lu_piv, b, check_finite=False)), lu_piv

    @property
    def released(self) -> bool:
        """Whether the factors were freed (:meth:`release`); a solve then factorises again."""
        return self._solve is None

    def release(self) -> None:
        """Free the factors, keeping the matrix.

        Whoever owns this K* calls it before factorising the next one, so that two LUs are
        never alive at once (on fine clouds one takes most of a run's memory); who owns it is
        the rule of :class:`~jaxanm.StepSolver`.  A later :meth:`solve` factorises the same
        matrix again, to the same factors (:func:`~jaxanm._problem.counted_solve` counts that factorisation).
        """
        self._solve = self._lu = None

    def refactor(self) -> None:
        """Make the factors again from the kept matrix if they were released (else nothing)."""
        if self._solve is None:
            self._solve, self._lu = self._factors(self.matrix)

    def slogdet(self) -> tuple[float, float]:
        """``(sign, log|det K*|)`` read off the factors (made again if released), as
        ``numpy.linalg.slogdet``: U's diagonal and the parities of the row and column
        permutations.  Path following watches the sign for branch points (:mod:`jaxanm.events`)."""
        self.refactor()
        return slogdet(self._lu)

    def solve(self, rhs) -> np.ndarray:
        """Solve ``K* x = rhs`` with the stored factors (host, float64); ``rhs`` of shape (n,)
        or (n, k)."""
        rhs = np.asarray(rhs, dtype=np.float64)
        self.refactor()
        return self._solve(rhs)


def permutation_parity(perm) -> int:
    """+1 for an even permutation ``perm`` of ``0..n-1``, -1 for an odd one: ``(-1)^(n - cycles)``,
    the cycles counted by labelling each index with the smallest index of its cycle (pointer
    jumping: O(n log n), vectorised)."""
    perm = np.asarray(perm, dtype=np.int64)
    label, jump = np.arange(perm.size), perm.copy()
    for _ in range(max(1, int(np.ceil(np.log2(max(perm.size, 2))))) + 1):
        label = np.minimum(label, label[jump])
        jump = jump[jump]
    cycles = int(np.count_nonzero(label == np.arange(perm.size)))
    return -1 if (perm.size - cycles) % 2 else 1


def slogdet(lu) -> tuple[float, float]:
    """``(sign, log|det|)`` of the matrix whose LU factors ``lu`` are: a dense ``lu_factor``
    pair, a SuperLU object (``Pr A Pc = L U``, L unit lower) or a :class:`NestedDissectionLU`
    (``P A P^T``, whose determinant is ``A``'s)."""
    if isinstance(lu, tuple):
        diagonal, pivots = np.diag(lu[0]), lu[1]
        parity = (-1) ** int(np.count_nonzero(pivots != np.arange(pivots.size)))
    else:
        inner = lu._lu if isinstance(lu, NestedDissectionLU) else lu
        diagonal = inner.U.diagonal()
        parity = permutation_parity(inner.perm_r) * permutation_parity(inner.perm_c)
    return float(parity * np.prod(np.sign(diagonal))), float(np.sum(np.log(np.abs(diagonal))))
