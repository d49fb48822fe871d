"""Oscillations of a probe's time series about its smooth trend.

The registration-point histories of the paper's Figs 2 and 3 are meant to be smooth: the
flow near the tool is quasi-steady and the temperature rises slowly.  On a Lagrangian cloud
the tool-edge points slide past the first plate ring and the histories pick up an
oscillation at the passing frequency (and jumps at each rezoning).  :func:`oscillation`
measures it: a low-order polynomial in time is fitted by least squares over a window, and the
residual's root mean square times sqrt 2 (the amplitude of a sine of the same power) is the
amplitude, given absolutely and relative to the mean of the values over the window; the
residual's half peak-to-peak and its spectrum's dominant frequency come with it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InputError
from ..internal import integer

__all__ = ["Oscillation", "oscillation"]


@dataclasses.dataclass(frozen=True)
class Oscillation:
    """What :func:`oscillation` measured.

    Attributes
    ----------
    amplitude : ``sqrt 2`` times the root mean square of the residual about the trend (units of
        the values): the amplitude of a sine with the residual's power.
    relative : ``amplitude / |mean|`` (the mean of the values over the window).
    half_range : half the peak-to-peak of the residual (at least ``amplitude / sqrt 2``; the
        amplitude for a sine away from the window's ends, more for jumps and spikes).
    mean : mean of the values over the window.
    frequency : the residual's dominant frequency (Hz; nan for non-uniform samples or
        fewer than 8 of them).
    samples : number of samples in the window.
    """

    amplitude: float
    relative: float
    half_range: float
    mean: float
    frequency: float
    samples: int


def oscillation(times, values, window=(0.05, 0.3), degree: int = 3) -> Oscillation:
    """Oscillation of ``values(times)`` about a polynomial trend of ``degree`` over ``window``.

    Parameters
    ----------
    times, values : (S,) arrays
        A history, e.g. one probe's speed ``hypot(u, v)`` against ``t`` from ``probes.csv``.
    window : (t0, t1)
        The span measured (s), both ends included; start it after the start-up transient,
        which a low-order trend does not follow.
    degree : int
        Degree of the least-squares trend (times mapped to [-1, 1], Legendre basis).  It must
        follow the slow drift (heating, softening) and stay far below the number of
        oscillation periods in the window, so that the trend cannot follow the oscillation.

    Returns
    -------
    Oscillation
        The amplitude is ``sqrt(2 mean(residual^2))``: for a sine of amplitude ``a`` on a trend
        the polynomial represents, ``a`` up to the window's partial period (relative
        ``1 / (4 pi f (t1 - t0))`` at most) and the power of the sine's least-squares
        projection onto the polynomials (second order in ``1 / (2 pi f (t1 - t0))``; that
        projection sits at the window's ends, where it distorts ``half_range``).  The frequency
        is the peak of the residual's Hann-windowed spectrum, refined by a parabola through
        the peak and its neighbours (log magnitudes), on uniformly spaced samples only.
    """
    t = np.asarray(times, dtype=np.float64)
    y = np.asarray(values, dtype=np.float64)
    if t.shape != y.shape or t.ndim != 1:
        raise InputError(f"times and values must be 1-D arrays of one length, got {t.shape} and {y.shape}: "
                         "pass one history, e.g. probes.csv's t and one probe's speed")
    integer("degree", degree, 0, hint="the degree of the least-squares trend")
    t0, t1 = window
    inside = (t >= t0) & (t <= t1)
    if inside.sum() <= degree + 1:
        raise InputError(f"{int(inside.sum())} samples in the window {window}: need more than degree + 1 = "
                         f"{degree + 1}; widen the window or lower the degree")
    t, y = t[inside], y[inside]
    x = 2.0 * (t - t[0]) / (t[-1] - t[0]) - 1.0
    trend = np.polynomial.legendre.Legendre.fit(x, y, degree, domain=[-1, 1])(x)
    residual = y - trend
    amplitude = float(np.sqrt(2.0 * np.mean(residual ** 2)))
    mean = float(y.mean())
    return Oscillation(amplitude=amplitude, relative=amplitude / abs(mean) if mean != 0 else float("inf"),
                       half_range=0.5 * float(residual.max() - residual.min()), mean=mean,
                       frequency=_dominant_frequency(t, residual), samples=int(t.size))


def _dominant_frequency(t: np.ndarray, residual: np.ndarray) -> float:
    """Peak frequency (Hz) of the Hann-windowed spectrum of ``residual`` (parabolic refinement
    in log magnitude); nan when the samples are not uniform to 1e-6 of their step or too few."""
    step = np.diff(t)
    if t.size < 8 or np.ptp(step) > 1e-6 * step.mean():
        return float("nan")
    spectrum = np.abs(np.fft.rfft(residual * np.hanning(t.size)))
    k = int(np.argmax(spectrum[1:])) + 1  # skip the mean
    shift = 0.0
    if 1 <= k < spectrum.size - 1 and np.all(spectrum[k - 1:k + 2] > 0):
        a, b, c = np.log(spectrum[k - 1:k + 2])
        shift = float(np.clip(0.5 * (a - c) / (a - 2 * b + c), -0.5, 0.5)) if a - 2 * b + c != 0 else 0.0
    return float((k + shift) / (t.size * step.mean()))
