"""The axisymmetric oracle (:mod:`jaxanm.fsw.axisymmetric`) and the FSW model against it.

(a) The oracle against what it must reproduce: the isothermal power-law Couette closed form
(n = 1 and the paper's n = 0.1324), pure conduction against the older uniform-cell reference,
its exact discrete energy balance, and its own error estimate.
(b) The FSW model (:func:`jaxanm.fsw.simulate.run`, fixed points, fsw_tracers physics) against
the oracle: the steady dissipated power (torque times omega) and the temperature rise over
a short span, with tolerances from the measured spatial convergence.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import jaxanm
from jaxanm.fsw import axisymmetric as ax
from jaxanm.fsw import continuum_error, load_scene, run
from jaxanm.fsw.energy import dissipated_power
from jaxanm.fsw.scene import Material, Scene, Thermal

GAP = 4.5e-3  # R2 - R1 of every scene below


# ------------------------------------------------------------------ (a) the oracle itself

@pytest.mark.parametrize("n", [1.0, 0.1324])
def test_isothermal_couette_matches_the_closed_form_at_second_order(n):
    """eps0 = 1e-14: the regularisation is far below round-off wherever the flow is not at rest
    (the slowest shear, at R2 for n = 0.1324, is |s| ~ 1e-7 1/s, so (eps0/s)^2 ~ 1e-14)."""
    scene = Scene(effects=("viscous",), material=Material(n=n, eps0=1e-14))
    g, omega, m = scene.geometry, scene.tool.omega, scene.material
    err, torque = [], []
    for refine in (1, 2):
        sol = ax.solve(scene, [0.0], refine=refine)
        exact = ax.couette_exact(sol.plate_edges, g.R1, g.R2, omega, n)
        err.append(np.max(np.abs(sol.v_faces[0] - exact)) / (omega * g.R1))
        torque.append(sol.torque[0])
    # midpoint rule on a fixed smooth mesh mapping: error c w^2 + O(w^4); halving every cell
    # divides it by 4 (measured 3.998 for both n); 0.3 leaves room for the w^4 term only
    assert err[1] <= 0.3 * err[0], err
    # measured 9.6e-5 (n = 0.1324) and 7.8e-5 (n = 1) at refine = 1: the default mesh
    # (refine = 2) holds v to 1/4 of that, < 3e-5 omega R1
    assert err[1] < 3e-5, err
    # torque 2 pi R1^2 tau(R1), tau = K T0^A |s|^n 3^((1 - n)/2) / 3 with the closed form's
    # |s(R1)| = (2/n) omega R1^(-2/n) / (R1^(-2/n) - R2^(-2/n)); same second order: the
    # relative error of refine = 2 is at most that of the velocity there (c = 4/3 of the change)
    a = 2.0 / n
    s1 = a * omega * g.R1 ** -a / (g.R1 ** -a - g.R2 ** -a)
    exact_M = 2 * math.pi * g.R1 ** 2 * m.K * scene.thermal.T0 ** m.A / 3 * s1 ** n * 3 ** ((1 - n) / 2)
    assert abs(torque[1] / exact_M - 1) <= 4.0 / 3.0 * abs(torque[1] / torque[0] - 1) + 1e-12, (torque, exact_M)


def test_pure_conduction_matches_the_uniform_cell_reference():
    """Conduction across the tool edge with a Robin ring, implicit Euler with the reference's
    steps (the setup of tests/test_fsw_validation.py's reference check)."""
    args = (1.5e-3, 6e-3, 36.0, 140.0, 7800 * 450.0, 2780 * 920.0, 2e4, 300.0, 600.0, 0.05, 10)
    rc, T_ref = ax.radial_finite_volumes(*args, cells=3000)
    rc_c, T_c = ax.radial_finite_volumes(*args, cells=1500)
    scene = Scene(effects=("conduction", "tool_conduction", "robin"), thermal=Thermal(h=2e4, Ta=300.0, T0=600.0))
    sol = ax.solve(scene, [0.5], dt=0.05, scheme="euler")
    fine = ax.solve(scene, [0.5], dt=0.05, scheme="euler", refine=4)
    diff = np.max(np.abs(sol.temperature(rc, 0) - T_ref))
    # both are second order in space with the same time steps: each one's error is 4/3 of its
    # change under halving the cells (Richardson); measured 2.2e-3 K against 0.0022 + 4e-5
    own = 4.0 / 3.0 * np.max(np.abs(sol.temperature(rc, 0) - fine.temperature(rc, 0)))
    ref_own = 4.0 / 3.0 * np.max(np.abs(np.interp(rc, rc_c, T_c) - T_ref))
    assert diff <= own + ref_own, (diff, own, ref_own)
    assert diff > 0  # two independent assemblies, not one code twice
    assert 380 < T_ref.min() < T_ref.max() < 450  # the disc has cooled, unevenly (premise)


def test_discrete_energy_balance_is_exact_with_implicit_euler():
    """Heat stored = sum over steps of (beta P - Robin loss) dt, the end-of-step values: the
    implicit-Euler finite volumes conserve it exactly, and the midpoint source sums to beta P
    (module docstring).  Round-off and the fixed-point tolerance (1e-13 T0 a step) leave
    ~1e-11 of it (measured 1.1e-11); 1e-9 is that with room for 100 steps' accumulation."""
    scene = load_scene("fsw_paper")
    dt, th = 1e-4, scene.thermal
    times = np.arange(0, 101) * dt
    sol = ax.solve(scene, times, scheme="euler", dt=dt)
    loss = 2 * math.pi * scene.geometry.R2 * th.h * (sol.T_R2 - th.Ta)
    flux = scene.material.beta * sol.power - loss
    supplied = np.concatenate([[0.0], np.cumsum(flux[1:] * dt)])
    assert np.max(np.abs(sol.stored - supplied)[1:] / sol.stored[1:]) < 1e-9
    assert np.all(np.diff(sol.power) < 0)  # softening: the hotter plate is easier to shear


def test_error_estimate_bounds_the_error_of_the_fsw_solution():
    """The estimate of :func:`solve` (4/3 of the change under halving cells and dt) against a
    solve with 4x the cells and dt / 4, over a short span of the paper's physics."""
    scene = load_scene("fsw_paper")
    times = [0.005, 0.01]
    sol = ax.solve(scene, times, estimate=True)
    best = ax.solve(scene, times, refine=8, dt=2.5e-5)
    err = max(np.max(np.abs(sol.temperature(sol.r, i) - best.temperature(sol.r, i))) for i in range(2))
    # Richardson's 4/3 is exact for a pure second-order error; the better solve still errs by
    # 1/16 of it, so the true error can exceed the estimate by that 1/16 (and its own error)
    assert err <= sol.error_T * (1 + 1.0 / 16) + 1e-9, (err, sol.error_estimate)
    assert sol.error_T < 1e-2  # converged to 0.01 K, what a reference for kelvin-level errors needs
    assert np.max(np.abs(best.power - sol.power) / best.power) <= sol.error_power * (1 + 1.0 / 16)


# ------------------------------------------------------------------ (b) the FSW model against it

def _steady_power_error(K: int) -> float:
    """(P_h - P) / P of fsw_tracers' isothermal steady flow (effect ``viscous`` only, one
    implicit step of 1 s: no inertia, stationary) at dr = GAP / K, P from the oracle."""
    scene = load_scene("fsw_tracers").with_overrides({
        "effects": "viscous", "time.dt": "1.0", "time.t_end": "1.0", "time.save": "", "solver.kind": "mnewton",
        "geometry.dr": repr(GAP / K)})
    P = ax.solve(scene, [0.0]).power[0]
    with jaxanm.float64():
        res = run(scene)
    return dissipated_power(res, -1) / P - 1


# The convergence of the steady power, measured (oracle P = 53.23 kW/m at the scene's
# eps0 = 0.1; its own error 1e-6): K = 6, 8, 12, 16 (dr = 0.75 ... 0.28 mm):
# (P_h - P) / P = 0.268, 0.242, 0.126, 0.054; order fitted between the finer levels 1.6 and 2.9
# (the shear band of 0.1 mm starts to be resolved); err K = 1.61, 1.94, 1.51, 0.87.
FIRST_ORDER_CONSTANT = 1.94
"""The largest err K of the measured steady-power convergence (above)."""


def test_steady_power_at_a_coarse_cloud_within_its_discretisation_error():
    """K = 6 (dr = 0.75 mm, 239 points).  The discrete flow dissipates more than the continuum:
    it is an admissible field, and the exact flow minimises the dissipation potential, which is
    P / (n + 1) for the power law (eps0 = 0.1 changes P by 7e-4 here), so P_h >= P.  From above, the
    error is held to first order (what the quadratic MLS basis guarantees for the second
    derivatives) with the largest constant measured on the finer clouds, 1.94 / K."""
    err = _steady_power_error(6)
    assert 0 <= err <= FIRST_ORDER_CONSTANT / 6, err


@pytest.mark.slow
def test_steady_power_converges_to_the_oracle():
    """K = 8, 12, 16 (0.5-1 min): the steady power falls to the oracle's."""
    Ks = (8, 12, 16)
    err = [_steady_power_error(K) for K in Ks]
    assert all(e >= 0 for e in err), err  # over-dissipation (previous test)
    assert all(a > b for a, b in zip(err, err[1:])), err
    # first order with the coarser clouds' constant (the project's rule, test_fsw_validation)
    assert err[-1] <= max(e * K for e, K in zip(err[:-1], Ks[:-1])) / Ks[-1], err


def _rise_error(K: int, n: float, t_end: float) -> float:
    """Relative L2 error, over the points, of T - T0 of fsw_tracers (material n) at t_end
    against the oracle, at dr = GAP / K (modified Newton, the scene's dt = 1e-4)."""
    scene = load_scene("fsw_tracers").with_overrides({
        "material.n": repr(n), "time.t_end": repr(t_end), "time.save": "", "solver.kind": "mnewton",
        "geometry.dr": repr(GAP / K)})
    ref = ax.solve(scene, [t_end])
    with jaxanm.float64():
        res = run(scene)
    r = np.hypot(*res.points[-1].T)
    rise = ref.temperature(r, 0) - scene.thermal.T0
    return float(np.linalg.norm(res.T[-1] - scene.thermal.T0 - rise) / np.linalg.norm(rise))


@pytest.mark.slow
def test_newtonian_temperature_rise_converges_to_the_oracle():
    """n = 1 (the shear band spans the gap: resolved at every dr), the full fsw_tracers effects
    (softening, dissipation, tool conduction, Robin) over 5 ms (0.5-1.5 min).  Measured
    0.356, 0.195, 0.072 at K = 6, 8, 12 (order 2.1, 2.5)."""
    Ks = (6, 8, 12)
    err = [_rise_error(K, 1.0, 0.005) for K in Ks]
    assert all(a > b for a, b in zip(err, err[1:])), err
    # first order with the coarser clouds' constant (largest err K 2.14 -> <= 0.178 at K = 12)
    assert err[-1] <= max(e * K for e, K in zip(err[:-1], Ks[:-1])) / Ks[-1], err


def test_newtonian_temperature_rise_at_a_coarse_cloud():
    """The fast counterpart of the test above: K = 6 over 5 ms, held to the first-order bound
    with the largest constant the convergence measured (err K = 2.14, 1.56, 0.86 at K = 6,
    8, 12): <= 2.14 / 6.  Not below 0.2 (the error measured there is 0.356; a much smaller one
    would mean the test no longer exercises an unresolved cloud)."""
    err = _rise_error(6, 1.0, 0.005)
    assert 0.2 < err <= 2.14 / 6, err


@pytest.mark.slow
@pytest.mark.xfail(strict=True, raises=AssertionError,
                   reason="at the paper's n the heat rows store more than the discrete "
                          "flow dissipates at fine dr (1.06 beta int P_h dt at K = 16, 0.87 at K = 8), which "
                          "offsets the flow's falling over-dissipation: the rise error stalls near 14 %")
def test_paper_exponent_temperature_rise_converges_to_the_oracle():
    """n = 0.1324 over 10 ms at K = 8 and 16 (0.5-2 min).  Measured 0.146 and 0.127: the
    stored heat is 14 % above the oracle's at both, while the dissipated power of the flow
    falls from 1.33 to 1.09 P (docs/notes/spatial_accuracy.md).  A first-order rate would
    halve the error; when a fix makes it so, this test passes and strict xfail says so."""
    err = [_rise_error(K, 0.1324, 0.01) for K in (8, 16)]
    assert err[1] <= err[0] / 2, err


# ------------------------------------------------------------------ (c) what a run's summary reports

def test_shear_band_width_matches_the_power_law_closed_form():
    """eps0 = 1e-14 (no regularisation, see the first test): v/r = omega (r^-a - R2^-a) /
    (R1^-a - R2^-a), a = 2/n, falls to omega/e at r^-a = R2^-a + (R1^-a - R2^-a)/e.  The
    oracle's v is within 3e-5 omega R1 (first test); near R1, d(v/(omega r))/dr ~ a / (e R1),
    so the width errs by ~3e-5 e R1 / a, 1e-4 of the width ~R1/a: 1e-3 leaves a factor 10."""
    for n in (1.0, 0.1324):
        scene = Scene(effects=("viscous",), material=Material(n=n, eps0=1e-14))
        g, a = scene.geometry, 2.0 / n
        exact = (g.R2 ** -a + (g.R1 ** -a - g.R2 ** -a) / math.e) ** (-1.0 / a) - g.R1
        width = continuum_error.shear_band_width(scene)
        assert abs(width / exact - 1) < 1e-3, (n, width, exact)


def test_summary_reports_band_resolution_and_rise_error(tmp_path):
    """summary.json's ``spatial_accuracy`` and the command-line lines, on results whose error is
    known: the converged oracle's own temperatures at fsw_tracers' points (error: the coarse
    reference's, < 3e-3 K of a ~25 K rise, so rel. L2 < 1e-3), then that rise made 10 % too
    high everywhere (rel. L2 and mean ratio exactly 0.1 and 1.1 of the reference's, within its
    1e-3).  The band: fsw_paper's n R1 / 2-like width over its ring spacing dr = 0.375 mm,
    0.10 mm by the closed form above (eps0 = 0.1 widens it by 1 %), 0.27-0.28 points."""
    import json
    import types

    from jaxanm.fsw.geometry import build_cloud
    from jaxanm.fsw.io import output

    scene = load_scene("fsw_tracers").with_overrides({"time.t_end": "0.05"})
    points = build_cloud(scene.geometry).points
    true = ax.solve(scene, [0.05]).temperature(np.hypot(*points.T), 0)
    T0 = scene.thermal.T0
    for factor in (1.0, 1.1):
        res = types.SimpleNamespace(scene=scene, t=np.array([0.0, 0.05]), points=np.stack([points, points]),
                                    T=np.stack([np.full(len(points), T0), T0 + factor * (true - T0)]))
        block = output.spatial_accuracy(res)
        err = block["rise_error"]
        assert err["t"] == 0.05
        assert abs(err["rel_l2"] - (factor - 1)) < 1e-3, err
        assert abs(err["mean_ratio"] - factor) < 1e-3, err
    assert block["edge_spacing_m"] == pytest.approx(scene.geometry.dr, rel=1e-12)  # 0.375 mm divides R2 - R1
    assert 0.27 < block["shear_band_points"] < 0.28, block
    assert block["shear_band_width_m"] == pytest.approx(block["shear_band_points"] * scene.geometry.dr, rel=1e-12)
    lines = output.spatial_accuracy_lines(block)
    assert "0.28 points across" in lines[0] and "% rel. L2 error, mean rise 1.1 x" in lines[1], lines
    # through write_summary (JSON round trip); a result without a Scene reports null
    from test_output import fake_result

    fake = fake_result()
    path = output.write_summary(fake, tmp_path)
    assert json.loads(path.read_text())["spatial_accuracy"] is None
    fake.scene = scene.with_overrides({"effects": "viscous"})
    summary = json.loads(output.write_summary(fake, tmp_path).read_text())
    assert summary["spatial_accuracy"]["shear_band_points"] == pytest.approx(block["shear_band_points"], rel=1e-12)
    assert "rise_error" not in summary["spatial_accuracy"]  # isothermal: no rise to compare
    # the command line prints the same lines from the written summary.json (jaxanm run)
    from jaxanm import cli

    assert cli._accuracy_lines([tmp_path / "fields.npz", tmp_path / "summary.json"]) == \
        output.spatial_accuracy_lines(summary["spatial_accuracy"]) + output.time_error_lines(
            summary["time_error"]) + output.probe_oscillation_lines(summary["probe_oscillation"]) + \
        cli.coarse_cloud_lines(summary["spatial_accuracy"])
    assert cli._accuracy_lines([]) == []
