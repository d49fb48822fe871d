"""The process window's corners and its centre, from rest over 0.1 s, with the ANM and with
modified Newton: steps, factorisations, series orders or Newton iterations, walls.

The five points are tasks of the process-window sweep (`benchmarks/grids/process_window.toml`:
omega 10 and 200 rad/s at advances of 0.05 and 1 mm per revolution, and omega = 44.7 rad/s at
0.224 mm), whose runs are `fsw_weld` from rest to 0.1 s with the scene's solver, the ANM: their
rows are read from the sweep's `results.csv`, not run again.  Modified Newton (`solver.kind =
"mnewton"`, the scene's other settings) is run here on the same scenes; the study resumes
from the rows of an earlier call (only the points not there are run).

    nice -n 10 python benchmarks/window_corners.py results/sweep-process_window --out benchmarks/results/window_corners

Counts are deterministic; the walls are indicative (a shared machine; the ANM's come from the
sweep's worker, with warm compile caches on neither side).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import time
from pathlib import Path

import jaxanm
from jaxanm.fsw import run
from jaxanm.fsw.scene import load_scene

POINTS = ((10.0, 7.958e-5), (10.0, 1.5915e-3), (44.721, 1.5915e-3), (200.0, 1.5915e-3), (200.0, 3.1830e-2))
"""(omega rad/s, U m/s): the four corners of the window (advances 0.05 and 1 mm per revolution at
10 and 200 rad/s) and its centre (0.224 mm at 44.7 rad/s), as in the process-window grid; the
cheapest first (a run's steps grow with omega)."""


def sweep_rows(sweep: Path) -> list:
    """The sweep's ANM rows of :data:`POINTS`."""
    with open(sweep / "results.csv", newline="") as f:
        table = list(csv.DictReader(f))
    rows = []
    for omega, U in POINTS:
        for r in table:
            if float(r["tool.omega"]) == omega and float(r["tool.traverse_speed"]) == U:
                ok = r["status"] == "ok"
                rows.append({"omega": omega, "U": U, "solver": "anm", "ok": ok, "message": r["message"],
                             **({k: int(r[k]) for k in ("time_steps", "factorizations", "series_orders",
                                                       "newton_iterations")} if ok else {}),
                             "t": float(r["t_end"]) if ok else None, "wall_s": float(r["wall_s"]) if ok else None})
    return rows


def mnewton_row(omega: float, U: float) -> dict:
    """fsw_weld at (omega, U) from rest to 0.1 s with modified Newton."""
    scene = load_scene("fsw_weld").with_overrides({"tool.omega": omega, "tool.traverse_speed": U, "time.t_end": 0.1,
                                                   "time.save": [0.025, 0.05, 0.075, 0.1],
                                                   "solver.kind": "mnewton"})
    row = {"omega": omega, "U": U, "solver": "mnewton"}
    began = time.perf_counter()
    try:
        result = run(scene)
        s = result.stats
        row.update(ok=True, message="", time_steps=s.time_steps, factorizations=s.factorizations,
                   series_orders=s.series_orders, newton_iterations=s.newton_iterations, t=float(result.t[-1]),
                   wall_s=s.wall_time_s)
    except (jaxanm.StepFailure, jaxanm.InputError) as exc:
        row.update(ok=False, message=" ".join(str(exc).split()), wall_s=time.perf_counter() - began)
    return row


def markdown(data: dict) -> str:
    """The results page."""
    lines = ["# The process window's corners and centre over 0.1 s: ANM and modified Newton", "",
             f"Made by `python benchmarks/window_corners.py {data['sweep']}` (`fsw_weld` from rest to 0.1 s; the "
             "ANM rows are the process-window sweep's, modified Newton's are run by the script); load average "
             f"{data['load'][0]:.1f} / {data['load'][1]:.1f} before / after the modified-Newton runs.  Walls: the "
             "time loop's (`Stats.wall_time_s`), not comparable between the solvers: the ANM's ran warm in the "
             "sweep's worker, modified Newton's include their compilation and ran at nice 10-19 beside other jobs "
             "on a shared machine.  The counts are what to compare.", "",
             "| omega (rad/s) | U (mm/s) | advance (mm/rev) | solver | outcome | steps | factorisations | "
             "series orders | Newton iterations | wall (s) |",
             "| ---: | ---: | ---: | --- | --- | ---: | ---: | ---: | ---: | ---: |"]
    for r in sorted(data["rows"], key=lambda r: (r["omega"], r["U"], r["solver"])):
        advance = 2e3 * math.pi * r["U"] / r["omega"]
        counts = (f"{r['time_steps']} | {r['factorizations']} | {r['series_orders']} | {r['newton_iterations']}"
                  if r["ok"] else "- | - | - | -")
        outcome = f"reached t = {r['t']:g} s" if r["ok"] else f"stopped: {r['message']}"
        wall = "-" if r.get("wall_s") is None else f"{r['wall_s']:.0f}"
        lines.append(f"| {r['omega']:g} | {r['U'] * 1e3:.4g} | {advance:.3f} | {r['solver']} | {outcome} | {counts} "
                     f"| {wall} |")
    missing = [(o, U, solver) for o, U in POINTS for solver in ("anm", "mnewton")
               if not any(r["omega"] == o and r["U"] == U and r["solver"] == solver for r in data["rows"])]
    if missing:
        lines += ["", "Not run yet (the study resumes from these rows): "
                  + "; ".join(f"omega {o:g} rad/s, U {U * 1e3:.4g} mm/s, {solver}" for o, U, solver in missing) + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep", help="the process-window sweep's directory (results.csv)")
    ap.add_argument("--out", default="benchmarks/results/window_corners")
    args = ap.parse_args(argv)
    out = Path(args.out)
    old = json.loads(out.with_suffix(".json").read_text()) if out.with_suffix(".json").exists() else {}
    done = [r for r in old.get("rows", []) if r["solver"] == "mnewton"]
    before = os.getloadavg()[0]
    for omega, U in POINTS:
        if any(r["omega"] == omega and r["U"] == U for r in done):
            continue
        done.append(mnewton_row(omega, U))
        print(done[-1], flush=True)
        data = {"sweep": args.sweep, "rows": sweep_rows(Path(args.sweep)) + done,
                "load": [before, os.getloadavg()[0]]}
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".json").write_text(json.dumps(data, indent=1) + "\n")
        out.with_suffix(".md").write_text(markdown(data))


if __name__ == "__main__":
    main()
