"""The ANM against modified Newton on the main job, whole `jaxanm run fsw` commands, back to back.

Per time scheme (the main job's implicit Euler; ESDIRK3 at ``time.atol = 1e-4``), three entries
in alternated order, ``--repeats`` times, each command in its own process with the compile cache
warm (an untimed first run of each): the ANM of a baseline checkout (``--baseline DIR``, e.g.
``git archive <commit> | tar -x -C DIR``: the code before a change), the ANM of this checkout,
and modified Newton of this checkout.  The table gives the median command wall, its ratio to
modified Newton's, and the deterministic counts from ``summary.json`` (steps, factorisations,
series orders, residual evaluations, solves).  Run under ``flock /work/timing.lock`` with
``OPENBLAS_NUM_THREADS=1``; the load average before and after each run is in the JSON.

    OPENBLAS_NUM_THREADS=1 flock /work/timing.lock python benchmarks/anm_main_job.py \\
        --baseline /tmp/anm_base --repeats 3 --out benchmarks/results/anm_main_job
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from main_job import run  # noqa: E402

SCHEMES = {
    "euler": [],
    "esdirk3 atol 1e-4": ["--set", "time.scheme=esdirk3", "--set", "time.atol=1e-4"],
}
ENTRIES = [  # label, from the baseline checkout, solver arguments
    ("ANM before", True, []),
    ("ANM", False, []),
    ("modified Newton", False, ["--solver", "mnewton"]),
]
COUNTS = ("time_steps", "rejected_steps", "factorizations", "series_orders", "newton_iterations",
          "residual_evaluations", "solves", "substeps")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", required=True, help="checkout whose jaxanm runs 'ANM before'")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--t-end", type=float, default=None, help="default: the scene's (0.7 s)")
    ap.add_argument("--schemes", default=",".join(SCHEMES))
    ap.add_argument("--work", default="results/anm_main_job")
    ap.add_argument("--out", default="benchmarks/results/anm_main_job")
    args = ap.parse_args()
    work = Path(args.work)
    extra = [] if args.t_end is None else ["--t-end", str(args.t_end)]
    runs: dict = {}
    for scheme in args.schemes.split(","):
        entries = [(f"{scheme}, {label}", base, ["fsw", *SCHEMES[scheme], *solver, *extra])
                   for label, base, solver in ENTRIES]
        for label, base, cmd in entries:  # warm the compile cache, untimed
            run(label, args.baseline if base else None, cmd, work / "warm")
        for r in range(args.repeats):
            order = entries if r % 2 == 0 else entries[::-1]
            for label, base, cmd in order:
                load = os.getloadavg()[0]
                name = label.replace(", ", "-").replace(" ", "_")
                row = run(label, args.baseline if base else None, cmd, work / f"{name}-{r}")
                stats = json.loads((Path(row["dir"]) / "summary.json").read_text())["stats"]
                row.update({k: stats[k] for k in COUNTS}, load_before=load, load_after=os.getloadavg()[0])
                runs.setdefault(label, []).append(row)
                print(f"{label} #{r}: {row['command_s']:.1f} s (run {row['run_s']:.1f} s), "
                      f"load {load:.1f}-{row['load_after']:.1f}", flush=True)
    write(runs, args, " ".join(sys.argv[1:]))


def write(runs: dict, args, argv: str) -> None:
    loads = [x for rs in runs.values() for r in rs for x in (r["load_before"], r["load_after"])]
    lines = ["# The ANM against modified Newton on the main job (`benchmarks/anm_main_job.py`)", "",
             f"`OPENBLAS_NUM_THREADS=1 flock /work/timing.lock python benchmarks/anm_main_job.py {argv}`: "
             f"whole `jaxanm run fsw` commands, compile cache warm, {args.repeats} alternated repeats, medians; "
             f"1-minute load average {min(loads):.1f}-{max(loads):.1f} over the runs (each run's in the JSON). "
             "Counts are deterministic (the same in every repeat).", "",
             "| scheme, solver | command wall s (median) | x modified Newton | time loop s | steps (refused) | "
             "factorisations | series orders | Newton its | residuals | solves | sub-steps |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for label, rs in runs.items():
        scheme = label.split(", ")[0]
        ref = statistics.median(r["command_s"] for r in runs[f"{scheme}, modified Newton"])
        wall = statistics.median(r["command_s"] for r in rs)
        r0 = rs[0]
        lines.append(f"| {label} | {wall:.1f} | {wall / ref:.2f} | {statistics.median(r['run_s'] for r in rs):.1f} | "
                     f"{r0['time_steps']} ({r0['rejected_steps']}) | {r0['factorizations']} | {r0['series_orders']} | "
                     f"{r0['newton_iterations']} | {r0['residual_evaluations']} | {r0['solves']} | {r0['substeps']} |")
    out = Path(args.out)
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    out.with_suffix(".json").write_text(json.dumps({"argv": argv, "runs": runs}, indent=1, default=float) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
