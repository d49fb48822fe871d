"""The one time loop of :func:`jaxanm.integrate`.

Every step goes the same way, whatever the controller (:mod:`jaxanm._step_size`):

1. the controller plans the step (:meth:`~jaxanm._step_size.StepSizeController.attempt`): its
   end time and the segments it is solved in;
2. each segment is one step of the time scheme (:class:`~jaxanm.TimeScheme`) from the state
   and the scheme's history the previous one reached (:meth:`TimeLoop._solve_segment`): the
   scheme poses its stages, and the step solver solves each (:meth:`TimeLoop._solve_stage`);
   a solve that fails (:class:`~jaxanm.StepFailure`, or a non-finite state) is handed back to
   the controller, which says how to retry
   (:meth:`~jaxanm._step_size.StepSizeController.retry`: fixed steps halve the segment, the
   adaptive controller retries the step at a quarter of its size) or raises;
3. the sensitivity method, if any, polishes each solved segment (its failures are not
   retried);
4. the controller judges the solved step (with the scheme's error estimate); a refused step
   is retried as it says;
5. the accepted step is recorded (:meth:`TimeLoop._accept`): the ``after_step`` hook, what
   is saved, the new :class:`~jaxanm._loop_state.LoopState` (with the scheme's history), then
   the callback, the progress bar and the periodic checkpoint.

The loop owns the run's record, a :class:`~jaxanm._loop_state.LoopState` it replaces at every
change, and is the one place that counts its own work in the run's :class:`~jaxanm.Stats`:
``time_steps``, ``residual_norm``, ``step_sizes``, ``dt_halvings``, ``rejected_steps``,
``resumes`` and ``wall_time_s``, and what each solve reports (its
:class:`~jaxanm._solver.StepReport`: Newton iterations, sub-steps, Padé acceptances, a_max and
orders), in :class:`_Tally`.  The work counters and timers (factorisations, evaluations,
solves) are the :class:`~jaxanm._problem.Problem`'s.
"""

from __future__ import annotations

import dataclasses
import os
import time
from typing import Callable

import numpy as np

from ._hooks import Remap
from ._loop_state import Kept, Log, LoopState
from ._problem import Problem
from ._run_checkpoint import Checkpoints, from_checkpoint
from ._run_inputs import on_device, remapped_state
from ._saveat import SaveAt
from ._scheme import SchemeStep
from ._sensitivity_method import SensitivityMethod
from ._solver import StepReport, StepSolver
from ._step_size import Segment, Span, StepPlan, StepSizeController, Verdict
from .checkpoint import SignalGuard, sigterm_as_interrupt
from .errors import NonFiniteError, StepFailure, run_stopped
from .stats import Stats


@dataclasses.dataclass(frozen=True)
class LoopOptions:
    """The options of one :func:`jaxanm.integrate` run, as documented there, each with a
    do-nothing default in place of None: ``after_step`` returns the params it is given,
    ``callback`` does nothing, ``sensitivity`` is a :class:`~jaxanm._sensitivity_method.NoSensitivity`,
    ``controller`` a :class:`~jaxanm.ConstantStepSize`, ``checkpoints`` without a path
    writes nothing."""

    span: Span
    controller: StepSizeController
    after_step: Callable
    callback: Callable
    progress: bool
    checkpoints: Checkpoints
    sensitivity: SensitivityMethod


class _Tally:
    """The loop's counts in the run's :class:`~jaxanm.Stats` (the one place that changes them)."""

    def __init__(self, stats: Stats, previous_wall: float, start: float):
        self.stats, self.previous_wall, self.start = stats, previous_wall, start

    def solved(self, report: StepReport | None) -> None:
        """A solve's :class:`~jaxanm._solver.StepReport` (None: a solver that reports nothing)
        added to the counters of the same names."""
        if report is None:
            return
        s = self.stats
        s.newton_iterations += report.newton_iterations
        s.substeps += report.substeps
        s.pade_accepted += report.pade_accepted
        s.amax.extend(report.amax)
        s.orders.extend(report.orders)

    def retried(self) -> None:
        """A failed solve retried (``dt_halvings``)."""
        self.stats.dt_halvings += 1

    def refused(self) -> None:
        """A solved step refused by the controller (``rejected_steps``)."""
        self.stats.rejected_steps += 1

    def resumed(self) -> None:
        """A continuation from a checkpoint whose stored K* is factorised again (``resumes``)."""
        self.stats.resumes += 1

    def accepted(self, residual_norm: float, size: float | None) -> None:
        """An accepted step: its residual norm and (with an adaptive controller) its size."""
        if size is not None:
            self.stats.step_sizes.append(size)
        self.stats.residual_norm.append(residual_norm)
        self.stats.time_steps += 1

    def closed(self) -> Stats:
        """The statistics with the wall time up to now (this run's and the resumed runs')."""
        self.stats.close(self.previous_wall + time.perf_counter() - self.start)
        return self.stats


class TimeLoop:
    """One run of :func:`jaxanm.integrate`: its record (:attr:`state`, a
    :class:`~jaxanm._loop_state.LoopState`) and how a step is planned, solved, retried and
    recorded (module docstring)."""

    def __init__(self, residual, solver: StepSolver, x0, params, scale, jacobian, sparsity,
                 saveat: SaveAt, options: LoopOptions, start: float):
        o = self.options = options
        self.solver, self.scale, self.saveat = solver, scale, saveat
        self.controller, self.span, self.sensitivity = o.controller, o.span, o.sensitivity
        self.scheme = o.span.scheme
        span = o.span
        payload = o.checkpoints.load() if o.checkpoints.resumable(os.path.exists) else None
        stats = Stats() if payload is None else payload["stats"]
        self.tally = _Tally(stats, stats.wall_time_s, start)
        self.problem = Problem(residual, scale, stats, jacobian, sparsity)
        solver_state, controller_state = solver.init(self.problem), o.controller.init(span)
        if payload is None:
            kept = Kept.start(span.t0, x0, params, saveat.params, saveat.fn)
        else:  # a placeholder: the checkpoint's record replaces it (from_checkpoint)
            kept = Kept(Log.of([]), Log.of([]), None, None)
        self.state = LoopState(k=0, t=float(span.t0), x=x0, params=params, solver_state=solver_state,
                               controller_state=controller_state, scheme_state=None, kstar_dt=None, kept=kept)
        if payload is not None:
            self._resume(payload)
        o.sensitivity.start(self.problem, span.t0, x0, params)
        self.bar = _progress_bar(o.controller.expected_steps(span), span.t1 - span.t0, o.progress,
                                 initial=self.state.k)
        self.guard: SignalGuard | None = None

    def _resume(self, payload: dict) -> None:
        """The record, the solver's K* and the controller's state from a checkpoint."""
        state = from_checkpoint(payload, self.state, self.options.checkpoints.path)
        state = state._replace(params=on_device(state.params),
                               controller_state=self.controller.from_checkpoint(state.controller_state,
                                                                                payload["controller"]))
        if payload["solver"] is not None:
            state = state._replace(solver_state=self.solver.from_checkpoint(state.solver_state, payload["solver"]))
            self.tally.resumed()
        self.state = state

    @property
    def stats(self) -> Stats:
        """The run's statistics so far."""
        return self.tally.stats

    def run(self):
        """Every step from the record's to the end of the span: ``(record, stats)``."""
        stats = self.stats
        try:
            with sigterm_as_interrupt() as self.guard:
                while not self.controller.done(self.state.controller_state, self.state.k, self.state.t, self.span):
                    self._step()
        except BaseException as exc:
            if not (self.guard is not None and self.guard.held):
                self._write_checkpoint()  # everything up to the last accepted step (not if recording it failed)
            if isinstance(exc, (StepFailure, KeyboardInterrupt)):  # with the work done until it stopped
                raise run_stopped(exc, stats=stats) from exc.__cause__
            raise
        finally:
            self.bar.close()
            self.tally.closed()
        self._write_checkpoint()
        return self.state, stats

    def _write_checkpoint(self) -> None:
        """The run's checkpoint (nothing without a path)."""
        s = self.state
        self.options.checkpoints.write(s, self.tally.closed, self.solver.to_checkpoint(s.solver_state),
                                       self.controller.to_checkpoint(s.controller_state))

    def _step(self) -> None:
        """Plan, solve, judge and record the next step."""
        start, k = self.state, self.state.k + 1
        controller = self.controller
        attempt = controller.attempt(start.controller_state, k, start.t, start.x, start.params, self.span)
        while True:
            x_new, r_norm, attempt, solved, dense = self._solve(attempt, k)
            verdict = controller.judge(start.controller_state, attempt, k, start.x, x_new, start.params,
                                       self.scale, self.span, solved.embedded)
            if verdict.retry is None:
                break
            self.tally.refused()
            attempt = verdict.retry
        self._accept(k, attempt.end, x_new, r_norm, verdict, solved.history, dense)

    def _solve(self, attempt: StepPlan, k: int):
        """The segments of ``attempt``, in order, retried as the controller says when a solve
        fails: ``(x at the end, |R|_inf there, the attempt as finally solved, the scheme's step
        of the last segment, the segments' dense output)``, that step's ``history`` carried
        through the segments; the dense output is ``(segment, Interpolant)`` for each solved
        segment when ``SaveAt.fn_ts`` asks for it, else empty."""
        x, history, pending = self.state.x, self.state.scheme_state, attempt.segments
        solved = None
        dense = []
        while pending:
            segment = pending[0]
            try:
                solved, r_norm = self._solve_segment(x, history, segment, k)
            except StepFailure as failure:
                attempt = self.controller.retry(self.state.controller_state, attempt._replace(segments=pending),
                                                failure, self.span)
                self.tally.retried()
                pending = attempt.segments
                continue
            x_end, r_norm = self._polished(x, solved.x, r_norm, segment, k)
            if self.saveat.fn_ts is not None:
                dense.append((segment, self.scheme.interpolant(history, x, solved._replace(x=x_end), segment.h)))
            x, history = x_end, solved.history
            pending = pending[1:]
        assert solved is not None  # an attempt has at least one segment
        return x, r_norm, attempt, solved._replace(history=history), dense

    def _solve_segment(self, x, history, segment: Segment, k: int) -> tuple[SchemeStep, float | None]:
        """One step of the time scheme over ``segment`` from ``x`` and the scheme's
        ``history``: ``(the scheme's step, |R|_inf at its end state)`` (None when the
        sensitivity method polishes, and measures, the state itself)."""
        norms: list = []

        def solve(z, t, gamma_h, last=False, start=None):
            x_stage, r_norm = self._solve_stage(z, t, gamma_h, k, last, start)
            norms.append(r_norm)
            return x_stage

        step = self.scheme.step(history, x, segment.t, segment.h, solve)
        return step, norms[-1]

    def _solve_stage(self, z, t, gamma_h, k: int, last: bool, start=None):
        """One solve of step ``k``: the stage ``R(x, z, t, gamma_h) = 0`` from ``start`` (or ``z``):
        ``(x, |R(x)|_inf)`` for the step's last stage (None when the sensitivity method
        polishes, and measures, the state itself), ``(x, None)`` for the others.

        A K* the solver carries from a stage size more than the controller's
        ``refactor_ratio`` away is dropped first (its factors freed: the loop owns the solver
        state, and one LU stays alive); the record then holds the solver's new state, and the
        stage size of the K* it carries.  A non-finite state or residual is a
        :class:`NonFiniteError`, retried like any failed solve.
        """
        solver, state = self.solver, self.state.solver_state
        kstar = solver.factorization(state) if solver.reuses_factorization else None
        kstar_dt = self.state.kstar_dt
        if kstar is not None and kstar_dt is not None:
            if max(gamma_h / kstar_dt, kstar_dt / gamma_h) > self.controller.refactor_ratio:
                kstar.release()  # before the solver makes the next: one LU alive
                state = solver.with_factorization(state, None)
                kstar = None
        # numpy scalars: a jnp scalar costs a device dispatch per conversion
        t_new, h_new = np.float64(t), np.float64(gamma_h)
        try:  # a start only when the scheme gives one: a user's solver written without it serves Euler
            extra = {} if start is None else {"start": start}
            x_new, state = solver.step(state, k, z, t_new, h_new, self.state.params, **extra)
            self.tally.solved(state.report)
        except StepFailure as failure:
            after = solver.state_after_failure(state, failure)
            if after is not state:  # the state the failed step attached, with its report
                self.tally.solved(after.report)
            state = after
            raise
        finally:  # a failed step may leave a K* it made for the retry (state_after_failure)
            if solver.factorization(state) is not kstar:
                kstar_dt = float(gamma_h)
            self.state = self.state._replace(solver_state=state, kstar_dt=kstar_dt)
        if not last:
            if not np.all(np.isfinite(x_new)):
                raise NonFiniteError(f"a stage of the {self.scheme.name} step has "
                                     f"{int(np.sum(~np.isfinite(x_new)))} non-finite entries", step=k, t=t_new)
            return x_new, None
        if self.sensitivity.polishes:
            return x_new, None
        return x_new, self._checked_residual(x_new, z, t_new, h_new, k)

    def _checked_residual(self, x_new, x, t_new, h_new, k: int) -> float:
        """``|R(x_new)|_inf`` (the solver's, if it evaluated it there); :class:`NonFiniteError`
        if it or ``x_new`` is not finite."""
        r_new = self.solver.accepted_residual(self.state.solver_state)
        if r_new is None:
            r_new = self.problem.residual(x_new, x, t_new, h_new, self.state.params)
        r_norm = float(np.max(np.abs(r_new)))
        if not (np.isfinite(r_norm) and np.all(np.isfinite(x_new))):
            amax = self.stats.amax[-1] if self.stats.amax else None
            raise NonFiniteError(f"the accepted state has {int(np.sum(~np.isfinite(x_new)))} non-finite "
                                 "entries or a non-finite residual", step=k, t=t_new, amax=amax,
                                 residual_norm=r_norm)
        return r_norm

    def _polished(self, x, x_new, r_norm, segment: Segment, k: int):
        """The solved segment as the sensitivity method leaves it: ``(state, |R|_inf)``; a K* it
        factorised becomes the solver's."""
        solver = self.solver
        polished = self.sensitivity.after_solve(solver.factorization(self.state.solver_state), x, x_new,
                                                np.float64(segment.t + segment.h), np.float64(segment.h), k)
        if polished is None:
            return x_new, r_norm
        if polished.factorization is not None:
            self.state = self.state._replace(
                solver_state=solver.with_factorization(self.state.solver_state, polished.factorization))
        return polished.x, polished.residual_norm

    def _accept(self, k: int, t_new: float, x_new, r_norm: float, verdict: Verdict, history, dense) -> None:
        """Hand an accepted step to the hooks and record it (signals wait meanwhile); a
        :class:`Remap` restarts the scheme's ``history`` (and the controller's, when the scheme
        had one or the remap says so).  ``dense``: the step's segments and their dense output
        (:meth:`_solve`), observed at ``SaveAt.fn_ts`` with the params they were solved with,
        before the hook may change them."""
        o, s, guard = self.options, self.state, self.guard
        if guard is None:  # run() sets it around the steps
            raise RuntimeError("a step is accepted outside TimeLoop.run")
        guard.hold()  # from here to release(): signals wait, the step is recorded whole
        self.tally.accepted(r_norm, verdict.size)
        kept, observe = s.kept, self.saveat.fn
        if self.saveat.fn_ts is not None and observe is not None:  # SaveAt refuses fn_ts without fn
            kept = kept.observing(self._observations(dense, t_new), s.params, observe)
        controller_state = verdict.state
        params_new = o.after_step(t_new, x_new, s.params)
        if isinstance(params_new, Remap):
            if not params_new.history or history is not None:
                controller_state = self.controller.forget(controller_state)
            history = self.scheme.restart(history)
            x_new = remapped_state(params_new.x, x_new)
            params_new = params_new.params
        if params_new is not s.params:
            params_new = on_device(params_new, s.params)
        saved = self.controller.saved(controller_state, k, t_new, self.span)
        kept = kept.after(t_new, x_new, params_new, saved=saved,
                          observe=self.saveat.fn if self.saveat.fn_ts is None else None)
        self.state = s._replace(k=k, t=t_new, x=x_new, params=params_new, controller_state=controller_state,
                                scheme_state=history, kept=kept)
        self.sensitivity.record(t_new, x_new, params_new)
        guard.release()
        o.callback(t_new, x_new, self.stats)
        self.bar.update(1)
        self.bar.set_postfix(t=f"{t_new:.4g}", factorizations=self.stats.factorizations, refresh=False)
        if o.checkpoints.due(k):
            self._write_checkpoint()

    def _observations(self, dense, t_new: float) -> list:
        """``(t, state)`` at each ``SaveAt.fn_ts`` within the step's segments, from their dense
        output (the last segment ends exactly at ``t_new``, as the step)."""
        observations = []
        for i, (segment, interpolant) in enumerate(dense):
            end = t_new if i == len(dense) - 1 else segment.t + segment.h
            for t in self.saveat.observed_within(segment.t, end):
                observations.append((float(t), interpolant.at(min((t - segment.t) / segment.h, 1.0))))
        return observations


class _NoBar:
    """The progress bar of a run without one."""

    def update(self, n: int) -> None:
        """Nothing to show."""

    def set_postfix(self, **kwargs) -> None:
        """Nothing to show."""

    def close(self) -> None:
        """Nothing to close."""


def _progress_bar(n_steps, span, enabled, initial=0):
    """A tqdm bar over ``n_steps`` (None: unknown) steps, or a :class:`_NoBar`."""
    if not enabled:
        return _NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=n_steps, initial=initial, unit="step", desc=f"t span {span:.4g} s", dynamic_ncols=True)
