"""Named exceptions: every failure says where (step, time), why and with which numbers."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ._solver.base import SolverState


class InputError(ValueError):
    """Invalid input detected before any computation; the message names the field and the fix."""


def _number(value) -> str:
    """``value`` for a message: 3 significant digits, ``n/a`` when unknown (``None``)."""
    if value is None:
        return "n/a"
    value = float(value)
    return f"{value:.3g}" if math.isfinite(value) else str(value)


class StepFailure(RuntimeError):
    """A time step could not be completed by the nonlinear solver.

    Attributes ``step``, ``t``, ``amax`` and ``residual_norm`` locate and quantify the failure.
    The message always names all four::

        step 3 (t = 0.0003): series diverged; a_max = 0.001, |R|_inf = 2.5

    ``amax`` is ``None`` (printed ``n/a``) for Newton solvers, and ``residual_norm`` is ``None``
    when no residual was evaluated at the failing state; a non-finite norm is printed as
    ``nan`` or ``inf``.
    """

    # set by a step solver on a failure inside its step: the state to retry from (absent
    # otherwise, hence read with getattr)
    solver_state: SolverState

    def __init__(self, reason: str, *, step: int, t: float, amax=None, residual_norm=None):
        self.reason = reason
        self.step = step
        self.t = float(t)
        self.amax = None if amax is None else float(amax)
        self.residual_norm = None if residual_norm is None else float(residual_norm)
        super().__init__(f"step {step} (t = {self.t:.6g}): {reason}; "
                         f"a_max = {_number(self.amax)}, |R|_inf = {_number(self.residual_norm)}")


class NonFiniteError(StepFailure):
    """A NaN or infinity appeared in a residual, a Jacobian, a series coefficient or a state."""


class SingularMatrixError(RuntimeError):
    """The tangent matrix K* could not be factorised (exactly singular or non-finite).

    Raised by :class:`jaxanm.Factorization`; inside a time step the solvers turn it into a
    :class:`StepFailure` (singular) or :class:`NonFiniteError` (non-finite entries) that
    carries step, time, a_max and residual norm.
    """
