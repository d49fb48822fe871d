"""The process window's sweep (benchmarks/grids/process_window.toml) on a 2 x 2 corner of its grid,
through ``jaxanm sweep``'s Dask runner, over a short time: the process quantities of every run
against physical bounds nobody tuned (energy balance of the sticking tool, peak temperature
rising with the rotation speed at a fixed travel speed, the plate carrying heat downstream).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import pytest

GRID = Path(__file__).resolve().parents[1] / "benchmarks" / "grids" / "process_window.toml"
T_END = 5e-3
"""Short runs (the committed sweep runs to 0.1 s): the bounds below hold from the first steps on."""


def corner_grid() -> dict:
    """The committed grid restricted to its two lowest rotation speeds and the two travel speeds
    they share (advances 0.05-1 mm per revolution), over :data:`T_END`."""
    data = tomllib.loads(GRID.read_text(encoding="utf-8"))
    low = sorted(data["overrides"], key=lambda e: e["tool.omega"])[:2]
    shared = sorted(set(low[0]["tool.traverse_speed"]) & set(low[1]["tool.traverse_speed"]))
    assert len(shared) == 2, "the grid's two lowest rotation speeds no longer share two travel speeds"
    overrides = [{"time.t_end": T_END, "time.save": [T_END], "tool.omega": e["tool.omega"],
                  "tool.traverse_speed": shared} for e in low]
    return {"scene": data["scene"], "overrides": overrides}


@pytest.mark.slow
def test_corner_of_the_process_window_meets_the_physical_bounds(tmp_path):
    from jaxanm.fsw.compare import load_run
    from jaxanm.sweep import grid_from_dict, run_sweep

    result = run_sweep(grid_from_dict(corner_grid(), name="corner"), tmp_path, workers=1, progress=False)
    assert not result.failed and len(result.rows) == 4
    runs = [load_run(tmp_path / "runs" / row["task"])["summary"] for row in result.rows]
    process = {(s["scene"]["tool"]["omega"], s["scene"]["tool"]["traverse_speed"]): s["process"] for s in runs}
    T0 = runs[0]["scene"]["thermal"]["T0"]
    for (omega, U), p in process.items():
        assert p["t"] == pytest.approx(T_END)
        # Energy: the plastic dissipation takes up the torque's power (a sticking tool: no
        # friction heat) plus the power of the traction on the ring r = R2, which pushes the
        # plate past the pin at U (the machine's traverse force times U, >= 0).  The torque
        # comes from the one-sided MLS shear at the edge points, the dissipation from a
        # quadrature of the band (1.7 points across it at 0.06 mm): 3 % is the resolution of
        # the edge stress (0.972 of the closed form on a Newtonian 0.1 mm cloud,
        # docs/notes/traverse_and_slip.md).
        assert p["dissipation"] > 0.97 * p["power"], (omega, U, p)
        assert p["power"] == pytest.approx(p["torque"] * omega, rel=1e-12)
        # heated, far below aluminium's melting point (933 K) after 5 ms
        assert T0 < p["peak_T"] < 933.0
        # the plate carries the heat downstream: the trailing side is the hotter one
        assert p["trailing_minus_leading"] > 0.0, (omega, U, p)
        # mass conservation with the pressure: within 1 % of the through-flow
        assert p["mass_flux_error"] < 0.01
    for omega in {omega for omega, _ in process}:
        # the traverse work grows with the travel speed; at the window's smallest advance
        # (0.05 mm) it is below 0.2 % of the torque's (U / (pi omega R1)), so the balance
        # closes there within the edge stress's 3 %
        (slow, p_slow), (fast, p_fast) = sorted((U, p) for (o, U), p in process.items() if o == omega)
        excess = [p["dissipation"] / p["power"] - 1.0 for p in (p_slow, p_fast)]
        assert excess[1] > excess[0], (omega, excess)
        if 2e3 * math.pi * slow / omega < 0.051:
            assert abs(excess[0]) < 0.03, (omega, slow, excess)
    for U in {U for _, U in process}:
        slow, fast = sorted((omega, p["peak_T"]) for (omega, u), p in process.items() if u == U)
        assert fast[1] > slow[1], f"peak T at U = {U} m/s does not rise with omega: {slow}, {fast}"
    # the advance per revolution of every corner is inside the window
    assert all(0.05 <= 2e3 * math.pi * U / omega <= 1.0 + 1e-9 for omega, U in process)


def test_speeds_beyond_the_ranges_are_refused_naming_the_key():
    """Beyond the window: an advance of 20 mm per revolution at 44.7 rad/s (U = 0.142 m/s, one of
    benchmarks/window_limits.py's cases) and a tool faster than 1000 rad/s are refused when the
    scene is read, naming the key and its range; the same advance at 10 rad/s is a valid scene
    (its start flow reaches it: benchmarks/results/window_limits.md)."""
    from jaxanm.fsw.scene import SceneError, load_scene

    base = load_scene("fsw_weld")
    U = 20e-3 * 44.721 / (2 * math.pi)
    with pytest.raises(SceneError, match=r"tool\.traverse_speed.*must be in \[0, 0\.1\]"):
        base.with_overrides({"tool.omega": 44.721, "tool.traverse_speed": U})
    with pytest.raises(SceneError, match=r"tool\.omega.*must be in \(0, 1000\]"):
        base.with_overrides({"tool.omega": 1500.0})
    slow = base.with_overrides({"tool.omega": 10.0, "tool.traverse_speed": 20e-3 * 10.0 / (2 * math.pi)})
    assert 2e3 * math.pi * slow.tool.traverse_speed / slow.tool.omega == pytest.approx(20.0)


def test_a_cell_peclet_number_beyond_the_measured_one_is_refused_naming_the_spacing():
    """The heat step's collocated transport has no growing mode up to a cell Peclet number of 11
    at the tool edge (benchmarks/results/heat_peclet.md): a travelling tool at 1000 rad/s on
    fsw_small's 0.75 mm spacing (20.6) is refused naming geometry.dr and the number; on the weld's
    0.06 mm band the same tool (1.65) is a valid scene."""
    from jaxanm.fsw.effects import PECLET_MAX
    from jaxanm.fsw.scene import SceneError, load_scene

    base = load_scene("fsw_weld").with_overrides({"tool.omega": 1000.0})
    g, m = base.geometry, base.material
    assert (1000.0 * g.R1 + base.tool.traverse_speed) * g.dr * m.rho * m.Cp / m.k < PECLET_MAX
    with pytest.raises(SceneError, match=r"geometry\.dr.*cell Peclet number .* = 20\.6 .*beyond 11"):
        base.with_overrides({"geometry.layout": "polar", "geometry.dr": 7.5e-4})
