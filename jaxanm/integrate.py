"""The time loop: implicit Euler steps of a user residual with a step solver (ANM, Newton, ...).

It is the only time loop: forward sensitivities ride on it (its ``sensitivity`` option)."""

from __future__ import annotations

import abc
import dataclasses
import math
import os
import time
import warnings
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

from ._x64 import entry_point
from .checkpoint import read, sigterm_as_interrupt, to_host, write_atomic
from .errors import InputError, NonFiniteError, StepFailure
from .jacobian import detect_sparsity
from .saveat import SaveAt, fixed_steps, step_end
from ._problem import Problem
from ._solver import StepSolver
from .stats import Stats
from .step_control import StepController

AUTO_SPARSE_SIZE = 400
"""Above this many unknowns ``jacobian="auto"`` picks the sparse Jacobian."""


class Remap(NamedTuple):
    """Returned by an ``after_step`` hook that changed the discretisation (e.g. moved points and
    rebuilt stencils): the new ``params`` and the accepted state mapped onto them.

    The next step starts its homotopy (or Newton iteration) from ``x`` and takes ``x`` as its
    old state, so a remapping that preserves the fields (``x`` such that the new operators
    reproduce the values the old ones gave) leaves only the physical change in the next
    residual.  ``x`` must keep the shape of the state.  ``history=False`` says the remap broke
    the continuity of what a :class:`~jaxanm.step_control.StepController` measures (e.g. a
    re-seeded cloud): the next step is then taken without a local error estimate.
    """

    params: object
    x: np.ndarray
    history: bool = True


@dataclasses.dataclass
class Solution:
    """Result of :func:`integrate`: saved times ``ts (S,)``, states ``xs (S, n)``, ``stats``.

    ``params`` holds the parameter pytree at each saved time when ``SaveAt(params=True)``
    (e.g. moving Lagrangian point clouds), else ``None``; ``observed`` the quantities recorded
    by ``SaveAt(fn=...)`` at every step (``{"t": (M,), key: (M, ...)}``), else ``None``.
    ``time_error``: with a controller, an estimate of the time discretisation's error at t1
    in the quantities it measures (its ``error_map``): the sum of the local error estimates of
    the accepted steps (Milne's device).  It leaves out how earlier errors propagate: where
    they decay (diffusion) and the local errors keep their sign, it errs on the large side.
    The first step, and the first after a ``Remap(history=False)``, have no estimate and add
    nothing.  None without a controller.
    """

    ts: np.ndarray
    xs: np.ndarray
    stats: Stats
    params: list | None = None
    observed: dict | None = None
    time_error: np.ndarray | None = None


def check_run_inputs(x0, t0, t1, dt, solver, scale, jacobian, saveat=None, controller=None):
    """Check a run's inputs before any computation (:class:`InputError` naming the fix);
    return ``x0`` and ``scale`` as float64 arrays.  Shared with :mod:`jaxanm.sensitivity`."""
    x0 = np.asarray(x0, dtype=np.float64)
    if x0.ndim != 1 or x0.size == 0:
        raise InputError(f"x0 must be a non-empty 1-D array of unknowns, got shape {x0.shape}; flatten your state")
    if not np.all(np.isfinite(x0)):
        raise InputError(f"x0 has {int(np.sum(~np.isfinite(x0)))} non-finite entries; give a finite initial state")
    for name, v in (("t0", t0), ("t1", t1), ("dt", dt)):
        if not (isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v)):
            raise InputError(f"{name} must be a finite number, got {v!r}")
    if not dt > 0:
        raise InputError(f"dt must be > 0, got {dt!r}")
    if not t1 > t0:
        raise InputError(f"t1 must be > t0, got t0={t0!r}, t1={t1!r}")
    if not isinstance(solver, StepSolver):
        raise InputError(f"solver must be jaxanm.ANM(...), jaxanm.Newton(...), jaxanm.ModifiedNewton(...) or another "
                         f"jaxanm.StepSolver, got {solver!r}")
    scale = np.broadcast_to(np.asarray(1.0 if scale is None else scale, dtype=np.float64), x0.shape).copy()
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise InputError("scale must be positive and finite (a characteristic magnitude per unknown)")
    if jacobian not in ("auto", "dense", "sparse"):
        raise InputError(f"jacobian must be 'auto', 'dense' or 'sparse', got {jacobian!r}")
    if saveat is not None and not isinstance(saveat, SaveAt):
        raise InputError(f"saveat must be jaxanm.SaveAt(ts=..., steps=..., fn=..., params=...), got {saveat!r}")
    if controller is not None and not isinstance(controller, StepController):
        raise InputError(f"controller must be jaxanm.StepController(...) or None, got {controller!r}")
    return x0, scale


def stored_host_state(path):
    """The host state a checkpoint of :func:`integrate` stores (the ``get()`` of its
    ``host_state`` pair at the last checkpointed step), or None if the run kept none."""
    return read(path).get("host_state")


def jacobian_kind(jacobian: str, sparsity, n: int) -> str:
    """``"dense"`` or ``"sparse"``: ``jacobian`` itself, or for ``"auto"`` sparse when a pattern
    is given or there are more than :data:`AUTO_SPARSE_SIZE` unknowns."""
    if jacobian != "auto":
        return jacobian
    return "sparse" if (sparsity is not None or n > AUTO_SPARSE_SIZE) else "dense"


def params_float64(params):
    """Floating leaves of ``params`` as float64; warn when a lower precision was given."""
    lowered = []

    def cast(leaf):
        dtype = np.asarray(leaf).dtype if not hasattr(leaf, "dtype") else leaf.dtype
        if np.issubdtype(dtype, np.floating) and dtype != np.float64:
            lowered.append(str(dtype))
            return jnp.asarray(leaf, dtype=jnp.float64)
        return leaf

    params = jax.tree_util.tree_map(cast, params)
    if lowered:
        warnings.warn(
            f"{len(lowered)} params leaves were {sorted(set(lowered))}, converted to float64; their values "
            "may already have lost precision: build them as numpy float64 or inside jaxanm.float64()",
            stacklevel=3,
        )
    return params


def on_device(params, previous=None):
    """``params`` with every array leaf placed on the device once (``jax.device_put``).

    A jitted call converts each numpy leaf it is given (a copy to the device per leaf and per
    call); a step makes several calls with the same params (residuals, series orders,
    tangents), so the run hands them over as device arrays, converted once per change.

    ``previous``: the device params they replace.  A numpy leaf equal to the device array at
    the same place there (same shape, dtype and values) keeps that array instead of a new
    copy: an ``after_step`` hook that rebuilds its params every step then pays a transfer only
    for what changed (fsw_paper's Lagrangian hook: the points and normals, not its 20 scalar
    constants and the cloud's kinds; 0.15 against 0.44 ms a step, comparisons included).  The
    device values are the same either way.
    """
    if previous is not None:
        leaves, tree = jax.tree.flatten(params)
        old, old_tree = jax.tree.flatten(previous)
        if tree == old_tree:
            kept = [_unchanged(leaf, o) for leaf, o in zip(leaves, old)]
            moved = iter(jax.device_put([leaf for leaf, k in zip(leaves, kept) if k is None]))
            return jax.tree.unflatten(tree, [next(moved) if k is None else k for k in kept])
    return jax.device_put(params)


def _unchanged(leaf, old):
    """The device array to keep for ``leaf``: ``leaf`` itself if on the device already, ``old``
    if ``leaf`` is a numpy array or scalar of its shape, dtype and values; else None."""
    if isinstance(leaf, jax.Array):
        return leaf
    if (isinstance(leaf, (np.ndarray, np.generic)) and isinstance(old, jax.Array) and not old.weak_type
            and old.shape == leaf.shape and old.dtype == leaf.dtype and np.array_equal(np.asarray(old), leaf)):
        return old
    return None


@entry_point
def integrate(residual: Callable, x0, params=None, *, t0: float, t1: float, dt: float, solver,
              scale=None, jacobian: str = "auto", sparsity=None, saveat: SaveAt | None = None,
              after_step: Callable | None = None, progress: bool = False, callback: Callable | None = None,
              max_dt_halvings: int = 4, checkpoint=None, checkpoint_every: int = 0,
              resume: bool = False, host_state: tuple | None = None,
              controller: StepController | None = None, sensitivity: SensitivityMethod | None = None) -> Solution:
    """Integrate ``R(x_new, x_old, t_new, dt, params) = 0`` by implicit Euler steps from t0 to t1.

    Returns a :class:`Solution` (``ts``, ``xs``, ``stats``; ``params``, ``observed`` if asked).
    Raises :class:`InputError` on invalid arguments, before any computation; :class:`StepFailure`
    or :class:`NonFiniteError` when a step failed even after ``max_dt_halvings`` halvings or an
    accepted state or its residual is not finite (message: step, time, a_max, residual norm);
    they (and a ``KeyboardInterrupt``) carry the run's statistics so far as ``stats``.

    Parameters
    ----------
    residual : callable
        ``residual(x_new, x_old, t_new, dt, params) -> (n,)`` in ``jax.numpy``, jet-compatible.
    x0 : array (n,)
        Initial state.
    params : pytree of arrays
        Traced parameters of the residual (changing values never recompiles), put on the device
        once per change: the residual and the hooks receive jax arrays.
    t0, t1, dt : float
        Time span and step; the last step is shortened to end exactly at t1.  With a
        ``controller``, ``dt`` is the first step's size.
    solver : StepSolver
        ``ANM``, ``Newton``, ``ModifiedNewton`` or a user's subclass of :class:`~jaxanm.StepSolver`.
    scale : float or array (n,)
        Characteristic magnitude of each unknown (series norms, Newton convergence test).
    jacobian, sparsity :
        Tangent by dense or coloured compressed ``jacfwd`` (``"dense"``, ``"sparse"``, or ``"auto"``:
        sparse when ``sparsity`` is given or n > 400); ``sparsity``: a scipy sparse pattern, a
        callable ``params -> pattern``, or None (detected from dense probes, small problems).
    saveat : SaveAt, optional
        What is kept (:class:`~jaxanm.SaveAt`): the state at given times (``ts``; the steps nearest
        to them, or with a ``controller`` steps ending exactly on them) or every k-th step
        (``steps``), t0 and t1 always (default: every step); ``params`` also keeps the
        parameters there (e.g. moving point clouds); ``fn(t, x, params) -> dict of arrays`` is
        observed at t0 and after every accepted step (probe histories), returned in
        ``Solution.observed`` as ``{"t": (M,), key: (M, ...)}`` and kept in checkpoints.
    after_step : callable ``(t_new, x_new, params) -> params | Remap(params, x)``
        Host hook after every accepted step (Lagrangian motion, stencil rebuild); :class:`Remap`
        also replaces the state.  The arrays it returns must keep their shapes and dtypes.
    progress, callback :
        A tqdm progress bar (time, steps/s, factorisations); ``callback(t_new, x_new, stats)``
        after every accepted step.
    max_dt_halvings : int
        A failed step is redone as two half steps, recursively up to this depth (with a
        ``controller``: retried at a quarter of its size, at most this many times in a row).
    checkpoint, checkpoint_every, resume :
        Checkpoint file, written atomically every ``checkpoint_every`` steps, at the end, and
        when the run is interrupted (SIGINT, SIGTERM) or fails; ``resume`` continues from it,
        bit-identical to an uninterrupted run (K* re-factorised from its stored matrix, counted
        in ``stats.resumes``, not in ``factorizations``).
    host_state : ``(get, set)`` pair of callables, optional
        State kept on the host outside ``x`` and ``params`` (the FSW recorder): ``get()``, a
        picklable snapshot taken only between steps, goes into every checkpoint; on resume
        ``set(snapshot)`` restores it before the first step.
    controller : StepController, optional
        Adaptive step sizes from a local error estimate (:mod:`jaxanm.step_control`; accepted
        sizes in ``stats.step_sizes``, refused steps in ``stats.rejected_steps``).  None: fixed.
    sensitivity : SensitivityMethod, optional
        Derivatives carried along the steps (:func:`jaxanm.sensitivities` passes a
        :class:`~jaxanm.sensitivity.ForwardSensitivity`): it gets every solved (sub-)step, may
        polish the state the run goes on from, and every accepted step.  Not with
        ``after_step``, a ``controller`` or checkpoints.
    """
    saveat = SaveAt() if saveat is None else saveat
    x0, scale = check_run_inputs(x0, t0, t1, dt, solver, scale, jacobian, saveat, controller)
    _check_run_options(checkpoint, checkpoint_every, resume, host_state, after_step, controller, sensitivity)
    params = on_device(params_float64(params))
    start = time.perf_counter()
    jacobian, sparsity = _tangent_pattern(residual, x0, t0, dt, params, jacobian, sparsity)
    options = _LoopOptions(t0=t0, t1=t1, dt=dt, saveat=saveat, after_step=after_step, progress=progress,
                           callback=callback,
                           max_dt_halvings=max_dt_halvings, checkpoint=checkpoint, checkpoint_every=checkpoint_every,
                           resume=resume, host_state=host_state, controller=controller, sensitivity=sensitivity)
    loop = _TimeLoop(residual, solver, x0, params, scale, jacobian, sparsity, options, start)
    return loop.run()


def _tangent_pattern(residual, x0, t0, dt, params, jacobian: str, sparsity):
    """The tangent's kind (``"dense"`` or ``"sparse"``) and its sparsity pattern: the one given,
    or for a sparse tangent without one, detected from dense probes at the first step."""
    jacobian = jacobian_kind(jacobian, sparsity, x0.size)
    if jacobian == "sparse" and sparsity is None:
        sparsity = detect_sparsity(residual, x0, x0, t0 + dt, dt, params)
    if sparsity is not None and not (callable(sparsity) or scipy.sparse.issparse(sparsity)):
        raise InputError("sparsity must be a scipy sparse matrix or a callable params -> matrix")
    return jacobian, sparsity


def _check_run_options(checkpoint, checkpoint_every, resume, host_state, after_step, controller, sensitivity):
    """Check the options of :func:`integrate` that go together (:class:`InputError`)."""
    if checkpoint_every and checkpoint is None:
        raise InputError("checkpoint_every needs a checkpoint path: pass checkpoint='run.ckpt'")
    if resume and checkpoint is None:
        raise InputError("resume=True needs the checkpoint path to resume from")
    if host_state is not None and not (isinstance(host_state, tuple) and len(host_state) == 2
                                       and all(callable(f) for f in host_state)):
        raise InputError("host_state must be a (get, set) pair of callables")
    if sensitivity is None:
        return
    if not isinstance(sensitivity, SensitivityMethod):
        raise InputError(f"sensitivity must be a jaxanm.SensitivityMethod (e.g. "
                         f"jaxanm.ForwardSensitivity), got {sensitivity!r}")
    if after_step is not None or controller is not None or checkpoint is not None:
        raise InputError("sensitivity cannot be combined with after_step (params changed on the host are not "
                         "differentiable), a controller or checkpoints (the sensitivities are not stored)")


class SensitivityMethod(abc.ABC):
    """Derivatives carried along the steps of :func:`integrate` (its ``sensitivity`` option,
    as diffrax's ``adjoint``): the loop hands it every solved (sub-)step and every accepted
    step; :class:`jaxanm.sensitivity.ForwardSensitivity` is the one in jaxanm."""

    @abc.abstractmethod
    def start(self, problem: Problem, t0: float, x0: np.ndarray, params) -> None:
        """Before the first step: the run's problem and initial state."""

    @abc.abstractmethod
    def after_solve(self, solver: StepSolver, state, x_old, x, t, dt, step: int):
        """After the solver solved the (sub-)step from ``x_old`` to ``x`` (its failures are not
        retried by dt halving): ``(x, |R(x)|_inf, solver state)``, ``x`` as the trajectory goes on."""

    @abc.abstractmethod
    def record(self, t: float, x: np.ndarray, params) -> None:
        """After every accepted step, with the state the run goes on from."""


@dataclasses.dataclass(frozen=True)
class _LoopOptions:
    """The options of one :func:`integrate` run, as documented there."""

    t0: float
    t1: float
    dt: float
    saveat: SaveAt
    after_step: Callable | None
    progress: bool
    callback: Callable | None
    max_dt_halvings: int
    checkpoint: object
    checkpoint_every: int
    resume: bool
    host_state: tuple | None
    controller: StepController | None
    sensitivity: SensitivityMethod | None


class _TimeLoop:
    """One run of :func:`integrate`: what it carries from step to step (``run_state``, a
    :class:`_RunState`, and the solver's ``state``) and how a step is taken, retried and recorded."""

    def __init__(self, residual, solver: StepSolver, x0, params, scale, jacobian, sparsity,
                 options: _LoopOptions, start: float):
        o = self.options = options
        self.solver, self.scale, self.start = solver, scale, start
        self.n_steps = fixed_steps(o.t0, o.t1, o.dt)
        self.fingerprint = {"n": x0.size, "t0": float(o.t0), "t1": float(o.t1), "dt": float(o.dt),
                            "solver": repr(solver), "controller": _describe(o.controller)}
        self.run_state = _RunState(k=0, t=float(o.t0), x=x0, params=params, stats=Stats(), ts=[float(o.t0)],
                                   xs=[x0.copy()], ps=[to_host(params)] if o.saveat.params else None,
                                   observed=_observation(o.saveat.fn, o.t0, x0, params, None))
        kstar = self._resumed() if o.resume and os.path.exists(o.checkpoint) else None
        self.stats = self.run_state.stats
        self.previous_wall = self.stats.wall_time_s
        self.problem = Problem(residual, scale, self.stats, jacobian, sparsity)
        self.state = solver.init(self.problem)
        if kstar is not None:
            self.state = solver.from_checkpoint(self.state, kstar)
            self.stats.resumes += 1
        if o.sensitivity is not None:
            o.sensitivity.start(self.problem, o.t0, x0, params)
        self.saves = o.saveat.fixed(o.t0, o.t1, o.dt)
        self.save_times = sorted({v for v in o.saveat.ts or () if o.t0 < v < o.t1})  # a controller ends on them
        self.bar = _progress_bar(None if o.controller else self.n_steps, o.t1 - o.t0, o.progress,
                                 initial=self.run_state.k)
        self.guard = None

    def _resumed(self):
        """Load the checkpoint into ``run_state`` (and the caller's host state); return what the
        solver stored of its state."""
        o = self.options
        self.run_state, kstar, host = _RunState.load(o.checkpoint, self.fingerprint)
        self.run_state.params = on_device(self.run_state.params)
        if o.host_state is not None:
            if host is None:
                raise InputError(f"checkpoint {o.checkpoint} holds no host state, but this run needs one; "
                                 "it was written by another kind of run: start afresh")
            o.host_state[1](host)
        return kstar

    def run(self) -> Solution:
        """Every step from the run's state to t1; the :class:`Solution`."""
        o, stats, run = self.options, self.stats, self.run_state
        try:
            with sigterm_as_interrupt() as self.guard:
                self._steps()
        except BaseException as exc:
            if isinstance(exc, (StepFailure, KeyboardInterrupt)):
                exc.stats = stats  # the work done until the failure (factorisations, halvings, ...)
            if o.checkpoint is not None and not (self.guard is not None and self.guard.held):
                self._save_checkpoint()  # everything up to the last accepted step (not if recording it failed)
            raise
        finally:
            if self.bar is not None:
                self.bar.close()
            stats.close(self.previous_wall + time.perf_counter() - self.start)
        if o.checkpoint is not None:
            self._save_checkpoint()
        observed = None if o.saveat.fn is None else {key: np.asarray(v) for key, v in run.observed.items()}
        return Solution(ts=np.asarray(run.ts), xs=np.asarray(run.xs), stats=stats, params=run.ps, observed=observed,
                        time_error=run.time_error)

    def _steps(self) -> None:
        """The time steps: fixed ones of dt (the last ending on t1), or sized by the controller."""
        o, run = self.options, self.run_state
        if o.controller is None:
            for k in range(run.k + 1, self.n_steps + 1):
                t_new = step_end(o.t0, o.t1, o.dt, k, self.n_steps)
                x_new, r_norm = self._advance(run.x, run.t, t_new - run.t, k, 0)
                self._record(k, t_new, x_new, r_norm, saved=k in self.saves)
        else:
            while run.t < o.t1:
                k = run.k + 1
                t_new, x_new, r_norm = self._controlled_step(k)
                saved = o.saveat.controlled(k, t_new, o.t1)
                self._record(k, t_new, x_new, r_norm, saved=saved)

    def _advance(self, x, t, h, step, depth):
        """One step of size h, split in halves on failure; returns the state and |R|_inf there.

        The residual of the accepted state is evaluated with the (sub-)step it solved; a
        non-finite state or residual is a :class:`NonFiniteError` (and is halved like any
        failed step).  With a ``sensitivity``, each solved (sub-)step goes to it, outside the
        halving (its own failures are not retried).
        """
        try:
            x_new, r_norm = self._solve_step(x, t, h, step)
        except StepFailure:
            if depth >= self.options.max_dt_halvings:
                raise
            self.stats.dt_halvings += 1
            xm, _ = self._advance(x, t, h / 2, step, depth + 1)
            return self._advance(xm, t + h / 2, h / 2, step, depth + 1)
        sensitivity = self.options.sensitivity
        if sensitivity is not None:
            x_new, r_norm, self.state = sensitivity.after_solve(self.solver, self.state, x, x_new,
                                                                np.float64(t + h), np.float64(h), step)
        return x_new, r_norm

    def _solve_step(self, x, t, h, step):
        """One step of size h by the solver, its accepted state checked (see :meth:`_advance`;
        not with a ``sensitivity``, whose polish takes the state on); the solver's state moves
        on to the one it returned (or, if it failed, left to retry from)."""
        # numpy scalars: a jnp scalar costs a device dispatch per conversion (13 % of a small step)
        t_new, h_new = np.float64(t + h), np.float64(h)
        try:
            x_new, self.state = self.solver.step(self.state, step, x, t_new, h_new, self.run_state.params)
        except StepFailure as failure:
            self.state = self.solver.state_after_failure(self.state, failure)
            raise
        if self.options.sensitivity is not None:
            return x_new, None
        r_new = self.solver.accepted_residual(self.state)
        if r_new is None:
            r_new = self.problem.residual(x_new, x, t_new, h_new, self.run_state.params)
        r_norm = float(np.max(np.abs(r_new)))
        if not (np.isfinite(r_norm) and np.all(np.isfinite(x_new))):
            amax = self.stats.amax[-1] if self.stats.amax else None
            raise NonFiniteError(f"the accepted state has {int(np.sum(~np.isfinite(x_new)))} non-finite "
                                 "entries or a non-finite residual", step=step, t=t_new, amax=amax,
                                 residual_norm=r_norm)
        return x_new, r_norm

    def _controlled_step(self, k):
        """Step k with a controller: sizes by the local error test; returns ``(t_new, x_new,
        r_norm)`` and leaves the next proposal in ``run_state.h_next``."""
        o, run, stats, controller = self.options, self.run_state, self.stats, self.options.controller
        h = run.h_next if run.h_next is not None else float(o.dt)  # the proposed size
        y_now = controller.measured(run.x, run.params) if run.history is not None else None
        failures = 0
        while True:
            # end exactly on the next save time or on t1 when the step reaches it (or falls
            # short of it by a sliver the next step could not resolve)
            t_new = run.t + h
            for end in [v for v in self.save_times if v > run.t][:1] + [float(o.t1)]:
                if t_new >= end - _MIN_STEP * (o.t1 - o.t0):
                    t_new = end
                    break
            size = t_new - run.t
            try:
                x_new, r_norm = self._sized_solve(size, k)
            except StepFailure:
                if failures >= o.max_dt_halvings:
                    raise
                failures += 1
                stats.dt_halvings += 1
                h = controller.clip(size / 4)
                continue
            if y_now is None:  # no earlier step to estimate with: accepted as proposed
                run.h_next = controller.clip(h)
                break
            y_before, h_prev = run.history
            y_new = controller.measured(x_new, run.params)
            local = controller.local_error(y_new, y_now, y_before, size, h_prev)
            err = controller.norm(local, y_new, self.scale)
            # refused: retried from x_n with a smaller step, unless the proposal is already at
            # dt_min (compared before the end-point snapping, which rounds the size)
            if err > 1 and h > controller.dt_min:
                if size <= _MIN_STEP * (o.t1 - o.t0):
                    raise StepFailure(f"the local error test still fails (error {err:.3g} times the tolerance) "
                                      f"at a step of {size:.3g}: give the controller a larger rtol/atol or a "
                                      "dt_min at which to accept such steps", step=k, t=t_new)
                stats.rejected_steps += 1
                h = controller.propose(size, err)
                continue
            run.h_next = controller.next_size(size, err)
            run.time_error = local if run.time_error is None else run.time_error + local
            break
        run.history = (y_now if y_now is not None else controller.measured(run.x, run.params), size)
        stats.step_sizes.append(size)
        return t_new, x_new, r_norm

    def _sized_solve(self, size, k):
        """:meth:`_solve_step` of step k, of size ``size`` from the run's state, with a
        controller: a K* the solver carries from a step size more than the controller's
        ``refactor_ratio`` away is dropped first (its factors freed), and the step size of the
        K* the solver holds afterwards is kept in ``run_state.kstar_dt``."""
        run, solver = self.run_state, self.solver
        kstar = solver.factorization(self.state) if solver.reuses_factorization else None
        if kstar is not None and run.kstar_dt is not None:
            if max(size / run.kstar_dt, run.kstar_dt / size) > self.options.controller.refactor_ratio:
                kstar.release()  # before the solver makes the next: one LU alive
                self.state = solver.with_factorization(self.state, None)
                kstar = None
        try:
            return self._solve_step(run.x, run.t, size, k)
        finally:  # a failed step may leave a K* it made for the retry (state_after_failure)
            if solver.factorization(self.state) is not kstar:
                run.kstar_dt = size

    def _save_checkpoint(self) -> None:
        """Write the run's state, what the solver stores of its state and the host state."""
        host_state = self.options.host_state
        self.stats.close(self.previous_wall + time.perf_counter() - self.start)
        self.run_state.dump(self.options.checkpoint, self.fingerprint, self.solver.to_checkpoint(self.state),
                            host=None if host_state is None else host_state[0]())

    def _record(self, k, t_new, x_new, r_norm, saved):
        """Hand an accepted step to the hooks and record it (signals wait meanwhile)."""
        o, run, stats = self.options, self.run_state, self.stats
        self.guard.hold()  # from here to release(): signals wait, the step is recorded whole
        stats.residual_norm.append(r_norm)
        stats.time_steps += 1
        params_new = run.params if o.after_step is None else o.after_step(t_new, x_new, run.params)
        if isinstance(params_new, Remap):
            if not params_new.history:
                run.history = None
            params_new, x_new = params_new.params, _remapped_state(params_new.x, x_new)
        if params_new is not run.params:
            params_new = on_device(params_new, run.params)
        run.advance(k, t_new, x_new, params_new, saved=saved, observe=o.saveat.fn)
        if o.sensitivity is not None:
            o.sensitivity.record(t_new, x_new, run.params)
        self.guard.release()
        if o.callback is not None:
            o.callback(t_new, x_new, stats)
        if self.bar is not None:
            self.bar.update(1)
            self.bar.set_postfix(t=f"{t_new:.4g}", factorizations=stats.factorizations, refresh=False)
        if o.checkpoint_every and k % o.checkpoint_every == 0:
            self._save_checkpoint()


_MIN_STEP = 1e-12
"""A step refused by the error test below this fraction of the span is a failure (the error
estimate is then round-off or a discontinuity, not the time discretisation)."""


def _describe(controller) -> dict | None:
    """The controller's settings for a checkpoint's fingerprint (its error_map by name: a
    function's repr holds its address, which differs from process to process)."""
    if controller is None:
        return None
    d = {f.name: getattr(controller, f.name) for f in dataclasses.fields(controller) if f.name != "error_map"}
    d["error_scale"] = None if controller.error_scale is None else np.asarray(controller.error_scale).tolist()
    em = controller.error_map
    d["error_map"] = None if em is None else getattr(em, "__qualname__", type(em).__name__)
    return d


def _remapped_state(x, like):
    """The state an ``after_step`` hook returned in :class:`Remap`, checked like ``x0``."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape != like.shape or not np.all(np.isfinite(x)):
        raise InputError(f"after_step returned a Remap state of shape {x.shape} with "
                         f"{int(np.sum(~np.isfinite(x)))} non-finite entries; it must be finite with shape {like.shape}")
    return x


def _observation(observe, t, x, params, observed):
    """Append ``observe(t, x, params)`` to the lists of ``observed`` (created on first call)."""
    if observe is None:
        return None
    values = observe(t, x, params)
    if observed is None:
        observed = {"t": [], **{key: [] for key in values}}
    observed["t"].append(float(t))
    for key, value in values.items():
        observed[key].append(np.asarray(value))
    return observed


@dataclasses.dataclass
class _RunState:
    """Everything a run carries from step to step (and what a checkpoint stores)."""

    k: int
    t: float
    x: np.ndarray
    params: object
    stats: Stats
    ts: list
    xs: list
    ps: list | None
    observed: dict | None
    h_next: float | None = None  # with a controller: the size proposed for the next step
    history: tuple | None = None  # with a controller: (measured state before the last step, its size)
    kstar_dt: float | None = None  # with a controller: the step size the solver's K* was made at
    time_error: np.ndarray | None = None  # with a controller: the sum of the local error estimates

    def advance(self, k, t, x, params, *, saved: bool, observe) -> None:
        """Record an accepted step."""
        self.k, self.t, self.x, self.params = k, t, x, params
        if saved:
            self.ts.append(t)
            self.xs.append(x.copy())
            if self.ps is not None:
                self.ps.append(to_host(params))  # numpy, as the user gave them
        self.observed = _observation(observe, t, x, params, self.observed)

    def dump(self, path, fingerprint: dict, kstar, host=None) -> None:
        """Write the state, what the solver stores of its state (``kstar``: the matrix of the K*
        it carries, or None) and the caller's host state to a checkpoint file."""
        payload = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        payload.update(fingerprint=fingerprint, kstar=kstar, params=to_host(self.params), host_state=host)
        payload["ps"] = None if self.ps is None else [to_host(p) for p in self.ps]
        write_atomic(path, payload)

    @classmethod
    def load(cls, path, fingerprint: dict):
        """Read a checkpoint; refuse one written by a different run."""
        payload = read(path)
        if payload["fingerprint"] != fingerprint:
            raise InputError(
                f"checkpoint {path} belongs to another run ({payload['fingerprint']}), not to this one "
                f"({fingerprint}); use a fresh output directory or the same settings"
            )
        fields = {f.name: payload[f.name] for f in dataclasses.fields(cls) if f.name in payload}
        return cls(**fields), payload["kstar"], payload.get("host_state")


def _progress_bar(n_steps, span, enabled, initial=0):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=n_steps, initial=initial, unit="step", desc=f"t span {span:.4g} s", dynamic_ncols=True)
