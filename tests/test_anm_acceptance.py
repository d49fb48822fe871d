"""ANM acceptance: a series accepted at a = 1 really solves the step (docs/notes/anm_acceptance.md).

Eq. 26 judges a series by its last coefficient c_p alone.  With K* factorised at the series'
start d_s, c_2 vanishes identically (order 2 of the homotopy reads K*(c_2 - c_1) + K(d_s) c_1 = 0),
and a residual whose second derivative vanishes at d_s (a cubic reaction from u = 0) makes every
coefficient but c_1, c_4, c_7, ... vanish.  For p = 2, 3, 5, 6, 8, ... a_max is then ~1e9 or more
and, before the end-point check, the truncated series was accepted far from the step's solution.

The checks here do not use the solver: the accepted state's Newton distance ``|J^-1 R(x)|`` by a
dense ``jax.jacfwd`` Jacobian, against what the tolerance promises (``benchmarks/hard_cases.py``:
``tol |x - x_old|`` with a round-off floor, at most ten times).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from model_problems import heat_1d, impulsive_cubic

import jaxanm
import jaxanm._problem
import jaxanm._solver.anm

CHECK_LIMIT = 10.0


def cubic_reaction_diffusion(n: int = 20):
    """u_t = u_xx + s sin(pi x) - k u^3 on (0, 1), u = 0 at the ends, from u = 0."""
    h = 1.0 / (n + 1)
    xg = np.linspace(h, 1.0 - h, n)

    def residual(u, u_old, t, dt, p):
        up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
        lap = (up[2:] - 2 * u + up[:-2]) / h**2
        return (u - u_old) / dt - lap - p["s"] * jnp.sin(jnp.pi * xg) + p["k"] * u**3

    return residual, np.zeros(n), {"s": 5.0, "k": 5.0}


def newton_distance_ratio(residual, params, sol, tol):
    """Largest ``|J(x)^-1 R(x)| / (tol |x - x_old| + 1e-12 |x|)`` over the saved steps (dense jacfwd)."""
    worst = 0.0
    with jaxanm.float64():
        for k in range(1, len(sol.ts)):
            x, x_old = sol.xs[k], sol.xs[k - 1]
            args = (jnp.asarray(x_old), jnp.float64(sol.ts[k]), jnp.float64(sol.ts[k] - sol.ts[k - 1]), params)
            f = lambda y, args=args: residual(y, *args)  # noqa: E731
            jac = np.asarray(jax.jacfwd(f)(jnp.asarray(x)))
            delta = np.linalg.solve(jac, np.asarray(f(jnp.asarray(x))))
            yardstick = tol * np.linalg.norm(x - x_old) + 1e-12 * np.linalg.norm(x)
            worst = max(worst, np.linalg.norm(delta) / yardstick)
    return worst


def test_the_series_from_rest_has_vanishing_last_coefficients():
    """The premise: from u = 0 with a fresh K*, c_2 and c_3 vanish, so eq. 26 sees no last term."""
    residual, x0, params = cubic_reaction_diffusion()
    p, tol, dt = 4, 1e-6, 0.1
    problem = jaxanm._problem.Problem(residual, np.ones(x0.size), jaxanm.Stats(), "dense", None)
    with jaxanm.float64():
        args = (x0, jnp.float64(dt), jnp.float64(dt), params)
        fact = problem.factorize_at(x0, *args)
        coeffs = np.zeros((p, x0.size))
        coeffs[0] = -fact.solve(problem.residual(x0, *args))
        for j in range(2, p + 1):
            coeffs[j - 1] = coeffs[j - 2] - fact.solve(problem.series(x0, coeffs[: p - 1], *args)[j - 2])
    norms = np.linalg.norm(coeffs, axis=1)
    assert norms[1] < 1e-14 * norms[0] and norms[2] < 1e-14 * norms[0] and norms[3] > 1e-3 * norms[0]
    assert jaxanm.validity_range(coeffs[:3], np.ones(x0.size), tol) > 1e9  # p = 3 "converged"
    assert jaxanm.validity_range(coeffs, np.ones(x0.size), tol) < 1  # p = 4 sees c_4


@pytest.mark.parametrize("order", [2, 3, 5, 6, 8])
def test_series_with_a_vanishing_last_coefficient_is_not_accepted_unconverged(order):
    residual, x0, params = cubic_reaction_diffusion()
    tol = 1e-6
    sol = jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.1, dt=0.1, solver=jaxanm.ANM.paper(order=order, tol=tol))
    assert sol.stats.time_steps == 1 and sol.stats.dt_halvings == 0
    assert newton_distance_ratio(residual, params, sol, tol) <= CHECK_LIMIT
    # the false acceptance was caught and continued from, not accepted
    assert sol.stats.substeps >= 1


def test_state_criterion_is_checked_too():
    residual, x0, params = cubic_reaction_diffusion()
    tol = 1e-6
    sol = jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.5, dt=0.1,
                           solver=jaxanm.ANM.paper(order=5, tol=tol, criterion="state"))
    # "state" promises tol |x| per step, a looser yardstick than tol |x - x_old|
    with jaxanm.float64():
        for k in range(1, len(sol.ts)):
            args = (jnp.asarray(sol.xs[k - 1]), jnp.float64(sol.ts[k]), jnp.float64(0.1), params)
            f = lambda y, args=args: residual(y, *args)  # noqa: E731
            delta = np.linalg.solve(np.asarray(jax.jacfwd(f)(jnp.asarray(sol.xs[k]))), np.asarray(f(sol.xs[k])))
            assert np.linalg.norm(delta) <= CHECK_LIMIT * tol * np.linalg.norm(sol.xs[k])


def test_a_rejected_series_without_continuation_is_a_named_failure():
    """max_substeps = 0: every dt halving starts from rest with a fresh K*, where the series is
    falsely exact; the step fails with a message that says so, never with a silent acceptance."""
    residual, x0, params = cubic_reaction_diffusion()
    with pytest.raises(jaxanm.StepFailure) as info:
        jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.1, dt=0.1,
                         solver=jaxanm.ANM.paper(order=3, tol=1e-6, max_substeps=0), max_dt_halvings=2)
    err = info.value
    assert "misses the promised accuracy" in str(err) and err.step == 1 and err.amax > 1
    assert err.stats.dt_halvings == 2


@pytest.mark.parametrize("make, solver, t1", [
    (heat_1d, jaxanm.ANM.paper(order=7, tol=1e-8), 1.0),
    (heat_1d, jaxanm.ANM.paper(order=5, tol=1e-8, criterion="state"), 1.0),
    (impulsive_cubic, jaxanm.ANM.paper(order=7, tol=1e-8), 0.05),
], ids=["heat_1d-p7", "heat_1d-p5-state", "impulsive-p7"])
def test_the_check_costs_no_factorisation_where_the_series_is_fine(make, solver, t1, monkeypatch):
    """Where eq. 26 tells the truth, the end-point check changes nothing: same factorisations,
    sub-steps, series and states, and no extra residual evaluation either (the time loop
    reuses the check's residual at the accepted state instead of evaluating its own)."""
    residual, x0, params = make()
    kw = dict(t0=0.0, t1=t1, dt=1e-2, solver=solver)
    checked = jaxanm.integrate(residual, x0, params, **kw)
    # the solver as it was before the check: every series with a_max >= 1 accepted unseen
    monkeypatch.setattr(jaxanm._solver.anm._ANMStep, "_end_point_check",
                        lambda self, *args: (0.0, 0.0, None, None))
    unchecked = jaxanm.integrate(residual, x0, params, **kw)
    a, b = checked.stats, unchecked.stats
    assert (a.factorizations, a.substeps, a.series_orders, a.dt_halvings) == \
        (b.factorizations, b.substeps, b.series_orders, b.dt_halvings)
    assert a.residual_evaluations == b.residual_evaluations
    np.testing.assert_array_equal(checked.xs, unchecked.xs)
