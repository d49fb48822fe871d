"""What a step-size controller tells the time loop (as diffrax's ``AbstractStepSizeController``):
where each step ends, how a failed solve is retried, whether a solved step is accepted, and
which steps are saved.  :class:`~jaxanm.ConstantStepSize` (fixed steps, the default) and
:class:`~jaxanm.StepController` (adaptive) are the two; the loop (:mod:`jaxanm._loop`) knows
only this interface.

A controller is a frozen set of options.  What it carries from step to step is its *state*, a
value it makes in :meth:`StepSizeController.init` and returns anew when it accepts a step;
the loop keeps it in its record and the checkpoint stores what :meth:`to_checkpoint` says.
"""

from __future__ import annotations

import abc
import math
from typing import Any, NamedTuple

import numpy as np

from ._saveat import SaveAt
from ._scheme import TimeScheme


class Span(NamedTuple):
    """The run as a controller sees it: the time span, the first (or fixed) step size, what is
    saved, how many retries a failed solve gets (``integrate``'s ``max_dt_halvings``) and the
    time scheme (whose error estimate and order an adaptive controller reads)."""

    t0: float
    t1: float
    dt: float
    saveat: SaveAt
    max_failures: int
    scheme: TimeScheme


class Segment(NamedTuple):
    """One solve of the step solver: from time ``t`` (the state the previous segment reached)
    over ``h``; the solver is handed the end time ``t + h``.  ``depth``: the retries that made
    it (fixed steps halve a failed segment into two of ``depth + 1``)."""

    t: float
    h: float
    depth: int = 0


class StepPlan(NamedTuple):
    """A step as planned: it ends at ``end`` (the time the accepted step is recorded at) and is
    solved as ``segments``, in order, each from the state the previous one reached (one
    segment unless a failure split it).  ``failures``: the solver failures retried in this
    step so far; ``memo``: what the controller keeps for its own decisions in this step."""

    end: float
    segments: tuple
    failures: int = 0
    memo: Any = None  # the controller's own: each controller reads back what it stored


class Verdict(NamedTuple):
    """A controller's decision on a solved step: ``retry`` None accepts it, with ``state`` the
    controller's next state and ``size`` the step size to log in ``stats.step_sizes`` (None:
    not logged); else the step is refused and ``retry`` is the attempt to solve instead, from
    the step's start."""

    state: object
    retry: StepPlan | None = None
    size: float | None = None


class StepSizeController(abc.ABC):
    """Base class of the step-size controllers :func:`jaxanm.integrate` accepts (module
    docstring).  ``refactor_ratio``: a factorised K* the solver carries from a step size more
    than this ratio away from the next segment's is dropped before it (``inf``: never)."""

    refactor_ratio: float = math.inf

    @abc.abstractmethod
    def init(self, span: Span):
        """The controller's state before the first step."""

    @abc.abstractmethod
    def done(self, state, k: int, t: float, span: Span) -> bool:
        """Whether the run is over after ``k`` accepted steps reaching time ``t``."""

    @abc.abstractmethod
    def attempt(self, state, k: int, t: float, x: np.ndarray, params, span: Span) -> StepPlan:
        """The first attempt at step ``k`` from time ``t``, state ``x`` on ``params``."""

    @abc.abstractmethod
    def retry(self, state, attempt: StepPlan, failure: Exception, span: Span) -> StepPlan:
        """The attempt to go on with after the solver failed ``attempt.segments[0]`` (the
        segments after it not solved yet); raises ``failure`` when the retries are spent."""

    @abc.abstractmethod
    def judge(self, state, attempt: StepPlan, k: int, x: np.ndarray, x_new: np.ndarray, params, scale,
              span: Span, embedded: np.ndarray | None = None) -> Verdict:
        """Accept or refuse step ``k``, solved from ``x`` to ``x_new`` as ``attempt`` planned
        (``embedded``: the scheme's embedded solution at its end, if it has one)."""

    @abc.abstractmethod
    def saved(self, state, k: int, t: float, span: Span) -> bool:
        """Whether the accepted step ``k``, ending at ``t``, is saved (:class:`~jaxanm.SaveAt`)."""

    def forget(self, state):
        """The state after a ``Remap(history=False)``: what the controller measured before the
        remap no longer compares with what follows.  Default: unchanged."""
        return state

    def expected_steps(self, span: Span) -> int | None:
        """The number of steps, when known before the run (for the progress bar)."""
        return None

    def time_error(self, state):
        """:attr:`jaxanm.Solution.time_error` of a run that ends in ``state`` (default None)."""
        return None

    def describe(self) -> dict | None:
        """The settings a checkpoint's fingerprint compares (None: fixed steps)."""
        return None

    def to_checkpoint(self, state):
        """What a checkpoint stores of ``state`` (default: nothing)."""
        return None

    def from_checkpoint(self, state, stored):
        """``state`` (from :meth:`init`) with what :meth:`to_checkpoint` stored."""
        return state
