"""The FSW examples run as a user runs them (small settings), each pinning physically meaningful numbers.

Every bound below comes from physics or from the scene's layout, not from a previous run:

- unknowns: (u, v) per point, plus T with ``conduction``;
- energy: the heat stored is at most ``beta P_h t``, P_h the power the discrete flow dissipates
  at the first step (softening only lowers the viscosity, hence the power; P_h exceeds the
  closed-form Couette power at these spacings, docs/notes/energy_balance.md);
- the paper's own statement (Fig. 3): point (1) near the tool heats more than point (3);
- inertia: the flow changes by less than the weight of ``rho dV/dt`` in one implicit step;
- softening: the heat drops, by at most the viscosity drop ``1 - (Tmax/T0)^A`` at the peak;
- Robin cooling: the relative heat lost is at most ``t / t_cool``, ``t_cool = rho Cp R2 / (2 h)``;
- tool conduction: the tool warms (it is held at T0 otherwise), the plate's peak drops.

Both runs use Newton (the ANM's order-7 jet of each new effect combination takes 20-30 s of CPU
to compile; the discrete solutions are the same).  The examples' defaults (ANM, finer clouds)
run in the notebooks 03 and 04.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_examples import load_example


def test_couette_power_closed_form_newtonian_limit():
    """n = 1, A = 0: the torque of Newtonian circular Couette flow, 4 pi mu omega R1^2 R2^2 / (R2^2 - R1^2)."""
    ex = load_example("fsw_scene")
    scene = ex.small_scene(t_end=0.01).with_overrides({"material.n": 1.0, "material.A": 0.0})
    mu = scene.material.K / 3.0
    R1, R2, om = scene.geometry.R1, scene.geometry.R2, scene.tool.omega
    torque = 4 * math.pi * mu * om * R1 ** 2 * R2 ** 2 / (R2 ** 2 - R1 ** 2)
    assert math.isclose(ex.couette_power(scene), torque * om, rel_tol=1e-12)


def test_fsw_scene_example(tmp_path, capsys):
    ex = load_example("fsw_scene")
    scene = ex.small_scene(dr=1.125e-3, dt=1e-3, t_end=0.005, solver="newton")
    result, history, wall = ex.simulate(scene)
    numbers = ex.summary(result, history, wall)
    ex.print_summary(numbers)
    assert "factorizations" in capsys.readouterr().out
    n_points = result.material.size
    assert numbers["unknowns"] == 3 * n_points  # u, v, T at every point
    assert history["t"].size == 5 and math.isclose(history["t"][-1], 0.005)

    # energy: dissipation is the only heat source, so 0 < E <= beta max(P_h) t
    balance = ex.energy_balance(result)
    assert 0 < balance["E"] <= balance["upper"], balance

    # paper, Fig. 3: the temperature at point (1) next to the tool exceeds that at point (3)
    T0 = scene.thermal.T0
    T1, T3 = (result.probes[name]["T"][-1] for name in ("1", "3"))
    assert T1 > T3 and T1 > T0 + 0.1

    # the mixing state is carried by the tracers (the points of a fixed-point run never move);
    # tracers started in the tool have turned rigidly by omega t
    from jaxanm.fsw.io import figures

    pts, material = figures.mixing_points(result, -1)
    start = result.tracers["points"][0]
    assert np.array_equal(pts, result.tracers["points"][-1])
    tool = material == 0
    r0 = np.hypot(*start[tool].T)
    moved = tool.copy()
    moved[tool] = r0 > 0.5 * scene.geometry.R1
    angle = np.arctan2(pts[moved, 1], pts[moved, 0]) - np.arctan2(start[moved, 1], start[moved, 0])
    angle = np.mod(angle + np.pi, 2 * np.pi) - np.pi
    assert np.allclose(angle, scene.tool.omega * 0.005, rtol=0, atol=1e-9)
    # each of the 5 steps turns a tool tracer by a 2x2 rotation (c^2 + s^2 = 1 to an ulp, two
    # products per component): its radius drifts by ~2 eps a step, 2e-15 relative here, 500x
    # below rtol 1e-12.  atol = 0: numpy's default 1e-8 would allow 1e-5 of these 1e-3 m radii
    assert np.allclose(np.hypot(*pts[tool].T), r0, rtol=1e-12, atol=0)

    # the figures a user gets
    paths = ex.save_figures(result, history, tmp_path)
    assert {p.name for p in paths} >= {"fig02_velocity_history.png", "fig03_temperature_history.png",
                                       "fig05_velocity_sections.png", "mixing_end.png", "temperature_maps.png"}
    assert all(p.stat().st_size > 10_000 for p in paths)


@pytest.mark.slow  # each effect's rows are checked against the pointwise equations (test_fsw_validation)
def test_effects_example(capsys):
    fx = load_example("effects")
    rows = fx.ladder(dr=1.125e-3, dt=1e-3, t_end=0.005, solver="newton", rungs=fx.LADDER[:6])
    fx.print_table(rows)
    assert "unknowns" in capsys.readouterr().out
    by = {r["label"]: r for r in rows}
    sc = rows[-1]["result"].scene
    T0, U = sc.thermal.T0, sc.tool.omega * sc.geometry.R1
    d = fx.dimensionless(sc)

    # unknowns: an isothermal scene carries exactly 2N (u, v), a thermal one 3N
    for r in rows:
        assert r["unknowns"] == (3 if "conduction" in r["effects"] else 2) * r["points"], r["label"]
    assert by["viscous"]["T_plate"] == by["viscous"]["T_tool"] == T0

    # inertia: Re ~ 3e-8; even rho dV/dt of one step weighs ~2e-4 of the viscous stress
    assert d["Re"] < 1e-6 and d["unsteady"] < 1e-3
    a, b = by["viscous"]["result"], by["+ inertia"]["result"]
    dV = max(np.abs(a.u[-1] - b.u[-1]).max(), np.abs(a.v[-1] - b.v[-1]).max())
    assert dV < d["unsteady"] * U

    # dissipation: 0 < stored heat <= beta P_h t (the power the discrete flow dissipates)
    heat = by["+ conduction, dissipation"]["heat"]
    assert 0 < heat <= sc.material.beta * by["+ conduction, dissipation"]["power"] * sc.time.t_end

    # softening (A < 0): less viscous when hot, so less heat, by at most 1 - (Tmax/T0)^A
    hot = by["+ conduction, dissipation"]["T_plate"]
    drop = 1 - by["+ softening"]["heat"] / heat
    assert 0 < drop <= 1 - (hot / T0) ** sc.material.A

    # robin: relative heat lost at most t / t_cool (t_cool = rho Cp R2 / (2h) ~ 7.7 s)
    lost = abs(by["+ robin"]["heat"] - by["+ softening"]["heat"]) / by["+ softening"]["heat"]
    assert lost <= sc.time.t_end / d["cooling time"]

    # tool conduction: the tool (held at T0 otherwise) warms and takes heat from the plate's peak;
    # T is continuous at the tool edge and the source is in the plate, so the tool stays cooler
    tc, no_tc = by["+ tool_conduction"], by["+ robin"]
    # without tool conduction the tool's nodal T is held at T0, and its value at the points is
    # an MLS sum of those T0s: 1 to within the partition-of-unity round-off, 36 eps / rcond
    # (tests/test_mls.py) with rcond >= 5e-5 at the tool-edge points of a regular cloud
    assert abs(no_tc["T_tool"] - T0) <= 36 * np.finfo(float).eps / 5e-5 * T0
    # T_tool = T_plate is the tool-edge row: the two MLS values agree to the partition-of-unity
    # round-off bounded on the line above, not bit for bit
    assert T0 < tc["T_tool"] <= tc["T_plate"] + 36 * np.finfo(float).eps / 5e-5 * T0
    assert tc["T_plate"] < no_tc["T_plate"]
