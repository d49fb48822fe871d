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


class RunStopped(BaseException):
    """What an exception that ends a run early carries, as declared fields: ``stats`` (the run's
    statistics up to the stop, the work of the step it stopped in included: a
    :class:`jaxanm.Stats`) and ``partial`` (what the caller made of the steps done so far, e.g.
    the FSW run's ``FSWResult``), None until given.  The base of :class:`StepFailure` and
    :class:`RunInterrupted` (never raised itself).  A caller that adds them raises
    :meth:`carrying`'s new exception in place of the one it caught: no exception is changed
    after it was raised.
    """

    stats: object = None
    partial: object = None

    def carrying(self, **fields):
        """A new exception of the same class, message, fields and traceback, with ``fields``
        (names the class declares, e.g. ``stats``, ``partial``) given; raise it ``from`` the
        caught one's cause."""
        undeclared = sorted(name for name in fields if not hasattr(type(self), name))
        if undeclared:
            raise TypeError(f"{type(self).__name__} declares no field {undeclared[0]!r}")
        made = type(self).__new__(type(self))
        made.args = self.args
        made.__dict__.update({**self.__dict__, **fields})
        return made.with_traceback(self.__traceback__)


class RunInterrupted(RunStopped, KeyboardInterrupt):
    """A run interrupted (SIGINT, or SIGTERM as :class:`jaxanm.checkpoint.Interrupted`), carrying
    its ``stats`` and ``partial`` result (:class:`RunStopped`); a ``KeyboardInterrupt``."""


def run_stopped(exc: BaseException, **fields) -> RunStopped:
    """The exception a run stopped by ``exc`` (a step failure or an interrupt) raises in its
    place: the same one carrying ``fields`` (:meth:`RunStopped.carrying`); a plain
    ``KeyboardInterrupt`` becomes a :class:`RunInterrupted` (still a ``KeyboardInterrupt``)."""
    if not isinstance(exc, RunStopped):
        exc = RunInterrupted(*exc.args).with_traceback(exc.__traceback__)
    return exc.carrying(**fields)


class StepFailure(RunStopped, RuntimeError):
    """A time step could not be completed by the nonlinear solver.

    Attributes ``step``, ``t``, ``amax`` and ``residual_norm`` locate and quantify the failure.
    The message always names all four::

        step 3 (t = 0.0003): series diverged; a_max = 0.001, |R|_inf = 2.5

    ``amax`` is ``None`` (printed ``n/a``) for Newton solvers, and ``residual_norm`` is ``None``
    when no residual was evaluated at the failing state; a non-finite norm is printed as
    ``nan`` or ``inf``.  What to change when a step fails (more ANM sub-steps, a smaller step,
    another solver, a better start): docs/guide/troubleshooting.md; the ``jaxanm`` command ends
    its error line with the options that apply to the failed scene.  Raised out of a run, it
    carries the run's ``stats`` (and a model's ``partial`` result): :class:`RunStopped`.
    """

    # given by a step solver on a failure inside its step (:meth:`RunStopped.carrying`): the
    # state to retry from, else None.  Its type, jaxanm._solver.base.SolverState, is the step
    # solvers' own: errors.py imports no module of the package, so every module may import it
    solver_state: object = None

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
