"""The paper's FSW scene on a coarse cloud over a short span: fields, mixing, sections, cost.

Runs ``fsw_tracers`` (the paper's physics, ``fsw_paper``, on fixed points with passive tracer
particles for the mixing picture) with a coarser point spacing and a shorter time span than the
paper, prints the run's statistics and an energy balance (heat stored against the heat the
discrete flow dissipated, and against the closed-form power of the isothermal power-law
Couette flow), and saves the paper's figures
(velocity and temperature histories at the registration points, sections A-A / B-B, the
mixing state, temperature maps) plus the a_max history into ``--out``.

    python examples/fsw_scene.py --out results/fsw_scene            # ~1 min on 2 cores
    python examples/fsw_scene.py --dr 3.75e-4 --dt 1e-4 --t-end 0.7  # the paper's settings (hours)

The full paper scene, with Lagrangian points, is the command ``jaxanm run fsw_paper --out DIR``.
"""

from __future__ import annotations

import argparse
import math
import pathlib
import time

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from jaxanm.fsw import load_scene, make_model, run
from jaxanm.fsw.energy import dissipated_power, stored_heat
from jaxanm.fsw.geometry import build_cloud
from jaxanm.fsw.io import figures

DEFAULTS = {"dr": 7.5e-4, "dt": 1e-3, "t_end": 0.1}
"""Small settings: twice the paper's point spacing (239 points), ten times its time step, 0.1 s."""


def small_scene(dr: float = DEFAULTS["dr"], dt: float = DEFAULTS["dt"], t_end: float = DEFAULTS["t_end"],
                solver: str = "anm", base: str = "fsw_tracers", saves: int = 5):
    """The shipped scene ``base`` with point spacing ``dr``, step ``dt``, span ``t_end`` and solver kind.

    Fields are saved at ``saves`` evenly spaced times (plus 0.001 s and 0.01 s when they fall
    within the span: the times of the paper's Figs 10 and 6).
    """
    times = sorted({*(t_end * (k + 1) / saves for k in range(saves)), *(t for t in (0.001, 0.01) if t < t_end)})
    return load_scene(base).with_overrides({
        "geometry.dr": dr, "time.dt": dt, "time.t_end": t_end, "solver.kind": solver,
        "time.save": ",".join(f"{t:.12g}" for t in times), "name": f"{base}_small"})


def simulate(scene) -> tuple:
    """Run ``scene``; return ``(result, history, wall_s)``.

    ``history`` holds, after every accepted step, the time ``t``, the cumulative
    ``factorizations`` and ``substeps`` (so a step with a new factorisation is visible).
    """
    history = {"t": [], "factorizations": [], "substeps": []}

    def callback(t, stats):
        history["t"].append(float(t))
        history["factorizations"].append(stats.factorizations)
        history["substeps"].append(stats.substeps)

    start = time.perf_counter()
    result = run(scene, callback=callback)
    return result, {k: np.asarray(v) for k, v in history.items()}, time.perf_counter() - start


def unknowns(scene) -> tuple[int, int]:
    """``(points N, unknowns)`` of the scene's model: 2 per point for (u, v), one more for T."""
    cloud = build_cloud(scene.geometry)
    return cloud.size, make_model(scene, cloud).size


def couette_power(scene, T: float | None = None) -> float:
    """Mechanical power per unit thickness (W/m) of the steady isothermal power-law Couette flow.

    Closed form (regularisation eps0 -> 0): with ``s = r d(v/r)/dr`` the shear stress is
    ``tau = B |s|^n``, ``B = K T^A 3^((1-n)/2) / 3``; equilibrium gives ``tau = C / r^2`` and
    ``omega = int_R1^R2 |s| / r dr``, hence ``C = B (2 omega / n)^n R1^2 (1 - (R1/R2)^(2/n))^(-n)``,
    torque ``M = 2 pi C`` and power ``P = M omega``.  The viscosity is evaluated at the
    uniform temperature ``T`` (default T0).
    """
    m, g, om = scene.material, scene.geometry, scene.tool.omega
    T = scene.thermal.T0 if T is None else T
    B = m.K * T ** m.A * 3.0 ** ((1.0 - m.n) / 2.0) / 3.0
    C = B * (2.0 * om / m.n) ** m.n * g.R1 ** 2 * (1.0 - (g.R1 / g.R2) ** (2.0 / m.n)) ** (-m.n)
    return 2.0 * math.pi * C * om


def energy_balance(result) -> dict:
    """Heat stored at the end of the run against the heat the discrete flow dissipated.

    ``E = int rho Cp (T - T0) dA`` (:func:`jaxanm.fsw.energy.stored_heat`).  Dissipation heats
    the material at ``beta P``; the discrete velocity field dissipates ``P_h``
    (:func:`jaxanm.fsw.energy.dissipated_power`, computed from the velocity and the viscosity law
    alone), largest at the first saved step (softening only lowers it as the material heats),
    so ``E <= beta max(P_h) t`` (``upper``): the heat equation creates no heat.  ``P_h``
    exceeds the closed-form isothermal Couette power ``P(T0)`` (``power_T0``) at affordable
    spacings, because the shear layer next to the tool (``v/r ~ r^-15``) is thinner than
    ``dr``: 1.76, 1.27, 1.13 P at dr = 1.5, 0.75, 0.375 mm, converging to P
    (docs/notes/energy_balance.md).  ``ratio`` is ``E / (beta P(T0) t)``.
    """
    sc = result.scene
    t = float(np.asarray(result.t)[-1])
    E = stored_heat(result)
    powers = [dissipated_power(result, s) for s in range(1, len(result.t))]
    p_T0 = couette_power(sc)
    beta = sc.material.beta
    return {"E": E, "upper": beta * max(powers) * t, "power_discrete": max(powers), "power_T0": p_T0,
            "ratio": E / (beta * p_T0 * t)}


def summary(result, history: dict, wall_s: float) -> dict:
    """The run's numbers: size, solver statistics, temperatures, energy balance."""
    sc, st = result.scene, result.stats
    n_points, n_unknowns = unknowns(sc)
    per_step = np.diff(history["factorizations"], prepend=0)
    probes = [name for name in result.probes if name != "t"]
    amax = np.asarray(st.amax, dtype=np.float64)
    return {
        "points": n_points, "unknowns": n_unknowns, "time steps": st.time_steps,
        "factorizations": st.factorizations, "continuation sub-steps": st.substeps,
        "steps with a factorisation": int(np.count_nonzero(per_step)),
        "factorisations after step 1": int(per_step[1:].sum()),
        "Newton iterations": st.newton_iterations, "dt halvings": st.dt_halvings,
        "min / median a_max": f"{amax.min():.3g} / {np.median(amax):.3g}" if amax.size else "-",
        "wall time [s]": round(wall_s, 1),
        **{f"  {k}": round(v, 1) for k, v in st.wall_time.items()},
        "T max [K]": round(float(np.max(result.T[-1])), 3),
        **{f"T at point ({name}) [K]": round(float(result.probes[name]["T"][-1]), 3) for name in probes},
        "heat stored / (beta P t)": round(energy_balance(result)["ratio"], 4),
    }


def print_summary(numbers: dict) -> None:
    """Print :func:`summary` as a two-column table."""
    width = max(len(k) for k in numbers)
    for key, value in numbers.items():
        print(f"{key:{width}s}  {value}")


def amax_figure(result, history: dict) -> Figure:
    """a_max of the accepted series per time step (ANM), steps with a new factorisation marked."""
    fig = Figure(figsize=(8, 3.5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    amax = np.asarray(result.stats.amax, dtype=np.float64)
    if amax.size == 0:
        ax.text(0.5, 0.5, "no a_max history (not an ANM run)", ha="center", transform=ax.transAxes)
        return fig
    steps = np.arange(1, amax.size + 1)
    fresh = np.diff(history["factorizations"], prepend=0)[:amax.size] > 0
    ax.semilogy(steps, amax, ".-", lw=0.8, ms=3, label="a_max of the accepted series")
    ax.semilogy(steps[fresh], amax[fresh], "o", mfc="none", mec="C3", ms=8,
                label=f"steps with a factorisation ({result.stats.factorizations} in all)")
    ax.axhline(1.0, color="k", ls="--", lw=0.8)
    ax.set(xlabel="time step", ylabel="a_max (eq. 26)", title="validity range of the series per step")
    ax.legend(fontsize=8)
    return fig


def save_figures(result, history: dict, out_dir) -> list[pathlib.Path]:
    """Save the paper's figures that the run's span allows, the mixing state and a_max history."""
    out = pathlib.Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t_last = float(np.asarray(result.t)[-1])
    builders = {
        "fig02_velocity_history.png": lambda: figures.fig02_velocity_history(result),
        "fig03_temperature_history.png": lambda: figures.fig03_temperature_history(result),
        "fig05_velocity_sections.png": lambda: figures.fig05_velocity_sections(result),
        "mixing_end.png": lambda: figures.mixing_figure(result, t_last, 6),
        "temperature_maps.png": lambda: figures.temperature_maps(result, [t_last / 2, None], 10),
        "amax_history.png": lambda: amax_figure(result, history),
    }
    paths = []
    for name, build in builders.items():
        try:
            fig = build()
        except figures.FigureSkipped as skipped:
            print(f"{name} skipped: {skipped}")
            continue
        fig.savefig(out / name, dpi=120)
        paths.append(out / name)
    return paths


def main(argv=None) -> None:
    """Command-line entry: run the small scene, print its numbers, save the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dr", type=float, default=DEFAULTS["dr"], help="point spacing (m)")
    parser.add_argument("--dt", type=float, default=DEFAULTS["dt"], help="time step (s)")
    parser.add_argument("--t-end", type=float, default=DEFAULTS["t_end"], help="end time (s)")
    parser.add_argument("--solver", default="anm", choices=("anm", "newton", "modified_newton"))
    parser.add_argument("--base", default="fsw_tracers", help="shipped scene to start from")
    parser.add_argument("--out", default="results/fsw_scene", help="directory for the figures")
    args = parser.parse_args(argv)
    scene = small_scene(args.dr, args.dt, args.t_end, args.solver, args.base)
    result, history, wall = simulate(scene)
    print_summary(summary(result, history, wall))
    for path in save_figures(result, history, args.out):
        print("wrote", path)


if __name__ == "__main__":
    main()
