"""Adaptive implicit-Euler steps (jaxanm.StepController, integrate(controller=...)), against the
closed forms of the linear decay x' = -lam x.

For x' = -lam x one implicit Euler step of size h from x_n gives x_n / (1 + lam h); the exact
solution gives x_n exp(-lam h), so the local error is

    LE = x_n (1/(1 + lam h) - exp(-lam h)) = x_n (lam^2 h^2 / 2 - 5 lam^3 h^3 / 6 + ...).

Milne's estimate with an equal previous step, (x_{n+1} - x_pred) / 2 with x_pred = x_n (1 - lam h),
is x_n (lam^2 h^2 / 2 - lam^3 h^3 / 2 + ...): the two agree to a relative (2/3) lam h + O(lam^2 h^2).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import jaxanm

LAM = 3.0


def decay(x, x_old, t, dt, p):
    """Implicit Euler step residual of x' = -lam x."""
    return (x - x_old) / dt + p["lam"] * x


def _local_error(x_n, h, lam=LAM):
    return x_n * (1.0 / (1.0 + lam * h) - math.exp(-lam * h))


@pytest.mark.parametrize("lam_h", [1e-3, 1e-2, 5e-2])
def test_milne_estimate_is_the_local_error_to_first_order(lam_h):
    h = lam_h / LAM
    x_before = 1.0
    x_now = x_before / (1 + LAM * h)
    x_new = x_now / (1 + LAM * h)
    # with one unknown the estimate's size is its absolute value
    est = abs(jaxanm.ImplicitEuler().local_error(np.array([x_new]), None, np.array([x_now]),
                                                 ((np.array([x_before]), h),), h)[0])
    exact = abs(_local_error(x_now, h))
    # the expansion above: relative difference (2/3) lam h + O((lam h)^2); lam h bounds it for lam h <= 0.05
    assert abs(est / exact - 1) <= lam_h


def test_accepted_steps_meet_the_tolerance_and_grow_as_the_solution_decays():
    """Every accepted step's true local error is within its tolerance, up to the estimate's own
    first-order error (1 + lam h), and the steps grow as x decays: with atol fixed the
    accepted h is about sqrt(2 atol / (lam^2 x)), and x falls by exp(-6) over the span, so h
    grows by about exp(3) = 20 (asserted: 10, the first steps being a transient of the
    controller from the initial dt)."""
    rtol, atol = 0.0, 1e-6
    ctl = jaxanm.StepController(rtol=rtol, atol=atol)
    sol = jaxanm.integrate(decay, np.ones(1), {"lam": LAM}, t0=0.0, t1=2.0, dt=1e-3, controller=ctl,
                           solver=jaxanm.Newton(tol=1e-12), saveat=jaxanm.SaveAt(steps=1))
    xs, ts, hs = sol.xs[:, 0], sol.ts, np.array(sol.stats.step_sizes)
    assert len(hs) == len(ts) - 1 and np.allclose(np.diff(ts), hs, rtol=0, atol=1e-15)
    for n in range(1, len(hs)):  # the first step is taken unchecked (no history)
        h = hs[n]
        assert abs(_local_error(xs[n], h)) <= (1 + LAM * h) * atol
    assert hs[-2] > 10 * hs[1]
    assert ts[-1] == 2.0


def test_tighter_tolerance_gives_smaller_global_error_and_more_steps():
    """A first-order method under error-per-step control: N ~ tol^(-1/2) steps, global error
    ~ N tol ~ tol^(1/2).  Between tol = 1e-5 and 1e-7 the error must fall and the steps rise,
    each by a factor of about 10; asserted is the direction and at least 3 of that 10 (the
    controller's safety factor and the rounding of N move it, not by a factor of 3)."""
    out = {}
    for tol in (1e-5, 1e-7):
        sol = jaxanm.integrate(decay, np.ones(1), {"lam": LAM}, t0=0.0, t1=1.0, dt=1e-4,
                               controller=jaxanm.StepController(rtol=0.0, atol=tol), solver=jaxanm.Newton(tol=1e-12))
        out[tol] = (abs(sol.xs[-1, 0] - math.exp(-LAM)), sol.stats.time_steps)
    (e5, n5), (e7, n7) = out[1e-5], out[1e-7]
    assert e7 < e5 / 3 and n7 > 3 * n5


def test_save_times_are_hit_exactly_and_a_too_large_step_is_refused():
    sol = jaxanm.integrate(decay, np.ones(1), {"lam": LAM}, t0=0.0, t1=1.0, dt=0.01,
                           saveat=jaxanm.SaveAt(ts=[0.3, 0.7]), controller=jaxanm.StepController(rtol=0.0, atol=1e-6),
                           solver=jaxanm.Newton(tol=1e-12))
    assert list(sol.ts) == [0.0, 0.3, 0.7, 1.0]
    # first step unchecked at 0.01 (LE ~ 4.5e-4 > atol): the second, proposed equal, is refused
    assert sol.stats.rejected_steps >= 1


def test_resume_with_a_controller_is_bit_identical(tmp_path):
    kw = dict(t0=0.0, t1=1.0, dt=1e-3, solver=jaxanm.ANM(order=5, tol=1e-8), saveat=jaxanm.SaveAt(steps=1),
              controller=jaxanm.StepController(rtol=1e-4, atol=1e-6))
    full = jaxanm.integrate(decay, np.ones(1), {"lam": LAM}, **kw)
    path = tmp_path / "run.ckpt"

    def stop_at_5(t, x, stats):
        if stats.time_steps == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        jaxanm.integrate(decay, np.ones(1), {"lam": LAM}, checkpoint=path, callback=stop_at_5, **kw)
    resumed = jaxanm.integrate(decay, np.ones(1), {"lam": LAM}, checkpoint=path, resume=True, **kw)
    assert np.array_equal(resumed.ts, full.ts) and np.array_equal(resumed.xs, full.xs)
    assert resumed.stats.step_sizes == full.stats.step_sizes


def test_error_map_measures_other_quantities():
    """The error in y = 2 x is twice the error in x: with the same atol the controller takes
    smaller steps, about 1/sqrt(2) of them (LE ~ h^2)."""
    kw = dict(t0=0.0, t1=1.0, dt=1e-4, solver=jaxanm.Newton(tol=1e-12))
    plain = jaxanm.integrate(decay, np.ones(1), {"lam": LAM}, controller=jaxanm.StepController(rtol=0, atol=1e-6), **kw)
    doubled = jaxanm.integrate(decay, np.ones(1), {"lam": LAM}, **kw,
                               controller=jaxanm.StepController(rtol=0, atol=1e-6, error_map=lambda x, p: 2 * x))
    assert doubled.stats.time_steps > plain.stats.time_steps


@pytest.mark.parametrize("kw, match", [
    ({"rtol": -1.0}, r"StepController.rtol must be a number >= 0"),
    ({"rtol": 0.0, "atol": 0.0}, "rtol > 0 or atol > 0"),
    ({"dt_min": 1.0, "dt_max": 0.5}, "dt_min < dt_max"),
    ({"shrink": 1.5}, "shrink < 1 < grow"),
])
def test_bad_controller_settings_are_refused(kw, match):
    with pytest.raises(jaxanm.InputError, match=match):
        jaxanm.StepController(**kw)


def test_controller_must_be_a_step_controller():
    with pytest.raises(jaxanm.InputError, match="controller must be jaxanm.StepController"):
        jaxanm.integrate(decay, np.ones(1), {"lam": LAM}, t0=0.0, t1=1.0, dt=0.1, solver=jaxanm.Newton(),
                         controller={"rtol": 1e-3})


def test_fsw_scene_with_adaptive_steps():
    """time.adaptive on the Lagrangian fsw_small: steps end exactly on the scene's save times,
    stay within the point-motion bound and the scene's ``time.dt_max`` (2e-4 s: the controller's
    own steps reach 2.7e-4 s here, the motion bound 2.5e-3 s), and the probes are recorded at
    every accepted step."""
    from jaxanm.fsw.lagrangian import motion_dt_max
    from jaxanm.fsw.scene import load_scene
    from jaxanm.fsw.simulate import run

    scene = load_scene("fsw_small").with_overrides({"time.adaptive": "true", "time.atol": "1e-5", "time.t_end": "0.003",
                                                    "time.save": "0.001", "time.dt": "1e-4", "time.dt_max": "2e-4"})
    res = run(scene)
    hs = np.array(res.stats.step_sizes)
    assert list(res.t) == [0.0, 0.001, 0.003]
    assert len(hs) == res.stats.time_steps == len(res.probes["t"]) - 1
    # the sizes t_{k+1} - t_k telescope to t_end up to one rounding each (steps * eps * t_end ~ 1e-17)
    assert hs.max() <= motion_dt_max(scene) and abs(hs.sum() - 0.003) <= len(hs) * np.finfo(float).eps * 0.003
    # the bound is reached, not exceeded (the step before a save time is t_save - t, one rounding off)
    assert hs.max() == pytest.approx(2e-4, rel=1e-12)


def _jump(x, x_old, t, dt, p):
    """An algebraic unknown that jumps at t = 0.5: x = 0 before, 1 after (Heaviside)."""
    return x - (t > 0.5)


def test_an_error_that_does_not_shrink_with_the_step_fails_by_name_or_is_accepted_at_dt_min():
    """Across the jump x_{n+1} - x_pred = 1 whatever h, so no step passes the error test: with
    dt_min = 0 the run stops with a StepFailure that says so; with dt_min > 0 the step of
    dt_min is accepted and the run goes on."""
    kw = dict(t0=0.0, t1=1.0, dt=0.01, solver=jaxanm.Newton(tol=1e-12), saveat=jaxanm.SaveAt(steps=1))
    with pytest.raises(jaxanm.StepFailure, match="local error test still fails"):
        jaxanm.integrate(_jump, np.zeros(1), None, controller=jaxanm.StepController(rtol=0, atol=1e-6), **kw)
    sol = jaxanm.integrate(_jump, np.zeros(1), None, controller=jaxanm.StepController(rtol=0, atol=1e-6, dt_min=1e-3),
                           **kw)
    assert sol.ts[-1] == 1.0 and sol.xs[-1, 0] == 1.0


def test_time_error_estimate_bounds_the_global_error_of_a_decaying_problem():
    # u' = -k u, exact e^(-k t).  Implicit Euler's local errors here all have one sign, and
    # each decays by e^(-k (t1 - t_n)) on the way to t1: their plain sum (the estimate) is at
    # least the true error at t1 and at most e^(k (t1 - t0)) times it (the decay it leaves out)
    def residual(u, u_old, t, dt, p):
        return (u - u_old) / dt + p["k"] * u

    k = np.array([0.5, 1.0, 2.0])
    sol = jaxanm.integrate(residual, np.ones(3), {"k": k}, t0=0.0, t1=2.0, dt=1e-3,
                           solver=jaxanm.ModifiedNewton(tol=1e-12),
                           controller=jaxanm.StepController(rtol=0.0, atol=1e-4))
    ratio = sol.time_error / (sol.xs[-1] - np.exp(-2.0 * k))
    assert np.all(ratio >= 1.0) and np.all(ratio <= np.exp(2.0 * k)), ratio
    fixed = jaxanm.integrate(residual, np.ones(3), {"k": k}, t0=0.0, t1=0.1, dt=1e-2,
                             solver=jaxanm.ModifiedNewton())
    assert fixed.time_error is None  # no controller, no estimate
