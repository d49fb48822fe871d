"""Gradients of simulations (jaxanm.sensitivity) and calibration of K, A, n (jaxanm.fsw.calibration).

References are independent of the forward-sensitivity machinery: reverse-mode ``jax.grad``
through an unrolled pure-JAX implicit Euler + Newton solver (core), and central finite
differences of the polished forward map (FSW, ANM and Newton).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from model_problems import heat_1d

import jaxanm
from jaxanm import sensitivity
from jaxanm.fsw import calibration, load_scene

# --- core: a small nonlinear model problem ---------------------------------------------------

N, DT, STEPS = 12, 0.02, 10
THETA = {"c": 1.3, "r": 0.7}


def _observe(t, x, p):
    return {"u": x[::3], "mean": jnp.mean(x) * jnp.ones(1)}


def _loss(obs, theta):
    return 0.5 * jnp.sum(obs["u"] ** 2) + jnp.sum(obs["mean"]) + 0.1 * theta["r"] ** 2


def _reference_value_and_grad(theta):
    """Pure JAX: implicit Euler with 12 dense Newton iterations per step (lax loops), jax.grad."""
    residual, x0, _ = heat_1d(N)

    def total(th):
        def step(x_old, k):
            t = k * DT
            f = lambda xx: residual(xx, x_old, t, DT, th)  # noqa: E731
            x = jax.lax.fori_loop(0, 12, lambda _, x: x - jnp.linalg.solve(jax.jacfwd(f)(x), f(x)), x_old)
            return x, _observe(t, x, th)

        _, obs = jax.lax.scan(step, jnp.asarray(x0), jnp.arange(1, STEPS + 1, dtype=jnp.float64))
        first = _observe(0.0, jnp.asarray(x0), th)
        stacked = {key: jnp.concatenate([first[key][None], obs[key]]) for key in first}
        return _loss(stacked, th)

    with jaxanm.float64():
        value, grad = jax.jit(jax.value_and_grad(total))({k: jnp.float64(v) for k, v in theta.items()})
    return float(value), {k: float(v) for k, v in grad.items()}


@pytest.fixture(scope="module")
def core_reference():
    return _reference_value_and_grad(THETA)


@pytest.mark.parametrize("solver", [jaxanm.ANM(order=7, tol=1e-6), jaxanm.Newton(tol=1e-6)], ids=["anm", "newton"])
def test_core_gradient_matches_unrolled_reference(solver, core_reference):
    residual, x0, params = heat_1d(N)
    value, grad = jaxanm.value_and_grad(_loss, residual, x0, params, THETA, observe=_observe, t0=0.0,
                                        t1=STEPS * DT, dt=DT, solver=solver)
    ref_value, ref_grad = core_reference
    assert isinstance(value, np.float64) and all(g.dtype == np.float64 for g in grad.values())
    assert abs(value - ref_value) <= 1e-12 * abs(ref_value)
    for key in THETA:
        assert abs(grad[key] - ref_grad[key]) <= 1e-9 * abs(ref_grad[key]), (key, grad[key], ref_grad[key])


def test_core_gradient_matches_central_differences_and_polish_removes_solver_dependence():
    residual, x0, params = heat_1d(N)
    kw = dict(observe=_observe, t0=0.0, t1=STEPS * DT, dt=DT)
    anm = sensitivity.sensitivities(residual, x0, params, THETA, solver=jaxanm.ANM(order=7, tol=1e-6), **kw)
    newton = sensitivity.sensitivities(residual, x0, params, THETA, solver=jaxanm.Newton(tol=1e-6), **kw)
    # polished steps are the exact implicit-Euler roots: the two solvers agree to round-off,
    # although their tolerances (1e-6) would leave differences ~1e-7
    assert np.max(np.abs(anm.observed["u"] - newton.observed["u"])) < 1e-12 * np.max(np.abs(newton.observed["u"]))
    assert max(anm.sensitivity_stats.residual_norm) < 1e-10
    assert anm.sensitivity_stats.extra_factorizations == 0  # the stale K* sufficed as preconditioner
    _, grad = sensitivity.loss_value_and_grad(_loss, anm, THETA)
    h = 1e-5
    for key in THETA:
        values = []
        for sign in (1, -1):
            th = dict(THETA, **{key: THETA[key] + sign * h})
            run = sensitivity.sensitivities(residual, x0, params, th, tangents=False,
                                            solver=jaxanm.ANM(order=7, tol=1e-6), **kw)
            with jaxanm.float64():
                values.append(float(_loss({k: jnp.asarray(v) for k, v in run.observed.items()},
                                          {k: jnp.float64(v) for k, v in th.items()})))
        fd = (values[0] - values[1]) / (2 * h)
        assert abs(grad[key] - fd) <= 1e-7 * abs(fd), (key, grad[key], fd)


def test_core_bad_theta_is_rejected_before_running():
    residual, x0, params = heat_1d(N)
    with pytest.raises(jaxanm.InputError, match="'k' names no leaf"):
        jaxanm.value_and_grad(_loss, residual, x0, params, {"k": 1.0}, observe=_observe, t0=0.0, t1=0.1,
                              dt=DT, solver=jaxanm.Newton())
    with pytest.raises(jaxanm.InputError, match="not finite"):
        jaxanm.value_and_grad(_loss, residual, x0, params, {"c": np.nan}, observe=_observe, t0=0.0, t1=0.1,
                              dt=DT, solver=jaxanm.Newton())


# --- FSW: gradients with respect to log K, A, n ------------------------------------------------

def _short_scene(**over):
    """calibration_small over 2 steps of 2 ms (the first one impulsive: the tool starts turning).

    With fsw_paper's penalty 0.1 mu_ref: the ANM's continuation from rest needs it (31
    sub-steps at order 7; with no penalty a_max stalls near 1e-3); fine at T0 = 300 K.
    """
    return load_scene("calibration_small").with_overrides(
        {"time.dt": 2e-3, "time.t_end": 4e-3, "mechanics.penalty": 4.08e5, **over})


def _fsw_loss(obs, theta):
    """Probe temperature rises and velocities, scaled to O(1)."""
    p = obs["probes"]
    return (sum(jnp.sum((p[k]["T"] - 300.0) ** 2) for k in p)
            + 1e6 * sum(jnp.sum(p[k]["u"] ** 2 + p[k]["v"] ** 2) for k in p)
            + jnp.sum(obs["sections"]["A-A"]["T"][-1] - 300.0))


@pytest.mark.parametrize("solver", [
    # the ANM's run takes about three times Newton's; the ANM's gradient through the core loop is
    # checked in the default suite by test_core_gradient_matches_unrolled_reference[anm]
    pytest.param(jaxanm.ANM(order=7, tol=1e-6), id="anm", marks=pytest.mark.slow),
    pytest.param(jaxanm.Newton(tol=1e-6), id="newton")])
def test_fsw_gradient_matches_central_differences(solver):
    scene = _short_scene()
    theta = calibration.material_theta(scene)
    value, grad = calibration.scene_value_and_grad(_fsw_loss, scene, theta, solver=solver)
    assert isinstance(value, np.float64) and all(isinstance(g, np.float64) for g in grad.values())
    steps = {"logK": 1e-4, "A": 1e-5, "n": 1e-6}
    for key, h in steps.items():
        values = []
        for sign in (1, -1):
            th = dict(theta, **{key: theta[key] + sign * h})
            obs = calibration.simulate(scene, th, solver=solver, tangents=False).observed
            with jaxanm.float64():
                values.append(float(_fsw_loss(obs, th)))
        fd = (values[0] - values[1]) / (2 * h)
        assert abs(grad[key] - fd) <= 1e-5 * abs(fd), (key, grad[key], fd)


def test_fsw_sensitivities_are_float64_and_consistent_with_the_jacobian():
    scene = _short_scene()
    theta = calibration.material_theta(scene)
    run = calibration.simulate(scene, theta)
    assert run.theta_names == ["A", "logK", "n"]
    for leaf in jax.tree_util.tree_leaves(run.observed) + jax.tree_util.tree_leaves(run.jacobian):
        assert leaf.dtype == np.float64
    assert run.jacobian["probes"]["1"]["T"].shape == (3, 3)
    assert np.all(run.jacobian["probes"]["1"]["T"][0] == 0.0)  # the initial state does not depend on theta
    # heating is 3 beta mu epsbar^2 with mu proportional to K: dT/dlogK > 0 at the probe near the tool
    assert np.all(run.jacobian["probes"]["1"]["T"][1:, 1] > 0)


def test_fsw_bad_input_gives_clear_errors():
    scene = _short_scene()
    theta = calibration.material_theta(scene)
    with pytest.raises(jaxanm.InputError, match="unknown calibration parameter.*'k0'"):
        calibration.scene_value_and_grad(_fsw_loss, scene, {**theta, "k0": 1.0})
    with pytest.raises(jaxanm.InputError, match="both 'logK' and 'K'"):
        calibration.simulate(scene, {**theta, "K": 1.0})
    lagrangian = scene.with_overrides({"effects": list(scene.effects) + ["lagrangian"]})
    with pytest.raises(jaxanm.InputError, match="lagrangian.*tracers"):
        calibration.scene_value_and_grad(_fsw_loss, lagrangian, theta)
    with pytest.raises(jaxanm.InputError, match="T0 and omega"):
        calibration.simulate(scene, {"T0": 300.0})
    with pytest.raises(jaxanm.InputError, match=r"theta\['n'\] must be a number in \(0, 2\], got 0.0"):
        calibration.simulate(scene, {"n": 0.0})
    with pytest.raises(jaxanm.InputError, match=r"theta\['K'\] must be a number > 0, got -1.0; or calibrate logK"):
        calibration.simulate(scene, {"K": -1.0})
    with pytest.raises(jaxanm.InputError, match=r"sigma\['T'\] must be a number > 0, got 0"):
        calibration.fit([scene], [{}], theta, sigma={"T": 0})


def test_fit_recovers_noiseless_parameters():
    """Two experiments (T0 = 300 K and 600 K) of 2 steps; start 20 % away; noiseless data."""
    scenes = [load_scene("calibration_small").with_overrides(
        {"time.dt": 4e-3, "time.t_end": 8e-3, "thermal.T0": T0, "thermal.Ta": T0, "tool.omega": 40.0})
        for T0 in (300.0, 600.0)]
    true = calibration.material_theta(scenes[0])
    data = [calibration.simulate(s, true, tangents=False).observed for s in scenes]
    start = {"logK": true["logK"] + math.log(0.8), "A": 1.2 * true["A"], "n": 1.2 * true["n"]}
    result = calibration.fit(scenes, data, start, sigma={"T": 0.01, "u": 1e-5, "v": 1e-5}, max_iter=15)
    fitted, truth = calibration.theta_to_material(result.theta), calibration.theta_to_material(true)
    for key in ("K", "A", "n"):
        assert abs(fitted[key] / truth[key] - 1) < 1e-3, (key, fitted[key], truth[key])
    assert result.loss_history[-1] < 1e-6 * result.loss_history[0]
    assert result.converged


def test_fit_that_runs_out_of_simulations_says_so():
    """Start 20 % away: two simulations cannot reach the minimum (the noiseless fit needs more)."""
    scene = load_scene("calibration_small").with_overrides(
        {"time.dt": 4e-3, "time.t_end": 8e-3, "tool.omega": 40.0})
    true = calibration.material_theta(scene)
    data = [calibration.simulate(scene, true, tangents=False).observed]
    start = {"logK": true["logK"] + math.log(0.8), "A": 1.2 * true["A"], "n": 1.2 * true["n"]}
    with pytest.warns(UserWarning, match="max_iter = 2 simulations ran out.*raise max_iter"):
        result = calibration.fit([scene], data, start, sigma={"T": 0.01, "u": 1e-5, "v": 1e-5}, max_iter=2)
    assert not result.converged and result.evaluations == 2
