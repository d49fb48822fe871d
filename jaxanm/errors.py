"""Named exceptions: every failure says where (step, time), why and with which numbers."""

from __future__ import annotations


class InputError(ValueError):
    """Invalid input detected before any computation; the message names the field and the fix."""


class StepFailure(RuntimeError):
    """A time step could not be completed by the nonlinear solver.

    Attributes ``step``, ``t``, ``amax`` and ``residual_norm`` locate and quantify the failure
    (``amax`` is ``None`` for Newton solvers).
    """

    def __init__(self, reason: str, *, step: int, t: float, amax=None, residual_norm=None):
        self.reason = reason
        self.step = step
        self.t = t
        self.amax = amax
        self.residual_norm = residual_norm
        parts = [f"step {step} (t = {t:.6g})", reason]
        if amax is not None:
            parts.append(f"a_max = {amax:.3g}")
        if residual_norm is not None:
            parts.append(f"|R|_inf = {residual_norm:.3g}")
        super().__init__(": ".join(parts[:2]) + ("; " + ", ".join(parts[2:]) if parts[2:] else ""))


class NonFiniteError(StepFailure):
    """A NaN or infinity appeared in a residual, a Jacobian or a series coefficient."""


class SingularMatrixError(RuntimeError):
    """The tangent matrix K* could not be factorised (exactly singular or non-finite)."""
