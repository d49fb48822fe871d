"""The start flow at t = 0 on fine clouds: damped Newton against the ANM's path following.

For each cloud (fsw_graded's, and fsw_tracers' uniform cloud at dr / 2 and dr / 4), in a
fresh process each: ``jaxanm.fsw.start.quasi_static_state`` (damped Newton from rest) and
``continuation_state`` (``jaxanm.continuation`` in the strain-rate regularisation), their
factorisations, iterations or steps, wall time (compilation included: each start compiles
its own functions once) and the largest difference between the two flows.  Writes
``OUT.md`` and ``OUT.json``.

    python benchmarks/start_from_rest.py --out benchmarks/results/start_from_rest
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

CLOUDS = {
    "fsw_graded (1603 points)": ("fsw_graded", {}),
    "uniform dr/2 (3369 points)": ("fsw_tracers", {"geometry.dr": 1.875e-4}),
    "uniform dr/4 (13173 points)": ("fsw_tracers", {"geometry.dr": 9.375e-5}),
}


def _measure(scene_name: str, overrides: dict, method: str) -> dict:
    """One start in this process: its counts, wall and flow."""
    import numpy as np

    from jaxanm.fsw.discretisation import discretise
    from jaxanm.fsw.scene import load_scene
    from jaxanm.fsw.start import continuation_state, quasi_static_state

    scene = load_scene(scene_name).with_overrides(overrides)
    _, stencils, model, _, _ = discretise(scene)
    start = time.perf_counter()
    solve = quasi_static_state if method == "damped Newton" else continuation_state
    x, report = solve(scene, model, stencils)
    wall = time.perf_counter() - start
    np.save(os.environ["START_FLOW"], x)
    st = report.stats
    return {"method": method, "factorizations": st.factorizations, "iterations": report.iterations,
            "series_orders": st.series_orders, "wall_s": wall, "split_s": st.wall_time, "load": os.getloadavg()}


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clouds", nargs="*", default=list(CLOUDS), help="labels of CLOUDS to run")
    ap.add_argument("--out", default=None, help="write OUT.md and OUT.json")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        scene, overrides, method = args.child
        print(json.dumps(_measure(scene, json.loads(overrides), method)))
        return
    import numpy as np

    rows = []
    for label in args.clouds:
        scene, overrides = CLOUDS[label]
        flows = {}
        for method in ("damped Newton", "continuation"):
            flow = Path(f"/tmp/start_flow_{os.getpid()}_{len(rows)}.npy")
            out = subprocess.run([sys.executable, __file__, "--child", scene, json.dumps(overrides), method],
                                 env={**os.environ, "START_FLOW": str(flow)}, capture_output=True, text=True)
            if out.returncode:
                raise RuntimeError(f"{label}, {method}: {out.stderr[-2000:]}")
            row = json.loads(out.stdout.strip().splitlines()[-1])
            row["cloud"] = label
            flows[method] = np.load(flow)
            flow.unlink()
            rows.append(row)
            print(f"{label}, {method}: {row['factorizations']} factorisations, {row['wall_s']:.1f} s", flush=True)
        rows[-1]["max_difference_scaled"] = float(np.abs(flows["continuation"] - flows["damped Newton"]).max())
    lines = ["| cloud | start | factorisations | iterations / steps | series orders | wall (s) | load | "
             "flows differ by (m/s) |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        diff = r.get("max_difference_scaled")
        lines.append(f"| {r['cloud']} | {r['method']} | {r['factorizations']} | {r['iterations']} | "
                     f"{r['series_orders']} | {r['wall_s']:.1f} | {r['load'][0]:.1f} | "
                     f"{'' if diff is None else f'{diff:.1e}'} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out + ".md").write_text(
            "# The start flow from rest: damped Newton against path following\n\n"
            "Made by `benchmarks/start_from_rest.py` (each start in a fresh process, compilation "
            "included; load: the 1-minute average at the end).\n\n" + text)
        Path(args.out + ".json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
