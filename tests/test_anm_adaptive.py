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
