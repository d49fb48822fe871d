"""Recording an FSW run: the probes at every step, the fields and the sections at the saved
steps (the end times of a :class:`jaxanm.SaveAt`'s saved steps), assembled into an
:class:`FSWResult`.

MLS is not interpolating: what is recorded are field values at the points (and at the section
samples), not nodal parameters.  The probes are material points, followed as they move; the
motion itself is :mod:`jaxanm.fsw.lagrangian`.
"""

from __future__ import annotations

import dataclasses

import numpy as np

import jaxanm

from .discretisation import Model
from .geometry import PLATE, evaluate_stencils
from .scene import Scene
from .start import StartReport

__all__ = ["FSWResult", "Recorder", "probe_points"]


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


def probe_points(scene: Scene, cloud) -> dict:
    """``{probe name: index of the plate point nearest its position}``: the registration points
    of a run (and of :func:`jaxanm.fsw.ida_scene.run_ida`), chosen on the initial cloud."""
    plate = np.flatnonzero(cloud.kind == PLATE)
    return {p.name: int(plate[np.argmin(np.hypot(*(cloud.points[plate] - (p.x, p.y)).T))]) for p in scene.probes}


class Recorder:
    """What a run records on the host: probes at every step, fields (and tracers) and sections at
    the saved steps, on the current nodes ``points`` (the cloud the unknowns live on).

    ``save_times``: the end times of the saved steps, from the run's :class:`jaxanm.SaveAt`
    (:meth:`~jaxanm.SaveAt.times`); ``initial``: field values (N, len(fields)) at the points at
    t = 0 (default: the model's rest state); ``start``: the StartReport of a quasi-static start.
    The state at t = 0 is recorded on construction.
    """

    def __init__(self, scene: Scene, model: Model, stencils, x0: np.ndarray, save_times: frozenset,
                 initial: np.ndarray | None = None, start: StartReport | None = None):
        self.scene, self.model, self.save_times = scene, model, save_times
        cloud = model.cloud
        self.points = cloud.points.copy()
        self.t = 0.0
        self.probe_index = probe_points(scene, cloud)
        self.section_points = {s.name: np.linspace(s.start, s.end, s.samples) for s in scene.sections}
        self.probes = {"t": [], **{name: {k: [] for k in "xyuvT"} for name in self.probe_index}}
        self.saved = {"t": [], "points": [], "nodes": [], "u": [], "v": [], "T": []}
        self.sections = {"t": [], **{name: {k: [] for k in "uvT"} for name in self.section_points}}
        self.tracers = cloud.points.copy() if model.effects.tracers else None
        self.tracer_saves = []
        self.rezone_times = []
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
