"""Run an FSW scene: cloud, model, time integration, Lagrangian motion, probes and sections.

:func:`run` builds the point cloud and MLS stencils of a :class:`~jaxanm.fsw.scene.Scene`,
its :class:`~jaxanm.fsw.discretisation.Model`, and calls :func:`jaxanm.integrate` with a host hook
after every accepted step that

- evaluates the fields at the points (MLS is not interpolating: values, not nodal parameters);
- records the registration points (probes: material points, followed as they move) and, at
  the save times, the fields and the registration sections;
- with ``lagrangian``: moves the points (tool and tool-edge points rotate rigidly by
  ``omega dt``, exactly; plate points ``x <- x + dt V``), rebuilds the stencils with the same
  width (nothing recompiles) and refits the unknowns so that the new stencils reproduce the
  values the points carry (:class:`jaxanm.Remap`);
- with ``lagrangian`` and ``geometry.rezone > 0``: when the cloud has sheared too far (some
  plate point's nearest neighbour is closer than ``rezone`` times its distance at the last
  seeding), re-seeds the plate points at their initial layout, with the values the current
  solution has there (:func:`_rezone`).  From the first rezoning on, the computational points
  (``nodes``) and the material points (``points``, which carry the colours and the probes)
  differ: the material points are then advected like tracers, through the moving cloud.
- with ``tracers``: advects passive tracer particles (initially at the points) through the
  fixed cloud, for the mixing picture.
"""

from __future__ import annotations

import dataclasses
import math
import os
from typing import Callable

import numpy as np
from scipy.spatial import cKDTree

import jaxanm

from .discretisation import Model, Refit, discretise
from .geometry import PLATE, build_stencils, evaluate_stencils, neighbour_list, rigid
from .scene import Scene
from .start import StartReport, quasi_static_state

__all__ = ["FSWResult", "run"]


@dataclasses.dataclass
class FSWResult:
    """Result of :func:`run` (see docs/architecture.md).

    Attributes
    ----------
    scene : Scene
    t : (S,) saved times (0, the scene's save times within t_end, t_end).
    points : (S, N, 2) material point positions at the saved times (they move in Lagrangian
        scenes; they start at the cloud's points).
    u, v, T : (S, N) field values at the points (u = v = 0 without ``viscous``;
        T = T0 without ``conduction``).
    material : (N,) int, 0 tool, 1 plate y > 0 ("blue"), 2 plate y < 0 ("red").
    probes : ``{"t": (M,), name: {"x", "y", "u", "v", "T": (M,)}}`` at t = 0 and every accepted
        step; each registration point is the plate point nearest the scene's probe position
        at t = 0, followed as it moves.
    sections : ``{"t": (S,), name: {"x", "y", "s": (P,), "u", "v", "T": (S, P)}}``: MLS values
        along each registration section at the saved times (``s`` is the abscissa along the
        segment, from its start).
    stats : jaxanm.Stats of the run.
    solver : the solver options used (``jaxanm.ANM``, ``Newton`` or ``ModifiedNewton``).
    tracers : with the ``tracers`` effect, ``{"points": (S, N, 2), "material": (N,)}``: passive
        particles started at the points, advected by the flow; else None.
    nodes : (S, N, 2) positions of the computational points at the saved times when a
        Lagrangian run was rezoned (they differ from ``points`` from the first rezoning on);
        else None (the nodes are the material points).
    rezone_times : times at which the plate points were re-seeded (empty without rezoning).
    start : with ``mechanics.start = "quasi_static"``, the :class:`~jaxanm.fsw.start.StartReport`
        of the flow solved at t = 0 (its factorisations are not in ``stats``); else None.
    """

    scene: Scene
    t: np.ndarray
    points: np.ndarray
    u: np.ndarray
    v: np.ndarray
    T: np.ndarray
    material: np.ndarray
    probes: dict
    sections: dict
    stats: jaxanm.Stats
    solver: object
    tracers: dict | None = None
    nodes: np.ndarray | None = None
    rezone_times: list = dataclasses.field(default_factory=list)
    start: StartReport | None = None


def _rotate(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return points @ np.array([[c, s], [-s, c]])


def _move(points: np.ndarray, kind: np.ndarray, velocity: np.ndarray, omega: float, dt: float) -> np.ndarray:
    """Material motion over dt: tool and edge points rotate rigidly, the others follow V."""
    return np.where(rigid(kind)[:, None], _rotate(points, omega * dt), points + dt * velocity)


def _velocity(values: dict) -> np.ndarray:
    """(N, 2) velocity from the ``{"u", "v", "T"}`` values."""
    return np.stack([values["u"], values["v"]], axis=1)


def probe_points(scene: Scene, cloud) -> dict:
    """``{probe name: index of the plate point nearest its position}``: the registration points
    of a run (and of :func:`jaxanm.fsw.ida_scene.run_ida`), chosen on the initial cloud."""
    plate = np.flatnonzero(cloud.kind == PLATE)
    return {p.name: int(plate[np.argmin(np.hypot(*(cloud.points[plate] - (p.x, p.y)).T))]) for p in scene.probes}


def _nearest_spacing(points: np.ndarray) -> np.ndarray:
    """Distance from each point to its nearest other point."""
    return cKDTree(points).query(points, 2)[0][:, 1]


class _Recorder:
    """Host-side state of a run: moving cloud, material points, probes, saved fields and sections."""

    def __init__(self, scene: Scene, model: Model, stencils, x0: np.ndarray, save_times: frozenset,
                 initial: np.ndarray | None = None, start: StartReport | None = None):
        # save_times: the end times of the saved steps, from the run's jaxanm.SaveAt (SaveAt.times);
        # initial: field values (N, len(fields)) at the points at t = 0 (default: the model's rest
        # state); start: the StartReport of a quasi-static start
        self.scene, self.model, self.save_times = scene, model, save_times
        cloud = model.cloud
        self.points = cloud.points.copy()
        self.width = stencils.index.shape[1]
        self.t = 0.0
        self.probe_index = probe_points(scene, cloud)
        self.section_points = {s.name: np.linspace(s.start, s.end, s.samples) for s in scene.sections}
        self.probes = {"t": [], **{name: {k: [] for k in "xyuvT"} for name in self.probe_index}}
        self.saved = {"t": [], "points": [], "nodes": [], "u": [], "v": [], "T": []}
        self.sections = {"t": [], **{name: {k: [] for k in "uvT"} for name in self.section_points}}
        self.tracers = cloud.points.copy() if model.effects.tracers else None
        self.tracer_saves = []
        # Rezoning: the material points separate from the nodes at the first re-seeding.
        self.markers = None
        self.rezone_times = []
        self.seeded_spacing = _nearest_spacing(self.points[cloud.n_tool:])
        # Lagrangian rebuilds: neighbour candidates (of the nodes, the material points after a
        # rezoning, the tracers) and the refit's factorisation, carried from step to step (and
        # through checkpoints)
        self.neighbours = neighbour_list(scene.geometry)
        self.marker_neighbours = neighbour_list(scene.geometry)
        self.tracer_neighbours = neighbour_list(scene.geometry)
        self.refit = Refit()
        self.start = start
        self._save_sections(x0)
        if initial is None:
            initial = model.initial_values(self.points)
        self._record(0.0, self.points, model.full_values(initial), save=True)

    def _record(self, t: float, positions: np.ndarray, values: dict, save: bool) -> None:
        """Probe values at every step; fields (and tracers) at the save steps.

        ``positions`` and ``values``: the material points and the fields there.
        """
        self.probes["t"].append(t)
        for name, i in self.probe_index.items():
            rec = self.probes[name]
            rec["x"].append(positions[i, 0])
            rec["y"].append(positions[i, 1])
            for k in "uvT":
                rec[k].append(values[k][i])
        if save:
            self.saved["t"].append(t)
            self.saved["points"].append(positions.copy())
            self.saved["nodes"].append(self.points.copy())
            for k in "uvT":
                self.saved[k].append(values[k].copy())
            if self.tracers is not None:
                self.tracer_saves.append(self.tracers.copy())

    def _save_sections(self, x) -> None:
        """MLS values along the sections, from unknowns ``x`` on the cloud they were solved on."""
        self.sections["t"].append(self.t)
        for name, targets in self.section_points.items():
            sec = self._values_at(x, targets)
            for k in "uvT":
                self.sections[name][k].append(sec[k])

    def _values_at(self, x, targets: np.ndarray, neighbours=None) -> dict:
        """Full field values at arbitrary ``targets`` from unknowns ``x`` on the current nodes
        (``neighbours``: candidate lists kept for these targets, see :func:`neighbour_list`)."""
        st = evaluate_stencils(self.points, self.model.cloud.n_tool, self.scene.geometry, targets,
                               derivatives=False, neighbours=neighbours)  # values only: 2x cheaper
        return self.model.full_values(self.model.values(x, st))

    def _advected(self, particles: np.ndarray, x, dt: float) -> np.ndarray:
        """Passive particles moved over dt by the flow of unknowns ``x`` on the current nodes."""
        v = self._values_at(x, particles, self.tracer_neighbours)
        return _move(particles, self.model.cloud.kind, _velocity(v), self.scene.tool.omega, dt)

    def _marker_values(self, node_values: dict, at_free: dict) -> dict:
        """Fields at the material points: the nodes' own values where they coincide (tool and
        tool-edge points, never re-seeded), elsewhere the MLS values ``at_free`` at the other
        (free) material points, in their order."""
        free = ~rigid(self.model.cloud.kind)
        out = {k: v.copy() for k, v in node_values.items()}
        for k in "uvT":
            out[k][free] = at_free[k]
        return out

    def _sheared(self, index: np.ndarray | None = None) -> bool:
        """Whether some plate point is closer to its nearest neighbour than ``rezone`` times
        its distance at the last seeding (never without ``geometry.rezone``).

        ``index``: the stencils' neighbour indices on the current points, if on hand (nearest
        first, so ``index[i, 1]`` is the point nearest to i; plate stencils hold only plate
        points): the same nearest distances as a cKDTree of the plate points, without
        building one.  Without it, that cKDTree.
        """
        fraction = self.scene.geometry.rezone
        if fraction <= 0:
            return False
        n_tool = self.model.cloud.n_tool
        if index is None:
            spacing = _nearest_spacing(self.points[n_tool:])
        else:
            plate = np.arange(n_tool, self.points.shape[0])
            d = self.points[index[plate, 1]] - self.points[plate]
            spacing = np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])
        return bool(np.any(spacing < fraction * self.seeded_spacing))

    def _rezone(self, x, values: np.ndarray) -> np.ndarray:
        """Re-seed the plate points at their initial layout; return the nodes' new values.

        Tool, tool-edge and plate-edge points keep their (rigidly turned) positions and values;
        the plate and outer-ring points go back to the layout of t = 0, where they take the MLS
        values of the current solution (``x`` on the nodes before re-seeding, whose own values
        are ``values``).
        The caller then moves the nodes and refits the unknowns as after any Lagrangian step.
        """
        cloud = self.model.cloud
        moved = ~rigid(cloud.kind)
        new_values = np.array(values)
        new_values[moved] = self.model.values(x, evaluate_stencils(self.points, cloud.n_tool, self.scene.geometry,
                                                                   cloud.points[moved], derivatives=False))
        self.points = self.points.copy()
        self.points[moved] = cloud.points[moved]
        self.seeded_spacing = _nearest_spacing(self.points[cloud.n_tool:])
        self.rezone_times.append(self.t)
        return new_values

    def after_step(self, t_new, x, params):
        """The :func:`jaxanm.integrate` hook: record, then move the cloud (Lagrangian) or tracers."""
        model, scene = self.model, self.scene
        dt = float(t_new) - self.t
        self.t = float(t_new)
        x = np.asarray(x)
        values = model.values(x, params["st"])
        full = model.full_values(values)
        save = self.t in self.save_times
        if save:
            self._save_sections(x)
        if self.tracers is not None:
            self.tracers = self._advected(self.tracers, x, dt)
        if not model.effects.lagrangian:
            self._record(self.t, self.points, full, save)
            return params
        # Recorded at t_new: the material points where this step's velocity takes them (the
        # step was solved on the cloud of the previous positions, as before any rezoning).
        kind, omega = model.cloud.kind, scene.tool.omega
        if self.markers is None:
            material, material_values = _move(self.points, kind, _velocity(full), omega, dt), full
        else:
            # MLS values at the free material points only: the rigid ones (tool and both sides
            # of its edge) take the nodes' values and turn with the tool
            at = self._values_at(x, self.markers[~rigid(kind)], self.marker_neighbours)
            material_values = self._marker_values(full, at)
            material = self.markers = _move(self.markers, kind, _velocity(material_values), omega, dt)
        rezoned = self._sheared(np.asarray(params["st"].index))
        if rezoned:
            if self.markers is None:  # the material points go on from where the nodes were
                self.markers = material
            values = self._rezone(x, values)
            full = model.full_values(values)
        self.points = _move(self.points, kind, _velocity(full), omega, dt)
        self._record(self.t, material, material_values, save)
        st = build_stencils(self.points, model.cloud.n_tool, scene.geometry, m_max=self.width,
                            neighbours=self.neighbours)
        # re-seeded nodes carry other material's values: a step controller restarts its estimate
        return jaxanm.Remap(model.params(self.points, st), model.fit_state(values, st, self.refit, guess=x),
                            history=not rezoned)

    def result(self, solver, stats) -> FSWResult:
        """Assemble the :class:`FSWResult`."""
        probes = {"t": np.asarray(self.probes["t"])}
        for name in self.probe_index:
            probes[name] = {k: np.asarray(v) for k, v in self.probes[name].items()}
        sections = {"t": np.asarray(self.sections["t"])}
        for name, targets in self.section_points.items():
            s = np.hypot(*(targets - targets[0]).T)
            sections[name] = {"x": targets[:, 0], "y": targets[:, 1], "s": s,
                              **{k: np.asarray(v) for k, v in self.sections[name].items()}}
        tracers = None
        if self.tracers is not None:
            tracers = {"points": np.asarray(self.tracer_saves), "material": self.model.cloud.material.copy()}
        points = np.asarray(self.saved["points"])
        nodes = np.asarray(self.saved["nodes"])
        return FSWResult(scene=self.scene, t=np.asarray(self.saved["t"]), points=points,
                         u=np.asarray(self.saved["u"]), v=np.asarray(self.saved["v"]),
                         T=np.asarray(self.saved["T"]), material=self.model.cloud.material.copy(),
                         probes=probes, sections=sections, stats=stats, solver=solver, tracers=tracers,
                         nodes=nodes if self.rezone_times else None, rezone_times=list(self.rezone_times),
                         start=self.start)


def motion_dt_max(scene: Scene) -> float:
    """Largest adaptive step of a Lagrangian scene: the tool edge (speed omega R1, the fastest
    points) moves at most a tenth of the spacing dr per step.

    The step controller measures the error of the fields, not of the point motion, which is
    explicit Euler (``x <- x + dt V``): on the circular paths near the tool it drifts outwards
    by ``omega^2 r dt / 2`` per unit time (1.4 % of r over fsw_paper's 0.7 s at its dt = 1e-4,
    17 % at this bound of 1.25e-3 s, until a rezoning re-seeds the cloud).  The bound keeps
    each step's motion small against the stencils (h = 3 dr) and the neighbour lists' skin
    (h / 4); it is no error control of the motion.
    """
    g = scene.geometry
    return 0.1 * g.dr / (scene.tool.omega * g.R1)


def step_controller(scene: Scene, model: Model):
    """The :class:`jaxanm.StepController` of a scene with ``time.adaptive`` (else None).

    The local error is measured in the values of the differential fields at the points: T
    with conduction (its scale T0), else the velocity (scale omega R1).  The velocity of a
    conducting scene is quasi-static, algebraic up to the small inertia term, and is left out
    as IDA leaves algebraic components out of its error test: carried by moving points it is
    off the field at their new place by ``dt |DV/Dt|`` after each move (2e-3 of omega R1 at
    fsw_paper's dt), which no smaller next step reduces.  Values at the points, not nodal
    parameters: a Lagrangian cloud's parameters jump at every stencil rebuild, its values do
    not.  Steps are bounded by :func:`motion_dt_max` when the points move.
    """
    tm = scene.time
    if not tm.adaptive:
        return None
    fields = model.fields
    measured = [fields.index("T")] if "T" in fields else [fields.index(f) for f in ("u", "v")]
    scale = model.scale().reshape(len(fields), -1)[measured].ravel()
    return jaxanm.StepController(
        rtol=tm.rtol, atol=tm.atol, dt_max=motion_dt_max(scene) if model.effects.lagrangian else math.inf,
        error_map=lambda x, p: model.values(x, p["st"])[:, measured].T.ravel(), error_scale=scale)


_HOST_INPUTS = ("scene", "model")
"""Recorder attributes rebuilt from the scene on resume (everything else is checkpointed)."""


def _host_state(scene: Scene, recorder: _Recorder, settings: dict):
    """The ``(get, set)`` pair :func:`jaxanm.integrate` stores in / restores from its checkpoints.

    The snapshot is ``{"scene": scene.to_dict(), "settings": settings, "recorder": {...}}`` where
    the recorder part holds every attribute of the recorder except the scene and model (moving
    points, step and time, probe histories, saved fields, sections, tracers); pickled as is.
    ``set`` refuses a checkpoint written for another scene (:class:`jaxanm.InputError` naming
    the differing fields).
    """
    def get():
        return {"scene": scene.to_dict(), "settings": dict(settings),
                "recorder": {k: v for k, v in vars(recorder).items() if k not in _HOST_INPUTS}}

    def set_(state):
        stored = state.get("scene") if isinstance(state, dict) else None
        if stored != scene.to_dict():
            raise jaxanm.InputError(f"the checkpoint was written for another scene ({scene_differences(stored, scene)} "
                                    "differ); resume with the scene it stores, or start afresh")
        for key, value in state["recorder"].items():
            setattr(recorder, key, value)

    return get, set_


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
        the exception carries ``partial``: the :class:`FSWResult` of the steps done so far
        (also on :class:`jaxanm.StepFailure`).
    """
    solver = scene.solver.make() if solver is None else solver
    _, stencils, model, params, x0 = discretise(scene)
    initial, start = None, None
    resuming = resume and checkpoint is not None and os.path.exists(checkpoint)
    if scene.mechanics.start == "quasi_static" and not resuming:  # a resumed run's state is in its checkpoint
        x0, start = quasi_static_state(scene, model, stencils)
        initial = model.values(x0, stencils)
    tm = scene.time
    controller = step_controller(scene, model)
    saveat = jaxanm.SaveAt(ts=[t for t in tm.save_times if t > 0])
    recorder = _Recorder(scene, model, stencils, x0, saveat.times(0.0, tm.t_end, tm.dt, adaptive=controller is not None),
                         initial=initial, start=start)
    latest = {"stats": jaxanm.Stats()}

    def step_done(t, x, stats):
        latest["stats"] = stats
        if callback is not None:
            callback(t, stats)

    host = None
    if checkpoint is not None:
        host = _host_state(scene, recorder, {"checkpoint_every": int(checkpoint_every)})
    try:
        sol = jaxanm.integrate(model.residual, x0, params, t0=0.0, t1=tm.t_end, dt=tm.dt, solver=solver,
                               scale=model.scale(), jacobian="sparse", sparsity=model.sparsity,
                               saveat=saveat, after_step=recorder.after_step,
                               progress=progress, callback=step_done, checkpoint=checkpoint,
                               checkpoint_every=checkpoint_every, resume=resume, host_state=host,
                               controller=controller)
    except (KeyboardInterrupt, jaxanm.StepFailure) as exc:
        try:  # the steps recorded so far (consistent: integrate defers signals while recording)
            exc.partial = recorder.result(solver, latest["stats"])
        except Exception:  # noqa: BLE001 - a broken recorder must not hide the original error
            pass
        raise
    return recorder.result(solver, sol.stats)
