"""The weld's process window: the report of `benchmarks/grids/process_window.toml`'s sweep.

Reads the sweep's runs (each `runs/<task>/summary.json`'s `process` block, its `fields.npz` and
its row) and writes `OUT.md`, `OUT.json` and `OUT.png`: maps over (omega, U) of peak
temperature, torque, mechanical power and the advancing-retreating and trailing-leading
temperature differences, and peak temperature against the pseudo heat index omega^2 / U.  Two
comparisons with what the field uses:

- Arbegast's relation ``T_peak / T_melt = K (omega^2 / (U 1e4))^alpha`` (omega in rpm, U in
  inches per minute, temperatures in degrees C; K 0.65-0.75 and alpha 0.04-0.06 reported for
  aluminium): K and alpha fitted to the sweep by least squares on the logarithms;
- Schmidt and Hattel's sticking-contact heat, in its 2-D form for the disc: per unit thickness
  a sticking ring of radius R1 under the shear flow stress tau carries the torque
  ``2 pi R1 * tau * R1``, so the heat is ``Q = 2 pi tau omega R1^2`` (the 3-D shoulder's
  ``2/3 pi tau omega R^3`` integrates ``tau omega r`` over the shoulder's disc instead of the
  pin's side).  tau is taken from the material's law at the interface's mean temperature and
  strain rate, and Q is set against the run's torque x omega.

How far from steady the 0.1 s runs are: the axisymmetric continuum of the same scene without the
travel (:func:`jaxanm.fsw.axisymmetric.solve`, which reaches its steady state within about 20 s)
gives the interface temperature rise at t_end over its steady value, for each omega.

    nice -n 10 jaxanm sweep benchmarks/grids/process_window.toml --workers 1 --out results/sweep-process_window
    python benchmarks/process_window.py results/sweep-process_window --out benchmarks/results/process_window
"""

from __future__ import annotations

import argparse
import json
import math
import os
import types
from pathlib import Path

import numpy as np

T_MELT_C = 660.0
"""Melting temperature (degrees C) in Arbegast's ratio: aluminium's (the flow law of the scenes is
an aluminium alloy's; an alloy's solidus, about 580 degrees C for 6xxx, would raise K by 14 %)."""
RPM_PER_RAD_S = 60.0 / (2.0 * math.pi)
IPM_PER_M_S = 60.0 / 0.0254
STEADY_TIMES = (10.0, 20.0, 40.0, 80.0)
"""Times (s) of the axisymmetric continuum runs: steady when the last two agree."""
MAPS = (("peak_T", "peak T (K)"), ("torque", "torque (N m/m)"), ("power", "power (kW/m)"),
        ("advancing_minus_retreating", "T_adv - T_ret (K)"), ("trailing_minus_leading", "T_trail - T_lead (K)"))


def heat_index(omega: float, U: float) -> float:
    """Arbegast's pseudo heat index ``omega^2 / (U 1e4)`` with omega in rpm and U in inches/min."""
    return (omega * RPM_PER_RAD_S) ** 2 / (U * IPM_PER_M_S * 1e4)


def sticking_heat(tau: float, omega: float, R1: float) -> float:
    """Schmidt-Hattel's sticking heat of the pin's side per unit thickness, ``2 pi tau omega R1^2`` (W/m)."""
    return 2.0 * math.pi * tau * omega * R1 ** 2


def run_result(run_dir: Path, summary: dict):
    """The saved fields of a sweep task as the result object :mod:`jaxanm.fsw.energy` reads."""
    from jaxanm.fsw.scene import Scene

    with np.load(run_dir / "fields.npz") as f:
        arrays = {k: f[k] for k in f.files}
    return types.SimpleNamespace(scene=Scene.from_dict(summary["scene"], source=str(run_dir)), **arrays)


def interface(result, angles: int = 720) -> dict:
    """Mean temperature, strain rate and shear flow stress of the plate at the tool edge (last save).

    ``tau_law`` is the law's shear flow stress ``sigma_bar / sqrt 3 = sqrt 3 mu epsbar`` at the
    mean temperature and mean strain rate (what Schmidt and Hattel's tau is: the material's
    yield shear stress at the interface's state), ``tau_mean`` the mean of the shear stress
    itself (``torque / (2 pi R1^2)``).
    """
    from jaxanm.fsw.energy import fields_at
    from jaxanm.fsw.physics import viscosity

    scene = result.scene
    g, m = scene.geometry, scene.material
    th = 2.0 * math.pi * (np.arange(angles) + 0.5) / angles
    nx, ny = np.cos(th), np.sin(th)
    f = fields_at(result, -1, g.R1 * (1.0 + 1e-9) * np.stack([nx, ny], axis=1))
    exy = 0.5 * (f["uy"] + f["vx"])
    e_rt = nx * ny * (f["vy"] - f["ux"]) + exy * (nx * nx - ny * ny)
    e2 = (2.0 / 3.0) * (f["ux"] ** 2 + f["vy"] ** 2 + 2.0 * exy ** 2)
    T, ebar = float(np.mean(f["T"])), float(np.mean(np.sqrt(e2)))
    mu = viscosity(T, ebar ** 2 + scene.eps0 ** 2, m.K, m.A, m.n)
    mu_local = viscosity(f["T"], e2 + scene.eps0 ** 2, m.K, m.A, m.n)
    return {"T_edge": T, "epsbar_edge": ebar, "tau_law": float(math.sqrt(3.0) * mu * ebar),
            "tau_mean": float(-np.mean(2.0 * mu_local * e_rt))}


def load_rows(sweep: Path) -> list:
    """One row per finished task of the sweep: speeds, process block, peak T at each save, counts."""
    rows = []
    for run_dir in sorted((sweep / "runs").iterdir()):
        try:
            row = json.loads((run_dir / "sweep_row.json").read_text())
            summary = json.loads((run_dir / "summary.json").read_text())
        except OSError:
            continue
        if row.get("status") != "ok" or not summary.get("process"):
            continue
        tool = summary["scene"]["tool"]
        result = run_result(run_dir, summary)
        plate = np.asarray(result.material) != 0
        out = {"task": row["task"], "omega": tool["omega"], "U": tool["traverse_speed"],
               "advance_mm": 2e3 * math.pi * tool["traverse_speed"] / tool["omega"],
               "heat_index": heat_index(tool["omega"], tool["traverse_speed"]),
               "t_saved": result.t.tolist(), "peak_T_saved": [float(T[plate].max()) for T in result.T],
               **summary["process"], **interface(result),
               **{k: row.get(k) for k in ("time_steps", "factorizations", "series_orders", "wall_s")}}
        out["Q_sticking"] = sticking_heat(out["tau_law"], out["omega"], result.scene.geometry.R1)
        rows.append(out)
    return rows


def fit_arbegast(rows: list, T_melt_C: float = T_MELT_C) -> dict:
    """K and alpha of ``T_peak / T_melt = K index^alpha`` (degrees C), least squares on the logs."""
    x = np.log([r["heat_index"] for r in rows])
    y = np.log([(r["peak_T"] - 273.15) / T_melt_C for r in rows])
    alpha, lnK = np.polyfit(x, y, 1)
    resid = y - (lnK + alpha * x)
    return {"K": float(math.exp(lnK)), "alpha": float(alpha), "T_melt_C": T_melt_C,
            "rms_log_residual": float(np.sqrt(np.mean(resid ** 2)))}


def steady_fraction(omegas, t_end: float) -> list:
    """For each omega: the axisymmetric continuum's interface temperature at ``t_end`` and at its
    steady state (fsw_weld without the travel), and the fraction of the steady rise reached."""
    from jaxanm.fsw import axisymmetric
    from jaxanm.fsw.scene import load_scene

    out = []
    for omega in sorted(set(omegas)):
        scene = load_scene("fsw_weld").with_overrides({"tool.omega": omega, "tool.traverse_speed": 0.0})
        # dt = 1e-2 s: the interface temperatures agree with dt = 5e-3 to 0.1 K at 200 rad/s.
        sol = axisymmetric.solve(scene, (t_end,) + STEADY_TIMES, dt=1e-2)
        T0 = scene.thermal.T0
        out.append({"omega": omega, "T_R1_t_end": float(sol.T_R1[0]), "T_R1_steady": float(sol.T_R1[-1]),
                    "T_R1_change_last": float(sol.T_R1[-1] - sol.T_R1[-2]),
                    "fraction": float((sol.T_R1[0] - T0) / (sol.T_R1[-1] - T0)),
                    "power_t_end": float(sol.power[0]), "power_steady": float(sol.power[-1])})
    return out


def figure(rows: list, fit: dict):
    """The five maps over (omega, U) and peak T against the heat index, with the fitted relation
    (a matplotlib Figure, no pyplot state: a script saves it, a notebook displays it)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(15, 9))
    axes = fig.subplots(2, 3)
    om = np.array([r["omega"] for r in rows])
    U = np.array([r["U"] for r in rows]) * 1e3
    for ax, (key, label) in zip(axes.flat, MAPS):
        v = np.array([r[key] for r in rows]) * (1e-3 if key == "power" else 1.0)
        sc = ax.scatter(om, U, c=v, s=400, cmap="inferno", edgecolors="k")
        for x, y, z in zip(om, U, v):
            ax.annotate(f"{z:.3g}", (x, y), textcoords="offset points", xytext=(0, 14), ha="center", fontsize=8)
        ax.set(xscale="log", yscale="log", xlabel="omega (rad/s)", ylabel="U (mm/s)", title=label)
        fig.colorbar(sc, ax=ax)
    ax = axes.flat[-1]
    idx = np.array([r["heat_index"] for r in rows])
    ax.scatter(idx, [r["peak_T"] - 273.15 for r in rows], c=np.log(om), cmap="viridis", edgecolors="k")
    xs = np.geomspace(idx.min(), idx.max(), 50)
    ax.plot(xs, fit["T_melt_C"] * fit["K"] * xs ** fit["alpha"], "k-",
            label=f"fit: K = {fit['K']:.3f}, alpha = {fit['alpha']:.3f}")
    for K, alpha, style in ((0.65, 0.04, ":"), (0.75, 0.06, "--")):
        ax.plot(xs, fit["T_melt_C"] * K * xs ** alpha, "r" + style, label=f"Arbegast K = {K}, alpha = {alpha}")
    ax.set(xscale="log", xlabel="omega^2 / (U 1e4)  (rpm^2 / (in/min))", ylabel="peak T (deg C)",
           title="peak T at t_end against the pseudo heat index")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def three_d_share(rows: list, scene) -> float:
    """The pin side's share of Schmidt-Hattel's 3-D sticking heat at one tau: side ``2 pi R1^2 H``
    against side + shoulder ``2/3 pi (R_sh^3 - R1^3)`` + pin tip ``2/3 pi R1^3`` (tau omega factored out)."""
    g, t = scene.geometry, scene.tool
    side = 2.0 * math.pi * g.R1 ** 2 * g.thickness
    return side / (side + 2.0 / 3.0 * math.pi * t.shoulder_radius ** 3)


def table(rows: list) -> list:
    """The markdown table of the sweep's rows."""
    lines = ["| omega (rad/s) | U (mm/s) | advance (mm/rev) | omega^2/(U 1e4) | peak T (K) | torque (N m/m) | "
             "power (kW/m) | dissipation / power | T_adv - T_ret (K) | T_trail - T_lead (K) | T edge (K) | "
             "tau law (MPa) | Q_sticking / power | flux error | steps | factorisations | wall (s) |",
             "| ---: " * 17 + "|"]
    for r in sorted(rows, key=lambda r: (r["omega"], r["U"])):
        lines.append(
            f"| {r['omega']:g} | {r['U'] * 1e3:.4g} | {r['advance_mm']:.3f} | {r['heat_index']:.3g} | "
            f"{r['peak_T']:.1f} | {r['torque']:.4g} | {r['power'] * 1e-3:.4g} | {r['dissipation'] / r['power']:.3f} | "
            f"{r['advancing_minus_retreating']:+.2f} | {r['trailing_minus_leading']:+.2f} | {r['T_edge']:.1f} | "
            f"{r['tau_law'] * 1e-6:.3g} | {r['Q_sticking'] / r['power']:.3f} | {r['mass_flux_error']:.4f} | "
            f"{r['time_steps']} | {r['factorizations']} | {float(r['wall_s']):.0f} |")
    return lines


def markdown(data: dict) -> str:
    """The results page."""
    fit, rows = data["arbegast"], data["rows"]
    lines = ["# The weld's process window (fsw_weld over omega x U)", "",
             f"Made by `python benchmarks/process_window.py {data['sweep']} --out {data['out']}` from the sweep "
             "`jaxanm sweep benchmarks/grids/process_window.toml --workers 1` (each run from rest to "
             f"t_end = {data['t_end']:g} s with the scene's solver, the ANM); load average during the sweep "
             f"{data['load']}.  Values at t_end; torque and powers per unit thickness; temperature differences "
             "0.75 mm outside the tool edge (`jaxanm.fsw.process`).  Counts are deterministic, walls indicative "
             "(a shared machine).  Guide: [the process window](../../docs/guide/process-window.md).", "",
             "![maps](process_window.png)", ""] + table(rows)
    lines += ["", "## Arbegast's relation", "",
              f"`T_peak / T_melt = K (omega^2 / (U 1e4))^alpha` (rpm, inches/min, degrees C, T_melt = "
              f"{fit['T_melt_C']:g} C) fitted to the {len(rows)} runs: **K = {fit['K']:.3f}, alpha = "
              f"{fit['alpha']:.3f}** (rms residual of ln(T/T_melt) {fit['rms_log_residual']:.3f}); reported for "
              "aluminium: K 0.65-0.75, alpha 0.04-0.06.", "",
              "## How far from steady", "",
              "The axisymmetric continuum of fsw_weld without the travel (`jaxanm.fsw.axisymmetric`): interface "
              "temperature at t_end and at 80 s (steady: its change from 40 s is in the last column).", "",
              "Beside it, the steady temperature as Arbegast's ratio (degrees C) and his band (K 0.65, alpha 0.04 to "
              "K 0.75, alpha 0.06) at the largest heat index of that omega's runs (its slowest travel).", "",
              "| omega (rad/s) | T(R1) at t_end (K) | T(R1) steady (K) | fraction of the steady rise | power at t_end "
              "/ steady | change 40-80 s (K) | steady T / T_melt | Arbegast's band |",
              "| ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for s in data["steady"]:
        index = max(r["heat_index"] for r in rows if r["omega"] == s["omega"])
        ratio = (s["T_R1_steady"] - 273.15) / fit["T_melt_C"]
        lines.append(f"| {s['omega']:g} | {s['T_R1_t_end']:.1f} | {s['T_R1_steady']:.1f} | {s['fraction']:.3f} | "
                     f"{s['power_t_end'] / s['power_steady']:.2f} | {s['T_R1_change_last']:.2g} | {ratio:.3f} | "
                     f"{0.65 * index ** 0.04:.2f}-{0.75 * index ** 0.06:.2f} |")
    lines += ["", "## Schmidt and Hattel's sticking heat in 2-D", "",
              "`Q = 2 pi tau omega R1^2` per unit thickness, tau the law's shear flow stress at the interface's "
              "mean temperature and strain rate (column `tau law`); `Q_sticking / power` sets it against the run's "
              "torque x omega.  In 3-D, at one tau, the pin's side is "
              f"{data['pin_side_share']:.2f} of side + shoulder + pin tip for this tool (R1 = 1.5 mm, shoulder "
              "4.5 mm, plate 3 mm): the disc carries that share of a real tool's sticking heat only.", ""]
    return "\n".join(lines)


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", help="the sweep's output directory")
    ap.add_argument("--out", default="benchmarks/results/process_window", help="writes OUT.md, OUT.json, OUT.png")
    ap.add_argument("--load", default=None, help="load average during the sweep, as recorded (text)")
    args = ap.parse_args(argv)
    from jaxanm.fsw.scene import load_scene

    rows = load_rows(Path(args.sweep))
    if len(rows) < 3:
        raise SystemExit(f"{args.sweep}: {len(rows)} finished runs; the fit needs at least 3")
    out = Path(args.out)
    t_end = max(r["t"] for r in rows)
    data = {"sweep": args.sweep, "out": args.out, "t_end": t_end, "load": args.load or f"{os.getloadavg()[0]:.1f}",
            "rows": rows, "arbegast": fit_arbegast(rows), "steady": steady_fraction([r["omega"] for r in rows], t_end),
            "pin_side_share": three_d_share(rows, load_scene("fsw_weld"))}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(data, indent=1) + "\n")
    out.with_suffix(".md").write_text(markdown(data) + "\n")
    figure(rows, data["arbegast"]).savefig(out.with_suffix(".png"), dpi=120)
    print(markdown(data))


if __name__ == "__main__":
    main()
