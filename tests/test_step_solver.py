"""The step-solver interface: solvers are StepSolver subclasses whose state is a value."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from model_problems import heat_1d, impulsive_cubic

import jaxanm
from jaxanm._problem import Problem

ITERATIONS: list = []
"""The chord iterations of each step :class:`FixedPointNewton` solved, as it counted them."""


@dataclasses.dataclass(frozen=True)
class FixedPointNewton(jaxanm.StepSolver):
    """A user's solver: chord iterations with the Jacobian at the step's start, refreshed every
    step (written against the public interface only); it reports its iterations."""

    tol: float = 1e-10
    max_iter: int = 50
    reuses_factorization = False

    def step(self, state, step, x_old, t, dt, params):
        """Chord iterations from ``x_old`` with the tangent there."""
        problem = state.problem
        x = np.array(x_old, dtype=np.float64)
        fact = problem.factorize_at(x, x_old, t, dt, params)
        for n in range(1, self.max_iter + 1):
            dx = -fact.solve(problem.residual(x, x_old, t, dt, params))
            x = x + dx
            if problem.norm(dx) <= self.tol * max(problem.norm(x), 1e-300):
                ITERATIONS.append(n)
                report = jaxanm.StepReport(newton_iterations=n)
                return x, dataclasses.replace(self.with_factorization(state, fact), report=report)
        raise jaxanm.StepFailure("chord iterations did not converge", step=step, t=t)


def test_a_user_subclass_runs_in_integrate_and_agrees_with_newton():
    residual, x0, params = heat_1d(12)
    kw = dict(t0=0.0, t1=0.2, dt=0.02)
    mine = jaxanm.integrate(residual, x0, params, solver=FixedPointNewton(), **kw)
    newton = jaxanm.integrate(residual, x0, params, solver=jaxanm.Newton(tol=1e-10), **kw)
    assert mine.stats.factorizations == mine.stats.time_steps == 10
    # the time loop, not the solver, adds each step's report to the run's statistics
    assert mine.stats.newton_iterations == sum(ITERATIONS[-10:]) and len(ITERATIONS) >= 10
    np.testing.assert_allclose(mine.xs, newton.xs, rtol=0, atol=1e-9 * np.abs(newton.xs).max())


def test_an_abstract_solver_cannot_be_made_and_a_non_solver_is_refused():
    with pytest.raises(TypeError):
        jaxanm.StepSolver()
    residual, x0, params = heat_1d(5)
    with pytest.raises(jaxanm.InputError, match="StepSolver"):
        jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.1, dt=0.01, solver=object())


@pytest.mark.parametrize("solver", [jaxanm.ANM(order=5, tol=1e-8), jaxanm.ModifiedNewton(tol=1e-8),
                                    jaxanm.Newton(tol=1e-8)], ids=["anm", "mnewton", "newton"])
def test_step_returns_a_new_state_and_leaves_the_old_one(solver):
    residual, x0, params = heat_1d(8)
    problem = Problem(residual, np.ones(x0.size), jaxanm.Stats(), "dense", None)
    with jaxanm.float64():
        start = solver.init(problem)
        x1, after = solver.step(start, 1, x0, np.float64(0.01), np.float64(0.01), params)
        x2, later = solver.step(after, 2, x1, np.float64(0.02), np.float64(0.01), params)
    assert start.factorization is None and after is not start and after.problem is problem
    assert solver.factorization(after) is not None
    with pytest.raises(dataclasses.FrozenInstanceError):
        after.factorization = None
    if isinstance(solver, jaxanm.Newton):  # a Jacobian per iteration: never the previous step's
        assert solver.factorization(later) is not solver.factorization(after)
    assert (solver.accepted_residual(after) is not None) == isinstance(solver, jaxanm.ANM)
    stored = solver.to_checkpoint(later)
    assert (stored is None) == isinstance(solver, jaxanm.Newton)


def test_a_failed_step_hands_back_the_factorisation_it_made():
    """An ANM step that factorises and then fails leaves that K* to the retry (dt halving)."""
    residual, x0, params = impulsive_cubic()
    solver = jaxanm.ANM(order=5, tol=1e-8, max_substeps=0)
    problem = Problem(residual, np.ones(x0.size), jaxanm.Stats(), "dense", None)
    start = solver.init(problem)
    with jaxanm.float64(), pytest.raises(jaxanm.StepFailure) as info:
        solver.step(start, 1, x0, np.float64(0.01), np.float64(0.01), params)
    retry = solver.state_after_failure(start, info.value)
    assert problem.stats.factorizations == 1 and solver.factorization(retry) is not None
    assert start.factorization is None


def test_the_problem_counts_and_times_solves_and_the_factorization_does_not():
    """Counting belongs to the caller's stats: a :class:`jaxanm.Factorization` only factors
    and solves; :class:`Problem` counts one solve per right-hand side."""
    stats = jaxanm.Stats()
    problem = Problem(lambda x, *_: x, np.ones(2), stats, "dense", None)
    fact = jaxanm.factorize(np.array([[2.0, 1.0], [0.0, 4.0]]), stats)
    x = problem.solve(fact, np.array([3.0, 4.0]))
    X = problem.solve(fact, np.ones((2, 3)))
    np.testing.assert_allclose(x, [1.0, 1.0])  # closed form of the triangular system
    np.testing.assert_allclose(X, np.tile([[0.375], [0.25]], 3))
    assert stats.solves == 4 and stats.factorizations == 1 and stats.wall_time["solve"] > 0
    assert jaxanm.Factorization(np.eye(2)).solve(np.ones(2)).tolist() == [1.0, 1.0]
    assert stats.solves == 4  # a bare solve is nobody's to count
    residual, x0, params = heat_1d(8)
    sol = jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.1, dt=0.01, solver=jaxanm.Newton(tol=1e-8))
    assert sol.stats.solves == sol.stats.newton_iterations > 0


def test_every_module_of_the_solver_package_is_imported_with_it():
    """Dropping a file into jaxanm/_solver/ is enough: the package imports all its modules."""
    import pkgutil
    import sys

    import jaxanm._solver as package
    names = [m.name for m in pkgutil.iter_modules(package.__path__)]
    assert {"base", "anm", "newton"} <= set(names)
    assert all(f"jaxanm._solver.{name}" in sys.modules for name in names)
    assert jaxanm.solver_kinds() == ("anm", "mnewton", "newton")


def test_a_solver_that_declares_a_kind_is_registered_and_made_by_name(monkeypatch):
    from jaxanm._solver import base
    monkeypatch.setattr(base, "_KINDS", dict(base._KINDS))  # the class below leaves with the test

    @dataclasses.dataclass(frozen=True)
    class Chord(FixedPointNewton):
        kind = "chord"

    assert "chord" in jaxanm.solver_kinds()
    made = jaxanm.make_solver("chord", tol=1e-9)
    assert type(made) is Chord and made.tol == 1e-9
    with pytest.raises(TypeError, match="already"):
        type("Other", (FixedPointNewton,), {"kind": "anm"})


def test_make_solver_refuses_an_unknown_kind_or_option_naming_what_it_knows():
    with pytest.raises(jaxanm.InputError, match="'rk4'.*anm, mnewton, newton"):
        jaxanm.make_solver("rk4")
    with pytest.raises(jaxanm.InputError, match="'order'.*tol, max_iter"):
        jaxanm.make_solver("newton", order=5)
    assert jaxanm.make_solver("mnewton", max_rate=0.3) == jaxanm.ModifiedNewton(max_rate=0.3)


@pytest.mark.parametrize("kind, options, message", [
    ("anm", {"order": 1}, "ANM.order must be an integer >= 2"),
    ("anm", {"tol": 0.0}, r"ANM.tol must be a number in \(0, 1\)"),
    ("anm", {"max_substeps": -1}, "ANM.max_substeps must be an integer >= 0"),
    ("anm", {"criterion": "size"}, "ANM.criterion must be 'increment'"),
    ("anm", {"homotopy": "arc"}, "ANM.homotopy must be 'convex'"),
    ("anm", {"adaptive": "yes"}, "ANM.adaptive must be True or False"),
    ("newton", {"max_iter": 0}, "Newton.max_iter must be an integer >= 1"),
    ("newton", {"tol": 1.5}, r"Newton.tol must be a number in \(0, 1\)"),
    ("mnewton", {"max_rate": 1.0}, r"ModifiedNewton.max_rate must be a number in \(0, 1\)"),
    ("mnewton", {"max_rate": "0.5"}, r"ModifiedNewton.max_rate must be a number in \(0, 1\)"),
    ("mnewton", {"max_iter": 2.5}, "ModifiedNewton.max_iter must be an integer >= 1"),
])
def test_each_solver_validates_its_own_options(kind, options, message):
    with pytest.raises(jaxanm.InputError, match=message):
        jaxanm.make_solver(kind, **options)
