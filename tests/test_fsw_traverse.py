"""The ``traverse`` effect (the tool travels along +x at U; seen from the tool the plate streams
through the disc) against references independent of the MLS code: U = 0 is the scene without
the effect, bit for bit; the net mass flux through closed circles vanishes; the trailing side
is hotter than the leading side, within the bound of the steady moving line source; the
through-flow passes the pin on both sides (mass conservation through the section x = 0).
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest

import jaxanm
from jaxanm import mls
from jaxanm.fsw import run
from jaxanm.fsw.discretisation import discretise, make_model
from jaxanm.fsw.geometry import build_cloud, cloud_stencils, evaluate_stencils
from jaxanm.fsw.scene import SceneError, load_scene

EULERIAN = "inertia,viscous,softening,conduction,tool_conduction,dissipation,robin,tracers"


def _rows(scene):
    cloud, st, model, params, x0 = discretise(scene)
    rng = np.random.default_rng(1)
    x = x0 * (1 + 0.01 * rng.standard_normal(x0.size)) + 1e-3 * rng.standard_normal(x0.size)
    with jaxanm.float64():
        return np.asarray(model.residual(jnp.asarray(x), jnp.asarray(x0), 1e-4, 1e-4, params)), x0


def test_no_travel_gives_the_scene_without_traverse_bit_for_bit():
    """U = 0 with ``traverse`` listed: the same rows and initial state, to the last bit."""
    base = load_scene("fsw_small").with_overrides({"effects": EULERIAN})
    (r0, x0), (r1, x1) = _rows(base), _rows(base.with_overrides({"effects": EULERIAN + ",traverse"}))
    assert np.array_equal(r0, r1) and np.array_equal(x0, x1)


def test_bad_contact_and_travel_refused_naming_the_key():
    base = load_scene("fsw_weld")
    for key, value in (("tool.contact_state", "1.2"), ("tool.contact_state", "-0.1"),
                       ("tool.traverse_speed", "-1e-3")):
        with pytest.raises(SceneError, match=key.replace(".", r"\.")):
            base.with_overrides({key: value})
    with pytest.raises(SceneError, match="'traverse' with 'lagrangian'"):
        load_scene("fsw_small").with_overrides({"effects": "viscous,lagrangian,traverse"})
    with pytest.raises(SceneError, match="'slip' with 'lagrangian'"):
        load_scene("fsw_small").with_overrides({"effects": "viscous,lagrangian,slip"})
    with pytest.raises(SceneError, match=r"tool\.traverse_speed.*'traverse' effect"):
        load_scene("fsw").with_overrides({"tool.traverse_speed": "1e-3"})
    with pytest.raises(SceneError, match=r"tool\.contact_state.*'slip' effect"):
        load_scene("fsw").with_overrides({"tool.contact_state": "0.7"})


U = 1e-3


@pytest.fixture(scope="module")
def travelling():
    """fsw_small's physics on its fixed cloud (0.75 mm), the tool travelling at 1 mm/s, from
    the quasi-static flow, five 10 ms steps by Newton; the MLS fields at the end."""
    scene = load_scene("fsw_small").with_overrides({
        "effects": EULERIAN + ",traverse", "tool.traverse_speed": U, "time.dt": 0.01, "time.t_end": 0.05,
        "time.save": "0.05", "solver.kind": "newton", "mechanics.start": "quasi_static", "geometry.rezone": 0.0})
    res = run(scene)
    cloud = build_cloud(scene.geometry)
    model = make_model(scene, cloud)
    st = cloud_stencils(cloud.points, cloud.n_tool, scene.geometry)
    nodal = model.split(model.fit_state(np.stack([res.u[-1], res.v[-1], res.T[-1]], 1), st))

    def at(pts):
        s = evaluate_stencils(cloud.points, cloud.n_tool, scene.geometry, pts, derivatives=False)
        return {k: np.asarray(mls.value(s, nodal[k])) for k in "uvT"}

    return scene, at


def test_net_mass_flux_through_circles_vanishes(travelling):
    """Through the ring r = R2 (its rows: V = (-U, 0)) and through circles inside the plate
    (the integral of div V over the annulus between them and the edges), the net flux is a
    small fraction of the flux 2 r U that crosses each half circle."""
    scene, at = travelling
    g = scene.geometry
    th = 2 * np.pi * (np.arange(360) + 0.5) / 360
    for R in (g.R2 * (1 - 1e-9), 0.5 * (g.R1 + g.R2), 1.2 * g.R1):
        f = at(R * np.stack([np.cos(th), np.sin(th)], 1))
        flux = np.sum(f["u"] * np.cos(th) + f["v"] * np.sin(th)) * R * 2 * np.pi / 360
        # 5e-3: measured 4e-8 (ring), 2e-5 and 3e-4 (inside) on this cloud, 1e-3 at half its
        # spacing; the midpoint rule in angle is exact to round-off for these smooth fields
        assert abs(flux) < 5e-3 * 2 * R * U, (R, flux / (2 * R * U))


def test_trailing_side_hotter_within_the_moving_source_bound(travelling):
    """At 2, 3 and 4.5 mm from the axis the rise behind the tool (x < 0) exceeds the rise ahead
    of it (x > 0).  A line source moving at U through an infinite plate (Rosenthal's steady
    solution, ``exp(-U x / 2 alpha) K0(U r / 2 alpha)``) has ``ln(rise_trail / rise_lead) =
    U r / alpha`` at distance r; the run, 50 ms after the start, has not reached that steady
    state, so its ratio lies between 0 and that bound."""
    scene, at = travelling
    m, T0 = scene.material, scene.thermal.T0
    alpha = m.k / (m.rho * m.Cp)
    for r in (2e-3, 3e-3, 4.5e-3):
        T = at(np.array([[r, 0.0], [-r, 0.0]]))["T"]
        asym = math.log((T[1] - T0) / (T[0] - T0))
        assert 0 < asym < U * r / alpha


def test_through_flow_passes_the_pin_on_both_sides(travelling):
    """Through the section x = 0 outside the tool the plate carries the through-flow 2 R2 U
    that entered the leading half ring; the tool's rotation adds to it on the retreating side
    (y > 0, the tool surface moving with the plate's stream past it) and takes from it on the
    advancing side.  Measured: 1.13 and -0.42 of 2 R2 U, together 0.71: the penalised
    incompressibility (lambda = 0.1 mu_ref, while the slowly sheared far field has mu ~ 60
    mu_ref) lets about 30 % of the through-flow compress ahead of the pin and expand behind
    it instead of passing it (docs/notes/traverse_and_slip.md); the bounds hold that much."""
    scene, at = travelling
    g = scene.geometry
    y = np.linspace(g.R1, g.R2, 801)
    w = np.full(y.size, y[1] - y[0])
    w[[0, -1]] *= 0.5
    retreating = -np.sum(w * at(np.stack([0 * y, y], 1))["u"])
    advancing = -np.sum(w * at(np.stack([0 * y, -y], 1))["u"])
    assert retreating > advancing
    # 0.5: well below the 0.71 measured (0.73 at half the spacing: the defect is the model's,
    # not the cloud's); 1.05: no more than the through-flow, beyond the integration's error
    assert 0.5 < (retreating + advancing) / (2 * g.R2 * U) < 1.05


def test_tracers_leaving_the_disc_reenter_on_the_leading_side_at_their_height():
    """A tracer carried past r = R2 comes back on the leading side at (sqrt(R2^2 - y^2), y),
    its carried polar velocity that of the inflow (-U, 0) there; the others are untouched."""
    import types

    from jaxanm.fsw.lagrangian import RunRecorder

    scene = load_scene("fsw_weld")
    R2, U = scene.geometry.R2, scene.tool.traverse_speed
    free = np.array([[-R2 * 1.001, 0.3 * R2], [0.5 * R2, -0.2 * R2], [-0.2 * R2, -R2 * 1.0005]])
    host = types.SimpleNamespace(scene=scene, tracer_velocity=np.ones((3, 2)))
    moved = RunRecorder._reentered(host, free)
    for i, y in ((0, 0.3 * R2), (2, -R2)):
        assert moved[i, 1] == y and moved[i, 0] == pytest.approx(math.sqrt(R2 * R2 - y * y), abs=1e-15)
    assert np.array_equal(moved[1], free[1]) and np.array_equal(host.tracer_velocity[1], [1.0, 1.0])
    x, y = moved[0]
    r = math.hypot(x, y)
    # (-U, 0) in polar form about the axis: angular speed (x v - y u) / r^2, radial (x u + y v) / r
    assert host.tracer_velocity[0] == pytest.approx([y * U / r ** 2, -x * U / r], rel=1e-12)
