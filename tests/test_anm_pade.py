"""ANM with Padé approximants (``ANM(pade=True)``): a series whose a_max < 1 is accepted when its
approximant's range reaches a = 1 and the approximant's end point passes the end-point check.

Judged without the solver where possible: the accepted states against Newton's at a tolerance
far below the ANM's, and every accepted state's Newton distance by a dense ``jax.jacfwd``
Jacobian (the yardstick of tests/test_anm_acceptance.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from model_problems import bratu_1d, heat_1d
from test_anm_acceptance import CHECK_LIMIT, newton_distance_ratio

import jaxanm
import jaxanm._solver.anm

TOL = 1e-6


def _run(make, solver, dt, t1=1.0):
    residual, x0, params = make()
    return jaxanm.integrate(residual, x0, params, t0=0.0, t1=t1, dt=dt, solver=solver)


@pytest.mark.parametrize("make, dt, order, criterion", [
    (bratu_1d, 0.5, 10, "increment"),
    (bratu_1d, 0.5, 10, "state"),
    pytest.param(heat_1d, 0.05, 10, "increment", marks=pytest.mark.slow),  # the bratu cases check the same
], ids=["bratu-dt0.5-p10", "bratu-dt0.5-p10-state", "heat_1d-dt0.05-p10"])
def test_large_steps_accepted_through_pade_solve_the_steps_with_fewer_factorisations(make, dt, order, criterion):
    """Large steps: series refused by eq. 26 are accepted through their approximant, the run needs
    fewer factorisations and no more sub-steps, and its states are those of Newton within what the
    tolerance promises.  Each accepted state is within ``CHECK_LIMIT tol |x_k - x_{k-1}|`` of its
    step's solution (the end-point check), and the step maps here are contractive (diffusion
    with a reaction below the fold), so the errors add up at most: the bound is
    ``CHECK_LIMIT tol sum_k |x_k - x_{k-1}|`` on Newton's states (Newton at tol 1e-12 is exact
    to that scale)."""
    residual, x0, params = make()
    plain = _run(make, jaxanm.ANM.paper(order=order, tol=TOL, criterion=criterion), dt)
    pade = _run(make, jaxanm.ANM.paper(order=order, tol=TOL, criterion=criterion, pade=True), dt)
    newton = _run(make, jaxanm.Newton(tol=1e-12), dt)
    a, b = pade.stats, plain.stats
    assert a.pade_accepted >= 1 and b.pade_accepted == 0
    assert a.summary()["pade_accepted"] == a.as_dict()["pade_accepted"] == a.pade_accepted
    assert a.factorizations < b.factorizations and a.substeps <= b.substeps
    assert len(a.amax) == len(a.orders) == a.time_steps and all(x >= 1.0 for x in a.amax)
    assert a.orders == [order] * a.time_steps
    bound = CHECK_LIMIT * TOL * np.linalg.norm(np.diff(newton.xs, axis=0), axis=1).sum()
    for sol in (pade, plain):
        assert np.abs(sol.xs - newton.xs).max() <= bound
    if criterion == "increment":
        assert newton_distance_ratio(residual, params, pade, TOL) <= CHECK_LIMIT


@pytest.mark.parametrize("make, dt, order", [(heat_1d, 0.01, 7), (heat_1d, 0.01, 5), (bratu_1d, 0.1, 7)],
                         ids=["heat_1d-dt0.01-p7", "heat_1d-dt0.01-p5", "bratu-dt0.1-p7"])
def test_pade_costs_no_factorisation(make, dt, order):
    """Where the plain series does well, the option adds no factorisation, sub-step or dt halving
    (it is only tried on series the plain criterion refuses)."""
    plain = _run(make, jaxanm.ANM.paper(order=order, tol=TOL), dt)
    pade = _run(make, jaxanm.ANM.paper(order=order, tol=TOL, pade=True), dt)
    a, b = pade.stats, plain.stats
    assert a.factorizations <= b.factorizations and a.substeps <= b.substeps and a.dt_halvings <= b.dt_halvings
    assert a.time_steps == b.time_steps


def test_a_pade_end_point_that_misses_is_not_accepted(monkeypatch):
    """The approximant's end point goes through the same end-point check as a series': with
    P_p(1) spoiled (1e-3 of the increment added), no series is accepted through it and every
    accepted state still solves its step."""
    residual, x0, params = bratu_1d()
    evaluate = jaxanm._pade.evaluate

    def spoiled(approx, a):
        inc = evaluate(approx, a)
        return inc + 1e-3 * np.abs(inc).max() if a == 1.0 else inc

    monkeypatch.setattr(jaxanm._pade, "evaluate", spoiled)
    sol = _run(bratu_1d, jaxanm.ANM.paper(order=10, tol=TOL, pade=True), 0.5)
    assert sol.stats.pade_accepted == 0
    assert newton_distance_ratio(residual, params, sol, TOL) <= CHECK_LIMIT


def test_adaptive_tries_pade_at_the_maximum_order_only(monkeypatch):
    """With ``adaptive`` the approximant is built for order-p series only (ANM docstring)."""
    calls = []
    pade_range = jaxanm._solver.anm._ANMStep._pade_range

    def recorded(self, coeffs, d_s):
        calls.append(coeffs.shape[0])
        return pade_range(self, coeffs, d_s)

    monkeypatch.setattr(jaxanm._solver.anm._ANMStep, "_pade_range", recorded)
    sol = _run(bratu_1d, jaxanm.ANM.paper(order=10, tol=TOL, adaptive=True, pade=True), 0.5)
    assert calls and set(calls) == {10} and sol.stats.pade_accepted >= 1
    assert min(sol.stats.orders) < 10  # the lower orders still stop early where the series suffices


def test_pade_is_validated():
    with pytest.raises(jaxanm.InputError, match="ANM.pade must be True or False"):
        jaxanm.ANM(pade="yes")
    with pytest.raises(jaxanm.InputError, match="order >= 3"):
        jaxanm.ANM(order=2, pade=True)
    assert jaxanm.ANM(order=3, pade=True).pade and not jaxanm.ANM().pade
