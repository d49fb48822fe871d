"""Recording an FSW run: the probes at every step, the fields and the sections at the saved
steps (the end times of a :class:`jaxanm.SaveAt`'s saved steps), assembled into an
:class:`FSWResult`.

MLS is not interpolating: what is recorded are field values at the points (and at the section
samples and probes), not nodal parameters.

The registration points (probes) of a fixed-point scene (no ``lagrangian`` effect) are the
scene's positions themselves (:class:`ProbeSites`: the MLS values there, from stencils built
once), so that their histories are the same quantity on every cloud and for every solver.
Those of a Lagrangian scene are material points: the plate point nearest each position at
t = 0 (:func:`probe_points`), followed as it moves (the motion is
:mod:`jaxanm.fsw.lagrangian`); its own collocated values are recorded, so that the paper's
scene keeps its results (a particle seeded at the position would carry MLS values of the
sheared cloud instead).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

import jaxanm

from .. import mls
from .discretisation import Model
from .geometry import PLATE, evaluate_stencils
from .scene import Scene
from .start import StartReport

__all__ = ["FSWResult", "ProbeSites", "Recorder", "probe_points"]


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
        step, ``x, y`` where each registration point was: the scene's probe position in a
        fixed-point scene (:class:`ProbeSites`), in a Lagrangian one the plate point nearest it
        at t = 0, followed as it moves (:func:`probe_points`).
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
    start : with ``mechanics.start`` other than ``"rest"``, the
        :class:`~jaxanm.fsw.start.StartReport` of the flow solved at t = 0 (its factorisations
        are not in ``stats``); else None.
    time_error : with ``time.adaptive``, the controller's estimate of the time error at the
        end, in the quantities it measures (T at the points; :attr:`jaxanm.Solution.time_error`);
        else None.
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
    time_error: np.ndarray | None = None


def probe_points(scene: Scene, cloud) -> dict:
    """``{probe name: index of the plate point nearest its position}``: the registration points
    of a Lagrangian run, material points chosen on the initial cloud (fixed-point scenes
    evaluate the fields at the positions themselves: :class:`ProbeSites`)."""
    plate = np.flatnonzero(cloud.kind == PLATE)
    return {p.name: int(plate[np.argmin(np.hypot(*(cloud.points[plate] - (p.x, p.y)).T))]) for p in scene.probes}


@dataclasses.dataclass(frozen=True)
class ProbeSites:
    """The registration points of a fixed-point scene at the scene's positions exactly.

    The values-only MLS stencils of the (fixed) cloud at the probe positions are built once;
    the fields there follow from any state on that cloud (:meth:`values`).  Runs
    (:class:`Recorder`), :func:`jaxanm.fsw.ida_scene.run_ida` and the calibration's
    observations use them, so a probe history is the same quantity on every cloud and for
    every solver.  A probe on a cloud point gets that point's values (the same stencil, to
    round-off).  Checkpoints do not store them: a resumed run makes them again from the scene.

    Attributes
    ----------
    names : tuple of str
        Probe names, in the scene's order.
    positions : (P, 2) float64
        The scene's probe positions (m).
    stencils : jaxanm.mls.Stencils or None
        Values-only stencils at ``positions`` (``index``, ``phi``); None without probes.
    """

    names: tuple
    positions: np.ndarray
    stencils: mls.Stencils | None

    @classmethod
    def of(cls, scene: Scene, cloud) -> "ProbeSites":
        """The probes of ``scene`` on ``cloud`` (its points at t = 0, which do not move)."""
        positions = np.array([[p.x, p.y] for p in scene.probes], dtype=np.float64).reshape(-1, 2)
        stencils = None
        if len(positions):
            st = evaluate_stencils(cloud.points, cloud.n_tool, scene.geometry, positions, derivatives=False)
            stencils = dataclasses.replace(st, index=np.asarray(st.index), phi=np.asarray(st.phi))
        return cls(names=tuple(p.name for p in scene.probes), positions=positions, stencils=stencils)

    def values(self, model: Model, x) -> dict:
        """``{"u", "v", "T": (P,)}`` at the probes from the unknowns ``x`` on the cloud."""
        if self.stencils is None:
            return model.full_values(np.zeros((0, len(model.fields))))
        return model.full_values(model.values(x, self.stencils))

    def at_rest(self, model: Model) -> dict:
        """``{"u", "v", "T": (P,)}`` of the plate at rest at T0, where every probe lies (a run
        started from rest records this at t = 0, as it does at the cloud's plate points)."""
        rest = np.array([model.scene.thermal.T0 if f == "T" else 0.0 for f in model.fields])
        return model.full_values(np.tile(rest, (len(self.names), 1)))


class Recorder:
    """What a run records on the host: probes at every step, fields (and tracers) and sections at
    the saved steps, on the current nodes ``points`` (the cloud the unknowns live on).

    ``save_times``: the end times of the saved steps, from the run's :class:`jaxanm.SaveAt`
    (:meth:`~jaxanm.SaveAt.times`); ``initial``: field values (N, len(fields)) at the points at
    t = 0 (default: the model's rest state); ``start``: the StartReport of a quasi-static start;
    ``tracers=False`` records no tracers even if the scene has them (a recorder fed states far
    apart, which cannot advect them).
    The state at t = 0 is recorded on construction.
    """

    CHECKPOINT_VERSION = 1
    """Version of the layout :meth:`to_checkpoint` writes; another version is refused on resume."""
    CHECKPOINTED: tuple[str, ...] = ("points", "t", "probes", "saved", "sections", "tracers", "tracer_saves",
                                     "rezone_times", "start")
    """The attributes a run changes, stored in checkpoints; the others (the scene, model, save
    times, probe sites and section points) are made again from the scene on resume."""

    def __init__(self, scene: Scene, model: Model, stencils, x0: np.ndarray, save_times: frozenset,
                 initial: np.ndarray | None = None, start: StartReport | None = None, tracers: bool = True):
        self.scene, self.model, self.save_times = scene, model, save_times
        cloud = model.cloud
        self.points = cloud.points.copy()
        self.t = 0.0
        # probes: fixed ones at the scene's positions, or (Lagrangian) followed plate points
        self.probe_sites = None if model.effects.lagrangian else ProbeSites.of(scene, cloud)
        self.probe_index = probe_points(scene, cloud) if model.effects.lagrangian else {}
        self.section_points = {s.name: np.linspace(s.start, s.end, s.samples) for s in scene.sections}
        # "t" -> the times; a probe's (section's) name -> its fields' histories
        self.probes: dict[str, Any] = {"t": [], **{p.name: {k: [] for k in "xyuvT"} for p in scene.probes}}
        self.saved: dict[str, list] = {"t": [], "points": [], "nodes": [], "u": [], "v": [], "T": []}
        self.sections: dict[str, Any] = {"t": [], **{name: {k: [] for k in "uvT"} for name in self.section_points}}
        self.tracers = cloud.points.copy() if model.effects.tracers and tracers else None
        self.tracer_saves: list[np.ndarray] = []
        self.rezone_times: list[float] = []
        self.start = start
        self._save_sections(x0)
        # from rest, the fields at t = 0 are the rest state (not the MLS values of its nodal
        # parameters, which are not interpolating); after a quasi-static start those of x0
        full = model.full_values(model.initial_values(self.points) if initial is None else initial)
        self._record(0.0, self.points, full, save=True,
                     probes=self._at_probes(self.points, full, None if initial is None else x0))

    def to_checkpoint(self) -> dict:
        """The run state of the recorder, ``{"version": CHECKPOINT_VERSION, name: value}`` for
        each name of :data:`CHECKPOINTED` (plain data, numpy arrays and the registered types of
        :func:`jaxanm.checkpoint.stored_type`: the neighbour lists, the refit, the start report)."""
        return {"version": self.CHECKPOINT_VERSION, **{name: getattr(self, name) for name in self.CHECKPOINTED}}

    def from_checkpoint(self, stored: dict) -> None:
        """Continue from what :meth:`to_checkpoint` stored; :class:`jaxanm.InputError` for
        another layout version or a missing entry (the checkpoint then cannot resume this run)."""
        version = stored.get("version") if isinstance(stored, dict) else None
        if version != self.CHECKPOINT_VERSION:
            raise jaxanm.InputError(f"the checkpoint's recorder has layout version {version!r}, this jaxanm reads "
                                    f"{self.CHECKPOINT_VERSION}: start the run afresh")
        missing = [name for name in self.CHECKPOINTED if name not in stored]
        if missing:
            raise jaxanm.InputError(f"the checkpoint's recorder lacks {', '.join(missing)}: start the run afresh")
        for name in self.CHECKPOINTED:
            setattr(self, name, stored[name])

    def record_state(self, t: float, x, stencils, probes: bool = True) -> None:
        """Record the unknowns ``x`` at time ``t`` on the fixed points (no motion): the probes
        (``probes=False``: not at this time, a run whose ``time.probe_dt`` samples them by
        :meth:`observe_probes`), and at a save time the fields and sections.  A run on fixed
        points (its step hook) and IDA (its outputs) pass their states through here in time
        order; ``stencils``: the cloud's, as in the model's parameters."""
        self.t = float(t)
        x = np.asarray(x)
        full = self.model.full_values(self.model.values(x, stencils))
        save = self.t in self.save_times
        if save:
            self._save_sections(x)
        self._record(self.t, self.points, full, save, self._at_probes(self.points, full, x) if probes else None)

    def observe_probes(self, t: float, x, params) -> dict:
        """The probes' ``{"u", "v", "T": (P,)}`` of the unknowns ``x`` at ``t``, recorded in the
        probe histories after t = 0 (which the recorder records itself): the
        :class:`jaxanm.SaveAt` ``fn`` of a scene with ``time.probe_dt``, observed at its
        :attr:`~jaxanm.fsw.scene_sections.Time.probe_times` on the scheme's dense output."""
        assert self.probe_sites is not None  # the scene refuses probe_dt with moving points
        at = self.probe_sites.values(self.model, np.asarray(x))
        if t > self.probes["t"][-1]:
            self._append_probes(float(t), {"x": self.probe_sites.positions[:, 0],
                                           "y": self.probe_sites.positions[:, 1], **at})
        return at

    def _at_probes(self, positions: np.ndarray, values: dict, state=None) -> dict:
        """``{"x", "y", "u", "v", "T": (P,)}`` at the probes in one step.

        Fixed probes (:class:`ProbeSites`): the MLS values of the unknowns ``state`` at the
        scene's positions (``state = None``: the plate at rest).  Followed ones (Lagrangian):
        the values ``values`` of their material points at ``positions``.
        """
        sites = self.probe_sites
        if sites is not None:
            at = sites.at_rest(self.model) if state is None else sites.values(self.model, state)
            return {"x": sites.positions[:, 0], "y": sites.positions[:, 1], **at}
        index = np.fromiter(self.probe_index.values(), dtype=np.intp, count=len(self.probe_index))
        return {"x": positions[index, 0], "y": positions[index, 1], **{k: values[k][index] for k in "uvT"}}

    def _record(self, t: float, positions: np.ndarray, values: dict, save: bool, probes: dict | None = None) -> None:
        """Probe values at every step; fields (and tracers) at the save steps.

        ``positions`` and ``values``: the material points and the fields there; ``probes``:
        the probes' record of this step (:meth:`_at_probes`; by default that of followed
        probes, from ``positions`` and ``values``; fixed ones need the state, and without it
        none is recorded at this step).
        """
        if probes is None and self.probe_sites is None:
            probes = self._at_probes(positions, values)
        if probes is not None:
            self._append_probes(t, probes)
        if save:
            self.saved["t"].append(t)
            self.saved["points"].append(positions.copy())
            self.saved["nodes"].append(self.points.copy())
            for k in "uvT":
                self.saved[k].append(values[k].copy())
            if self.tracers is not None:
                self.tracer_saves.append(self.tracers.copy())

    def _append_probes(self, t: float, probes: dict) -> None:
        """One sample of every probe's history (``probes``: as :meth:`_at_probes` gives)."""
        self.probes["t"].append(t)
        for j, name in enumerate(p.name for p in self.scene.probes):
            rec = self.probes[name]
            for k in "xyuvT":
                rec[k].append(probes[k][j])

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

    def result(self, solver, stats, time_error=None) -> FSWResult:
        """Assemble the :class:`FSWResult` (``time_error``: the controller's estimate, if any)."""
        probes: dict[str, Any] = {"t": np.asarray(self.probes["t"])}
        for name in (p.name for p in self.scene.probes):
            probes[name] = {k: np.asarray(v) for k, v in self.probes[name].items()}
        sections: dict[str, Any] = {"t": np.asarray(self.sections["t"])}
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
                         start=self.start, time_error=time_error)
