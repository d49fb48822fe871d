"""The public entry of the time loop: :func:`integrate` (the steps of a time scheme, implicit
Euler by default, each stage solved by a step solver: ANM, Newton, ...) and its
:class:`Solution`.

It is the only time loop (:mod:`jaxanm._loop`): fixed and adaptive steps are two controllers
of it, and forward sensitivities ride on it (its ``sensitivity`` option)."""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

import numpy as np

from ._constant_step import ConstantStepSize
from ._hooks import Remap, no_callback, same_params
from ._loop import LoopOptions, TimeLoop
from ._run_checkpoint import Checkpoints
from ._run_inputs import check_run_inputs, check_run_options, check_scheme, on_device, params_float64, tangent_pattern
from ._saveat import SaveAt
from ._scheme import SemiDiscrete, TimeScheme
from ._sensitivity_method import NoSensitivity, SensitivityMethod
from ._step_size import Span, StepSizeController
from ._x64 import entry_point
from .stats import Stats

__all__ = ["Remap", "Solution", "integrate"]


@dataclasses.dataclass
class Solution:
    """Result of :func:`integrate`: saved times ``ts (S,)``, states ``xs (S, n)``, ``stats``.

    ``params`` holds the parameter pytree at each saved time when ``SaveAt(params=True)``
    (e.g. moving Lagrangian point clouds), else ``None``; ``observed`` the quantities recorded
    by ``SaveAt(fn=...)`` at every step (``{"t": (M,), key: (M, ...)}``), else ``None``.
    ``time_error``: with a :class:`~jaxanm.StepController`, an estimate of the time
    discretisation's error at t1 in the quantities it measures (its ``error_map``): the sum of
    the local error estimates of the accepted steps (the scheme's estimate).  It leaves out how
    earlier errors propagate: where they decay (diffusion) and the local errors keep their
    sign, it errs on the large side.  The first step, and the first after a
    ``Remap(history=False)``, have no estimate and add nothing (and so do the first two of
    BDF2).  None with fixed steps.
    """

    ts: np.ndarray
    xs: np.ndarray
    stats: Stats
    params: list | None = None
    observed: dict | None = None
    time_error: np.ndarray | None = None


@entry_point
def integrate(residual: Callable | SemiDiscrete, x0, params=None, *, t0: float, t1: float, dt: float, solver,
              scale=None, jacobian: str = "auto", sparsity=None, saveat: SaveAt | None = None,
              after_step: Callable | None = None, progress: bool = False, callback: Callable | None = None,
              max_dt_halvings: int = 4, checkpoint=None, checkpoint_every: int = 0, resume: bool = False,
              host_state: tuple | None = None, controller: StepSizeController | None = None,
              sensitivity: SensitivityMethod | None = None, scheme: TimeScheme | None = None) -> Solution:
    """Integrate ``R(x_new, x_old, t_new, dt, params) = 0`` by implicit Euler steps from t0 to t1,
    or ``F(u, u_dot, t, params) = 0`` by the steps of a time ``scheme``.

    Returns a :class:`Solution`.  Raises :class:`InputError` on invalid arguments, before any
    computation; :class:`StepFailure` or :class:`NonFiniteError` when a step failed even after
    ``max_dt_halvings`` retries or an accepted state or its residual is not finite (message: step,
    time, a_max, residual norm), with the run's ``stats`` so far (as an interrupt: ``errors.RunInterrupted``).

    Parameters
    ----------
    residual : callable or SemiDiscrete
        ``residual(x_new, x_old, t_new, dt, params) -> (n,)``, one implicit-Euler step's, in
        ``jax.numpy``, jet-compatible; or a :class:`~jaxanm.SemiDiscrete` (any ``scheme``).
    x0, params : array (n,), pytree of arrays
        Initial state; traced parameters of the residual (changing values never recompiles), put
        on the device once per change: the residual and the hooks receive jax arrays.
    t0, t1, dt : float
        Time span and step; the last step is shortened to end exactly at t1.  With a
        :class:`~jaxanm.StepController`, ``dt`` is the first step's size.
    solver : StepSolver
        ``ANM``, ``Newton``, ``ModifiedNewton`` or a user's subclass of :class:`~jaxanm.StepSolver`.
    scale : float or array (n,)
        Characteristic magnitude of each unknown (series norms, Newton convergence test).
    jacobian, sparsity :
        ``"dense"``, ``"sparse"`` (coloured compressed ``jacfwd``) or ``"auto"`` (sparse when ``sparsity``
        is given or n > 400); ``sparsity``: a scipy sparse pattern, a callable ``params -> pattern``,
        or None (found from the residual's jaxpr).
    saveat : SaveAt, optional
        What is kept (:class:`~jaxanm.SaveAt`): the state at given times ``ts`` (the steps nearest
        to them; with a ``StepController``, steps ending on them) or every k-th step (``steps``),
        t0 and t1 always (default: every step); ``params`` keeps the parameters there too (moving
        clouds); ``fn(t, x, params) -> dict of arrays`` is observed at t0 and after every accepted
        step, returned in ``Solution.observed`` (``{"t": (M,), key: (M, ...)}``) and checkpointed.
    after_step : callable ``(t_new, x_new, params) -> params | Remap(params, x)``
        Host hook after every accepted step (Lagrangian motion, stencil rebuild); :class:`Remap`
        also replaces the state.  The arrays it returns must keep their shapes and dtypes.
    progress, callback :
        A tqdm progress bar; ``callback(t_new, x_new, stats)`` after every accepted step.
    max_dt_halvings : int
        Retries of a failed step: fixed steps halve it, recursively up to this depth; a
        ``StepController`` retries it at a quarter of its size, at most this many times in a row.
    checkpoint, checkpoint_every, resume :
        Checkpoint file, written atomically every ``checkpoint_every`` steps, at the end, and
        when the run is interrupted (SIGINT, SIGTERM) or fails; ``resume`` continues from it,
        bit-identical to an uninterrupted run (K* re-factorised from its stored matrix, counted
        in ``stats.resumes``, not in ``factorizations``; :func:`jaxanm.stored_host_state`).
    host_state : ``(get, set)`` pair of callables, optional
        State kept on the host outside ``x`` and ``params`` (the FSW recorder): ``get()``, a
        snapshot taken only between steps, goes into every checkpoint; on resume
        ``set(snapshot)`` restores it before the first step (plain data, arrays: :mod:`jaxanm.checkpoint`).
    controller : StepController or ConstantStepSize, optional
        Fixed steps (None: :class:`~jaxanm.ConstantStepSize`) or :class:`~jaxanm.StepController`'s.
    sensitivity : SensitivityMethod, optional
        Derivatives carried along the steps (:func:`jaxanm.sensitivities` passes a
        :class:`~jaxanm.sensitivity.ForwardSensitivity`): it gets every solved (sub-)step, may
        polish the state the run goes on from, and every accepted step.  Implicit Euler only,
        without ``after_step``, a ``StepController`` or checkpoints.
    scheme : TimeScheme, optional
        :class:`~jaxanm.ImplicitEuler` (default), :class:`~jaxanm.BDF2` or :class:`~jaxanm.ESDIRK`:
        its implicit-Euler-shaped stages are solved by ``solver``, it gives a ``StepController`` its
        estimate and order, a :class:`Remap` restarts it; all but implicit Euler need a ``SemiDiscrete``.
    """
    saveat = SaveAt() if saveat is None else saveat
    x0, scale = check_run_inputs(x0, t0, t1, dt, solver, scale, jacobian, saveat, controller)
    check_run_options(checkpoint, checkpoint_every, resume, host_state, after_step, controller, sensitivity)
    residual, scheme = check_scheme(residual, scheme, sensitivity)
    params = on_device(params_float64(params))
    start = time.perf_counter()
    jacobian, sparsity = tangent_pattern(residual, x0, t0, dt, params, jacobian, sparsity)
    options = _options(x0, solver, saveat, controller, sensitivity, scheme, t0=t0, t1=t1, dt=dt, after_step=after_step,
                       callback=callback, progress=progress, max_dt_halvings=max_dt_halvings, checkpoint=checkpoint,
                       checkpoint_every=checkpoint_every, resume=resume, host_state=host_state)
    state, stats = TimeLoop(residual, solver, x0, params, scale, jacobian, sparsity, saveat, options, start).run()
    return _solution(state, stats, options.controller)


def _options(x0, solver, saveat, controller, sensitivity, scheme, *, t0, t1, dt, after_step, callback, progress,
             max_dt_halvings, checkpoint, checkpoint_every, resume, host_state) -> LoopOptions:
    """The loop's options (:func:`integrate`'s), with the do-nothing defaults in place of None."""
    controller = ConstantStepSize() if controller is None else controller
    fingerprint = {"n": x0.size, "t0": float(t0), "t1": float(t1), "dt": float(dt), "solver": repr(solver),
                   "controller": controller.describe(), "scheme": repr(scheme)}
    return LoopOptions(
        span=Span(t0, t1, dt, saveat, max_dt_halvings, scheme), controller=controller,
        after_step=same_params if after_step is None else after_step,
        callback=no_callback if callback is None else callback, progress=progress,
        checkpoints=Checkpoints(checkpoint, checkpoint_every, resume, host_state, fingerprint),
        sensitivity=NoSensitivity() if sensitivity is None else sensitivity)


def _solution(state, stats: Stats, controller: StepSizeController) -> Solution:
    """The :class:`Solution` of a run that ended in ``state`` (a :class:`~jaxanm._loop_state.LoopState`)."""
    kept = state.kept
    observed = None if kept.observed is None else {key: np.asarray(log.tolist()) for key, log in kept.observed.items()}
    return Solution(ts=np.asarray(kept.ts.tolist()), xs=np.asarray(kept.xs.tolist()), stats=stats,
                    params=None if kept.ps is None else kept.ps.tolist(), observed=observed,
                    time_error=controller.time_error(state.controller_state))
