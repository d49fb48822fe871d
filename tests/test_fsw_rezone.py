"""Rezoning of the Lagrangian cloud (``geometry.rezone``): re-seeding, remap, material points.

The closed-form check: MLS with a quadratic basis reproduces quadratic fields, so re-seeding a
sheared cloud that carries quadratic fields must give those fields at the new points to
round-off.  The run-level checks compare a run rezoned at (nearly) every step with the same
run never rezoned: they solve the same problem, so they must agree to well within the model's
discretisation error, and the material points must stay material points.
"""

from __future__ import annotations

import numpy as np
import pytest

from jaxanm.fsw import load_scene, run
from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.geometry import PLATE, PLATE_EDGE, RING, cloud_stencils
from jaxanm.fsw.lagrangian import RunRecorder
from jaxanm.fsw.scene import SceneError


@pytest.mark.parametrize("value", ["1.0", "-0.1", "1.5"])
def test_rezone_fraction_is_validated(value):
    with pytest.raises(SceneError, match=r"geometry.rezone.*\[0, 1\)"):
        load_scene("fsw_small").with_overrides({"geometry.rezone": value})


def _quadratic(points):
    x, y = points[:, 0] / 1e-3, points[:, 1] / 1e-3
    return np.stack([0.01 + 0.02 * x - 0.03 * y ** 2, -0.02 * x * y + 0.01 * y,
                     300.0 + 5.0 * x ** 2 - 3.0 * x * y + 2.0 * y], axis=1)


def test_rezone_reseeds_the_plate_and_remaps_a_quadratic_field_exactly():
    scene = load_scene("fsw_small").with_overrides({"geometry.rezone": "0.9"})
    cloud, stencils, model, _, x0 = discretise(scene)
    rec = RunRecorder(scene, model, stencils, x0, save_times=frozenset())
    # a sheared cloud: plate points displaced by up to 0.2 dr, the tool turned by 0.3 rad
    rng = np.random.default_rng(3)
    sheared = cloud.points.copy()
    free = cloud.kind == PLATE
    sheared[free] += 0.2 * scene.geometry.dr * rng.uniform(-1, 1, (free.sum(), 2))
    c, s = np.cos(0.3), np.sin(0.3)
    rigid = cloud.kind <= PLATE_EDGE
    sheared[rigid] = sheared[rigid] @ np.array([[c, s], [-s, c]])
    st = cloud_stencils(sheared, cloud.n_tool, scene.geometry, m_max=rec.width)
    x = model.fit_state(_quadratic(sheared), st)
    rec.points = sheared
    values = rec._rezone(x, model.values(x, st))

    moved = np.isin(cloud.kind, (PLATE, RING))
    assert np.array_equal(rec.points[moved], cloud.points[moved])  # back on the layout
    assert np.array_equal(rec.points[~moved], sheared[~moved])  # tool and edges keep turning
    exact = _quadratic(rec.points)
    scale = np.abs(exact).max(axis=0)
    assert np.all(np.abs(values - exact).max(axis=0) <= 1e-10 * scale)
    assert rec.rezone_times == [0.0]
    # the spacing reference is the re-seeded cloud's: the layout does not trigger at once
    assert not rec._sheared()


def _couette_scene(rezone: str):
    return load_scene("fsw_small").with_overrides({
        "effects": "viscous,conduction,dissipation,softening,tool_conduction,robin,lagrangian",
        "material.n": 0.3, "time.dt": 4e-3, "time.t_end": 0.04, "time.save": "0.02",
        "solver.kind": "newton", "geometry.rezone": rezone})


def test_rezoned_run_agrees_with_the_unrezoned_run():
    """Re-seeding at nearly every step changes the fields at the material points by less than the
    discretisation error, keeps the material points' colours and rigid tool, and puts the nodes
    back on the layout.

    The yardstick: half the isothermal n = 0.3 Couette error at *twice* this resolution
    (4.4e-2 omega R1 at dr = 3.75e-4, test_couette_power_law_converges), 2.2e-2 omega R1;
    the same fraction of the heating for T.  Measured: 9 rezonings in 10 steps, V differs by
    1.6e-2 omega R1, T by 7.7e-3 of the heating, the material points by 2.6e-3 omega R1 t.
    """
    ref = run(_couette_scene("0"))
    res = run(_couette_scene("0.9999"))
    cloud = discretise(res.scene).cloud
    g, omega, dt = ref.scene.geometry, ref.scene.tool.omega, ref.scene.time.dt
    assert ref.rezone_times == [] and ref.nodes is None
    assert len(res.rezone_times) >= 3
    assert np.array_equal(res.material, ref.material)
    # material points: tool and edges turn rigidly (identical in both runs), the plate follows the flow
    rigid = cloud.kind <= PLATE_EDGE
    np.testing.assert_allclose(res.points[:, rigid], ref.points[:, rigid], rtol=0, atol=1e-15)
    speed = omega * g.R1
    bound = 2.2e-2
    # a velocity difference below bound * omega R1 moves a point by less than that times t
    assert np.abs(res.points - ref.points).max() < bound * speed * res.t[-1]
    assert np.abs(res.u - ref.u).max() < bound * speed and np.abs(res.v - ref.v).max() < bound * speed
    heating = ref.T[-1].max() - ref.scene.thermal.T0
    assert heating > 0 and np.abs(res.T - ref.T).max() < bound * heating
    for name in ("1", "2", "3"):
        for k in "xy":
            np.testing.assert_allclose(res.probes[name][k], ref.probes[name][k], rtol=0,
                                       atol=bound * speed * res.t[-1])
    # the nodes: the re-seeded points sit on the layout, moved by at most one step of the flow
    moved = np.isin(cloud.kind, (PLATE, RING))
    assert np.abs(res.nodes[-1, moved] - cloud.points[moved]).max() <= dt * speed
    np.testing.assert_array_equal(res.nodes[:, rigid], res.points[:, rigid])


def test_rezoned_run_resumes_bit_identically(tmp_path):
    """The material points, the re-seeding reference and the rezone times are checkpointed:
    a run interrupted after a rezoning and resumed equals the uninterrupted run."""
    scene = _couette_scene("0.9999").with_overrides({"time.t_end": "0.016", "time.save": "0.008"})
    ref = run(scene)
    assert 0 < len(ref.rezone_times) and ref.rezone_times[0] < 0.012

    def stop(t, stats):
        if stats.time_steps == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(scene, callback=stop, checkpoint=tmp_path / "c.pkl", checkpoint_every=1)
    steps = []
    res = run(scene, checkpoint=tmp_path / "c.pkl", resume=True, callback=lambda t, st: steps.append(t))
    assert steps == pytest.approx([0.016])  # only the last step was computed again
    assert res.rezone_times == ref.rezone_times
    for key in ("t", "points", "nodes", "u", "v", "T"):
        np.testing.assert_array_equal(getattr(res, key), getattr(ref, key), err_msg=key)
    for name in ("1", "2", "3"):
        for k in "xyuvT":
            np.testing.assert_array_equal(res.probes[name][k], ref.probes[name][k])
