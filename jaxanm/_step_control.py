"""Adaptive step sizes: the time scheme's local error estimate and an elementary controller.

**Estimate.**  Each time scheme estimates the local error of its steps
(:meth:`jaxanm.TimeScheme.local_error`): implicit Euler by Milne's device (its extrapolation
from the previous step, no extra solve), BDF2 from the quadratic through the three states
before the step, an ESDIRK by its embedded solution.  The estimate is made in the
quantities the controller measures (``error_map``, below), from the states the scheme's
estimate reads: the step's start and end, the embedded solution, and for the multistep
schemes the measured states of the last accepted steps, which this controller keeps.  A step
without an estimate (a run's first step, BDF2's first two, the first after
``Remap(history=False)`` or after any ``Remap`` of a scheme with a history) is taken at the
proposed size.

**Norm.**  ``err = sqrt(mean((le / (atol * scale + rtol * |y|))^2))`` (the weighted RMS norm of
DASSL, IDA and diffrax), with the run's ``scale`` (the characteristic magnitude of each
unknown), so ``atol`` is relative to the scale, ``rtol`` to the value.  The step is accepted
when ``err <= 1``.  ``error_map(x, params)`` (identity by default) may measure the error in
other quantities, with their own ``error_scale``: for a meshless scene, the field values at
the points, which are continuous from step to step where the nodal parameters of a Lagrangian
cloud jump at each stencil rebuild; and only the differential ones, as IDA leaves algebraic
components out of its error test.  (A quasi-static velocity carried by moving points is off
the field at their new place by ``h |DV/Dt|`` after every move, whatever the next step's size:
Milne's device would read that as a local error that does not shrink with h,
:mod:`jaxanm.fsw.simulate`.)

**Controller.**  An estimate of order q (``O(h^(q+1))``, the scheme's ``error_order``) gives
``h_new = h * clip(safety * err^(-1/(q+1)), shrink, grow)``, the growth also capped by the
scheme's ``max_growth`` (BDF2's zero-stability); a rejected step is retried from ``x_n`` with
that h, an accepted one proposes it for the next step.  ``dt_min`` and ``dt_max`` bound every
proposal (``dt_max``: e.g. the largest step the point motion of a Lagrangian scene allows).

**Holding the step size.**  The solvers reuse a factorised K* across steps, and K* holds the
``1/(gamma h)`` of the stage's time derivative: a K* made at a stage size ``h_K`` solves one of
size h as a modified-Newton iteration (or an ANM series) whose contraction on the slow
components is ``|1 - h_K / h|``.  A new size at every step, as the proposals give, keeps K*
stale (the ANM, whose series from a stale K* tolerates less of that than modified Newton's
iteration, refactorises far more often than it), and a K* made at a much smaller h fools the
convergence tests that measure with it (modified Newton's ``|dx|`` and the ANM's end-point
check shrink with ``h_K / h``, so a step is accepted with its state left behind, and the
error estimate, seeing no change, grows the next step).  So, as BDF codes do, an accepted
step's size is kept while the proposal is between h and ``hold`` times h, and the run drops a
K* whose stage size is more than ``refactor_ratio`` away from the next stage's before that
stage (the solver then factorises at its start, instead of wasting a series or trusting a
wrong test).  Measured on stiff problems: ``docs/notes/adaptive_time_steps.md``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, NamedTuple

import numpy as np

from ._checks import real
from ._scheme import TimeScheme
from ._step_size import Segment, Span, StepPlan, StepSizeController, Verdict
from .errors import InputError, StepFailure

HOLD = 1.5
"""Default :attr:`StepController.hold` (module docstring, "Holding the step size")."""

REFACTOR_RATIO = 1.5
"""Default :attr:`StepController.refactor_ratio` (module docstring, "Holding the step size")."""


SPREAD = 4
"""Within this many steps of a save time (or t1) the steps before it share the distance equally
(the first of them at least 3/4 of the proposal)."""

MIN_STEP = 1e-12
"""A step refused by the error test below this fraction of the span is a failure (the error
estimate is then round-off or a discontinuity, not the time discretisation)."""


class _Adaptive(NamedTuple):
    """The state of :class:`StepController` between steps."""

    h_next: float | None  # the size proposed for the next step (None: the run's dt)
    past: tuple  # (measured state at the start of each accepted step, its size), newest first
    time_error: np.ndarray | None  # the sum of the local error estimates of the accepted steps
    save_times: tuple  # SaveAt.ts within (t0, t1), sorted: steps end exactly on them


@dataclasses.dataclass(frozen=True)
class StepController(StepSizeController):
    """Adaptive step sizes for :func:`jaxanm.integrate` (``controller=StepController(...)``).

    The estimate (the time scheme's), the norm, the controller and why it holds the step size
    are described in ``docs/notes/adaptive_time_steps.md`` (and this module's docstring).  A step whose solve
    fails is retried from its start at a quarter of its size, at most ``max_dt_halvings``
    times in a row; a step refused by the error test is retried at the size the controller
    proposes.  Steps end exactly on ``SaveAt.ts`` and on ``t1``, the distance to each shared
    equally by the steps before it.

    Parameters
    ----------
    rtol, atol : float
        Local error per step below ``atol * scale + rtol * |y|`` in the weighted RMS norm
        (module docstring).
    dt_min, dt_max : float
        Bounds of the step size.  A step of ``dt_min`` that fails its error test is accepted as
        it is; with ``dt_min = 0`` a step still refused below 1e-12 of the span raises
        :class:`jaxanm.StepFailure` (a discontinuity, or an estimate at round-off).
    safety, shrink, grow : float
        The controller's factor ``clip(safety * err^(-1/(q+1)), shrink, grow)``, q the order of
        the scheme's estimate (1 for implicit Euler).
    error_map : callable ``(x, params) -> array``, optional
        Quantities the error is measured in (default: the unknowns themselves).
    error_scale : float or array, optional
        Characteristic magnitude of each quantity of ``error_map`` (default: the run's
        ``scale``, for quantities shaped like x).
    hold : float
        After an accepted step of size h, a proposal between h and ``hold * h`` keeps h (as
        CVODE keeps h below 1.5 h and IDA below 2 h); a larger one is taken, and so is any
        smaller one.  1: every proposal is taken.  Default :data:`HOLD`.
    refactor_ratio : float
        Before a step of size h, a factorised K* the solver carries from a step of size h_K is
        dropped when ``max(h / h_K, h_K / h)`` exceeds this ratio (as IDA refactorises when its
        ``alpha / h`` moves by 25 %); the solver then factorises at the start of the step.
        ``inf``: K* is kept whatever its step size.  Default :data:`REFACTOR_RATIO`.
    """

    rtol: float = 1e-3
    atol: float = 1e-6
    dt_min: float = 0.0
    dt_max: float = math.inf
    safety: float = 0.9
    shrink: float = 0.2
    grow: float = 5.0
    error_map: Callable | None = None
    error_scale: object = None
    hold: float = HOLD
    refactor_ratio: float = REFACTOR_RATIO

    def __post_init__(self):
        for name in ("rtol", "atol"):
            real(f"StepController.{name}", getattr(self, name), 0.0)
        if self.rtol == 0 and self.atol == 0:
            raise InputError("StepController needs rtol > 0 or atol > 0 (both 0 accepts no step)")
        if not (0 <= self.dt_min < self.dt_max):
            raise InputError(f"StepController needs 0 <= dt_min < dt_max, got dt_min={self.dt_min!r}, "
                             f"dt_max={self.dt_max!r}")
        if not (0 < self.safety <= 1 and 0 < self.shrink < 1 < self.grow):
            raise InputError("StepController needs 0 < safety <= 1 and 0 < shrink < 1 < grow, got "
                             f"safety={self.safety!r}, shrink={self.shrink!r}, grow={self.grow!r}")
        for name in ("hold", "refactor_ratio"):
            real(f"StepController.{name}", getattr(self, name), 1.0, finite=False, hint="1: off")
        if self.error_map is not None and not callable(self.error_map):
            raise InputError("StepController.error_map must be a callable (x, params) -> array")
        if self.error_scale is not None and not np.all(np.isfinite(self.error_scale)
                                                       & (np.asarray(self.error_scale) > 0)):
            raise InputError("StepController.error_scale must be positive and finite")

    def measured(self, x, params) -> np.ndarray:
        """The quantities the local error is measured in, at state ``x`` on ``params``."""
        return np.asarray(x if self.error_map is None else self.error_map(x, params), dtype=np.float64)

    def norm(self, local, y_new, scale) -> float:
        """Weighted RMS norm of a local error ``local`` at the step's end state ``y_new``;
        ``scale``: the run's, used unless the controller has its own ``error_scale``."""
        scale = scale if self.error_scale is None else self.error_scale
        weight = self.atol * scale + self.rtol * np.abs(y_new)
        return float(np.sqrt(np.mean((local / weight) ** 2)))

    def propose(self, h: float, err: float, scheme: TimeScheme | None = None) -> float:
        """Next step size after a step of size h with error norm ``err`` (its order and growth
        cap those of ``scheme``; default implicit Euler's)."""
        q, cap = (1, math.inf) if scheme is None else (scheme.error_order, scheme.max_growth)
        grow = min(self.grow, cap)
        factor = grow if err == 0 else min(grow, max(self.shrink, self.safety * err ** (-1.0 / (q + 1))))
        return self.clip(h * factor)

    def next_size(self, h: float, err: float, scheme: TimeScheme | None = None) -> float:
        """Size of the step after an accepted step of size h with error norm ``err``: h itself
        while :meth:`propose` asks for at most ``hold`` times it (and not less), else the
        proposal."""
        proposal = self.propose(h, err, scheme)
        return self.clip(h) if h <= proposal <= self.hold * h else proposal

    def clip(self, h: float) -> float:
        """``h`` within ``[dt_min, dt_max]``."""
        return min(max(h, self.dt_min), self.dt_max)

    # -- the time loop's interface (jaxanm._step_size) --

    def init(self, span: Span) -> _Adaptive:
        """No proposal and no history yet; the save times steps end on."""
        return _Adaptive(None, (), None, tuple(sorted({v for v in span.saveat.ts or () if span.t0 < v < span.t1})))

    def done(self, state: _Adaptive, k: int, t: float, span: Span) -> bool:
        """Once ``t1`` is reached."""
        return not t < span.t1

    def attempt(self, state: _Adaptive, k: int, t: float, x, params, span: Span) -> StepPlan:
        """The proposed size (the run's dt at first), the state measured for the estimate (when
        the scheme's estimate reads the steps before, and there are some)."""
        h = state.h_next if state.h_next is not None else float(span.dt)
        y_now = self.measured(x, params) if state.past and span.scheme.estimate_history else None
        return self._planned(state, h, t, span, 0, y_now)

    def _planned(self, state: _Adaptive, h: float, t: float, span: Span, failures: int, y_now) -> StepPlan:
        """A step of at most ``h`` from ``t`` towards the next save time (or t1): within
        :data:`SPREAD` steps of it, the remaining distance in equal steps, ``ceil(distance / h)``
        of them, so that the steps end exactly on it without a short last step (whose stage
        size would need another K*, and after which the next proposal would start from the
        short size); a step that reaches it, or falls short of it by a sliver the next step
        could not resolve, ends on it."""
        target = min([v for v in state.save_times if v > t][:1] + [float(span.t1)])
        distance = target - t
        steps = math.ceil(distance / h)
        if distance <= h + MIN_STEP * (span.t1 - span.t0):
            end = target
        elif steps <= SPREAD:
            end = t + distance / steps
        else:
            end = t + h
        return StepPlan(end, (Segment(t, end - t),), failures, (h, y_now))

    def retry(self, state: _Adaptive, attempt: StepPlan, failure: Exception, span: Span) -> StepPlan:
        """The step from its start at a quarter of its size (the failure raised after
        ``max_failures`` in a row)."""
        if attempt.failures >= span.max_failures:
            raise failure
        start = attempt.segments[0]
        return self._planned(state, self.clip(start.h / 4), start.t, span, attempt.failures + 1, attempt.memo[1])

    def judge(self, state: _Adaptive, attempt: StepPlan, k: int, x, x_new, params, scale, span: Span,
              embedded=None) -> Verdict:
        """The scheme's local error test (none without an estimate); refused steps are retried
        from x at the proposed size unless already at ``dt_min`` (compared before the
        end-point snapping, which rounds the size)."""
        h, y_now = attempt.memo
        start, scheme = attempt.segments[0], span.scheme
        size = start.h
        y_new = self.measured(x_new, params)
        y_hat = None if embedded is None else self.measured(embedded, params)
        local = scheme.local_error(y_new, y_hat, y_now, state.past, size)
        if local is None:  # no estimate: accepted as proposed
            state = state._replace(h_next=self.clip(h))
        else:
            err = self.norm(local, y_new, scale)
            if err > 1 and h > self.dt_min:
                if size <= MIN_STEP * (span.t1 - span.t0):
                    raise StepFailure(f"the local error test still fails (error {err:.3g} times the tolerance) "
                                      f"at a step of {size:.3g}: give the controller a larger rtol/atol or a "
                                      "dt_min at which to accept such steps", step=k, t=attempt.end)
                return Verdict(state, retry=self._planned(state, self.propose(size, err, scheme), start.t, span,
                                                          attempt.failures, y_now))
            state = state._replace(h_next=self.next_size(size, err, scheme),
                                   time_error=local if state.time_error is None else state.time_error + local)
        kept = scheme.estimate_history
        if kept:
            now = y_now if y_now is not None else self.measured(x, params)
            state = state._replace(past=((now, size),) + state.past[:kept - 1])
        return Verdict(state, size=size)

    def saved(self, state: _Adaptive, k: int, t: float, span: Span) -> bool:
        """:meth:`jaxanm.SaveAt.controlled`."""
        return span.saveat.controlled(k, t, span.t1)

    def forget(self, state: _Adaptive) -> _Adaptive:
        """No history: the next step is taken without an estimate."""
        return state._replace(past=())

    def time_error(self, state: _Adaptive):
        """The sum of the accepted steps' local error estimates (None before any)."""
        return state.time_error

    def describe(self) -> dict:
        """The settings (``error_map`` by name: a function's repr holds its address, which
        differs from process to process)."""
        d = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "error_map"}
        d["error_scale"] = None if self.error_scale is None else np.asarray(self.error_scale).tolist()
        em = self.error_map
        d["error_map"] = None if em is None else getattr(em, "__qualname__", type(em).__name__)
        return d

    def to_checkpoint(self, state: _Adaptive) -> dict:
        """The proposal, the measured states of the past steps and the error sum."""
        return {"h_next": state.h_next, "past": state.past, "time_error": state.time_error}

    def from_checkpoint(self, state: _Adaptive, stored: dict) -> _Adaptive:
        """``state`` with the stored proposal, history and error sum."""
        return state._replace(**stored)
