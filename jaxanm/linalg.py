"""The host boundary: the only place where tangent matrices are factorised (and counted).

A solver receives a :class:`Factorization` ("a factorised K*") and applies it as often as it
likes; factorising is what the ANM saves, so every factorisation goes through
:func:`factorize`, which counts it in the run's :class:`~jaxanm.stats.Stats`.
"""

from __future__ import annotations

import warnings

import numpy as np
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from .errors import SingularMatrixError
from .stats import Stats


# Column ordering of SuperLU.  On the fsw_paper tangent (2643 unknowns, 198 693 non-zeros, MLS
# stencils) minimum degree on A^T A gives 1.13e6 non-zeros in L + U and factorises in 47 ms;
# SciPy's default COLAMD gives 1.89e6 and 143 ms (3x, median of 3, 2 cores), with the same
# residual of the solve.  Partial pivoting is kept (no diag_pivot_thresh tweak) for robustness.
PERMC_SPEC = "MMD_ATA"


def sparse_lu(matrix) -> scipy.sparse.linalg.SuperLU:
    """SuperLU factors of a square sparse matrix with the column ordering :data:`PERMC_SPEC`."""
    return scipy.sparse.linalg.splu(scipy.sparse.csc_matrix(matrix), permc_spec=PERMC_SPEC)


class Factorization:
    """LU factors of a square matrix: ``splu`` for sparse input, ``lu_factor`` for dense."""

    def __init__(self, matrix):
        if scipy.sparse.issparse(matrix):
            matrix = scipy.sparse.csc_matrix(matrix, dtype=np.float64)
            if not np.all(np.isfinite(matrix.data)):
                raise SingularMatrixError("tangent matrix has non-finite entries")
            try:
                self._lu = sparse_lu(matrix)
            except RuntimeError as exc:  # "Factor is exactly singular"
                raise SingularMatrixError(f"sparse LU failed: {exc}") from exc
            self._solve = self._lu.solve
        else:
            matrix = np.asarray(matrix, dtype=np.float64)
            if not np.all(np.isfinite(matrix)):
                raise SingularMatrixError("tangent matrix has non-finite entries")
            with warnings.catch_warnings():
                warnings.simplefilter("error", scipy.linalg.LinAlgWarning)
                try:
                    lu_piv = scipy.linalg.lu_factor(matrix, check_finite=False)
                except scipy.linalg.LinAlgWarning as exc:
                    raise SingularMatrixError(f"dense LU: {exc}") from exc
            if np.any(np.diag(lu_piv[0]) == 0.0):
                raise SingularMatrixError("dense LU: matrix is exactly singular")
            self._solve = lambda b: scipy.linalg.lu_solve(lu_piv, b, check_finite=False)
        self.matrix = matrix  # kept so that a checkpoint can re-create these exact factors
        self.shape = matrix.shape

    def solve(self, rhs) -> np.ndarray:
        """Solve ``K* x = rhs`` with the stored factors (host, float64)."""
        return self._solve(np.asarray(rhs, dtype=np.float64))


def factorize(matrix, stats: Stats) -> Factorization:
    """Factorise ``matrix`` on the host, counting and timing it in ``stats``."""
    with stats.timer("factorize"):
        fact = Factorization(matrix)
    stats.factorizations += 1
    return fact
