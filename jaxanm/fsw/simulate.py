"""Run an FSW scene: :func:`run` from a :class:`~jaxanm.fsw.scene.Scene` to an
:class:`~jaxanm.fsw.record.FSWResult`.

:func:`run` discretises the scene (:func:`~jaxanm.fsw.discretisation.discretise`: cloud, MLS
stencils, :class:`~jaxanm.fsw.discretisation.Model`), optionally solves the quasi-static start
flow (:mod:`jaxanm.fsw.start`: by damped Newton or by continuation), and calls :func:`jaxanm.integrate` with the scene's
:class:`jaxanm.SaveAt`, its step controller, its time scheme and the host hook of
:mod:`jaxanm.fsw.lagrangian` (records, Lagrangian motion, rezoning) after every accepted step;
the hook's state is checkpointed with the run.

A scheme other than implicit Euler builds its stages from the model's residual in
semi-discrete form: on fixed points the FSW step residual depends on the old state only
through the difference quotients of its MLS values (``dT/dt`` and, with inertia, ``dV/dt``),
so it is its own stage residual (:class:`jaxanm.SemiDiscrete`, ``step_residual``; the claim
is checked on the FSW rows in ``tests/test_ida.py``).
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Callable

import jaxanm

from ..errors import run_stopped
from .discretisation import Model, discretise
from .lagrangian import RunRecorder, motion_dt_max
from .record import FSWResult
from .scene import Scene
from .stability import TemperatureGuard
from .start import continuation_state, quasi_static_state

_STARTS = {"quasi_static": quasi_static_state, "continuation": continuation_state}
"""The solvers of the start flow per ``mechanics.start`` ("rest" solves none)."""

__all__ = ["run", "scene_differences", "step_controller"]


def step_controller(scene: Scene, model: Model):
    """The :class:`jaxanm.StepController` of a scene with ``time.adaptive`` (else None).

    The local error is measured in the values of the differential fields at the points: T
    with conduction (its scale T0), else the velocity (scale omega R1).  The velocity of a
    conducting scene is quasi-static, algebraic up to the small inertia term, and is left out
    as IDA leaves algebraic components out of its error test: carried by moving points it is
    off the field at their new place by ``dt |DV/Dt|`` after each move (2e-3 of omega R1 at
    fsw_paper's dt), which no smaller next step reduces.  Values at the points, not nodal
    parameters: a Lagrangian cloud's parameters jump at every stencil rebuild, its values do
    not.  Steps are bounded by :func:`motion_dt_max` when the points move, and by
    ``time.dt_max`` when it is set.
    """
    tm = scene.time
    if not tm.adaptive:
        return None
    fields = model.fields
    measured = [fields.index("T")] if "T" in fields else [fields.index(f) for f in ("u", "v")]
    scale = model.scale().reshape(len(fields), -1)[measured].ravel()
    return jaxanm.StepController(
        rtol=tm.rtol, atol=tm.atol,
        dt_max=min(motion_dt_max(scene) if model.effects.lagrangian else math.inf, tm.dt_max or math.inf),
        error_map=lambda x, p: model.values(x, p["st"])[:, measured].T.ravel(), error_scale=scale)


def _host_state(scene: Scene, recorder: RunRecorder, settings: dict):
    """The ``(get, set)`` pair :func:`jaxanm.integrate` stores in / restores from its checkpoints.

    The snapshot is ``{"scene": scene.to_dict(), "settings": settings, "recorder":
    recorder.to_checkpoint()}`` (the recorder's versioned layout: moving points, time, probe
    histories, saved fields, sections, tracers).  ``set`` refuses a checkpoint written for
    another scene (:class:`jaxanm.InputError` naming the differing fields) or with another
    recorder layout.
    """
    def get():
        return {"scene": scene.to_dict(), "settings": dict(settings), "recorder": recorder.to_checkpoint()}

    def set_(state):
        stored = state.get("scene") if isinstance(state, dict) else None
        if stored != scene.to_dict():
            raise jaxanm.InputError(f"the checkpoint was written for another scene ({scene_differences(stored, scene)} "
                                    "differ); resume with the scene it stores, or start afresh")
        recorder.from_checkpoint(state["recorder"])

    return get, set_


def _recording(scene: Scene, model: Model, stencils, x0, controller, initial, start):
    """The run's :class:`jaxanm.SaveAt` (the scene's save times; with ``time.probe_dt`` the
    probes observed on the scheme's dense output at its probe times) and its recorder."""
    tm = scene.time
    saveat = jaxanm.SaveAt(ts=tuple(t for t in tm.save_times if t > 0))
    save_times = saveat.times(0.0, tm.t_end, tm.dt, adaptive=controller is not None)
    recorder = RunRecorder(scene, model, stencils, x0, save_times, initial=initial, start=start)
    if tm.probe_dt > 0:
        saveat = dataclasses.replace(saveat, fn=recorder.observe_probes, fn_ts=tm.probe_times)
    return saveat, recorder


def scene_differences(stored, scene: Scene) -> str:
    """Comma-separated dotted keys whose values differ between a stored scene dict and ``scene``."""
    if not isinstance(stored, dict):
        return "no scene stored"
    mine = scene.to_dict()
    keys = []
    for key in sorted(set(stored) | set(mine)):
        a, b = stored.get(key), mine.get(key)
        if isinstance(a, dict) and isinstance(b, dict):
            keys += [f"{key}.{k}" for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)]
        elif a != b:
            keys.append(key)
    return ", ".join(keys) or "none"


def run(scene: Scene, solver=None, progress: bool = False, callback: Callable | None = None, *,
        checkpoint=None, checkpoint_every: int = 0, resume: bool = False) -> FSWResult:
    """Simulate ``scene`` from t = 0 to ``scene.time.t_end``; return an :class:`FSWResult`.

    Parameters
    ----------
    scene : Scene
        A validated scene (:func:`~jaxanm.fsw.scene.load_scene`, ``Scene(...)``).
    solver : jaxanm.ANM | jaxanm.Newton | jaxanm.ModifiedNewton, optional
        Step solver; default ``scene.solver.make()``.
    progress : bool
        Show a progress bar.
    callback : callable ``(t, stats)``, optional
        Called after every accepted step with the time reached and the run's ``jaxanm.Stats``
        so far (e.g. a progress display).
    checkpoint : path, optional
        Checkpoint file (written atomically every ``checkpoint_every`` steps, at the end, and
        when the run is interrupted or fails).  Besides integrate's state it holds the scene
        and the host-side recorder (moving points, probe histories, saved fields, sections,
        tracers), so a resumed run returns the same result as an uninterrupted one.
    checkpoint_every : int
        Checkpoint period in time steps (0: only at the end, on interruption and on failure).
    resume : bool
        Continue from ``checkpoint`` if it exists (bit-identical to an uninterrupted run).

    Raises
    ------
    jaxanm.StepFailure, jaxanm.NonFiniteError
        A step failed even after dt halvings (the message gives step, time, a_max and |R|).
    jaxanm.InputError
        Bad checkpoint options, or a checkpoint written for another scene or solver.
    KeyboardInterrupt
        The run was interrupted (SIGINT, or SIGTERM as :class:`jaxanm.checkpoint.Interrupted`);
        the exception (a :class:`jaxanm.errors.RunInterrupted`) carries ``partial``: the
        :class:`FSWResult` of the steps done so far (also a :class:`jaxanm.StepFailure`'s: both are
        :class:`jaxanm.errors.RunStopped`).
    """
    solver = scene.solver.make() if solver is None else solver
    scheme = jaxanm.make_scheme(scene.time.scheme)  # the scene refuses one its points cannot serve
    _, stencils, model, params, x0 = discretise(scene)
    # the FSW step residual on fixed points is its own stage residual (module docstring)
    residual = model.residual if scheme.one_step else jaxanm.SemiDiscrete(step_residual=model.residual)
    initial, start = None, None
    resuming = resume and checkpoint is not None and os.path.exists(checkpoint)
    if scene.mechanics.start in _STARTS and not resuming:  # a resumed run's state is in its checkpoint
        x0, start = _STARTS[scene.mechanics.start](scene, model, stencils)
        initial = model.values(x0, stencils)
    tm = scene.time
    controller = step_controller(scene, model)
    saveat, recorder = _recording(scene, model, stencils, x0, controller, initial, start)
    latest = {"stats": jaxanm.Stats()}
    # a temperature outside the range the continuum keeps it in ends the run, named
    guard = TemperatureGuard.for_model(model, params, x0)

    def step_done(t, x, stats):
        latest["stats"] = stats
        if guard is not None:
            guard(t, x, stats)
        if callback is not None:
            callback(t, stats)

    host = None if checkpoint is None else _host_state(scene, recorder, {"checkpoint_every": int(checkpoint_every)})
    try:
        sol = jaxanm.integrate(residual, x0, params, t0=0.0, t1=tm.t_end, dt=tm.dt, solver=solver, scheme=scheme,
                               scale=model.scale(), jacobian="sparse", sparsity=model.sparsity,
                               saveat=saveat, after_step=recorder.after_step,
                               progress=progress, callback=step_done, checkpoint=checkpoint,
                               checkpoint_every=checkpoint_every, resume=resume, host_state=host,
                               controller=controller)
    except (KeyboardInterrupt, jaxanm.StepFailure) as caught:
        exc = run_stopped(caught)  # an interrupt before integrate's loop carries nothing yet
        try:  # the steps recorded so far (integrate defers signals while recording), with integrate's
            # statistics: they count the work of the step it stopped in, which no callback reported
            partial = recorder.result(solver, latest["stats"] if exc.stats is None else exc.stats)
        except Exception:  # noqa: BLE001 - a broken recorder must not hide the original error
            raise exc from caught.__cause__
        raise exc.carrying(partial=partial) from caught.__cause__
    return recorder.result(solver, sol.stats, sol.time_error)
