"""Calibrating the contact state delta (and K) by gradient: the sensitivities with respect to
delta against central differences of the forward map, and the fit of examples/calibrate_weld.py
recovering the true values within two standard deviations."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import jax.numpy as jnp
import pytest

import jaxanm
from jaxanm.fsw import calibration

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
import calibrate_weld  # noqa: E402


def _loss(obs, theta):
    p = obs["probes"]
    return sum(jnp.sum((p[k]["T"] - 300.0) ** 2) for k in p)


@pytest.mark.slow  # 76 s (five runs); test_calibration's default Newton FD check exercises the same
# sensitivity pass on this scene's rows, and test_fsw_slip checks the slip rows themselves
def test_contact_state_gradient_matches_central_differences():
    """Two 4 ms steps of the example's experiment: d loss / d delta and d loss / d log K."""
    scene = calibrate_weld.weld_experiment().with_overrides({"time.t_end": 8e-3})
    theta = {"logK": math.log(scene.material.K), "delta": 0.7}
    value, grad = calibration.scene_value_and_grad(_loss, scene, theta)
    for key, h in {"delta": 1e-5, "logK": 1e-5}.items():
        values = []
        for sign in (1, -1):
            th = dict(theta, **{key: theta[key] + sign * h})
            obs = calibration.simulate(scene, th, tangents=False).observed
            with jaxanm.float64():
                values.append(float(_loss(obs, th)))
        fd = (values[0] - values[1]) / (2 * h)
        # 1e-5: five digits of the gradient; central differences err by h^2 f''' / 6 (~1e-10 relative at
        # this h) plus round-off eps |loss| / h (~1e-10 of it): far below
        assert abs(grad[key] - fd) <= 1e-5 * abs(fd), (key, grad[key], fd)


def test_contact_state_outside_its_range_is_refused():
    scene = calibrate_weld.weld_experiment()
    with pytest.raises(jaxanm.InputError, match=r"theta\['delta'\].*\[0, 1\]"):
        calibration.simulate(scene, {"delta": 1.5})


@pytest.mark.slow
def test_fit_recovers_contact_state_and_K_within_two_sigma():
    """The example (0.5 K noise on three thermocouples, 10 steps): delta = 0.696 +- 0.0085 and
    log K 0.76 sigma off, measured; the truth must lie within two Gauss-Newton sigmas."""
    out = calibrate_weld.main()
    for name, (fitted, true, sd) in out.items():
        assert abs(fitted - true) <= 2 * sd, (name, fitted, true, sd)
    assert out["delta"][2] < 0.05  # the thermocouples do determine delta
