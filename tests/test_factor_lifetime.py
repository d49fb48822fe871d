"""Lifetime of the LU factors: a solver frees a K* it replaces before making the next one.

On fine clouds one LU takes most of a run's memory; two alive at a refactorisation (the stale
K*, held by the state the step started from, and the new one) doubled the peak memory of a
long run (docs/notes/sparse_lu_at_scale.md).  The rule (:class:`jaxanm.StepSolver`): a state
passed to ``step`` hands its K* over, unless the caller retained it; the state keeps the
matrix, so a released K* still solves, by factorising it again (counted).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
from model_problems import heat_1d, impulsive_cubic

import jaxanm
from jaxanm import _problem as linalg
from jaxanm._problem import Problem
from jaxanm.stats import Stats


def test_a_released_factorization_solves_by_factorising_again():
    """The same matrix gives the same factors: the solution after a release is bit for bit
    the one before, and the second factorisation is counted."""
    rng = np.random.default_rng(3)
    a = scipy.sparse.random(40, 40, density=0.1, random_state=rng) + 4.0 * scipy.sparse.identity(40)
    b = rng.standard_normal(40)
    stats = Stats()
    fact = linalg.factorize(a, stats)
    before = linalg.counted_solve(fact, b, stats)
    fact.release()
    assert stats.factorizations == 1 and fact.released
    after = linalg.counted_solve(fact, b, stats)
    assert np.array_equal(before, after) and not fact.released
    assert stats.factorizations == 2 and stats.solves == 2


def _source_jump():
    """heat_1d whose source jumps at t = 0.5: the ANM's K* goes stale and is replaced."""
    residual0, x0, params = heat_1d()

    def residual(u, u_old, t, dt, p):
        return residual0(u, u_old, t, dt, p) - jnp.where(t > 0.5, 40.0, 0.0)

    return residual, x0, params


@pytest.mark.parametrize("problem, solver", [
    (_source_jump, jaxanm.ANM.paper(order=5, tol=1e-8)),  # the paper's: a stale K* is replaced
    (impulsive_cubic, jaxanm.ANM.paper(order=7, tol=1e-8)),
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

    def register(self, matrix):
        init(self, matrix)
        made.append(self)

    monkeypatch.setattr(linalg.Factorization, "_factors", staticmethod(counting))
    monkeypatch.setattr(linalg.Factorization, "__init__", register)
    residual, x0, params = problem()
    sol = jaxanm.integrate(residual, x0, params, t0=0.0, t1=1.0 if problem is not impulsive_cubic else 0.05,
                           dt=1e-2, solver=solver)
    assert sol.stats.factorizations == len(made) >= 2


def _stale_kstar_start():
    """A state of the ANM on ``_source_jump`` whose K* goes stale at the next step (the source
    jumps), and that step's arguments."""
    residual, x0, params = _source_jump()
    solver = jaxanm.ANM.paper(order=5, tol=1e-8)  # the paper's: a stale K* is replaced
    problem = Problem(residual, np.ones(x0.size), Stats(), "dense", None)
    dt = np.float64(0.01)
    with jaxanm.float64():
        x1, state = solver.step(solver.init(problem), 1, x0, np.float64(0.5), dt, params)
    assert state.factorization is not None
    return solver, problem, state, (2, x1, np.float64(0.51), dt, params)


def test_a_step_frees_the_kstar_handed_over_to_it():
    """The documented hand-over: stepping from a state whose K* goes stale frees that K* before
    the new one is made (the time loop's case: one LU alive)."""
    solver, problem, state, args = _stale_kstar_start()
    old = state.factorization
    with jaxanm.float64():
        _, after = solver.step(state, *args)
    assert after.factorization is not old and old.released and not after.factorization.released


def test_a_retained_state_keeps_its_kstar_and_steps_again_identically():
    """A retained K* is never freed: two steps from the same retained state make the same
    factorisations (none made again for a released K*) and the same state, bit for bit."""
    solver, problem, state, args = _stale_kstar_start()
    kept = solver.retain(state)
    assert kept is state
    results = []
    for _ in range(2):
        before = problem.stats.factorizations
        with jaxanm.float64():
            x, after = solver.step(kept, *args)
        assert not state.factorization.released
        results.append((x, problem.stats.factorizations - before, after.factorization))
    (x_a, made_a, fact_a), (x_b, made_b, fact_b) = results
    assert np.array_equal(x_a, x_b) and made_a == made_b >= 1  # the stale K* was replaced both times
    assert fact_a is not state.factorization and fact_b is not fact_a
