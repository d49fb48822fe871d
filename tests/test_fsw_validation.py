"""Validation of the FSW model against references nobody tuned.

- the strong form: on quadratic fields (reproduced exactly by the MLS stencils) every residual
  row equals the pointwise equation evaluated by autodiff of the analytic constitutive law;
- isothermal power-law circular Couette flow: closed form ``v(r)``, errors fall under
  refinement (fitted slope) for n = 1 and n = 0.3;
- conduction across the tool/plate conductivity jump with a Robin edge: an independent 1-D
  radial finite-volume solution (same implicit Euler steps), errors fall under refinement;
- Lagrangian motion: rigid tool, no point lost, colours conserved;
- ANM and Newton agree on fsw_paper over a short span (slow).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanm
from jaxanm.fsw import load_scene, run
from jaxanm.fsw.axisymmetric import couette_exact, radial_finite_volumes
from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.geometry import PLATE, PLATE_EDGE, RING, TOOL, TOOL_EDGE, build_cloud
from jaxanm.fsw.scene import Geometry, Material, Scene, Thermal, Time

GAP = 4.5e-3  # R2 - R1 of every scene below


def _discretise(scene):
    cloud, st, model, params, _ = discretise(scene)
    return cloud, st, model, params


def _slope(dr, err):
    return float(np.polyfit(np.log(dr), np.log(err), 1)[0])


# ------------------------------------------------------------------ strong form, pointwise

def _quadratic(coef, xy):
    x, y = xy[..., 0], xy[..., 1]
    return coef[0] + coef[1] * x + coef[2] * y + coef[3] * x * x + coef[4] * x * y + coef[5] * y * y


def test_residual_rows_equal_the_pointwise_equations():
    """Every row of the full Eulerian model on quadratic u, v, T against the analytic law.

    ``div sigma`` is differentiated by autodiff of ``sigma(x)`` (no hand-written chain rule),
    so the pointwise momentum, heat, interface and boundary rows are checked independently.
    """
    effects = ("inertia", "viscous", "softening", "conduction", "tool_conduction", "dissipation",
               "robin", "tracers")
    scene = Scene(effects=effects, geometry=Geometry(dr=7.5e-4),
                  material=Material(n=0.3, eps0=0.5), thermal=Thermal(h=5e3, Ta=290.0, T0=300.0))
    scene = scene.with_overrides({"mechanics.penalty": 2e6})
    cloud, st, model, params = _discretise(scene)
    m, tl, th, g = scene.material, scene.tool, scene.thermal, scene.geometry
    lam, omega, dt, U, Ts = scene.mechanics.penalty, tl.omega, 1e-4, tl.omega * g.R1, th.T0
    L = g.R2
    cu = np.array([0.01, 3.0, -2.0, 40 / L, -70 / L, 25 / L]) * 0.01
    cv = np.array([-0.02, 1.0, 4.0, -30 / L, 20 / L, 60 / L]) * 0.01
    cT = np.array([420.0, 3e3, -2e3, 5e6, -3e6, 4e6])
    old = [c * f for c, f in zip((cu, cv, cT), (0.9, 1.1, 0.999))]

    def fields(coefs, xy):
        return [_quadratic(c, xy) for c in coefs]

    pts = cloud.points
    x_new = np.concatenate(fields((cu, cv, cT), pts))
    x_old = np.concatenate(fields(old, pts))
    with jaxanm.float64():
        r = np.asarray(model.residual(jnp.asarray(x_new), jnp.asarray(x_old), 0.0, dt, params))

        def mu_of(xy):
            grad = jax.jacfwd(lambda z: jnp.stack(fields((cu, cv), z)))(xy)
            e = 0.5 * (grad + grad.T)
            e2 = 2.0 / 3.0 * jnp.sum(e * e)
            T = _quadratic(cT, xy)
            return m.K / 3 * T ** m.A * (e2 + m.eps0 ** 2) ** ((m.n - 1) / 2), e, e2

        def sigma(xy):
            mu, e, _ = mu_of(xy)
            return lam * jnp.trace(e) * jnp.eye(2) + 2 * mu * e

        def pointwise(xy):
            u, v, T = fields((cu, cv, cT), xy)
            uo, vo, To = fields(old, xy)
            gV = jax.jacfwd(lambda z: jnp.stack(fields((cu, cv), z)))(xy)
            gT = jax.grad(lambda z: _quadratic(cT, z))(xy)
            lapT = jnp.trace(jax.hessian(lambda z: _quadratic(cT, z))(xy))
            div_sigma = jnp.einsum("ijj->i", jax.jacfwd(sigma)(xy))
            V = jnp.stack([u, v])
            acc = m.rho * ((V - jnp.stack([uo, vo])) / dt + gV @ V)
            mu, _, e2 = mu_of(xy)
            dTdt = (T - To) / dt + V @ gT
            plate_heat = m.rho * m.Cp * dTdt - m.k * lapT - 3 * m.beta * mu * e2
            tool_heat = tl.rho * tl.Cp * dTdt - tl.k * lapT
            n = xy / jnp.linalg.norm(xy)
            return (acc - div_sigma) / mu, V, T, gT @ n, plate_heat, tool_heat

        out = jax.vmap(pointwise)(jnp.asarray(pts))
    momentum, V, T, dTdn, plate_heat, tool_heat = (np.asarray(o) for o in out)
    N, kind, dr = cloud.size, cloud.kind, g.dr
    mu_ref = m.K * th.T0 ** m.A * omega ** (m.n - 1) / 3
    s_m = dr ** 2 / (U * (1 + lam / mu_ref + m.rho * dr ** 2 / (mu_ref * dt)))
    tool_v = omega * np.stack([-pts[:, 1], pts[:, 0]], axis=1)
    expect_V = np.where((kind == PLATE)[:, None], momentum * s_m,
                        np.where((kind == RING)[:, None], V, V - tool_v) / U)
    s_plate = dr ** 2 / (Ts * (m.k + m.rho * m.Cp * dr ** 2 / dt))
    s_tool = dr ** 2 / (Ts * (tl.k + tl.rho * tl.Cp * dr ** 2 / dt))
    s_flux = dr / (m.k * Ts)
    expect_T = np.select(
        [kind == TOOL, kind == TOOL_EDGE, kind == PLATE_EDGE, kind == PLATE, kind == RING],
        [tool_heat * s_tool, 0.0 * T, (m.k - tl.k) * dTdn * s_flux, plate_heat * s_plate,
         (m.k * dTdn + th.h * (T - th.Ta)) * s_flux])
    rows = r.reshape(3, N)
    for got, want, what in ((rows[0], expect_V[:, 0], "u"), (rows[1], expect_V[:, 1], "v"),
                            (rows[2], expect_T, "T")):
        scale = np.max(np.abs(want))
        assert scale > 0
        err = np.max(np.abs(got - want)) / scale
        assert err < 1e-7, f"{what} rows differ from the pointwise equations by {err:.3g}"


# ------------------------------------------------------------------ power-law Couette flow

def couette_error(K: int, ns, eps0: float) -> float:
    """Max |V - V_exact| / (omega R1) over the plate, at dr = (R2 - R1) / K.

    The stationary problem (no inertia) is solved by Newton, continued in n through ``ns``
    (each solution starts the next) and compared for the last n.
    """
    x = None
    for n in ns:
        scene = Scene(effects=("viscous",), geometry=Geometry(dr=GAP / K),
                      material=Material(n=n, eps0=eps0), time=Time(dt=1.0, t_end=1.0))
        cloud, st, model, params = _discretise(scene)
        x0 = model.initial_state(cloud.points) if x is None else x
        sol = jaxanm.integrate(model.residual, x0, params, t0=0.0, t1=1.0, dt=1.0,
                               solver=jaxanm.Newton(tol=1e-10, max_iter=40), scale=model.scale(),
                               jacobian="sparse", sparsity=model.sparsity)
        x = sol.xs[-1]
    g, omega = scene.geometry, scene.tool.omega
    values = model.values(x, st)
    plate = cloud.kind >= PLATE_EDGE
    p = cloud.points[plate]
    r = np.hypot(p[:, 0], p[:, 1])
    vt = couette_exact(r, g.R1, g.R2, omega, ns[-1])
    exact = np.stack([-vt * p[:, 1] / r, vt * p[:, 0] / r], axis=1)
    return float(np.max(np.linalg.norm(values[plate] - exact, axis=1)) / (omega * g.R1))


def test_couette_newtonian_converges():
    Ks = (6, 8, 12, 16)
    dr = [GAP / K for K in Ks]
    err = [couette_error(K, (1.0,), 1e-4) for K in Ks]
    # measured: 1.49e-2, 1.00e-2, 7.25e-3, 4.01e-3; fitted slope 1.26
    assert all(a > b for a, b in zip(err, err[1:])), err
    # First order is what the theory gives (quadratic MLS basis: the rows' second derivatives
    # err by O(dr)), so the finest error is held to it with the largest constant err/dr of the
    # coarser clouds (err K = 0.089, 0.080, 0.087 at K = 6, 8, 12): <= 5.6e-3 at K = 16.  It
    # replaces slope > 1.1 and err < 5e-3, which asked more than first order (the fixed 5e-3
    # sat below what first order allows).  Deterministic: errors 1e-3, Newton to 1e-10.
    assert err[-1] <= max(e / d for e, d in zip(err[:-1], dr[:-1])) * dr[-1], (err, _slope(dr, err))


@pytest.mark.slow
def test_couette_power_law_converges():
    """n = 0.3: the shear layer is steep (v/r ~ r^-6.7); errors fall once dr resolves it."""
    Ks = (12, 16, 24)
    err = [couette_error(K, (1.0, 0.7, 0.5, 0.4, 0.3), 1e-4) for K in Ks]
    slope = _slope([GAP / K for K in Ks], err)
    # measured: 4.42e-2, 2.83e-2, 1.28e-2; slope 1.8
    assert all(a > b for a, b in zip(err, err[1:])), err
    assert slope > 1.4, (slope, err)
    assert err[-1] < 1.5e-2, err


@pytest.mark.slow
def test_couette_paper_exponent_converges():
    """n = 0.1324 (the paper's): v/r ~ r^-15, a shear layer thinner than the paper's dr.

    eps0 = 1e-2 (fsw_paper uses 1e-1): the regularised law departs from the closed form by at
    most 7.8e-4 omega R1 (1-D solution), far below these errors (about 2.5 min).
    """
    Ks = (12, 16, 24)
    ns = (1.0, 0.7, 0.5, 0.4, 0.3, 0.25, 0.2, 0.17, 0.15, 0.1324)
    err = [couette_error(K, ns, 1e-2) for K in Ks]
    slope = _slope([GAP / K for K in Ks], err)
    # measured: 8.07e-2, 6.78e-2, 4.02e-2 (and 2.67e-2 at K = 32); slope 1.0
    assert all(a > b for a, b in zip(err, err[1:])), err
    assert slope > 0.8, (slope, err)
    assert err[-1] < 5e-2, err


# ------------------------------------------------------------------ conduction across the jump

def conduction_error(K: int) -> float:
    """Max |T - T_ref| / (T0 - Ta) at t = 0.5 s of conduction_small at dr = (R2 - R1) / K."""
    scene = load_scene("conduction_small").with_overrides({"geometry.dr": GAP / K})
    cloud, st, model, params = _discretise(scene)
    tm, th, m, tl, g = scene.time, scene.thermal, scene.material, scene.tool, scene.geometry
    steps = round(tm.t_end / tm.dt)
    sol = jaxanm.integrate(model.residual, model.initial_state(cloud.points), params, t0=0.0,
                           t1=tm.t_end, dt=tm.dt, solver=jaxanm.Newton(tol=1e-10),
                           scale=model.scale(), sparsity=model.sparsity)
    T = model.values(sol.xs[-1], st)[:, 0]
    rc, T_ref = radial_finite_volumes(g.R1, g.R2, tl.k, m.k, tl.rho * tl.Cp, m.rho * m.Cp, th.h,
                                      th.Ta, th.T0, tm.dt, steps)
    r = np.hypot(*cloud.points.T)
    return float(np.max(np.abs(T - np.interp(r, rc, T_ref))) / (th.T0 - th.Ta))


def test_radial_reference_is_converged():
    """The reference itself: halving its cells changes it by < 1e-5 of the range."""
    args = (1.5e-3, 6e-3, 36.0, 140.0, 7800 * 450.0, 2780 * 920.0, 2e4, 300.0, 600.0, 0.05, 10)
    rc, T = radial_finite_volumes(*args, cells=1500)
    rc2, T2 = radial_finite_volumes(*args, cells=3000)
    assert np.max(np.abs(np.interp(rc, rc2, T2) - T)) / 300 < 1e-5
    # the disc has cooled and is far from uniform (389.6 to 446.8 K): a premise of the test below,
    # not derived.  Deterministic (a direct sparse solve, round-off ~1e-12 K).  Derived is only
    # that the heat-weighted mean (411.6 K) is at least the lumped implicit-Euler value 390.5 K:
    # the Robin surface is the coolest point, so the disc loses heat slower than a lumped one
    assert 380 < T.min() < T.max() < 450


def test_conduction_across_tool_edge_converges():
    Ks = (6, 8, 12, 16)
    dr = [GAP / K for K in Ks]
    err = [conduction_error(K) for K in Ks]
    # measured: 2.7e-3, 2.1e-3, 9.9e-4, 5.0e-4; fitted slope 1.7 (c = 0.3, half-cell edge rows;
    # with c = 0.2 and flux rows 7.3e-3, 5.2e-3, 2.9e-3, 1.8e-3, slope 1.4)
    assert all(a > b for a, b in zip(err, err[1:])), err
    # first order, as for the Couette flow above (the Laplacian's MLS error is O(dr)), with the
    # largest constant of the coarser clouds (err K = 0.016, 0.017, 0.012): <= 1.04e-3 at K = 16
    assert err[-1] <= max(e / d for e, d in zip(err[:-1], dr[:-1])) * dr[-1], (err, _slope(dr, err))


# ------------------------------------------------------------------ Lagrangian motion

def test_lagrangian_motion_rigid_tool_no_loss_colours_kept():
    scene = load_scene("fsw_small").with_overrides({
        "effects": "viscous,conduction,dissipation,softening,tool_conduction,robin,lagrangian",
        "material.n": 0.3, "time.dt": 4e-3, "time.t_end": 0.04, "time.save": "0.02",
        "solver.kind": "newton"})
    res = run(scene)
    cloud = build_cloud(scene.geometry)
    g = scene.geometry
    assert res.t.tolist() == pytest.approx([0.0, 0.02, 0.04])
    assert np.all(np.isfinite(res.points)) and np.all(np.isfinite(res.u)) and np.all(np.isfinite(res.T))
    assert np.array_equal(res.material, cloud.material)
    rigid = np.flatnonzero(cloud.kind <= PLATE_EDGE)
    d0 = np.linalg.norm(cloud.points[rigid, None] - cloud.points[None, rigid], axis=-1)
    plate = np.flatnonzero(cloud.kind >= PLATE)
    for s in range(len(res.t)):
        P = res.points[s]
        d = np.linalg.norm(P[rigid, None] - P[None, rigid], axis=-1)
        assert np.max(np.abs(d - d0)) <= 1e-12 * np.max(d0)
        # the tool turned by omega t, exactly: each of the 10 steps rotates by a rounded (c, s),
        # an angle error of ~2 eps rad a step, and arctan2 / mod add a few eps of 2 pi: ~1e-14
        # rad against 1e-12 omega t >= 4e-13 rad (t >= 0.02).  atol = 0, not numpy's 1e-8 (t = 0
        # is exact: the saved points are the cloud's)
        e = np.flatnonzero(cloud.kind == TOOL_EDGE)[0]
        angle = np.arctan2(P[e, 1], P[e, 0]) - np.arctan2(cloud.points[e, 1], cloud.points[e, 0])
        assert np.isclose(np.mod(angle, 2 * np.pi), scene.tool.omega * res.t[s], rtol=1e-12, atol=0)
        r = np.hypot(P[:, 0], P[:, 1])
        assert np.all(r <= g.R2 * (1 + 1e-12))
        assert np.all(r[plate] > g.R1)  # no plate point entered the tool
    # the plate next to the tool was dragged along (counter-clockwise, slower than the tool)
    first = plate[np.abs(np.hypot(*cloud.points[plate].T) - (g.R1 + g.dr)) < 1e-9]
    turn = np.mod(np.arctan2(res.points[-1, first, 1], res.points[-1, first, 0])
                  - np.arctan2(cloud.points[first, 1], cloud.points[first, 0]) + np.pi, 2 * np.pi) - np.pi
    assert np.all(turn > 0) and np.all(turn < scene.tool.omega * res.t[-1])
    assert res.T[-1].max() > scene.thermal.T0  # dissipation heated the plate
    assert len(res.probes["t"]) == 11 and set(res.sections) == {"t", "A-A", "B-B"}
    assert res.sections["A-A"]["T"].shape == (3, 161) and np.all(np.isfinite(res.sections["A-A"]["u"]))


@pytest.mark.slow
def test_tracers_fixed_points_advected_particles():
    scene = load_scene("fsw_small").with_overrides({
        "effects": "viscous,conduction,dissipation,softening,tool_conduction,robin,tracers",
        "material.n": 0.3, "time.dt": 4e-3, "time.t_end": 0.04, "time.save": "0.02",
        "solver.kind": "newton"})
    res = run(scene)
    cloud = build_cloud(scene.geometry)
    assert np.all(res.points == cloud.points)  # Eulerian: the cloud does not move
    tr = res.tracers["points"]
    assert tr.shape == (3, cloud.size, 2) and np.array_equal(res.tracers["material"], cloud.material)
    rigid = cloud.kind <= PLATE_EDGE
    # 10 rigid rotations of the tracers, ~2 eps of radius each (see the Lagrangian test above);
    # atol = 0, not numpy's 1e-8, which would dominate on radii of 1e-3 m
    assert np.allclose(np.hypot(*tr[-1, rigid].T), np.hypot(*cloud.points[rigid].T), rtol=1e-12, atol=0)
    r = np.hypot(*tr[-1].T)
    plate = cloud.kind >= PLATE
    assert np.all(r[plate] > scene.geometry.R1) and np.all(r <= scene.geometry.R2 * (1 + 1e-9))
    moved = np.linalg.norm(tr[-1] - tr[0], axis=1)
    assert moved[plate].max() > 0 and res.T[-1].max() > scene.thermal.T0


# ------------------------------------------------------------------ ANM vs Newton

@pytest.mark.slow
def test_anm_and_newton_agree_on_fsw_paper():
    """Same discrete problem, two solvers: 5 steps of fsw_paper from rest (about 2.5 min).

    The scene's ANM (criterion "state") against Newton.  ``max_substeps`` is raised so that the
    impulsive start never falls back to halving dt (which would change the discrete problem).
    Measured with eq. 26 and eps0 = 1e-2: V differs by 4e-12, T - T0 by 5e-10 (relative).
    """
    scene = load_scene("fsw_paper").with_overrides({"time.t_end": 5e-4, "time.save": ""})
    anm = run(scene, solver=dataclasses.replace(scene.solver.make(), max_substeps=1000))
    newton = run(scene, solver=jaxanm.Newton(tol=1e-6))
    for res in (anm, newton):
        assert res.stats.time_steps == 5 and res.stats.dt_halvings == 0
    V = np.stack([anm.u[-1], anm.v[-1]], axis=1)
    Vn = np.stack([newton.u[-1], newton.v[-1]], axis=1)
    assert np.max(np.abs(V - Vn)) / np.max(np.abs(Vn)) <= 1e-5
    rise = newton.T[-1] - scene.thermal.T0
    assert np.max(rise) > 0.1
    assert np.max(np.abs(anm.T[-1] - newton.T[-1])) / np.max(np.abs(rise)) <= 1e-5


# ------------------------------------------------------------------ stability of the heat step

def _heat_step_spectral_radius(scene, dt: float) -> float:
    """Spectral radius of the linear implicit-Euler heat step ``x_old -> x_new`` (dense)."""
    cloud, st, model, params = _discretise(scene)
    x0 = jnp.asarray(model.initial_state(cloud.points))
    with jaxanm.float64():
        j_new = np.asarray(jax.jacfwd(lambda x: model.residual(x, x0, dt, dt, params))(x0))
        j_old = np.asarray(jax.jacfwd(lambda xo: model.residual(x0, xo, dt, dt, params))(x0))
    return float(np.abs(np.linalg.eigvals(-np.linalg.solve(j_new, j_old))).max())


def test_heat_step_of_the_paper_effects_is_stable():
    """Conduction with the tool/plate interface and Robin cooling is dissipative: the implicit-
    Euler heat step of fsw_small's cloud has spectral radius < 1 (the continuum decays).

    A strong-form collocation does not guarantee this: the paper's weight c = 0.2 gives an
    unstable interface mode on deformed Lagrangian clouds (docs/notes/anm_on_fsw_paper.md).
    This pins the configuration the FSW scenes use (c = 0.3, half-cell edge rows).
    """
    scene = load_scene("fsw_small").with_overrides({"effects": "conduction,tool_conduction,robin"})
    radius = _heat_step_spectral_radius(scene, 1e-4)
    assert radius < 1.0, radius
    # and the slowest mode is the Robin-cooled near-constant one, not a spurious fast mode:
    # uniform T decays at rate 2 h / (rho Cp R2)-ish, far below 1/dt (radius ~ 1 - 1e-5).
    # The margin below 1 is that physics, not luck: lumped, lambda = 2 pi R2 h / C with C the
    # heat capacity of disc and tool, 1 - 1/(1 + lambda dt) = 1.27e-5 (measured 1.26e-5);
    # the eigenvalue's round-off is ~ eps ||A|| times its condition number 1.2, ~ 4e-16
    assert radius > 1.0 - 1e-3, radius


@pytest.mark.parametrize("dt", [1e-4, 1e-3])
def test_half_cell_rows_make_the_insulated_tool_edge_stable(dt):
    """Without ``tool_conduction`` the tool edge is insulated.  Collocating ``dT/dr = 0`` alone
    there gives a growing mode (radius 1.018 at dt = 1e-4, 1.21 at 1e-3 on fsw_small's cloud:
    the continuum decays); the heat balance of the edge half cell does not."""
    scene = load_scene("fsw_small").with_overrides({"effects": "conduction,robin"})
    assert scene.thermal.edge_rows == "half_cell"
    # below 1 by the lumped Robin decay of the plate alone, 1 - 1/(1 + lambda dt) with
    # lambda = 2 pi R2 h / C_plate: 1.39e-5 and 1.39e-4 (measured 1.37e-5, 1.37e-4)
    assert 1.0 - 1e-3 < _heat_step_spectral_radius(scene, dt) < 1.0
    flux = scene.with_overrides({"thermal.edge_rows": "flux"})
    assert _heat_step_spectral_radius(flux, dt) > 1.0
