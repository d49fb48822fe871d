"""Fixed step sizes as a controller (as diffrax's ``ConstantStepSize``): the default of
:func:`jaxanm.integrate`."""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

from ._saveat import fixed_steps, step_end
from ._step_size import Segment, Span, StepPlan, StepSizeController, Verdict


class _Fixed(NamedTuple):
    """The state of :class:`ConstantStepSize`: the run's step count and the saved step
    numbers (both fixed by the span; nothing changes from step to step)."""

    n_steps: int
    saves: frozenset


@dataclasses.dataclass(frozen=True)
class ConstantStepSize(StepSizeController):
    """Steps of ``dt`` from ``t0``, the last one shortened to end exactly on ``t1``
    (``controller=None`` in :func:`jaxanm.integrate` is this).

    Every solved step is accepted.  A step whose solve fails is redone as two half steps,
    each of them halved again if it fails, to a depth of ``max_dt_halvings``; the halves are
    one step (recorded, saved and handed to the hooks once, at its end).  ``SaveAt(ts=...)``
    saves the steps ending nearest to the times asked.
    """

    def init(self, span: Span) -> _Fixed:
        """The step count and the saved steps of the span."""
        return _Fixed(fixed_steps(span.t0, span.t1, span.dt), frozenset(span.saveat.fixed(span.t0, span.t1, span.dt)))

    def done(self, state: _Fixed, k: int, t: float, span: Span) -> bool:
        """After the last of the fixed steps."""
        return k >= state.n_steps

    def attempt(self, state: _Fixed, k: int, t: float, x, params, span: Span) -> StepPlan:
        """Step ``k`` ends at ``t0 + k dt`` (the last at ``t1``), solved from ``t`` in one segment."""
        end = step_end(span.t0, span.t1, span.dt, k, state.n_steps)
        return StepPlan(end, (Segment(t, end - t),))

    def retry(self, state: _Fixed, attempt: StepPlan, failure: Exception, span: Span) -> StepPlan:
        """The failed segment replaced by its two halves (the failure raised past the depth)."""
        failed = attempt.segments[0]
        if failed.depth >= span.max_failures:
            raise failure
        half, depth = failed.h / 2, failed.depth + 1
        halves = (Segment(failed.t, half, depth), Segment(failed.t + half, half, depth))
        return attempt._replace(segments=halves + attempt.segments[1:], failures=attempt.failures + 1)

    def judge(self, state: _Fixed, attempt: StepPlan, k: int, x, x_new, params, scale, span: Span,
              embedded=None) -> Verdict:
        """Every solved step is accepted."""
        return Verdict(state)

    def saved(self, state: _Fixed, k: int, t: float, span: Span) -> bool:
        """Step ``k`` is among the saved step numbers (:meth:`jaxanm.SaveAt.fixed`)."""
        return k in state.saves

    def expected_steps(self, span: Span) -> int:
        """The fixed step count."""
        return fixed_steps(span.t0, span.t1, span.dt)
