"""The variable-step BDF2 scheme and its error estimate from the predictor.

**Step.**  With ``omega = h / h_prev``, the derivative of the quadratic through
``(t_{n-1}, x_{n-1})``, ``(t_n, x_n)``, ``(t_{n+1}, x_{n+1})`` at ``t_{n+1}`` is

    x'_{n+1} = (a0 x_{n+1} - (1 + omega) x_n + omega^2 / (1 + omega) x_{n-1}) / h,
    a0 = (1 + 2 omega) / (1 + omega),

so the step is one implicit-Euler-shaped stage ``F(x, (x - z) / (h / a0), t_{n+1}) = 0`` with
``z = ((1 + omega) x_n - omega^2 / (1 + omega) x_{n-1}) / a0``.  While the controller holds the
step size, ``omega = 1`` and ``h / a0 = 2 h / 3`` stays the same: one K* serves every step.  The
first step (and the first after a :class:`~jaxanm.Remap`) has no ``x_{n-1}``: it is an
implicit-Euler step, as BDF codes start at order one.

**Local error.**  For the exact solution, the quadratic's derivative at ``t_{n+1}`` is off by
``y''' h (h + h_1) / 6`` (``h_1`` the previous size), so the local error is
``y''' h^2 (h + h_1)^2 / (6 (2 h + h_1))`` (``2 h^3 y''' / 9`` at a constant step).  The
quadratic through the three accepted states before the step, extrapolated to ``t_{n+1}``,
misses ``x_{n+1}`` by ``y''' h (h + h_1) (h + h_1 + h_2) / 6``; so, as BDF codes estimate it
from their predictor,

    local error = h (h + h_1) / ((2 h + h_1) (h + h_1 + h_2)) (x_{n+1} - x_pred),

``2/9 (x_{n+1} - x_pred)`` at a constant step.  It needs two earlier accepted steps: the first
two steps of a run have no estimate.
"""

from __future__ import annotations

import dataclasses

from .base import Interpolant, SchemeStep, TimeScheme, register


def bdf2_stage(x, x_prev, h: float, h_prev: float):
    """``(z, h / a0)`` of the BDF2 step of size ``h`` from ``x`` after a step of ``h_prev`` from
    ``x_prev`` (module docstring)."""
    omega = h / h_prev
    a0 = (1 + 2 * omega) / (1 + omega)
    z = ((1 + omega) * x - (omega * omega / (1 + omega)) * x_prev) / a0
    return z, h / a0


def predictor_error(y_new, y_now, past, h: float):
    """The local error of a BDF2 step of size ``h`` from ``y_now`` to ``y_new``, from the
    quadratic through ``y_now`` and the two earlier states ``past = ((y_1, h_1), (y_2, h_2))``
    (module docstring)."""
    (y1, h1), (y2, h2) = past
    # Lagrange weights of the nodes 0, -h1, -(h1 + h2) (time from t_n) at h
    w0 = (h + h1) * (h + h1 + h2) / (h1 * (h1 + h2))
    w1 = -h * (h + h1 + h2) / (h1 * h2)
    w2 = h * (h + h1) / ((h1 + h2) * h2)
    y_pred = w0 * y_now + w1 * y1 + w2 * y2
    return h * (h + h1) / ((2 * h + h1) * (h + h1 + h2)) * (y_new - y_pred)


@dataclasses.dataclass(frozen=True)
class BDF2(TimeScheme):
    """Variable-step BDF2 (name ``"bdf2"``): second order, one implicit stage per step, L-stable
    at a constant step and zero-stable while each step is below 1 + sqrt 2 times the one
    before (so a step controller grows it at most twofold: ``max_growth``); the error estimate
    comes from the predictor (module docstring).  Its history is the previous state and step
    size.  Needs a :class:`~jaxanm.SemiDiscrete` residual."""

    name = "bdf2"
    order = 2
    error_order = 2
    estimate_history = 2
    max_growth = 2.0

    def step(self, history, x, t, h, solve) -> SchemeStep:
        """One BDF2 step (an implicit-Euler step without a previous state)."""
        if history is None:
            return SchemeStep(solve(x, t + h, h, last=True), (x, h))
        x_prev, h_prev = history
        z, gamma_h = bdf2_stage(x, x_prev, h, h_prev)
        start = x + (h / h_prev) * (x - x_prev)  # the line through the last two states: O(h^2) off
        return SchemeStep(solve(z, t + h, gamma_h, last=True, start=start), (x, h))

    def interpolant(self, history, x, step, h) -> Interpolant:
        """The quadratic through the previous state, ``x`` and the step's end (BDF2's own
        interpolating polynomial; second order); the line after a first step."""
        if history is None:
            return super().interpolant(history, x, step, h)
        x_prev, h_prev = history
        x_new = step.x

        def at(theta):
            s = theta * h  # time from the step's start; Lagrange weights of the nodes -h_prev, 0, h
            return (s * (s - h) / (h_prev * (h_prev + h)) * x_prev - (s + h_prev) * (s - h) / (h_prev * h) * x
                    + (s + h_prev) * s / ((h + h_prev) * h) * x_new)

        return Interpolant(at, order=2)

    def local_error(self, y_new, y_embedded, y_now, past, h):
        """The predictor's estimate (None without two earlier steps)."""
        if len(past) < 2:
            return None
        return predictor_error(y_new, y_now, past, h)


register("bdf2", BDF2)
