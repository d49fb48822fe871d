"""Mass conservation of the weld scene at every saved time, and which speeds start.

Two studies, each a table of `benchmarks/results/weld_flux.md` (+ `.json`); the numbers are
counts and fluxes (deterministic), the walls are only indicative:

- **flux**: `fsw_weld` run to `--t-end` (ANM, its saved times) with the `incompressible`
  effect (the scene as shipped), and the same scene as it was before that effect (the main
  job's penalty 4.08e5 Pa s, its 0.085 mm cloud, eps0 = 0.1 1/s): the flux through every
  section and circle of `jaxanm.fsw.mass_flux.flux_table` minus its exact value (`2 sqrt(R2^2 -
  x^2) U` or 0), in units of `2 R2 U` (sections) and `2 r U` (circles), at t = 0 (the start
  flow), a quarter, half and three quarters of `--t-end`, and at its end; with each run its
  solver counts, the registration points' temperatures at half of `--t-end`, and the material
  paths through the flow at that time (`jaxanm.fsw.io.weld_figures.paths`: where each of the
  figure's 17 paths entering on the leading side crosses x = 0 and leaves the disc).  The
  incompressible scene is also run with modified Newton (its counts and temperatures only).
- **speeds**: `fsw_weld` at pairs (omega, U) of the process window (omega in [10, 200] rad/s,
  advance per revolution `2 pi U / omega` in [0.05, 1] mm), run for `--speeds-t-end` with the
  ANM and with modified Newton: whether the run starts and reaches its end, its steps, or the
  message it stopped with.  Each case takes minutes; the study resumes from the committed rows
  (only the cases not there are run).

    nice -n 19 python benchmarks/weld_flux.py --t-end 0.1 --out benchmarks/results/weld_flux

(`--only flux|speeds` runs one study and keeps the other's committed rows; `--flux-cases 0,2`
reruns those flux cases only.)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
import types
from pathlib import Path

import numpy as np

import jaxanm
from jaxanm.fsw import run
from jaxanm.fsw.io.weld_figures import paths
from jaxanm.fsw.mass_flux import flux_table
from jaxanm.fsw.scene import load_scene

PENALTY = {"effects": "inertia,viscous,softening,conduction,tool_conduction,dissipation,robin,tracers,slip,traverse",
           "mechanics.penalty": 4.08e5, "geometry.dr": 8.5e-5, "material.eps0_relative": 0.0,
           "material.eps0": 0.1}
"""fsw_weld as it was before the ``incompressible`` effect (the main job's penalty and cloud)."""

SPEEDS = ((20.0, 2e-3, "anm"), (20.0, 2e-3, "modified_newton"), (200.0, 3e-2, "anm"), (10.0, 1e-4, "anm"),
          (10.0, 1.5e-3, "anm"), (200.0, 1.6e-3, "anm"), (200.0, 3e-2, "modified_newton"),
          (10.0, 1e-4, "modified_newton"), (10.0, 1.5e-3, "modified_newton"), (200.0, 1.6e-3, "modified_newton"))
"""(omega rad/s, U m/s, solver): a speed that used to fail at the scene's omega, then the corners
of the window (advances 0.94, 0.063, 0.94 and 0.050 mm per revolution)."""


FLUX_CASES = (("incompressible (fsw_weld)", {}), ("penalty 4.08e5 Pa s (before)", PENALTY),
              ("incompressible (fsw_weld), modified Newton", {"solver.kind": "mnewton"}))
"""The flux study's runs: the scene as shipped, as it was before, and the first with the other solver."""


def path_crossings(result, s: int, count: int = 17) -> list:
    """The material paths of the weld figure (``count`` entry heights on the leading side) through
    the flow of saved step ``s``: ``[y_entry, y at the first crossing of x = 0 (None if none),
    y where the path ends]`` (m) each."""
    g = result.scene.geometry
    y = np.linspace(-0.9, 0.9, count) * g.R2
    seeds = np.stack([0.98 * np.sqrt(g.R2 ** 2 - y ** 2), y], axis=1)
    upto = types.SimpleNamespace(scene=result.scene, t=result.t[:s + 1], material=result.material,
                                 points=result.points[:s + 1], u=result.u[:s + 1], v=result.v[:s + 1])
    out = []
    for y0, path in zip(y, paths(upto, seeds, step=0.02 * g.R1)):
        cross = np.flatnonzero((path[:-1, 0] > 0) & (path[1:, 0] <= 0))
        at_x0 = None if cross.size == 0 else float(np.interp(0.0, path[cross[0] + 1::-1, 0][:2],
                                                              path[cross[0] + 1::-1, 1][:2]))
        out.append([float(y0), at_x0, float(path[-1, 1])])
    return out


def flux_rows(t_end: float, cases: list, rows: list, save) -> list:
    """The runs of :data:`FLUX_CASES` numbered ``cases``, in place of their rows in ``rows`` (the
    others' kept), ``save(rows)`` after each run."""
    for label, overrides in [FLUX_CASES[i] for i in cases]:
        scene = load_scene("fsw_weld").with_overrides({**overrides, "time.t_end": t_end,
                                                       "time.save": [t_end * f for f in (0.25, 0.5, 0.75)]})
        began = time.perf_counter()
        result = run(scene)
        wall = time.perf_counter() - began
        table = flux_table(result)
        half = int(np.argmin(np.abs(np.asarray(result.t) - t_end / 2)))
        probes = result.probes
        at = int(np.argmin(np.abs(np.asarray(probes["t"]) - t_end / 2)))
        s = result.stats
        rows = [r for r in rows if r["case"] != label]
        rows.append({"case": label, "wall_s": wall, "t": table["t"].tolist(),
                     "sections": {f"{x * 1e3:+.2f}": v.tolist() for x, v in table["sections"].items()},
                     "circles": {f"{r * 1e3:.3f}": v.tolist() for r, v in table["circles"].items()},
                     "counts": {"time_steps": s.time_steps, "factorizations": s.factorizations,
                                "series_orders": s.series_orders, "newton_iterations": s.newton_iterations,
                                "run_wall_s": s.wall_time_s},
                     "probes_t": float(probes["t"][at]),
                     "probes_T": {name: float(probes[name]["T"][at]) for name in probes if name != "t"},
                     "paths_t": float(result.t[half]), "paths": path_crossings(result, half)})
        rows.sort(key=lambda r: [c[0] for c in FLUX_CASES].index(r["case"]))
        save(rows)
        print(label, f"{wall:.0f} s", flush=True)
    return rows


def speed_rows(t_end: float, rows: list, save) -> list:
    """The cases of :data:`SPEEDS` not in ``rows`` yet (a long study resumes), ``save(rows)``
    after each run."""
    done = {(r["omega"], r["U"], r["solver"]) for r in rows}
    for omega, U, solver in SPEEDS:
        if (omega, U, solver) in done:
            continue
        scene = load_scene("fsw_weld").with_overrides({"tool.omega": omega, "tool.traverse_speed": U,
                                                       "time.t_end": t_end, "solver.kind": solver})
        row = {"omega": omega, "U": U, "advance_mm": 2e3 * math.pi * U / omega, "solver": solver}
        began = time.perf_counter()
        try:
            result = run(scene)
            row.update(ok=True, steps=int(result.stats.time_steps), t=float(result.t[-1]))
        except (jaxanm.StepFailure, jaxanm.InputError) as exc:
            row.update(ok=False, message=str(exc).splitlines()[0])
        row["wall_s"] = time.perf_counter() - began
        rows.append(row)
        save(rows)
        print(row, flush=True)
    return rows


def run_lines(r: dict) -> list:
    """The counts, registration temperatures and material paths of a flux row (when recorded)."""
    if "counts" not in r:
        return []
    c = r["counts"]
    lines = [f"Solver counts: {c['time_steps']} steps, {c['factorizations']} factorisations, {c['series_orders']} "
             f"series orders, {c['newton_iterations']} Newton iterations; time loop {c['run_wall_s']:.0f} s.", "",
             f"Registration points at t = {r['probes_t']:.4g} s (K): "
             + ", ".join(f"{k} {v:.2f}" for k, v in r["probes_T"].items()) + ".", ""]
    if "modified Newton" in r["case"]:
        return lines
    lines += [f"Material paths through the flow at t = {r['paths_t']:.4g} s (y in mm): entering on the leading side "
              "at y, crossing x = 0 at y (retreating side y > 0), ending at y.", "",
              "| y entering | y at x = 0 | y at the end |", "| ---: | ---: | ---: |"]
    for y0, y_x0, y_end in r["paths"]:
        lines.append(f"| {y0 * 1e3:+.2f} | {'-' if y_x0 is None else f'{y_x0 * 1e3:+.2f}'} | {y_end * 1e3:+.2f} |")
    return lines + [""]


def markdown(data: dict) -> str:
    lines = ["# Mass conservation of the weld scene, and which speeds start", "",
             "Made by `benchmarks/weld_flux.py`; load average "
             f"{data['load'][0]:.1f} / {data['load'][1]:.1f} (before / after).", ""]
    for r in data.get("flux", []):
        lines += [f"## {r['case']}: flux errors at the saved times", "",
                  "Sections x = const (mm): flux minus `2 sqrt(R2^2 - x^2) U`, in `2 R2 U`; circles r (mm): net "
                  "flux in `2 r U`.", "",
                  "| t (s) | " + " | ".join(f"x {k}" for k in r["sections"]) + " | "
                  + " | ".join(f"r {k}" for k in r["circles"]) + " |",
                  "| --- |" + " --- |" * (len(r["sections"]) + len(r["circles"]))]
        for i, t in enumerate(r["t"]):
            cells = [f"{v[i]:+.4f}" for v in r["sections"].values()] + [f"{v[i]:+.1e}" for v in r["circles"].values()]
            lines.append(f"| {t:.4g} | " + " | ".join(cells) + " |")
        worst = max(abs(x) for group in ("sections", "circles") for v in r[group].values() for x in v)
        lines += ["", f"Largest error over lines and saved times: {worst:.4f}; run wall {r['wall_s']:.0f} s.", ""]
        lines += run_lines(r)
    if data.get("speeds"):
        lines += ["## Speeds (fsw_weld, from rest)", "",
                  "| omega (rad/s) | U (mm/s) | advance (mm/rev) | solver | outcome |",
                  "| --- | --- | --- | --- | --- |"]
        for r in data["speeds"]:
            outcome = f"reached t = {r['t']:g} s in {r['steps']} steps" if r["ok"] else f"stopped: {r['message']}"
            lines.append(f"| {r['omega']:g} | {r['U'] * 1e3:g} | {r['advance_mm']:.3f} | {r['solver']} | {outcome} |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="benchmarks/results/weld_flux")
    ap.add_argument("--t-end", type=float, default=0.1)
    ap.add_argument("--speeds-t-end", type=float, default=0.01)
    ap.add_argument("--only", choices=("flux", "speeds"), default=None)
    ap.add_argument("--flux-cases", default=",".join(str(i) for i in range(len(FLUX_CASES))),
                    help="which of FLUX_CASES to (re)run, e.g. 0,2 (the others' rows are kept)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    data: dict = json.loads(out.with_suffix(".json").read_text()) if out.with_suffix(".json").exists() else {}
    before = os.getloadavg()[0]

    def save(key, rows):
        data[key] = rows
        data["load"] = [before, os.getloadavg()[0]]
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".json").write_text(json.dumps(data, indent=1))
        out.with_suffix(".md").write_text(markdown(data))

    if args.only in (None, "flux"):
        flux_rows(args.t_end, [int(i) for i in args.flux_cases.split(",")], data.get("flux", []),
                  lambda rows: save("flux", rows))
    if args.only in (None, "speeds"):
        speed_rows(args.speeds_t_end, data.get("speeds", []), lambda rows: save("speeds", rows))
    print(markdown(data))


if __name__ == "__main__":
    main()
