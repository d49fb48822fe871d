"""The oscillation of a history about its trend (:mod:`jaxanm.fsw.oscillation`), on synthetic
signals whose amplitude and frequency are known in closed form."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxanm.fsw.oscillation import oscillation

DT = 1e-4  # the FSW scenes' time step: probes.csv has one row per step
T = np.arange(0, 3001) * DT  # 0 ... 0.3 s
TREND = 0.02 * (1.0 - 0.3 * T / 0.3 + 0.2 * (T / 0.3) ** 2)  # a slowly softening flow (m/s)


@pytest.mark.parametrize("amplitude", [0.0, 4e-4, 5e-3])
def test_sine_on_a_quadratic_trend(amplitude):
    # 79 Hz (the sliding-stencil frequency of fsw_paper's Fig. 2) over 0.05-0.3 s: 19.75
    # periods.  The cubic trend represents the quadratic exactly, so the residual is the sine
    # minus its least-squares projection onto the cubics.  sqrt(2) times its RMS is the
    # amplitude up to the partial period, relative 1 / (4 pi f (t1 - t0)) = 4.0e-3 at most, and
    # the projection's power, second order in 1 / (2 pi f (t1 - t0)) = 8e-3 (measured:
    # -3.2e-3 ... +2.4e-3 over four phases).  Tolerance 1 % of the amplitude; the trend alone
    # must give an amplitude at round-off (1e-12 of the values).
    f = 79.0
    values = TREND + amplitude * np.sin(2 * math.pi * f * T + 0.3)
    osc = oscillation(T, values, window=(0.05, 0.3))
    assert osc.samples == 2501
    assert abs(osc.amplitude - amplitude) <= 0.01 * amplitude + 1e-12 * TREND.max(), osc
    # the projection onto the cubics sits at the window's ends, where the crests then stand
    # out: half the peak-to-peak is above the amplitude there (5-9 % measured), never below
    assert osc.half_range >= osc.amplitude / math.sqrt(2) - 1e-15
    # the sine averages out over the window to within amplitude / (2 pi f (t1 - t0)) = 8e-3 of it
    assert abs(osc.mean - TREND[500:].mean()) <= 0.01 * amplitude + 1e-15, osc
    assert osc.relative == pytest.approx(osc.amplitude / abs(osc.mean))
    if amplitude > 0:
        # spectral resolution 1 / 0.25 s = 4 Hz; the parabolic refinement lands within a
        # quarter of a bin for a pure tone (78.94 Hz measured)
        assert abs(osc.frequency - f) < 1.0, osc


def test_a_step_shows_as_an_oscillation():
    # a jump of height J (a rezoning) is no smooth trend: the residual about a cubic keeps a
    # large part of it (measured for a jump at 60 % of the window: amplitude 0.28 J, half
    # range 0.50 J); asserted above J / 5 and 2 J / 5
    osc = oscillation(T, TREND + 1e-3 * (T > 0.2))
    assert osc.amplitude > 0.2e-3 and osc.half_range > 0.4e-3, osc


def test_irregular_samples_give_no_frequency_and_short_windows_are_refused():
    t = np.sort(np.random.default_rng(0).uniform(0, 0.3, 500))
    osc = oscillation(t, 1.0 + 0.01 * np.sin(2 * math.pi * 79 * t))
    assert math.isnan(osc.frequency)
    # 428 random samples in the window: the RMS of a sine sampled at random times is its
    # amplitude / sqrt 2 within a few 1 / sqrt(428) (measured 0.9827 of it)
    assert osc.amplitude == pytest.approx(0.01, rel=0.05)
    with pytest.raises(ValueError, match="samples in the window"):
        oscillation(T, TREND, window=(0.0, 2 * DT))
    with pytest.raises(ValueError, match="1-D arrays"):
        oscillation(T, TREND[:-1])
    with pytest.raises(ValueError, match=r"degree must be an integer >= 0, got 2.5"):
        oscillation(T, TREND, degree=2.5)
