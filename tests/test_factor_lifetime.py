"""Lifetime of the LU factors: a solver frees a K* it replaces before making the next one.

At dr/4 one LU takes about 0.8 GB; two alive at a refactorisation (the stale K*, held by the
state the step started from, and the new one) doubled the peak memory of a long run
(docs/notes/sparse_lu_at_scale.md).  The state keeps the matrix, so a released K* still
solves, by factorising it again.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse

import jaxanm
from jaxanm import linalg
from jaxanm.stats import Stats
from model_problems import heat_1d, impulsive_cubic


def test_a_released_factorization_solves_by_factorising_again():
    """The same matrix gives the same factors: the solution after a release is bit for bit
    the one before, and the second factorisation is counted."""
    rng = np.random.default_rng(3)
    a = scipy.sparse.random(40, 40, density=0.1, random_state=rng) + 4.0 * scipy.sparse.identity(40)
    b = rng.standard_normal(40)
    stats = Stats()
    fact = linalg.factorize(a, stats)
    before = fact.solve(b)
    fact.release()
    assert stats.factorizations == 1
    after = fact.solve(b)
    assert np.array_equal(before, after)
    assert stats.factorizations == 2 and stats.solves == 2


def _source_jump():
    """heat_1d whose source jumps at t = 0.5: the ANM's K* goes stale and is replaced."""
    residual0, x0, params = heat_1d()

    def residual(u, u_old, t, dt, p):
        return residual0(u, u_old, t, dt, p) - jnp.where(t > 0.5, 40.0, 0.0)

    return residual, x0, params


@pytest.mark.parametrize("problem, solver", [
    (_source_jump, jaxanm.ANM(order=5, tol=1e-8)),
    (impulsive_cubic, jaxanm.ANM(order=7, tol=1e-8)),
    (impulsive_cubic, jaxanm.ModifiedNewton(tol=1e-10)),
    (heat_1d, jaxanm.Newton(tol=1e-10)),
], ids=["anm-stale", "anm-substeps", "modified-newton", "newton"])
def test_at_most_one_lu_alive(problem, solver, monkeypatch):
    """At every factorisation of a run that refactorises, no other factors are alive; the
    counts are those of factorisations actually made (none made again after a release)."""
    made = []
    factors = linalg.Factorization._factors

    def counting(matrix):
        assert sum(f._solve is not None for f in made) == 0
        return factors(matrix)

    init = linalg.Factorization.__init__

    def register(self, matrix, stats=None):
        init(self, matrix, stats)
        made.append(self)

    monkeypatch.setattr(linalg.Factorization, "_factors", staticmethod(counting))
    monkeypatch.setattr(linalg.Factorization, "__init__", register)
    residual, x0, params = problem()
    sol = jaxanm.integrate(residual, x0, params, t0=0.0, t1=1.0 if problem is not impulsive_cubic else 0.05,
                           dt=1e-2, solver=solver)
    assert sol.stats.factorizations == len(made) >= 2
