"""Where the weld's model stops beyond the process window: how far in advance per revolution the
start flow gets on the weld's cloud, per rotation speed.

The start flow of `fsw_weld` (`jaxanm.fsw.start.quasi_static_state`: the tool turning in place,
then a path in omega, then in the travel speed U) is asked for an advance per revolution
`2 pi U / omega` far beyond the window's 1 mm.  Either its path gets there, or it stops and the
message names the U it reached (the cloud's measured limit), or the scene is refused at
validation (a key out of its range, named).  Each case is the start flow only (no time step);
a path of tens of points takes tens of minutes on one core.  The study resumes from the rows of
an earlier call (only the cases not there are run).

    nice -n 10 python benchmarks/window_limits.py --out benchmarks/results/window_limits
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import time
from pathlib import Path

import jaxanm
from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.scene import load_scene
from jaxanm.fsw.start import quasi_static_state

CASES = ((10.0, 20.0), (44.721, 20.0), (200.0, 20.0))
"""(omega rad/s, advance asked mm per revolution) on the scene's cloud (0.06 mm at the tool edge)."""


def limit(omega: float, advance_mm: float) -> dict:
    """The start flow of fsw_weld at ``omega`` and the advance asked: reached, stopped, or refused."""
    U = advance_mm * 1e-3 * omega / (2.0 * math.pi)
    row: dict = {"omega": omega, "advance_asked_mm": advance_mm, "U_asked": U}
    began = time.perf_counter()
    try:
        scene = load_scene("fsw_weld").with_overrides({"tool.omega": omega, "tool.traverse_speed": U})
    except jaxanm.InputError as exc:
        return {**row, "outcome": "refused", "message": str(exc).splitlines()[0], "U_reached": None,
                "advance_reached_mm": None, "wall_s": time.perf_counter() - began}
    d = discretise(scene)
    row.update(dr=scene.geometry.dr, points=int(d.cloud.points.shape[0]))
    try:
        _, report = quasi_static_state(scene, d.model, d.stencils)
        row.update(outcome="reached", message="", U_reached=U, path_points=len(report.path),
                   iterations=report.iterations)
    except jaxanm.StepFailure as exc:
        found = re.search(r"stopped at U = ([0-9.e+-]+) m/s", str(exc))
        row.update(outcome="stopped", message=str(exc).splitlines()[0],
                   U_reached=float(found.group(1)) if found else None)
    row["advance_reached_mm"] = None if row["U_reached"] is None else 2e3 * math.pi * row["U_reached"] / omega
    row["wall_s"] = time.perf_counter() - began
    return row


def markdown(data: dict) -> str:
    """The results page."""
    lines = ["# How far the weld's start flow gets beyond the process window", "",
             "Made by `python benchmarks/window_limits.py` (`fsw_weld`'s start flow asked for an advance per "
             "revolution far beyond the window's 1 mm, on the scene's cloud: 0.06 mm at the tool edge, 2363 "
             f"points); load average {data['load'][0]:.1f} / {data['load'][1]:.1f} before / after the last call.",
             "", "| omega (rad/s) | advance asked (mm/rev) | U asked (mm/s) | outcome | reached (mm/rev) | "
             "path points | Newton iterations | wall (s) |", "| ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: |"]
    for r in data["rows"]:
        reached = "-" if r["advance_reached_mm"] is None else f"{r['advance_reached_mm']:.3g}"
        outcome = r["outcome"] + (f": {r['message']}" if r["message"] else "")
        lines.append(f"| {r['omega']:g} | {r['advance_asked_mm']:g} | {r['U_asked'] * 1e3:.4g} | {outcome} | "
                     f"{reached} | {r.get('path_points', '-')} | {r.get('iterations', '-')} | {r['wall_s']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="benchmarks/results/window_limits")
    args = ap.parse_args(argv)
    out = Path(args.out)
    old = json.loads(out.with_suffix(".json").read_text()) if out.with_suffix(".json").exists() else {}
    rows, before = old.get("rows", []), os.getloadavg()[0]
    for omega, advance in CASES:
        if any(r["omega"] == omega and r["advance_asked_mm"] == advance for r in rows):
            continue
        rows.append(limit(omega, advance))
        print(rows[-1], flush=True)
        data = {"rows": rows, "load": [before, os.getloadavg()[0]]}
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".json").write_text(json.dumps(data, indent=1) + "\n")
        out.with_suffix(".md").write_text(markdown(data))


if __name__ == "__main__":
    main()
