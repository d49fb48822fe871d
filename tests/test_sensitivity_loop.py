"""Forward sensitivities ride on integrate's one time loop (its ``sensitivity`` option)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest
from model_problems import bratu_1d, heat_1d

import jaxanm
from jaxanm import sensitivity


def _observe(t, x, p):
    return {"u": x[::5]}


def test_sensitivities_through_halved_steps_match_central_differences():
    """Steps of 0.5 that the ANM (one continuation sub-step allowed) only takes after dt
    halvings: S follows every polished sub-step, and d u / d lam agrees with central
    differences of the polished map."""
    residual, x0, params = bratu_1d()
    kw = dict(observe=_observe, t0=0.0, t1=1.0, dt=0.5, solver=jaxanm.ANM(order=6, tol=1e-8, max_substeps=1),
              max_dt_halvings=6)
    sens = sensitivity.sensitivities(residual, x0, params, {"lam": 2.0}, **kw)
    assert sens.stats.dt_halvings > 0 and sens.stats.time_steps == 2
    assert len(sens.stats.residual_norm) == 2 and max(sens.stats.residual_norm) < 1e-9
    h = 1e-6
    runs = [sensitivity.sensitivities(residual, x0, params, {"lam": 2.0 + s * h}, tangents=False, **kw)
            for s in (1, -1)]
    fd = (runs[0].observed["u"] - runs[1].observed["u"]) / (2 * h)
    np.testing.assert_allclose(sens.jacobian["u"][..., 0], fd, rtol=0, atol=1e-6 * np.abs(fd).max())


def test_the_sensitivity_option_is_checked():
    residual, x0, params = heat_1d(6)
    base = dict(t0=0.0, t1=0.1, dt=0.01, solver=jaxanm.Newton())
    with pytest.raises(jaxanm.InputError, match="sensitivity must be"):
        jaxanm.integrate(residual, x0, params, sensitivity=object(), **base)
    forward = sensitivity.ForwardSensitivity(residual, params, {"c": 1.0}, _observe)
    with pytest.raises(jaxanm.InputError, match="after_step"):
        jaxanm.integrate(residual, x0, forward.bound_params, sensitivity=forward,
                         controller=jaxanm.StepController(rtol=1e-3, atol=1e-3), **base)


def test_integrate_with_a_forward_sensitivity_is_what_sensitivities_returns():
    residual, x0, params = heat_1d(6)
    theta = {"c": 1.2}
    kw = dict(t0=0.0, t1=0.1, dt=0.02, solver=jaxanm.ModifiedNewton(tol=1e-8))
    with jaxanm.float64():
        forward = sensitivity.ForwardSensitivity(residual, params, theta, _observe)
        sol = jaxanm.integrate(residual, x0, forward.bound_params, sensitivity=forward, **kw)
    mine = forward.result(sol.stats, sol.stats.wall_time_s)
    theirs = sensitivity.sensitivities(residual, x0, params, theta, observe=_observe, **kw)
    np.testing.assert_array_equal(mine.jacobian["u"], theirs.jacobian["u"])
    np.testing.assert_array_equal(sol.xs[-1], theirs.x)  # the run goes on from the polished states
    assert jnp.asarray(mine.observed["u"]).shape == (6, 2)
