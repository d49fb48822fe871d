"""Effects on and off: what each effect of an FSW scene changes, and what it costs.

Starting from the isothermal power-law flow around the turning tool (``viscous``), the effects
of ``fsw_paper`` are added one at a time (inertia; conduction with dissipation heating; thermal
softening; Robin cooling; heat conduction into the tool; then fixed points with tracers or
Lagrangian points), each run for a short span on a coarse cloud.  For each rung the script
prints the unknown count, the solver's work (factorisations, iterations, wall time) and the
physical numbers the effect changes (stored heat, peak plate temperature, tool temperature,
velocity near the tool), with the dimensionless numbers that predict the size of each change.
A second table compares fixed points + tracers with Lagrangian points under the ANM.

    python examples/effects.py --out results/effects        # ~1-2 min on 2 cores
"""

from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from fsw_scene import couette_power, unknowns  # noqa: E402

from jaxanm.fsw import load_scene, run  # noqa: E402
from jaxanm.fsw.energy import dissipated_power, stored_heat  # noqa: E402
from jaxanm.fsw.physics import mu_reference  # noqa: E402

LADDER = (
    ("viscous", ("viscous",)),
    ("+ inertia", ("viscous", "inertia")),
    ("+ conduction, dissipation", ("viscous", "inertia", "conduction", "dissipation")),
    ("+ softening", ("viscous", "inertia", "conduction", "dissipation", "softening")),
    ("+ robin", ("viscous", "inertia", "conduction", "dissipation", "softening", "robin")),
    ("+ tool_conduction", ("viscous", "inertia", "conduction", "dissipation", "softening", "robin",
                           "tool_conduction")),
    ("+ tracers (fsw_tracers)", ("viscous", "inertia", "conduction", "dissipation", "softening", "robin",
                                 "tool_conduction", "tracers")),
    ("+ lagrangian (fsw_paper)", ("viscous", "inertia", "conduction", "dissipation", "softening", "robin",
                                  "tool_conduction", "lagrangian")),
)
"""(label, effects) of each rung; each adds the effects named in its label to the rung before
(the last two are the alternatives: fixed points with tracers, or moving points)."""

SMALL = {"dr": 1.125e-3, "dt": 1e-3, "t_end": 0.005}
"""Small settings of the ladder: 113 points (4 point spacings across the plate), 5 steps."""


def effect_scene(effects, dr: float = SMALL["dr"], dt: float = SMALL["dt"], t_end: float = SMALL["t_end"],
                 solver: str = "newton"):
    """``fsw_paper`` with only ``effects``, point spacing ``dr``, step ``dt``, span ``t_end`` and solver kind."""
    return load_scene("fsw_paper").with_overrides({
        "effects": ",".join(effects), "geometry.dr": dr, "time.dt": dt, "time.t_end": t_end,
        "solver.kind": solver, "name": "effects"})


def measure(scene) -> dict:
    """Run ``scene``; return the result, the cost and the physical numbers of one rung."""
    history = []
    start = time.perf_counter()
    result = run(scene, callback=lambda t, stats: history.append(stats.factorizations))
    wall = time.perf_counter() - start
    n_points, n_unknowns = unknowns(scene)
    T, material = np.asarray(result.T[-1]), np.asarray(result.material)
    st = result.stats
    return {
        "result": result, "points": n_points, "unknowns": n_unknowns,
        "factorizations": st.factorizations, "iterations": st.newton_iterations,
        "substeps": st.substeps, "per_step": np.diff(history, prepend=0), "wall": wall,
        "heat": stored_heat(result) if scene.has("conduction") else 0.0,
        "power": max(dissipated_power(result, s) for s in range(1, len(result.t))),
        "T_plate": float(T[material != 0].max()), "T_tool": float(T[material == 0].max()),
        "v1": float(result.probes[next(k for k in result.probes if k != "t")]["v"][-1]),
    }


def ladder(dr: float = SMALL["dr"], dt: float = SMALL["dt"], t_end: float = SMALL["t_end"],
           solver: str = "newton", rungs=LADDER) -> list[dict]:
    """:func:`measure` every rung of ``rungs``; each row also holds its ``label`` and ``effects``."""
    rows = []
    for label, effects in rungs:
        row = measure(effect_scene(effects, dr, dt, t_end, solver))
        rows.append({"label": label, "effects": effects, **row})
    return rows


def motion_costs(dr: float = SMALL["dr"], dt: float = 1e-4, t_end: float = 0.003, solver: str = "anm") -> list[dict]:
    """The full physics on fixed points + tracers vs Lagrangian points, with the ANM, at the paper's dt."""
    return ladder(dr, dt, t_end, solver, rungs=LADDER[-2:])


def dimensionless(scene) -> dict:
    """The numbers that predict how much each effect can change over the span of ``scene``.

    - ``Re = rho omega R1^2 / mu_ref``: inertia against viscous stress (quasi-static flow if tiny);
    - ``unsteady``: ``rho R2^2 / (mu_tool dt)``, the weight of ``rho dV/dt`` in one implicit step,
      with the lowest viscosity of the flow (at the tool, strain rate ``2 omega / (sqrt(3) n)``);
    - ``heating rate``: ``beta P / (rho Cp pi (R2^2 - R1^2))`` (K/s), the mean temperature rise
      rate of the plate from the closed-form dissipated power;
    - ``softening per K``: ``|A| / T0``, the relative drop of the viscosity per kelvin;
    - ``cooling time``: ``rho Cp R2 / (2 h)`` (s), the lumped time to lose the plate's heat
      through the Robin edge; ``t_end / cooling time`` bounds the relative heat lost;
    - ``diffusion length``: ``sqrt(k t_end / (rho Cp))`` (m), how far heat spreads in the span.
    """
    m, g, tl, th = scene.material, scene.geometry, scene.tool, scene.thermal
    mu_ref = mu_reference(scene)
    mu_tool = mu_ref * (2 / (math.sqrt(3) * m.n)) ** (m.n - 1)
    rho_cp = m.rho * m.Cp
    return {
        "Re": m.rho * tl.omega * g.R1 ** 2 / mu_ref,
        "unsteady": m.rho * g.R2 ** 2 / (mu_tool * scene.time.dt),
        "heating rate": m.beta * couette_power(scene) / (rho_cp * math.pi * (g.R2 ** 2 - g.R1 ** 2)),
        "softening per K": abs(m.A) / th.T0,
        "cooling time": rho_cp * g.R2 / (2 * th.h) if th.h > 0 else math.inf,
        "diffusion length": math.sqrt(m.k * scene.time.t_end / rho_cp),
    }


def print_table(rows: list[dict]) -> None:
    """Print the ladder: size, cost and the physical numbers of every rung."""
    head = (f"{'rung':28s}{'N':>5s}{'unknowns':>9s}{'fact.':>7s}{'iter.':>7s}{'substeps':>9s}{'wall s':>8s}"
            f"{'heat J/m':>10s}{'T plate max':>12s}{'T tool max':>11s}{'v at (1) m/s':>14s}")
    print(head)
    for r in rows:
        print(f"{r['label']:28s}{r['points']:5d}{r['unknowns']:9d}{r['factorizations']:7d}{r['iterations']:7d}"
              f"{r['substeps']:9d}{r['wall']:8.1f}{r['heat']:10.2f}{r['T_plate']:12.3f}{r['T_tool']:11.3f}"
              f"{r['v1']:14.4e}")


def ladder_figure(rows: list[dict]) -> Figure:
    """Per rung: factorisations and wall time (bars); stored heat and peak plate temperature rise (lines)."""
    fig = Figure(figsize=(11, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    ax_cost, ax_phys = fig.subplots(1, 2)
    x = np.arange(len(rows))
    labels = [r["label"] for r in rows]
    ax_cost.bar(x - 0.2, [r["factorizations"] for r in rows], 0.4, label="factorisations")
    ax_wall = ax_cost.twinx()
    ax_wall.bar(x + 0.2, [r["wall"] for r in rows], 0.4, color="C1", label="wall time (s), incl. compilation")
    ax_cost.set_ylabel("factorisations")
    ax_wall.set_ylabel("wall time (s)")
    ax_phys.plot(x, [r["heat"] for r in rows], "o-", color="C3", label="stored heat (J/m)")
    ax_dT = ax_phys.twinx()
    T0 = rows[0]["result"].scene.thermal.T0
    ax_dT.plot(x, [r["T_plate"] - T0 for r in rows], "s--", color="C2", label="peak plate T - T0 (K)")
    ax_dT.plot(x, [r["T_tool"] - T0 for r in rows], "^:", color="0.4", label="peak tool T - T0 (K)")
    ax_phys.set_ylabel("stored heat (J/m)")
    ax_dT.set_ylabel("temperature rise (K)")
    for ax, twin in ((ax_cost, ax_wall), (ax_phys, ax_dT)):
        ax.set_xticks(x, labels, rotation=35, ha="right", fontsize=8)
        handles = ax.get_legend_handles_labels()[0] + twin.get_legend_handles_labels()[0]
        ax.legend(handles, [h.get_label() for h in handles], fontsize=8, loc="lower left",
                  bbox_to_anchor=(0.0, 1.01), ncol=2, frameon=False)
    return fig


def main(argv=None) -> None:
    """Command-line entry: run the ladder and the motion comparison, print tables, save a figure."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dr", type=float, default=SMALL["dr"], help="point spacing (m)")
    parser.add_argument("--dt", type=float, default=SMALL["dt"], help="time step of the ladder (s)")
    parser.add_argument("--t-end", type=float, default=SMALL["t_end"], help="span of the ladder (s)")
    parser.add_argument("--solver", default="newton", choices=("anm", "newton", "modified_newton"),
                        help="solver of the ladder (the motion comparison always uses the ANM)")
    parser.add_argument("--motion-t-end", type=float, default=0.003, help="span of the motion comparison (s)")
    parser.add_argument("--out", default="results/effects", help="directory for the figure")
    args = parser.parse_args(argv)
    rows = ladder(args.dr, args.dt, args.t_end, args.solver)
    print_table(rows)
    print()
    for key, value in dimensionless(rows[-1]["result"].scene).items():
        print(f"{key:18s} {value:.3g}")
    print("\nfixed points + tracers vs Lagrangian points, ANM, dt = 1e-4 s:")
    motion = motion_costs(args.dr, 1e-4, args.motion_t_end)
    print_table(motion)
    for r in motion:
        print(f"{r['label']:28s} factorisations per step: {r['per_step'].tolist()}")
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ladder_figure(rows).savefig(out / "effects_ladder.png", dpi=120)
    print("wrote", out / "effects_ladder.png")


if __name__ == "__main__":
    main()
