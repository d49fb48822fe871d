"""Lagrangian motion of an FSW run, the host hook after every accepted step (:class:`RunRecorder`).

- evaluates the fields at the points and records them (:class:`~jaxanm.fsw.record.Recorder`);
- with ``lagrangian``: moves the points (tool and tool-edge points rotate rigidly by
  ``omega dt``, exactly; plate points ``x <- x + dt V``), rebuilds the stencils with the same
  width (nothing recompiles) and refits the unknowns so that the new stencils reproduce the
  values the points carry (:class:`jaxanm.Remap`).  The plate points' explicit Euler motion
  (the paper's updated Lagrangian step) drifts outwards on the circular paths by
  ``omega^2 r dt / 2`` per unit time (:func:`motion_dt_max`); it is kept, for the nodes and
  for the material points after a rezoning alike, so that fsw_paper reproduces its results
  (Table 1's factorisations, its probe temperatures) bit for bit, where :func:`advect` would
  cost one MLS evaluation at every node per step;
- with ``lagrangian`` and ``geometry.rezone > 0``: when the cloud has sheared too far (some
  plate point's nearest neighbour is closer than ``rezone`` times its distance at the last
  seeding), re-seeds the plate points at their initial layout, with the values the current
  solution has there (:meth:`RunRecorder._rezone`).  From the first rezoning on, the
  computational points (``nodes``) and the material points (``points``, which carry the colours
  and the probes) differ: the material points are then advected like tracers, through the
  moving cloud.
- with ``tracers``: advects passive tracer particles (initially at the points) through the
  fixed cloud, for the mixing picture: those started on the tool or its edge turn with it,
  the others move by :func:`advect` (the midpoint rule in polar coordinates about the tool
  axis: on circles exactly in a circular flow, second order in dt in any steady one, one
  MLS evaluation a step), so that they stay on their paths at the large steps of a step
  controller.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree

import jaxanm

from .discretisation import Model, Refit
from .geometry import PLATE_EDGE, cloud_stencils, evaluate_stencils, neighbour_list, rigid
from .record import Recorder
from .scene import Scene
from .start import StartReport

__all__ = ["RunRecorder", "advect", "motion_dt_max"]


def _rotate(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return points @ np.array([[c, s], [-s, c]])


def _move(points: np.ndarray, kind: np.ndarray, velocity: np.ndarray, omega: float, dt: float) -> np.ndarray:
    """Material motion over dt: tool and edge points rotate rigidly, the others follow V."""
    return np.where(rigid(kind)[:, None], _rotate(points, omega * dt), points + dt * velocity)


def _polar(offset: np.ndarray, velocity: np.ndarray) -> np.ndarray:
    """(M, 2) angular velocity ``v_theta / r`` and radial velocity ``v_r`` about the centre, of
    points at ``offset`` (M, 2) from it (none at it) moving at Cartesian ``velocity`` (M, 2)."""
    dx, dy = offset[:, 0], offset[:, 1]
    vx, vy = velocity[:, 0], velocity[:, 1]
    r2 = dx * dx + dy * dy
    return np.stack([(dx * vy - dy * vx) / r2, (dx * vx + dy * vy) / np.sqrt(r2)], axis=1)


def _turned(offset: np.ndarray, span: float, polar: np.ndarray) -> tuple:
    """Offsets from the centre after ``span`` at the polar velocity ``polar`` (M, 2): turned by
    ``span v_theta / r`` and the radius moved by ``span v_r``; and the ratio of new to old radius."""
    angle = span * polar[:, 0]
    c, s = np.cos(angle), np.sin(angle)
    ratio = 1.0 + span * polar[:, 1] / np.hypot(offset[:, 0], offset[:, 1])
    turned = np.stack([c * offset[:, 0] - s * offset[:, 1], s * offset[:, 0] + c * offset[:, 1]], axis=1)
    return turned * ratio[:, None], ratio


def _cartesian_midpoint(offset: np.ndarray, velocity, dt: float) -> tuple:
    """``x + dt V(x + dt/2 V(x))`` for points at ``offset`` from the centre (``velocity`` takes
    offsets too), for those :func:`advect` cannot move in polar form; and the polar velocity
    at the midpoint (0 at the centre)."""
    mid = offset + 0.5 * dt * np.asarray(velocity(offset), dtype=np.float64)
    v_mid = np.asarray(velocity(mid), dtype=np.float64)
    carried = np.zeros_like(offset)
    away = np.hypot(mid[:, 0], mid[:, 1]) > 0
    carried[away] = _polar(mid[away], v_mid[away])
    return offset + dt * v_mid, carried


def advect(points: np.ndarray, velocity, dt: float, carried: np.ndarray | None = None,
           centre=(0.0, 0.0)) -> tuple:
    """Passive points moved over one step ``dt`` by the flow at the step's end.

    The explicit midpoint rule in polar coordinates about ``centre`` (the tool axis): the
    angle advances by ``dt v_theta / r`` and the radius by ``dt v_r``, the velocity
    ``velocity(positions) -> (K, 2)`` (the implicit step's new flow, frozen over the step)
    taken at the midpoint of the path.  In a circular flow (``v_r = 0``, any ``v_theta(r)``)
    the points stay on their circles and turn by ``dt v_theta(r) / r`` exactly, at any step
    size (to round-off), where ``x + dt V`` drifts outwards by ``omega^2 r dt / 2`` per unit
    time.  Along any other smooth flow it is second order in dt, its error constant growing
    with ``dt |V| / r`` for the part of the flow that is no rotation about ``centre``.

    One velocity evaluation per step: the midpoint is predicted with ``carried``, the polar
    velocity (``v_theta / r``, ``v_r``, per point) that this function returned for the
    previous step.  Taken at that step's midpoint it is O(dt) off, which moves the midpoint by
    O(dt^2) and the end point by O(dt^3): still second order; in a circular flow the predicted
    midpoint lies on the circle, so the end point stays exact.  ``carried = None`` (a first
    step) samples the velocity at ``points`` first: one evaluation more.

    The flow is the one at the step's end: where it changes over a step (the start from rest;
    a tool travelling through the plate, seen from the plate) the paths are first order in
    time, as the implicit-Euler fields are; where it is steady (the stirring once started, a
    travelling tool seen from the tool), second order.

    Points at the centre, or whose radius half a step would shrink below half of it (a flow
    through the centre, where the polar form fails), take the Cartesian midpoint rule
    ``x + dt V(x + dt/2 V(x))`` instead (two evaluations for those points).

    Returns the moved points (M, 2) and the polar velocity (M, 2) to carry to the next step.
    """
    points = np.asarray(points, dtype=np.float64)
    centre = np.asarray(centre, dtype=np.float64)
    offset = points - centre
    polar = np.hypot(offset[:, 0], offset[:, 1]) > 0
    if carried is None:
        carried = np.zeros_like(points)
        if polar.any():
            carried[polar] = _polar(offset[polar], np.asarray(velocity(points[polar]), dtype=np.float64))
    carried = np.asarray(carried, dtype=np.float64)
    half, ratio = _turned(offset[polar], 0.5 * dt, carried[polar])
    polar[polar] = ratio >= 0.5
    moved, out = points.copy(), np.zeros_like(points)
    if polar.any():
        half = half[ratio >= 0.5]
        out[polar] = _polar(half, np.asarray(velocity(centre + half), dtype=np.float64))
        new, ratio = _turned(offset[polar], dt, out[polar])
        moved[polar] = centre + new
        polar[polar] = ratio >= 0.5  # the others are redone below
    if not polar.all():
        new, out[~polar] = _cartesian_midpoint(offset[~polar], lambda at: velocity(centre + at), dt)
        moved[~polar] = centre + new
    return moved, out


def _velocity(values: dict) -> np.ndarray:
    """(N, 2) velocity from the ``{"u", "v", "T"}`` values."""
    return np.stack([values["u"], values["v"]], axis=1)


def _nearest_spacing(points: np.ndarray) -> np.ndarray:
    """Distance from each point to its nearest other point."""
    return cKDTree(points).query(points, 2)[0][:, 1]


class RunRecorder(Recorder):
    """The host side of every FSW run, fixed cloud or moving: the
    :class:`~jaxanm.fsw.record.Recorder`'s records and, as the scene's effects ask, the moving
    cloud (``lagrangian``: motion, rezoning, refits), the material points and the tracers, with
    what their rebuilds carry from step to step (neighbour candidates, the refit's
    factorisation), checkpointed with it."""

    CHECKPOINTED = Recorder.CHECKPOINTED + ("width", "markers", "seeded_spacing", "neighbours", "marker_neighbours",
                                            "tracer_neighbours", "refit", "tracer_velocity")

    def __init__(self, scene: Scene, model: Model, stencils, x0: np.ndarray, save_times: frozenset,
                 initial: np.ndarray | None = None, start: StartReport | None = None):
        super().__init__(scene, model, stencils, x0, save_times, initial=initial, start=start)
        if self.tracers is not None or model.effects.lagrangian:
            # values at moving points at every step: their kernel compiles while the run sets up
            jaxanm.mls.compile_values_ahead(scene.geometry.c, scene.geometry.q)
        self.width = stencils.index.shape[1]
        # Rezoning: the material points separate from the nodes at the first re-seeding.
        self.markers = None
        self.seeded_spacing = _nearest_spacing(self.points[model.cloud.n_tool:])
        # Lagrangian rebuilds: neighbour candidates (of the nodes, the material points after a
        # rezoning, the tracers) and the refit's factorisation, carried from step to step (and
        # through checkpoints)
        self.neighbours = neighbour_list(scene.geometry)
        self.marker_neighbours = neighbour_list(scene.geometry)
        self.tracer_neighbours = neighbour_list(scene.geometry)
        self.refit = Refit()
        # the tracers' polar velocity of the last step (advect's carried; None: not yet moved)
        self.tracer_velocity: np.ndarray | None = None

    def _advected(self, particles: np.ndarray, x, dt: float) -> np.ndarray:
        """Tracers moved over dt: those started on the tool or its edge turn with the tool by
        ``omega dt``, exactly (on the plate edge by ``delta omega dt`` with ``slip``); the others
        follow the flow of unknowns ``x`` by :func:`advect` (the MLS velocity at their predicted
        midpoints, one evaluation a step); with ``traverse``, those that left the disc re-enter
        (:meth:`_reentered`)."""
        kind, tool = self.model.cloud.kind, self.scene.tool
        turning = rigid(kind)
        moved = particles.copy()
        moved[turning] = _rotate(particles[turning], tool.omega * dt)
        if self.model.effects.slip:
            edge = kind == PLATE_EDGE
            moved[edge] = _rotate(particles[edge], tool.contact_state * tool.omega * dt)

        def velocity(at):
            return _velocity(self._values_at(x, at, self.tracer_neighbours))

        moved[~turning], self.tracer_velocity = advect(particles[~turning], velocity, dt, self.tracer_velocity)
        if self.model.effects.traverse:
            moved[~turning] = self._reentered(moved[~turning])
        return moved

    def _reentered(self, free: np.ndarray) -> np.ndarray:
        """Free tracers that the through-flow carried out of the disc (r > R2) re-enter on the
        leading side at their height y, ``(sqrt(R2^2 - y^2), y)``: the material arriving there
        has moved at (-U, 0) along its line y = const.  Their colour (plate y > 0 or y < 0)
        stays right, since y is kept; their carried velocity becomes the inflow's."""
        R2, U = self.scene.geometry.R2, self.scene.tool.traverse_speed
        out = np.hypot(free[:, 0], free[:, 1]) > R2
        if not out.any():
            return free
        free = free.copy()
        y = np.clip(free[out, 1], -R2, R2)
        free[out] = np.stack([np.sqrt(R2 * R2 - y * y), y], axis=1)
        inflow = np.broadcast_to([-U, 0.0], free[out].shape)
        away = np.hypot(free[out, 0], free[out, 1]) > 0
        tracer_velocity = self.tracer_velocity
        assert tracer_velocity is not None  # set by the advection that moved these tracers out
        carried = tracer_velocity[out]
        carried[away] = _polar(free[out][away], inflow[away])
        tracer_velocity[out] = carried
        return free

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
        x = np.asarray(x)
        if self.tracers is not None:
            self.tracers = self._advected(self.tracers, x, dt)
        if not model.effects.lagrangian:
            self.record_state(t_new, x, params["st"], probes=scene.time.probe_dt == 0)
            return params
        self.t = float(t_new)
        values = model.values(x, params["st"])
        full = model.full_values(values)
        save = self.t in self.save_times
        if save:
            self._save_sections(x)
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
        self._record(self.t, material, material_values, save, self._at_probes(material, material_values))
        st = cloud_stencils(self.points, model.cloud.n_tool, scene.geometry, m_max=self.width,
                            neighbours=self.neighbours)
        # re-seeded nodes carry other material's values: a step controller restarts its estimate
        return jaxanm.Remap(model.params(self.points, st), model.fit_state(values, st, self.refit, guess=x),
                            history=not rezoned)


def motion_dt_max(scene: Scene) -> float:
    """Largest adaptive step of a Lagrangian scene: the tool edge (speed omega R1, the fastest
    points) moves at most a tenth of the spacing dr per step.

    The step controller measures the error of the fields, not of the point motion, which is
    explicit Euler (``x <- x + dt V``) in Lagrangian scenes: on the circular paths near the
    tool it drifts outwards by ``omega^2 r dt / 2`` per unit time (1.4 % of r over fsw_paper's
    0.7 s at its dt = 1e-4, 17 % at this bound of 1.25e-3 s, until a rezoning re-seeds the
    cloud; the tracers of fixed-point scenes move by :func:`advect`, which keeps circles).  The bound keeps
    each step's motion small against the stencils (h = 3 dr) and the neighbour lists' skin
    (h / 4); it is no error control of the motion.
    """
    g = scene.geometry
    return 0.1 * g.dr / (scene.tool.omega * g.R1)
