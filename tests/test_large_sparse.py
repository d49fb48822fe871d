"""Large sparse problems: what repeats is not recomputed (the nested-dissection ordering of a
pattern met again), and the 2D Bratu at 250,000 unknowns through its fold by both path
followers (slow), against the continuum's fold and its discretisation error."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse
from model_problems import bratu_2d

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
    m = 142  # 20164 unknowns, above SYMMETRIC_MAX_UNKNOWNS
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


def test_a_pattern_pivoting_off_the_diagonal_is_ordered_by_nested_dissection(monkeypatch):
    """Between GUARDED_ABOVE and SYMMETRIC_MAX_UNKNOWNS the symmetric mode is tried first; a
    pattern whose factors took more than OFF_DIAGONAL_PIVOTS_MAX of their pivots off the
    diagonal (here a third of the diagonal is zero: those pivots cannot stay on it) is ordered
    by nested dissection from its next factorisation on, and one that keeps its diagonal
    pivots (the shifted Laplacian) keeps the symmetric mode; every solve matches a direct one."""
    pytest.importorskip("pymetis")
    monkeypatch.setattr(_factorization, "_OFF_DIAGONAL", [])
    m = 75  # 5625 unknowns: between the two bounds
    assert _factorization.GUARDED_ABOVE < m * m <= _factorization.SYMMETRIC_MAX_UNKNOWNS
    rhs = np.random.default_rng(0).standard_normal(m * m)
    zero_diagonal = np.arange(m * m) % 3 == 0
    for matrix, symmetric_after in ((_laplacian(m, 1.0), True),
                                    ((_laplacian(m, 1.0) - scipy.sparse.diags(np.where(zero_diagonal, -5.0, 0.0)))
                                     .tocsc(), False)):
        kinds = []
        for _ in range(2):
            lu = _factorization.sparse_lu(matrix)
            kinds.append(isinstance(lu, _factorization.NestedDissectionLU))
            np.testing.assert_allclose(lu.solve(rhs), scipy.sparse.linalg.spsolve(matrix, rhs), rtol=1e-8, atol=0)
        assert kinds == [False, not symmetric_after]


LAM_CONTINUUM = 6.808124
"""The fold of the continuum 2D Bratu problem on the unit square, to the digits quoted in the
literature (Bratu-Gelfand; e.g. 6.808124423): within 5e-7."""


def _branch(method, m: int) -> jaxanm.Branch:
    """From rest past the fold to u(centre) = 1.5, sparse Jacobian, no pattern given, defaults."""
    follow = jaxanm.continuation if method == "anm" else jaxanm.newton_continuation
    return follow(bratu_2d(m), np.zeros(m * m), 0.0, stop_at=((m // 2) * m + m // 2, 1.5), max_steps=200,
                  jacobian="sparse")


def _fold(branch: jaxanm.Branch) -> float:
    """The branch's fold: its fold event, else (the ANM) the root of d lam / d a of its series."""
    events = [e.lam for e in getattr(branch, "events", ()) if e.kind == "fold"]
    if events:
        return float(events[0])
    if branch.method != "anm":
        pytest.skip("this newton_continuation reports no fold events: its Hermite interpolant alone does not "
                    "locate the fold to 1e-6")
    (lam,) = branch.limit_points().lam
    return float(lam)


@pytest.mark.slow
def test_bratu_2d_at_250000_unknowns_folds_where_the_continuum_and_its_h2_error_say():
    """500 x 500 unknowns, no pattern given (a dense Jacobian would be 500 GB).  The discrete fold
    is ``lam_h = lam* + C h^2 + D h^4 + ...`` (the 5-point Laplacian's error expansion).  C comes
    from the folds at m = 63 and 127 (two-grid Richardson; its own error is D (h_63^2 + h_127^2),
    about 1e-3 C here with |D| < 10, measured in benchmarks/results/bratu_2d_scale.md): the fold at
    m = 500 must then be ``6.808124 + C h^2`` within the continuum value's last digit (5e-7) plus
    1 % of C h^2 (ten times C's error).  Both path followers must agree on it to 1e-6."""
    coarse = {m: _fold(_branch("anm", m)) for m in (63, 127)}
    h2 = {m: 1.0 / (m + 1) ** 2 for m in (63, 127, 500)}
    C = (coarse[63] - coarse[127]) / (h2[63] - h2[127])
    anm = _branch("anm", 500)
    assert anm.stopped == "stop_at"
    lam_anm = _fold(anm)
    assert abs(lam_anm - C * h2[500] - LAM_CONTINUUM) <= 5e-7 + 0.01 * abs(C) * h2[500]
    newton = _branch("newton", 500)
    assert newton.stopped == "stop_at"
    assert abs(_fold(newton) - lam_anm) <= 1e-6 * lam_anm
