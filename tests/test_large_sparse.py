"""Large sparse problems: what repeats is not recomputed (the nested-dissection ordering of a
pattern met again), and the 2D Bratu at 250,000 unknowns through its fold by both path
followers (slow), against the continuum's fold and its discretisation error."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse

import jaxanm
from jaxanm import _factorization


def _laplacian(m: int, shift: float = 0.0) -> scipy.sparse.csc_matrix:
    line = scipy.sparse.diags([1.0, -2.0, 1.0], [-1, 0, 1], shape=(m, m))
    eye = scipy.sparse.identity(m)
    return (scipy.sparse.kron(line, eye) + scipy.sparse.kron(eye, line) - shift * scipy.sparse.identity(m * m)).tocsc()


def test_an_ordering_is_made_once_per_pattern(monkeypatch):
    """Matrices above SYMMETRIC_MAX_UNKNOWNS are ordered by METIS; a second matrix of the same
    pattern (new values: the next Newton iterate) reuses the ordering, a new pattern gets its
    own; the solutions are those of a direct solve (to round-off of a well-conditioned matrix)."""
    pymetis = pytest.importorskip("pymetis")
    calls = []
    original = pymetis.nested_dissection
    monkeypatch.setattr(pymetis, "nested_dissection", lambda *a, **k: calls.append(1) or original(*a, **k))
    monkeypatch.setattr(_factorization, "_ORDERINGS", [])
    m = 75  # 5625 unknowns, above SYMMETRIC_MAX_UNKNOWNS
    rhs = np.random.default_rng(0).standard_normal(m * m)
    stats = jaxanm.Stats()
    for shift, count in ((1.0, 1), (2.0, 1), (3.0, 2)):
        matrix = _laplacian(m, shift)
        if shift == 3.0:  # one more coupling: another pattern
            matrix = (matrix + scipy.sparse.csc_matrix(([1.0, 1.0], ([0, m * m - 1], [m * m - 1, 0])),
                                                       shape=matrix.shape)).tocsc()
        x = jaxanm.factorize(matrix, stats).solve(rhs)
        assert len(calls) == count
        np.testing.assert_allclose(x, scipy.sparse.linalg.spsolve(matrix, rhs), rtol=1e-10, atol=0)
