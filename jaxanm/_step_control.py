"""Adaptive implicit-Euler step sizes: a local error estimate from the step history and an
elementary controller.

**Estimate (Milne's device, no extra solve).**  For ``x' = f(x)``, an implicit Euler step of
size h from ``x_n`` gives ``x_{n+1} = x_n + h f(x_{n+1})``, so the previous step says
``x_n - x_{n-1} = h_prev f(x_n)`` exactly and the extrapolation

    x_pred = x_n + (h / h_prev) (x_n - x_{n-1}) = x_n + h f(x_n)

is the explicit Euler step from ``x_n``.  With y the exact solution through ``x_n``,
``y(t_n + h) - x_pred = h^2 y''/2 + O(h^3)`` and ``x_{n+1} - y(t_n + h) = h^2 y''/2 + O(h^3)``
(the local error of implicit Euler), so

    local error = (x_{n+1} - x_pred) / 2 + O(h^3),

whatever h_prev.  The same holds for a DAE with a mass matrix and algebraic rows (their
local error is that of the differential variables they follow).  The estimate needs one
earlier accepted step: the first step of a run (and the first after ``Remap(history=False)``)
is taken at the proposed size without an estimate.

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

**Controller.**  The local error is O(h^2), so ``h_new = h * clip(safety * err^(-1/2),
shrink, grow)``; a rejected step is retried from ``x_n`` with that h, an accepted one proposes
it for the next step.  ``dt_min`` and ``dt_max`` bound every proposal (``dt_max``: e.g. the
largest step the point motion of a Lagrangian scene allows).

**Holding the step size.**  The solvers reuse a factorised K* across steps, and K* holds the
``1/h`` of the time derivative: a K* made at step size h_K solves a step of size h as a
modified-Newton iteration (or an ANM series) whose contraction on the slow components is
``|1 - h_K / h|``.  A new size at every step, as the proposals give, keeps K* stale (the ANM,
whose series from a stale K* tolerates less of that than modified Newton's iteration,
refactorises far more often than it), and a K* made at a much smaller h fools the
convergence tests that measure with it (modified Newton's ``|dx|`` and the ANM's end-point
check shrink with ``h_K / h``, so a step is accepted with its state left behind, and the
error estimate, seeing no change, grows the next step).  So, as BDF codes do, an accepted
step's size is kept while the proposal is between h and ``hold`` times h, and the run drops a
K* whose step size is more than ``refactor_ratio`` away from the next step's before that step
(the solver then factorises at its start, instead of wasting a series or trusting a wrong
test).  Measured on stiff problems: ``docs/notes/adaptive_time_steps.md``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, NamedTuple, cast

import numpy as np

from ._step_size import Attempt, Segment, Span, StepSizeController, Verdict
from .errors import InputError, StepFailure

HOLD = 1.5
"""Default :attr:`StepController.hold` (module docstring, "Holding the step size")."""

REFACTOR_RATIO = 1.5
"""Default :attr:`StepController.refactor_ratio` (module docstring, "Holding the step size")."""


MIN_STEP = 1e-12
"""A step refused by the error test below this fraction of the span is a failure (the error
estimate is then round-off or a discontinuity, not the time discretisation)."""


class _Adaptive(NamedTuple):
    """The state of :class:`StepController` between steps."""

    h_next: float | None  # the size proposed for the next step (None: the run's dt)
    history: tuple | None  # (measured state before the last step, its size); None: no estimate yet
    time_error: np.ndarray | None  # the sum of the local error estimates of the accepted steps
    save_times: tuple  # SaveAt.ts within (t0, t1), sorted: steps end exactly on them


@dataclasses.dataclass(frozen=True)
class StepController(StepSizeController):
    """Adaptive step sizes for :func:`jaxanm.integrate` (``controller=StepController(...)``).

    The estimate, the norm, the controller and why it holds the step size are described in
    ``docs/notes/adaptive_time_steps.md`` (and this module's docstring).  A step whose solve
    fails is retried from its start at a quarter of its size, at most ``max_dt_halvings``
    times in a row; a step refused by the error test is retried at the size the controller
    proposes.  Steps end exactly on ``SaveAt.ts`` and on ``t1``.

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
        The controller's factor ``clip(safety * err^(-1/2), shrink, grow)``.
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
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InputError(f"StepController.{name} must be a finite number >= 0, got {v!r}")
        if self.rtol == 0 and self.atol == 0:
            raise InputError("StepController needs rtol > 0 or atol > 0 (both 0 accepts no step)")
        if not (0 <= self.dt_min < self.dt_max):
            raise InputError(f"StepController needs 0 <= dt_min < dt_max, got dt_min={self.dt_min!r}, "
                             f"dt_max={self.dt_max!r}")
        if not (0 < self.safety <= 1 and 0 < self.shrink < 1 < self.grow):
            raise InputError("StepController needs 0 < safety <= 1 and 0 < shrink < 1 < grow, got "
                             f"safety={self.safety!r}, shrink={self.shrink!r}, grow={self.grow!r}")
        for name in ("hold", "refactor_ratio"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not math.isnan(v) and v >= 1):
                raise InputError(f"StepController.{name} must be a number >= 1 (1: off), got {v!r}")
        if self.error_map is not None and not callable(self.error_map):
            raise InputError("StepController.error_map must be a callable (x, params) -> array")
        if self.error_scale is not None and not np.all(np.isfinite(self.error_scale)
                                                       & (np.asarray(self.error_scale) > 0)):
            raise InputError("StepController.error_scale must be positive and finite")

    def measured(self, x, params) -> np.ndarray:
        """The quantities the local error is measured in, at state ``x`` on ``params``."""
        return np.asarray(x if self.error_map is None else self.error_map(x, params), dtype=np.float64)

    @staticmethod
    def local_error(y_new, y_now, y_before, h: float, h_prev: float) -> np.ndarray:
        """Milne's estimate of the local error of the step ``y_now -> y_new`` of size h, the
        step before it ``y_before -> y_now`` of size ``h_prev`` (module docstring), in the
        measured quantities."""
        return 0.5 * (y_new - (y_now + (h / h_prev) * (y_now - y_before)))

    def error(self, y_new, y_now, y_before, h: float, h_prev: float, scale) -> float:
        """Weighted RMS norm of :meth:`local_error`; ``scale``: the run's, used unless the
        controller has its own ``error_scale``."""
        return self.norm(self.local_error(y_new, y_now, y_before, h, h_prev), y_new, scale)

    def norm(self, local, y_new, scale) -> float:
        """Weighted RMS norm of a local error ``local`` at the step's end state ``y_new``."""
        scale = scale if self.error_scale is None else self.error_scale
        weight = self.atol * scale + self.rtol * np.abs(y_new)
        return float(np.sqrt(np.mean((local / weight) ** 2)))

    def propose(self, h: float, err: float) -> float:
        """Next step size after a step of size h with error norm ``err``."""
        factor = self.grow if err == 0 else min(self.grow, max(self.shrink, self.safety * err ** -0.5))
        return self.clip(h * factor)

    def next_size(self, h: float, err: float) -> float:
        """Size of the step after an accepted step of size h with error norm ``err``: h itself
        while :meth:`propose` asks for at most ``hold`` times it (and not less), else the
        proposal."""
        proposal = self.propose(h, err)
        return self.clip(h) if h <= proposal <= self.hold * h else proposal

    def clip(self, h: float) -> float:
        """``h`` within ``[dt_min, dt_max]``."""
        return min(max(h, self.dt_min), self.dt_max)

    # -- the time loop's interface (jaxanm._step_size) --

    def init(self, span: Span) -> _Adaptive:
        """No proposal and no history yet; the save times steps end on."""
        return _Adaptive(None, None, None, tuple(sorted({v for v in span.saveat.ts or () if span.t0 < v < span.t1})))

    def done(self, state: _Adaptive, k: int, t: float, span: Span) -> bool:
        """Once ``t1`` is reached."""
        return not t < span.t1

    def attempt(self, state: _Adaptive, k: int, t: float, x, params, span: Span) -> Attempt:
        """The proposed size (the run's dt at first), the state measured for the estimate."""
        h = state.h_next if state.h_next is not None else float(span.dt)
        y_now = self.measured(x, params) if state.history is not None else None
        return self._planned(state, h, t, span, 0, y_now)

    def _planned(self, state: _Adaptive, h: float, t: float, span: Span, failures: int, y_now) -> Attempt:
        """A step of about ``h`` from ``t``: it ends exactly on the next save time or on t1 when
        it reaches it (or falls short of it by a sliver the next step could not resolve)."""
        end = t + h
        for target in [v for v in state.save_times if v > t][:1] + [float(span.t1)]:
            if end >= target - MIN_STEP * (span.t1 - span.t0):
                end = target
                break
        return Attempt(end, (Segment(t, end - t),), failures, (h, y_now))

    def retry(self, state: _Adaptive, attempt: Attempt, failure: Exception, span: Span) -> Attempt:
        """The step from its start at a quarter of its size (the failure raised after
        ``max_failures`` in a row)."""
        if attempt.failures >= span.max_failures:
            raise failure
        start = attempt.segments[0]
        return self._planned(state, self.clip(start.h / 4), start.t, span, attempt.failures + 1, attempt.memo[1])

    def judge(self, state: _Adaptive, attempt: Attempt, k: int, x, x_new, params, scale, span: Span) -> Verdict:
        """The local error test (none on the first step and after a history-breaking remap);
        refused steps are retried from x at the proposed size unless already at ``dt_min``
        (compared before the end-point snapping, which rounds the size)."""
        h, y_now = attempt.memo
        start = attempt.segments[0]
        size = start.h
        if y_now is None:  # no earlier step to estimate with: accepted as proposed
            state = state._replace(h_next=self.clip(h))
        else:
            # y_now is measured only when the state has a history (attempt, retry)
            y_before, h_prev = cast(tuple, state.history)
            y_new = self.measured(x_new, params)
            local = self.local_error(y_new, y_now, y_before, size, h_prev)
            err = self.norm(local, y_new, scale)
            if err > 1 and h > self.dt_min:
                if size <= MIN_STEP * (span.t1 - span.t0):
                    raise StepFailure(f"the local error test still fails (error {err:.3g} times the tolerance) "
                                      f"at a step of {size:.3g}: give the controller a larger rtol/atol or a "
                                      "dt_min at which to accept such steps", step=k, t=attempt.end)
                return Verdict(state, retry=self._planned(state, self.propose(size, err), start.t, span,
                                                          attempt.failures, y_now))
            state = state._replace(h_next=self.next_size(size, err),
                                   time_error=local if state.time_error is None else state.time_error + local)
        history = (y_now if y_now is not None else self.measured(x, params), size)
        return Verdict(state._replace(history=history), size=size)

    def saved(self, state: _Adaptive, k: int, t: float, span: Span) -> bool:
        """:meth:`jaxanm.SaveAt.controlled`."""
        return span.saveat.controlled(k, t, span.t1)

    def forget(self, state: _Adaptive) -> _Adaptive:
        """No history: the next step is taken without an estimate."""
        return state._replace(history=None)

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
        """The proposal, the history and the error sum."""
        return {"h_next": state.h_next, "history": state.history, "time_error": state.time_error}

    def from_checkpoint(self, state: _Adaptive, stored: dict) -> _Adaptive:
        """``state`` with the stored proposal, history and error sum."""
        return state._replace(**stored)
