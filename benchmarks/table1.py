"""Table 1 of the paper: influence of the truncation order p on the ANM continuation.

For p in {5, 7, 10, 15, 20}, runs ``fsw_paper`` (its defaults, eta = 1e-6) over [0, T] and
reports, beside the paper's values:

- continuation steps: the number of factorised K* (each K* starts one continuation step of
  the paper; sub-steps within a time step that reuse the same K* do not count);
- average validity range t_max (s): the time span covered per K*, ``T / factorisations``
  (the paper's t_max: 0.7 s / 40 steps = 0.0175 s);
- the mean accepted a_max (eq. 26, per time step), series evaluations and wall time.

Usage::

    python benchmarks/table1.py                       # [0, 0.7] s, every order (hours)
    python benchmarks/table1.py --t-end 0.02 --scene fsw_paper --orders 5 7 10
    python benchmarks/table1.py --out benchmarks/results/table1     # writes benchmarks/results/table1.{md,json}

The paper's first column is unlabelled in the text (p = 5 or 7, see DESIGN §3); its four
columns are 0.0175 / 0.0185 / 0.0209 / 0.0209 s and 46 / 43 / 39 / 39 steps.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from jaxanm.fsw.scene import load_scene
from jaxanm.fsw.simulate import run

PAPER = {"orders": "5 or 7, 10, 15, 20 (first column unlabelled)",
         "t_max_s": [0.0175, 0.0185, 0.0209, 0.0209], "steps": [46, 43, 39, 39]}


def measure(scene_name: str, order: int, t_end: float, criterion: str | None) -> dict:
    """One ANM run of ``scene_name`` at truncation order ``order`` over [0, t_end]."""
    overrides = {"time.t_end": t_end, "solver.kind": "anm", "solver.order": order, "solver.adaptive": False}
    if criterion:
        overrides["solver.criterion"] = criterion
    scene = load_scene(scene_name).with_overrides(overrides)
    start = time.perf_counter()
    result = run(scene)
    wall = time.perf_counter() - start
    st = result.stats
    return {"order": order, "t_end": t_end, "criterion": scene.solver.setting("criterion"),
            "factorizations": st.factorizations, "t_max_s": t_end / max(st.factorizations, 1),
            "time_steps": st.time_steps, "substeps": st.substeps, "dt_halvings": st.dt_halvings,
            "series_orders": st.series_orders, "mean_amax": float(np.mean(st.amax)),
            "wall_s": wall, "wall_split_s": dict(st.wall_time)}


def markdown(rows: list[dict], scene_name: str, load: tuple) -> str:
    """The table, beside the paper's values."""
    lines = [f"Scene `{scene_name}`, ANM eta = 1e-6, criterion `{rows[0]['criterion']}`, span "
             f"[0, {rows[0]['t_end']:g}] s; load average at start {load[0]:.1f} (2 cores).", "",
             "| p | continuation steps (factorised K*) | average validity range t_max (s) | mean a_max | "
             "sub-steps | series evaluations | wall (s) |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        lines.append(f"| {r['order']} | {r['factorizations']} | {r['t_max_s']:.4g} | {r['mean_amax']:.3g} | "
                     f"{r['substeps']} | {r['series_orders']} | {r['wall_s']:.0f} |")
    lines += ["", f"Paper (Table 1, [0, 0.7] s, p = {PAPER['orders']}): t_max = "
              + " / ".join(f"{v}" for v in PAPER["t_max_s"]) + " s, continuation steps = "
              + " / ".join(str(v) for v in PAPER["steps"]) + "."]
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="fsw_paper")
    ap.add_argument("--t-end", type=float, default=0.7)
    ap.add_argument("--orders", type=int, nargs="+", default=[5, 7, 10, 15, 20])
    ap.add_argument("--criterion", choices=["increment", "state"], default=None,
                    help="ANM acceptance criterion (default: the scene's)")
    ap.add_argument("--out", default=None, help="write OUT.md and OUT.json")
    args = ap.parse_args(argv)
    load = os.getloadavg()
    rows = []
    for p in args.orders:
        rows.append(measure(args.scene, p, args.t_end, args.criterion))
        print(json.dumps(rows[-1]), flush=True)
    table = markdown(rows, args.scene, load)
    print(table)
    if args.out:
        with open(args.out + ".json", "w") as f:
            json.dump({"scene": args.scene, "load_average": load, "rows": rows, "paper": PAPER}, f, indent=1)
        with open(args.out + ".md", "w") as f:
            f.write(table)


if __name__ == "__main__":
    main()
