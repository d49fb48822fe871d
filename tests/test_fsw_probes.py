"""Registration points (probes) and tracers as the run's recorder keeps them, fed prescribed
states (no solver): fixed-point scenes take the fields at the scene's probe positions exactly
(:class:`jaxanm.fsw.record.ProbeSites`), the same quantity on every cloud; Lagrangian scenes
follow the plate point nearest each position; tracers move by
:func:`jaxanm.fsw.lagrangian.advect`.

A state whose fields are quadratic in x, y is reproduced exactly by the quadratic MLS basis
(nodal parameters = the field at the nodes), so the fields at any probe or tracer are known.
"""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest

from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.geometry import PLATE, rigid
from jaxanm.fsw.io.output import probe_positions
from jaxanm.fsw.lagrangian import RunRecorder
from jaxanm.fsw.record import ProbeSites, probe_points
from jaxanm.fsw.scene import Geometry, Probe, Scene

OMEGA, T0 = 20.0, 300.0
PROBES = (Probe(name="p1", x=1.875e-3, y=0.0), Probe(name="p2", x=0.0, y=2.25e-3),
          Probe(name="p3", x=3.1e-3, y=-2.2e-3))


def _scene(dr: float = 7.5e-4, effects=("viscous", "conduction", "tracers"), probes=PROBES,
           layout: str = "polar") -> Scene:
    return Scene(name="probes", effects=effects, geometry=Geometry(dr=dr, c=0.3, layout=layout), probes=probes)


def _field(points: np.ndarray) -> dict:
    """A rigid rotation and a quadratic temperature: within the MLS basis on each side of the edge."""
    x, y = points[:, 0], points[:, 1]
    return {"u": -OMEGA * y, "v": OMEGA * x, "T": T0 + 2e6 * (x * x + 0.5 * y * y) + 3e3 * x}


def _recorder(scene: Scene):
    """A run's recorder on ``scene`` at t = 0 (from rest), and what it runs on."""
    cloud, stencils, model, params, x0 = discretise(scene)
    return RunRecorder(scene, model, stencils, x0, frozenset()), cloud, model, params


def _state(model, points) -> np.ndarray:
    """Flat unknowns whose MLS fields are :func:`_field` everywhere (nodal parameters = values)."""
    f = _field(points)
    return np.concatenate([f[k] for k in model.fields])


def _history(recorder, name: str) -> np.ndarray:
    """(M, 5) x, y, u, v, T of probe ``name`` over the recorded steps."""
    return np.stack([np.asarray(recorder.probes[name][k]) for k in "xyuvT"], axis=1)


def test_fixed_probes_sit_at_the_scene_positions_on_every_cloud():
    """Three clouds of one fixed-point scene (polar at two spacings, a square grid; chosen of one
    size class, so the MLS kernels compile once): each probe is at the scene's position on all
    (its nearest plate point is not: 0.27-0.53 mm off), and all record the same values, the field
    there (t = 0: the plate at rest)."""
    given = np.array([[p.x, p.y] for p in PROBES])
    histories = []
    for dr, layout in ((7.5e-4, "polar"), (7.2e-4, "polar"), (7.5e-4, "grid")):
        recorder, cloud, model, params = _recorder(_scene(dr, layout=layout))
        nearest = cloud.points[list(probe_points(recorder.scene, cloud).values())]
        assert np.max(np.hypot(*(nearest - given).T)) > 5e-5
        x = _state(model, cloud.points)
        for t in (1e-2, 2e-2):
            recorder.after_step(t, x, params)
        exact = _field(given)
        for j, p in enumerate(PROBES):
            h = _history(recorder, p.name)
            assert np.array_equal(h[:, 0], np.full(3, p.x)) and np.array_equal(h[:, 1], np.full(3, p.y))
            assert np.array_equal(h[0, 2:], [0.0, 0.0, T0])
            for k, key in enumerate("uvT"):
                assert np.allclose(h[1:, 2 + k], exact[key][j], rtol=1e-10, atol=1e-10 * OMEGA * 6e-3)
        histories.append(np.stack([_history(recorder, p.name) for p in PROBES]))
    for other in histories[1:]:
        assert np.array_equal(histories[0][..., :2], other[..., :2])
        assert np.allclose(histories[0], other, rtol=1e-10, atol=1e-12)


def test_a_probe_on_a_cloud_point_records_that_points_values():
    """A probe placed exactly on a plate point takes that point's own values (the same MLS
    stencil, to round-off) for any state."""
    scene = _scene()
    cloud = discretise(scene).cloud
    plate = np.flatnonzero(cloud.kind == PLATE)
    i = plate[np.argmin(np.hypot(*(cloud.points[plate] - (2.6e-3, 1.3e-3)).T))]
    on_point = _scene(probes=(Probe(name="on", x=float(cloud.points[i, 0]), y=float(cloud.points[i, 1])),))
    recorder, cloud, model, params = _recorder(on_point)
    x = np.random.default_rng(4).normal(size=model.size) * np.repeat([OMEGA * 1.5e-3] * 2 + [T0], cloud.size)
    recorder.after_step(1e-2, x, params)
    at_points = model.full_values(model.values(x, params["st"]))
    h = _history(recorder, "on")
    assert np.array_equal(h[-1, :2], cloud.points[i])
    for k, key in enumerate("uvT"):
        assert h[-1, 2 + k] == pytest.approx(at_points[key][i], rel=1e-12, abs=1e-12 * np.abs(at_points[key]).max())


def test_lagrangian_probes_follow_the_nearest_plate_point():
    """A Lagrangian scene keeps its registration points as material points: the plate point
    nearest each position at t = 0 (:func:`probe_points`), reported as such."""
    scene = _scene(effects=("viscous", "lagrangian"))
    recorder, cloud, model, params = _recorder(scene)
    assert recorder.probe_sites is None
    result = recorder.result(None, None)
    where = probe_positions(result)
    for p, i in zip(PROBES, probe_points(scene, cloud).values()):
        assert (result.probes[p.name]["x"][0], result.probes[p.name]["y"][0]) == tuple(cloud.points[i])
        assert where[p.name]["scene"] == [p.x, p.y]
        assert where[p.name]["offset_m"] == pytest.approx(np.hypot(*(cloud.points[i] - (p.x, p.y))), rel=1e-15)


def test_fixed_probe_positions_reported_and_checkpointed():
    """``summary.json``'s ``probe_positions`` of a fixed-point run: at the scene's positions, no
    offset, not moving; the probe stencils pickle with the recorder (a checkpoint) unchanged."""
    recorder, cloud, model, params = _recorder(_scene())
    recorder.after_step(1e-2, _state(model, cloud.points), params)
    where = probe_positions(recorder.result(None, None))
    for p in PROBES:
        assert where[p.name] == {"scene": [p.x, p.y], "x": p.x, "y": p.y, "r": float(np.hypot(p.x, p.y)),
                                 "offset_m": 0.0, "moves": False}
    stored = pickle.loads(pickle.dumps(recorder.probe_sites))
    assert isinstance(stored.stencils.phi, np.ndarray)
    assert np.array_equal(stored.stencils.phi, recorder.probe_sites.stencils.phi)
    assert np.array_equal(stored.stencils.index, recorder.probe_sites.stencils.index)
    assert ProbeSites.of(dataclasses.replace(recorder.scene, probes=()), cloud).stencils is None


def test_tracers_turn_on_their_circles_with_the_recorded_flow():
    """The recorder's tracers in a rigidly turning flow, at a controller's largest step (0.2 rad
    a step): those started on the tool or its edge turn with it, the others follow the MLS
    velocity by :func:`advect`; all stay on their circles and reach the angle omega t (1e-11:
    the MLS reproduction of the flow, against explicit Euler's 80 % of r over these steps)."""
    recorder, cloud, model, params = _recorder(_scene())
    x, dt = _state(model, cloud.points), 1e-2
    for k in range(1, 31):
        recorder.after_step(k * dt, x, params)
    tracers, start = recorder.tracers, cloud.points
    assert recorder.tracer_velocity.shape == (int(np.sum(~rigid(cloud.kind))), 2)
    r0, r = np.hypot(*start.T), np.hypot(*tracers.T)
    away = r0 > 0
    assert np.max(np.abs(r[away] / r0[away] - 1)) < 1e-11 and np.max(r[~away]) == 0.0
    turned = np.angle((tracers[away, 0] + 1j * tracers[away, 1]) / (start[away, 0] + 1j * start[away, 1])
                      * np.exp(-1j * OMEGA * 30 * dt))
    assert np.max(np.abs(turned)) < 1e-11
