"""The accuracy a run reports in summary.json and on the command line: the rise error at every
saved time (against the axisymmetric oracle) and the registration points' oscillation about a
smooth trend, each on results whose error is known by construction."""

import types

import numpy as np
import pytest

from jaxanm.fsw import axisymmetric as ax
from jaxanm.fsw import continuum_error
from jaxanm.fsw.geometry import build_cloud
from jaxanm.fsw.io import output
from jaxanm.fsw.scene import load_scene


def test_rise_errors_at_every_saved_time():
    # the converged oracle's own temperatures at fsw_tracers' points, made 0 %, 10 % and 20 % too
    # high at 0.02, 0.04 and 0.05 s: the rel. L2 errors are those factors to the coarse
    # reference's own error (< 3e-3 K of a rise of ~20 K: 1e-3 relative); t = 0.001 s is before
    # the reference's tenth step and is not reported
    scene = load_scene("fsw_tracers").with_overrides({"time.t_end": "0.05"})
    points = build_cloud(scene.geometry).points
    times = [0.001, 0.02, 0.04, 0.05]
    true = ax.solve(scene, times)
    T0 = scene.thermal.T0
    factors = [1.0, 1.0, 1.1, 1.2]
    T = [T0 + f * (true.temperature(np.hypot(*points.T), i) - T0) for i, f in enumerate(factors)]
    res = types.SimpleNamespace(scene=scene, t=np.array(times), points=np.stack([points] * 4), T=np.stack(T))
    errors = continuum_error.rise_errors(res)
    assert [e["t"] for e in errors] == times[1:]
    for e, f in zip(errors, factors[1:]):
        assert abs(e["rel_l2"] - (f - 1)) < 1e-3, e
        assert abs(e["mean_ratio"] - f) < 1e-3, e
    last = continuum_error.rise_error(res)
    assert last == pytest.approx(errors[-1], rel=1e-12)  # the same reference solve at the last time
    block = output.spatial_accuracy(res)
    assert block["rise_errors"] == errors and block["rise_error"] == errors[-1]


def _probe_result(amplitude: float, frequency: float = 80.0, t_end: float = 0.7, dt: float = 1e-3):
    """Registration-point histories: a speed on a slow quadratic trend with a sine of relative
    ``amplitude``, and a rise T - T0 growing like sqrt(t) with the same relative sine."""
    scene = load_scene("fsw_tracers")
    t = np.arange(0.0, t_end + dt / 2, dt)
    wave = amplitude * np.sin(2 * np.pi * frequency * t)
    speed = 0.02 * (1 - 0.1 * t ** 2)
    rise = 80.0 * np.sqrt(t)
    probe = {"u": speed * (1 + wave), "v": np.zeros_like(t), "T": scene.thermal.T0 + rise * (1 + wave)}
    return types.SimpleNamespace(scene=scene, probes={"t": t, "1": probe})


def test_probe_oscillation_recovers_a_known_amplitude():
    # a 5 % sine at 80 Hz (the Lagrangian cloud's passing frequency): the amplitude about a
    # quadratic trend is the sine's to its windowing bias, 1 / (4 pi f (t1 - t0)) = 1 % relative
    # at most over the 0.1 s window (history.oscillation); the smooth T rise on its own leaves
    # what a quadratic cannot follow of sqrt(t) over 0.05-0.15 s (below 1 % of the rise)
    block = output.probe_oscillation(_probe_result(0.05))
    assert block["windows"] == [[0.05, 0.15], [0.3, 0.7]]
    for rel in block["speed"]["1"] + block["T"]["1"]:
        assert abs(rel - 0.05) < 0.05 * 0.02, rel
    smooth = output.probe_oscillation(_probe_result(0.0))
    assert max(smooth["max_speed"]) < 1e-12
    assert max(smooth["max_T"]) < 1e-2
    lines = output.probe_oscillation_lines(block)
    assert len(lines) == 2 and "0.05-0.15 s" in lines[0] and "5 % of the mean speed" in lines[0], lines


def test_probe_oscillation_needs_a_covered_window():
    # a run to 0.1 s covers neither window whole; one stepping 0.05 s has too few samples in them
    assert output.probe_oscillation(_probe_result(0.05, t_end=0.1)) is None
    assert output.probe_oscillation(_probe_result(0.05, dt=0.05)) is None
    assert output.probe_oscillation_lines(None) == []


def test_time_error_block_beside_the_spatial_error():
    # an estimate of 1 % of the rise at every point: rel. L2 0.01, the largest 1 % of the top
    scene = load_scene("fsw_tracers")
    rise = np.linspace(0.0, 80.0, 50)
    res = types.SimpleNamespace(scene=scene, t=np.array([0.0, 0.7]), T=np.stack([np.zeros(50), rise]) + 300.0,
                                time_error=0.01 * rise)
    block = output.time_error(res)
    assert block["t"] == 0.7 and block["rel_l2"] == pytest.approx(0.01) and block["max_abs_K"] == pytest.approx(0.8)
    line = output.time_error_lines(block, {"rise_error": {"t": 0.7, "rel_l2": 0.016}})
    assert line == ["time error at t = 0.7 s, upper estimate (the controller's local errors summed, their decay "
                    "left out): 1 % of the rise, max 0.8 K, against a spatial error of 1.6 %"]
    res.time_error = None  # fixed steps
    assert output.time_error(res) is None and output.time_error_lines(None) == []
