"""Named exceptions: every failure says where (step, time), why and with which numbers."""

from __future__ import annotations

import difflib
import math
from collections.abc import Iterable


class InputError(ValueError):
    """Invalid input detected before any computation; the message names the field and the fix."""


def did_you_mean(word: str, choices: Iterable[str], cutoff: float = 0.6, prefix: str = "") -> str:
    """The closest of ``choices`` to a misspelt ``word``, for an error message.

    Returns ``"did you mean 'material.n'?"`` (the choices equally close to ``word``, by
    :class:`difflib.SequenceMatcher`'s similarity ratio, each after ``prefix``), or ``""`` when
    none reaches ``cutoff``.  One suggestion instead of the list of every choice: the message
    stays one line.
    """
    scored = [(difflib.SequenceMatcher(None, word, c).ratio(), c) for c in choices]
    best = max((ratio for ratio, _ in scored), default=0.0)
    if best < cutoff:
        return ""
    closest = [prefix + c for ratio, c in scored if ratio == best]
    return f"did you mean {' or '.join(repr(c) for c in closest)}?"


def format_number(value) -> str:
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
    ``nan`` or ``inf``.  What to change when a step fails (more ANM sub-steps, a smaller step,
    another solver, a better start): docs/guide/troubleshooting.md; the ``jaxanm`` command ends
    its error line with the options that apply to the failed scene.
    """

    # set by a step solver on a failure inside its step: the state to retry from (absent
    # otherwise, hence read with getattr).  Its type, jaxanm._solver.base.SolverState, is the
    # step solvers' own: errors.py imports no module of the package, so every module may import it
    solver_state: object

    def __init__(self, reason: str, *, step: int, t: float, amax=None, residual_norm=None):
        self.reason = reason
        self.step = step
        self.t = float(t)
        self.amax = None if amax is None else float(amax)
        self.residual_norm = None if residual_norm is None else float(residual_norm)
        super().__init__(f"step {step} (t = {self.t:.6g}): {reason}; "
                         f"a_max = {format_number(self.amax)}, |R|_inf = {format_number(self.residual_norm)}")


class NonFiniteError(StepFailure):
    """A NaN or infinity appeared in a residual, a Jacobian, a series coefficient or a state."""


class SingularMatrixError(RuntimeError):
    """The tangent matrix K* could not be factorised (exactly singular or non-finite).

    Raised by :class:`jaxanm.Factorization`; inside a time step the solvers turn it into a
    :class:`StepFailure` (singular) or :class:`NonFiniteError` (non-finite entries) that
    carries step, time, a_max and residual norm.
    """
