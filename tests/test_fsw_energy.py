"""Energy balance of the FSW heat equation against the continuum (docs/notes/energy_balance.md).

Newtonian (n = 1) circular Couette flow between the turning tool and the fixed ring, heated by
its own dissipation, every edge insulated (no ``tool_conduction``, no ``robin``): the continuum
stores exactly ``beta P t``, with ``P = 4 pi mu omega^2 R1^2 R2^2 / (R2^2 - R1^2)`` per unit
thickness (closed form, independent of the code).  n = 1 keeps the shear layer wide
(``q ~ r^-4``), so the discrete flow is accurate and what is measured is the heat equation's
balance.  The stored heat is ``int rho Cp (T - T0) dA`` of the MLS temperature field,
integrated on a fine polar Gauss grid (not on the points).
"""

from __future__ import annotations

import math
import types

import jax.numpy as jnp
import numpy as np
import pytest

import jaxanm
from jaxanm import mls
from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.energy import annulus_quadrature, dissipated_power, stored_heat
from jaxanm.fsw.geometry import PLATE_EDGE, build_cloud, evaluate_stencils
from jaxanm.fsw.scene import Geometry, Material, Scene, Thermal, Time


def _couette_power_newtonian(scene) -> float:
    """Dissipated power per unit thickness of the steady Newtonian Couette flow (W/m)."""
    m, g, om, T0 = scene.material, scene.geometry, scene.tool.omega, scene.thermal.T0
    mu = m.K * T0 ** m.A / 3.0  # mu = K T^A epsbar^(n-1) / 3 at n = 1
    return 4.0 * math.pi * mu * om ** 2 * g.R1 ** 2 * g.R2 ** 2 / (g.R2 ** 2 - g.R1 ** 2)


def _one_step(scene):
    """``(cloud, stencils, model, x)`` after one step of ``scene.time.dt`` from rest, by Newton
    to 1e-10 (the discrete solution to round-off)."""
    cloud, st, model, params, x0 = discretise(scene)
    dt = scene.time.dt
    sol = jaxanm.integrate(model.residual, x0, params, t0=0.0, t1=dt, dt=dt,
                           solver=jaxanm.Newton(tol=1e-10), scale=model.scale(),
                           jacobian="sparse", sparsity=model.sparsity)
    return cloud, st, model, sol.xs[-1]


def _stored_over_beta_P_t(dr: float, edge_rows: str) -> float:
    scene = Scene(effects=("viscous", "conduction", "dissipation"),
                  geometry=Geometry(dr=dr, c=0.3), material=Material(n=1.0, eps0=1e-4),
                  time=Time(dt=1e-3, t_end=1e-3), thermal=Thermal(edge_rows=edge_rows))
    cloud, st, model, x = _one_step(scene)
    g, m = scene.geometry, scene.material
    pts, w = annulus_quadrature(g.R1, g.R2)
    T = np.asarray(mls.value(evaluate_stencils(cloud.points, cloud.n_tool, g, pts), model.split(x)["T"]))
    stored = float(np.sum(w * m.rho * m.Cp * (T - scene.thermal.T0)))
    return stored / (m.beta * _couette_power_newtonian(scene) * 1e-3)


def test_newtonian_couette_power_closed_form():
    """The closed form above: torque M = 4 pi mu omega R1^2 R2^2 / (R2^2 - R1^2) times omega."""
    scene = Scene(effects=("viscous",), material=Material(n=1.0))
    g, mu = scene.geometry, scene.material.K * scene.thermal.T0 ** scene.material.A / 3.0
    r = np.linspace(scene.geometry.R1, scene.geometry.R2, 200001)
    # v = a r + b / r with v(R1) = omega R1, v(R2) = 0; dissipation mu (r d(v/r)/dr)^2
    b = scene.tool.omega * g.R1 ** 2 * g.R2 ** 2 / (g.R2 ** 2 - g.R1 ** 2)
    q = mu * (2 * b / r ** 2) ** 2 * 2 * math.pi * r
    assert math.isclose(np.trapezoid(q, r), _couette_power_newtonian(scene), rel_tol=1e-6)


def test_annulus_quadrature_integrates_the_couette_dissipation_to_round_off():
    """The default rule on the tool-to-ring annulus against the closed form of
    :func:`_couette_power_newtonian` (the density mu (2 b / r^2)^2, steepest at R1)."""
    scene = Scene(effects=("viscous",), material=Material(n=1.0))
    g, mu = scene.geometry, scene.material.K * scene.thermal.T0 ** scene.material.A / 3.0
    b = scene.tool.omega * g.R1 ** 2 * g.R2 ** 2 / (g.R2 ** 2 - g.R1 ** 2)
    pts, w = annulus_quadrature(g.R1, g.R2)
    r = np.hypot(pts[:, 0], pts[:, 1])
    # 1e-10: 60 three-point Gauss cells integrate this r^-3 density to 3e-12 (measured), well inside it
    assert math.isclose(np.sum(w * mu * (2 * b / r ** 2) ** 2), _couette_power_newtonian(scene), rel_tol=1e-10)


def test_half_cell_edge_rows_keep_the_dissipated_heat():
    """With the edge half-cell balance the plate stores beta P t (the continuum balance).

    Measured (stored / beta P t): dr = 1.5e-3, 7.5e-4, 3.75e-4: 0.77, 0.92, 0.994 with
    ``edge_rows="half_cell"``; 0.73, 0.82, 0.91 with the flux rows ("flux"), which leave out the
    heat dissipated within dr/2 of the tool edge (38 % of P at dr = 7.5e-4).
    """
    # 0.02 is not derived: the balance's error (0.232, 0.085, 0.0062 at these three dr) is
    # pre-asymptotic (ratios 2.7 and 14: the n = 1 source q ~ r^-4 varies on R1/4, which is dr
    # here), so the coarser levels give no rate to extrapolate.  It cannot move with the CPU:
    # Newton to 1e-10 on a deterministic discretisation, 4e-15 apart with XLA's AVX2 code.
    assert _stored_over_beta_P_t(3.75e-4, "half_cell") == pytest.approx(1.0, abs=0.02)


@pytest.mark.slow
def test_half_cell_energy_error_falls_faster_than_the_flux_rows():
    dr = (1.5e-3, 7.5e-4, 3.75e-4)
    half = [abs(1 - _stored_over_beta_P_t(d, "half_cell")) for d in dr]
    flux = [abs(1 - _stored_over_beta_P_t(d, "flux")) for d in dr]
    assert all(a > b for a, b in zip(half, half[1:])), half
    assert all(h < f for h, f in zip(half, flux)), (half, flux)
    assert half[-1] < 0.02 < 0.05 < flux[-1], (half, flux)


def _graded_stored_over_beta_Ph_t(edge_source: str) -> float:
    """Stored heat over ``beta P_h t`` after one 1 ms step of the paper's power law (n = 0.1324)
    on a graded cloud (0.1 mm at the tool edge, fsw_graded's grading), every edge insulated.

    ``P_h`` is the discrete flow's own dissipated power (fine quadrature of ``3 mu epsbar^2``
    of its MLS velocity), so what is measured is the heat rows' balance, not the flow's error.
    """
    scene = Scene(effects=("viscous", "conduction", "dissipation"),
                  geometry=Geometry(layout="graded", dr=1e-4, band=2e-4, grading=1.25, dr_far=3.75e-4, c=0.3),
                  material=Material(eps0=0.1), time=Time(dt=1e-3, t_end=1e-3),
                  thermal=Thermal(edge_rows="half_cell", edge_source=edge_source))
    cloud, st, model, x = _one_step(scene)
    values = model.values(x, st)
    result = types.SimpleNamespace(scene=scene, points=cloud.points[None],
                                   **{f: values[None, :, i] for i, f in enumerate(model.fields)})
    return stored_heat(result) / (scene.material.beta * dissipated_power(result) * 1e-3)


def test_exponential_edge_source_keeps_the_steep_power_law_heat():
    """At n = 0.1324 the source falls by e within 0.088 mm of the tool edge, so once the edge
    spacing resolves it (0.1 mm) the one-point half-cell source ``q(R1) dr/2`` over-counts
    (stored / beta P_h t = 1.050 measured; the e-folding estimate of the over-count is 0.135 for
    the continuum's peak, less for the discrete q(R1)).  Integrated along its local decay
    (``edge_source = "exponential"``) it stores what the flow dissipates: 1.005 measured.
    """
    # 0.02: the collocation's own balance error, as in the Newtonian test above (0.0062 at the
    # paper's dr there), well below the 0.05 that the point quadrature's over-count makes here.
    assert _graded_stored_over_beta_Ph_t("exponential") == pytest.approx(1.0, abs=0.02)


@pytest.mark.slow
def test_point_edge_source_overcounts_the_steep_power_law_heat():
    assert _graded_stored_over_beta_Ph_t("point") > 1.03  # the 0.05 over-count measured above


@pytest.mark.parametrize("tool_conduction,edge_source",
                         [(False, "point"), (True, "point"), (True, "exponential")])
def test_half_cell_row_is_the_edge_cell_balance(tool_conduction, edge_source):
    """On quadratic u, v, T (reproduced exactly by the MLS stencils) the plate-edge row equals
    ``d (rho Cp T_t - k Lap T) - w q [+ d (rho_t Cp_t T_t - k_t Lap T)] - (k - k_t) dT/dr``,
    d = dr/2, evaluated from the analytic fields (up to the row's positive scale).  The source's
    width is ``w = d`` (``"point"``), or ``w = lam (1 - exp(-d / lam))`` with ``1 / lam =
    -(dq/dr) / q`` where q decays outwards and ``w = d`` where it does not (``"exponential"``)."""
    effects = ("viscous", "conduction", "dissipation") + (("tool_conduction",) if tool_conduction else ())
    scene = Scene(effects=effects, geometry=Geometry(dr=7.5e-4, c=0.3),
                  material=Material(n=0.3, eps0=0.5),
                  thermal=Thermal(edge_rows="half_cell", edge_source=edge_source))
    cloud, st, model, params, _ = discretise(scene)
    m, tl, th, g = scene.material, scene.tool, scene.thermal, scene.geometry
    pts, dt = cloud.points, 1e-4
    x, y = pts[:, 0], pts[:, 1]
    L = g.R2
    u = 1e-2 * (0.01 + 3 * x - 2 * y + 40 / L * x * x - 70 / L * x * y + 25 / L * y * y)
    v = 1e-2 * (-0.02 + x - 40 * y - 30 / L * x * x + 20 / L * x * y + 60 / L * y * y)
    T = 420 + 3e3 * x - 2e3 * y + 5e6 * x * x - 3e6 * x * y + 4e6 * y * y
    T_old = 0.999 * T
    ux, uy = 1e-2 * (3 + 80 / L * x - 70 / L * y), 1e-2 * (-2 - 70 / L * x + 50 / L * y)
    vx, vy = 1e-2 * (1 - 60 / L * x + 20 / L * y), 1e-2 * (-40 + 20 / L * x + 120 / L * y)
    Tx, Ty, lapT = 3e3 + 1e7 * x - 3e6 * y, -2e3 - 3e6 * x + 8e6 * y, 1e7 + 8e6
    e2 = 2 / 3 * (ux ** 2 + vy ** 2 + 0.5 * (uy + vx) ** 2)
    q = 3 * m.beta * m.K / 3 * th.T0 ** m.A * (e2 + m.eps0 ** 2) ** ((m.n - 1) / 2) * e2
    dTdt = (T - T_old) / dt
    r = np.maximum(np.hypot(x, y), 1e-12)  # (the centre point is no edge point)
    dTdr = (Tx * x + Ty * y) / r
    d = g.dr / 2
    width = np.full_like(q, d)
    if edge_source == "exponential":
        # dq/dr by the chain rule on e2 (the hand-written second derivatives of u, v)
        exy, exy_x, exy_y = 0.5 * (uy + vx), 0.5e-2 * (-70 - 60) / L, 0.5e-2 * (50 + 20) / L
        e2x = 4 / 3 * (ux * 80e-2 / L + vy * 20e-2 / L + 2 * exy * exy_x)
        e2y = 4 / 3 * (ux * -70e-2 / L + vy * 120e-2 / L + 2 * exy * exy_y)
        er2 = e2 + m.eps0 ** 2
        dq_de2 = q / e2 * (1 + 0.5 * (m.n - 1) * e2 / er2)
        dqdr = dq_de2 * (e2x * x + e2y * y) / r
        decays = dqdr < 0
        lam = -q[decays] / dqdr[decays]
        width[decays] = lam * (1 - np.exp(-d / lam))
        edge = cloud.kind == PLATE_EDGE
        assert 0 < np.count_nonzero(decays[edge]) < np.count_nonzero(edge)  # both branches tested
    expect = d * (m.rho * m.Cp * dTdt - m.k * lapT) - width * q - m.k * dTdr
    if tool_conduction:
        expect = expect + d * (tl.rho * tl.Cp * dTdt - tl.k * lapT) + tl.k * dTdr
    with jaxanm.float64():
        rows = np.asarray(model.residual(jnp.asarray(np.concatenate([u, v, T])),
                                         jnp.asarray(np.concatenate([u, v, T_old])), dt, dt, params))
    edge = cloud.kind == PLATE_EDGE
    got = rows.reshape(3, -1)[2, edge]
    scale = got / expect[edge]
    assert np.all(scale > 0) and np.ptp(scale) <= 1e-7 * scale.mean(), scale


def _sampled(scene, u, v, T):
    """A result-like object holding fields sampled at the scene's points (one saved step)."""
    cloud = build_cloud(scene.geometry)
    x, y = cloud.points.T
    return types.SimpleNamespace(scene=scene, points=cloud.points[None], u=u(x, y)[None],
                                 v=v(x, y)[None], T=T(x, y)[None])


def test_stored_heat_of_a_uniform_rise_is_the_heat_capacity():
    scene = Scene(effects=("viscous", "conduction", "tool_conduction"), geometry=Geometry(c=0.3))
    g, m, tl = scene.geometry, scene.material, scene.tool
    zero = lambda x, y: 0 * x  # noqa: E731
    res = _sampled(scene, zero, zero, lambda x, y: 0 * x + scene.thermal.T0 + 2.0)
    exact = 2.0 * (m.rho * m.Cp * math.pi * (g.R2 ** 2 - g.R1 ** 2) + tl.rho * tl.Cp * math.pi * g.R1 ** 2)
    assert stored_heat(res) == pytest.approx(exact, rel=1e-10)


def test_dissipated_power_of_the_newtonian_couette_field():
    """The exact n = 1 Couette velocity, sampled at the points, dissipates the closed-form P
    (the MLS refit of this smooth field is accurate to well below 1 % at the paper's dr)."""
    scene = Scene(effects=("viscous", "conduction"), geometry=Geometry(c=0.3),
                  material=Material(n=1.0, eps0=1e-4))
    g, om = scene.geometry, scene.tool.omega
    b = om * g.R1 ** 2 * g.R2 ** 2 / (g.R2 ** 2 - g.R1 ** 2)
    a = -b / g.R2 ** 2

    def speed_over_r(x, y):
        r2 = np.maximum(x * x + y * y, g.R1 ** 2)  # rigid rotation inside the tool
        return np.where(x * x + y * y < g.R1 ** 2, om, a + b / r2)

    res = _sampled(scene, lambda x, y: -y * speed_over_r(x, y), lambda x, y: x * speed_over_r(x, y),
                   lambda x, y: 0 * x + scene.thermal.T0)
    assert dissipated_power(res) == pytest.approx(_couette_power_newtonian(scene), rel=1e-2)
