"""Implicit Euler, the paper's scheme, and Milne's estimate of its local error.

One stage: ``x_{n+1}`` solves ``R(x_{n+1}, x_n, t_{n+1}, h) = 0``, i.e.
``F(x_{n+1}, (x_{n+1} - x_n) / h, t_{n+1}) = 0``.  It is the only scheme that serves a one-step
residual (the residual *is* its step).

**Estimate (Milne's device, no extra solve).**  For ``x' = f(x)`` the previous step says
``x_n - x_{n-1} = h_prev f(x_n)`` exactly, so the extrapolation

    x_pred = x_n + (h / h_prev) (x_n - x_{n-1}) = x_n + h f(x_n)

is the explicit Euler step from ``x_n``.  With y the exact solution through ``x_n``,
``y(t_n + h) - x_pred = h^2 y''/2 + O(h^3)`` and ``x_{n+1} - y(t_n + h) = h^2 y''/2 + O(h^3)``,
so the local error is ``(x_{n+1} - x_pred) / 2 + O(h^3)`` whatever ``h_prev`` (the BDF1
predictor-corrector estimate).  The same holds for a DAE with a mass matrix and algebraic
rows.  It needs one earlier accepted step: the first step of a run has no estimate.
"""

from __future__ import annotations

import dataclasses

from .base import SchemeStep, TimeScheme, register


def milne_error(y_new, y_now, y_before, h: float, h_prev: float):
    """Milne's estimate of the local error of the implicit-Euler step ``y_now -> y_new`` of
    size ``h``, the step before it ``y_before -> y_now`` of size ``h_prev`` (module docstring)."""
    return 0.5 * (y_new - (y_now + (h / h_prev) * (y_now - y_before)))


@dataclasses.dataclass(frozen=True)
class ImplicitEuler(TimeScheme):
    """Implicit Euler (name ``"euler"``, the default): first order, L-stable, one stage per
    step; the error estimate is Milne's (the module docstring).  It serves one-step residuals
    and :class:`~jaxanm.SemiDiscrete` ones alike."""

    name = "euler"
    order = 1
    one_step = True
    error_order = 1
    estimate_history = 1

    def step(self, history, x, t, h, solve) -> SchemeStep:
        """One implicit-Euler step: the stage ``R(x_new, x, t + h, h) = 0``; no history."""
        return SchemeStep(solve(x, t + h, h, last=True), None)

    def local_error(self, y_new, y_embedded, y_now, past, h):
        """Milne's estimate (None on a run's first step)."""
        if not past:
            return None
        y_before, h_prev = past[0]
        return milne_error(y_new, y_now, y_before, h, h_prev)


register("euler", ImplicitEuler)
