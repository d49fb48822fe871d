"""The ANM against modified Newton where the answer is right: short runs from rest on fine
clouds, whole `jaxanm run` commands back to back (compile cache warm: one untimed run of each
first), alternated, medians of the repeats.

    python benchmarks/anm_vs_mnewton_fine.py --out benchmarks/results/anm_vs_mnewton_fine
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CASES = {
    "fsw_graded, 0.02 s": ["fsw_graded", "--t-end", "0.02"],
    "fsw_tracers at dr/2, 0.02 s": ["fsw_tracers", "--t-end", "0.02", "--set", "geometry.dr=1.875e-4",
                                    "--set", "mechanics.start=quasi_static"],
}
# The main job itself (fsw, the ANM and modified Newton under its step controller, 0.7 s) is
# measured by benchmarks/main_job.py.
SOLVERS = ("anm", "mnewton")


def run(args: list[str], solver: str) -> dict:
    """One command: its wall and the counts its summary reports."""
    with tempfile.TemporaryDirectory() as out:
        start = time.perf_counter()
        done = subprocess.run([sys.executable, "-m", "jaxanm", "run", *args, "--solver", solver, "--out", out,
                               "--no-progress"], capture_output=True, text=True)
        wall = time.perf_counter() - start
        if done.returncode:
            raise RuntimeError(f"{args} {solver}: {done.stderr[-2000:]}")
        summary = json.loads((Path(out) / "summary.json").read_text())
    st = summary["stats"]
    return {"command_s": wall, "run_s": st["wall_time_s"], "steps": st["time_steps"],
            "factorizations": st["factorizations"], "split_s": st["wall_time"], "load": os.getloadavg()[0],
            "T_final": {k: v["T"] for k, v in summary["probes_final"].items()}}


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    rows = {}
    for case in args.cases:
        for solver in SOLVERS:
            run(CASES[case], solver)  # warm the compile cache
        runs = {s: [] for s in SOLVERS}
        for _ in range(args.repeats):
            for solver in SOLVERS:
                runs[solver].append(run(CASES[case], solver))
        rows[case] = runs
        print(case, {s: round(statistics.median(r["command_s"] for r in v), 1) for s, v in runs.items()}, flush=True)
    lines = [
        "| case | solver | command wall (s, median) | ANM / mnewton | run wall (s) | steps | factorisations | "
        "series or residuals (s) | solves (s) | load |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for case, runs in rows.items():
        med = {s: statistics.median(r["command_s"] for r in v) for s, v in runs.items()}
        for s, v in runs.items():
            last = v[-1]
            lines.append(
                f"| {case} | {s} | {med[s]:.1f} | {med['anm'] / med['mnewton']:.2f} | "
                f"{statistics.median(r['run_s'] for r in v):.1f} | {last['steps']} | {last['factorizations']} | "
                f"{last['split_s']['series']:.1f} | {last['split_s']['solve']:.1f} | "
                f"{min(r['load'] for r in v):.1f}-{max(r['load'] for r in v):.1f} |"
            )
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out + ".md").write_text(
            "# The ANM against modified Newton on fine clouds\n\nMade by "
            "`benchmarks/anm_vs_mnewton_fine.py`: whole commands, compile cache warm, "
            f"{args.repeats} alternated repeats, 2 CPUs.\n\n" + text
        )
        Path(args.out + ".json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
