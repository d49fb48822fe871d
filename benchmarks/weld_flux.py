"""Mass conservation of the weld scene at every saved time, and which speeds start.

Two studies, each a table of `benchmarks/results/weld_flux.md` (+ `.json`); the numbers are
counts and fluxes (deterministic), the walls are only indicative:

- **flux**: `fsw_weld` run to `--t-end` (ANM, its saved times) with the `incompressible`
  effect (the scene as shipped), and the same scene as it was before that effect (the main
  job's penalty 4.08e5 Pa s, its 0.085 mm cloud, eps0 = 0.1 1/s): the flux through every
  section and circle of `jaxanm.fsw.mass_flux.flux_table` minus its exact value (`2 sqrt(R2^2 -
  x^2) U` or 0), in units of `2 R2 U` (sections) and `2 r U` (circles), at t = 0 (the start
  flow), a quarter, half and three quarters of `--t-end`, and at its end.
- **speeds**: `fsw_weld` at pairs (omega, U) of the process window (omega in [10, 200] rad/s,
  advance per revolution `2 pi U / omega` in [0.05, 1] mm), run for `--speeds-t-end` with the
  ANM and with modified Newton: whether the run starts and reaches its end, its steps, or the
  message it stopped with.  Each case takes minutes; the study resumes from the committed rows
  (only the cases not there are run).

    nice -n 19 python benchmarks/weld_flux.py --t-end 0.1 --out benchmarks/results/weld_flux

(`--only flux|speeds` runs one study and keeps the other's committed rows.)
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np

import jaxanm
from jaxanm.fsw import run
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


def flux_rows(t_end: float) -> list:
    rows = []
    for label, overrides in (("incompressible (fsw_weld)", {}), ("penalty 4.08e5 Pa s (before)", PENALTY)):
        scene = load_scene("fsw_weld").with_overrides({**overrides, "time.t_end": t_end,
                                                       "time.save": [t_end * f for f in (0.25, 0.5, 0.75)]})
        began = time.perf_counter()
        result = run(scene)
        table = flux_table(result)
        rows.append({"case": label, "wall_s": time.perf_counter() - began, "t": table["t"].tolist(),
                     "sections": {f"{x * 1e3:+.2f}": v.tolist() for x, v in table["sections"].items()},
                     "circles": {f"{r * 1e3:.3f}": v.tolist() for r, v in table["circles"].items()}})
        print(label, {k: np.abs(v).max() for k, v in rows[-1]["sections"].items()}, flush=True)
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
        save("flux", flux_rows(args.t_end))
    if args.only in (None, "speeds"):
        speed_rows(args.speeds_t_end, data.get("speeds", []), lambda rows: save("speeds", rows))
    print(markdown(data))


if __name__ == "__main__":
    main()
