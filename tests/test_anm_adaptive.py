"""Order-adaptive ANM (``ANM(adaptive=True)``): one order at a time, stop at the first order
whose validity range reaches a = 1 and whose end point passes the check.

Checked without the solver's own judgement where possible: the truncated jet against the
zero-padded one (the coefficient of order j - 1 depends on c_1 .. c_{j-1} only), and every
accepted state's Newton distance by a dense ``jax.jacfwd`` Jacobian against what the
tolerance promises (the yardstick of tests/test_anm_acceptance.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_anm_acceptance import CHECK_LIMIT, cubic_reaction_diffusion, newton_distance_ratio

import jaxanm
from jaxanm import taylor_coefficients


def test_truncated_jet_gives_the_padded_coefficient():
    """[R]_k along c_1..c_k alone equals [R]_k of the path padded with zero terms up to K = 6.

    Both programs form the same products in the same order (the padding only adds exact zeros
    to later orders), so they agree to a few roundings of the largest term: 1e-13 relative to
    the coefficient's largest term bounds any re-association XLA's fusion may choose.
    """
    residual, x0, params = cubic_reaction_diffusion()
    rng = np.random.default_rng(3)
    x = rng.uniform(0.5, 1.5, x0.size)
    terms = [rng.standard_normal(x0.size) for _ in range(6)]
    args = (np.zeros(x0.size), np.float64(0.1), np.float64(0.1), params)
    padded = taylor_coefficients(residual, x, terms, *args)
    for k in range(1, 7):
        truncated = taylor_coefficients(residual, x, terms[:k], *args)[-1]
        np.testing.assert_allclose(truncated, padded[k], rtol=0, atol=1e-13 * np.abs(padded[k]).max())


@pytest.mark.parametrize("criterion", ["increment", "state"])
def test_adaptive_steps_solve_each_step_to_the_promised_accuracy(criterion):
    residual, x0, params = cubic_reaction_diffusion()
    tol, p = 1e-6, 8
    kw = dict(t0=0.0, t1=0.5, dt=0.02)
    adaptive = jaxanm.integrate(residual, x0, params, solver=jaxanm.ANM.paper(order=p, tol=tol,
                                                                             criterion=criterion, adaptive=True), **kw)
    fixed = jaxanm.integrate(residual, x0, params, solver=jaxanm.ANM.paper(order=p, tol=tol, criterion=criterion), **kw)
    st = adaptive.stats
    assert len(st.orders) == len(st.amax) == st.time_steps  # one accepted series per step
    assert all(2 <= j <= p for j in st.orders) and min(st.orders) < p  # it did adapt
    assert fixed.stats.orders == [p] * fixed.stats.time_steps
    assert st.series_orders < fixed.stats.series_orders
    if criterion == "increment":
        assert newton_distance_ratio(residual, params, adaptive, tol) <= CHECK_LIMIT
    # the two runs solve the same steps, each within the tolerance of the step's increment
    # (or of the state): their difference is bounded by twice that, compounded over the steps
    # by the (contractive, diffusive) step map; 50 steps times 2 CHECK_LIMIT tol |x|
    scale = np.abs(fixed.xs).max()
    assert np.abs(adaptive.xs - fixed.xs).max() <= 2 * CHECK_LIMIT * tol * scale * len(fixed.ts)


def test_adaptive_is_validated():
    with pytest.raises(jaxanm.InputError, match="adaptive"):
        jaxanm.ANM(adaptive="yes")


def test_a_corrected_end_point_is_within_the_promised_accuracy(monkeypatch):
    """Where the contraction of its last two coefficients predicts that the next order would
    reach a = 1, the series stops and a modified-Newton correction with K* stands for that
    order; the corrected state is accepted only when the correction is within the promised
    accuracy, and then (checked by a dense Jacobian, not by the solver) it is within it."""
    import jax
    import jax.numpy as jnp

    from jaxanm._solver import anm

    residual, x0, params = cubic_reaction_diffusion()
    tol = jaxanm.ANM().tol
    corrected, missed = [], []
    original = anm._ANMStep._corrected

    def spy(self, coeffs, d_s, args, substeps):
        outcome = original(self, coeffs, d_s, args, substeps)
        (corrected if isinstance(outcome, tuple) and not isinstance(outcome, anm._Start) else missed).append(
            (outcome, d_s, args))
        return outcome

    monkeypatch.setattr(anm._ANMStep, "_corrected", spy)
    sol = jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.5, dt=0.02, solver=jaxanm.ANM())
    assert len(corrected) >= sol.stats.time_steps // 2  # the correction is the common way out here
    assert missed  # and at least one missed and went on from its end point: the run still solves every step,
    # against modified Newton at a tolerance 1e4 times tighter: each step within CHECK_LIMIT tol |x| of its
    # solution, compounded over the 25 steps by the (contractive, diffusive) step map
    reference = jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.5, dt=0.02, solver=jaxanm.ModifiedNewton(tol=1e-10))
    scale = np.abs(reference.xs).max()
    assert np.abs(sol.xs - reference.xs).max() <= CHECK_LIMIT * tol * scale * len(reference.ts)
    with jaxanm.float64():
        for (x, r_x), d_s, (x_old, t, dt, p) in corrected:
            assert r_x is None  # not evaluated: the time loop evaluates it
            f = lambda y, a=(x_old, t, dt, p): residual(y, *a)  # noqa: E731
            delta = np.linalg.solve(np.asarray(jax.jacfwd(f)(jnp.asarray(x))), np.asarray(f(jnp.asarray(x))))
            # promised: tol |d_s| (criterion "state"; d_s = x_old here) or tol |c_1| ~ tol |x - x_old|;
            # the correction met it, and what it leaves is its contraction (<= max_rate = 0.5)
            promised = tol * max(np.linalg.norm(d_s), np.linalg.norm(x - x_old))
            assert np.linalg.norm(delta) <= 0.5 * promised


def test_the_next_order_is_predicted_from_a_contraction_only():
    """next_order_suffices: a geometric tail within max_rate that reaches the tolerance at the
    next order, and nothing from a ratio above max_rate or of a vanished coefficient."""
    from jaxanm._acceptance import next_order_suffices, range_of_norms

    tol, n1 = 1e-6, 1.0
    # |c_3| = 0.07 |c_2| = 7e-6 |c_1| predicts |c_4| = 4.9e-7 |c_1|: eq. 26 at order 4 reaches 1 (tol 1e-6)
    assert range_of_norms(4, n1, 4.9e-7, tol) >= 1.0
    assert next_order_suffices(3, n1, 1e-4, 7e-6, tol, None, 0.5)
    assert not next_order_suffices(3, n1, 1e-4, 2e-5, tol, None, 0.5)  # predicts 4e-6 |c_1|: not yet
    assert not next_order_suffices(3, n1, 1e-6, 0.9e-6, tol, None, 0.5)  # contraction 0.9 > max_rate
    assert not next_order_suffices(3, n1, 1e-4, 7e-6, tol, None, 0.0)  # max_rate 0: the paper's rule
    assert not next_order_suffices(3, n1, 0.0, 0.0, tol, None, 0.5)  # vanished: no ratio
    # relative to the state: c_3 = 1e-7 |d_s| contracting by 0.5 predicts c_4 = 5e-8 |d_s| < tol |d_s|
    assert next_order_suffices(3, 1e-3, 2e-7, 1e-7, tol, 1.0, 0.5)
