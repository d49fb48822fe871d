"""The main job against today's baseline: whole `jaxanm run` commands, back to back.

Each entry is a `jaxanm run` command line, run in its own process with the compile cache warm
(every command is run once untimed first with ``--warm``), alternately, ``--repeats`` times;
the table gives per entry the median command wall (process start to exit: discretisation,
start, time loop, outputs), the run wall that ``summary.json`` reports (the time loop), the
peak RSS of the process, time steps, factorisations, and the accuracy the run reports: the
rise error against the axisymmetric continuum at the checked times and the registration
points' oscillation about a smooth trend.  The accuracy is computed here, by this checkout's
code, from each run's written files (`fields.npz`, `probes.csv`), so that runs of an older
code that did not report it are measured the same way.  ``--baseline DIR`` runs the entries
marked ``baseline`` from another checkout (``PYTHONPATH=DIR``), e.g. the commit before a
change, so that both run on the same machine in the same minutes.  ``--render`` rebuilds the
table from a finished benchmark's JSON and its runs' files, without running anything.

    python benchmarks/main_job.py --baseline /path/to/checkout-of-the-old-main \\
        --out benchmarks/results/main_job

The main job against the main job as it was (the entry ``fsw as it was (baseline)``, the
baseline checkout's ``fsw``) and the ANM against modified Newton on it, keeping the
fsw_paper row of the committed results::

    python benchmarks/main_job.py --baseline /path/to/checkout-of-the-old-main \\
        --only "fsw as it was (baseline)" "fsw (main job, ANM)" "fsw, modified Newton" \\
        --keep benchmarks/results/main_job.json --out benchmarks/results/main_job
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

BEFORE = "fsw as it was (baseline)"
"""The entry the main job is held to: the same command run by the baseline checkout."""

ENTRIES = [
    # (label, use the baseline checkout, arguments of `jaxanm run` after the scene)
    ("fsw_paper (before)", True, ["fsw_paper"]),
    (BEFORE, True, ["fsw"]),
    ("fsw (main job, ANM)", False, ["fsw"]),
    ("fsw, modified Newton", False, ["fsw", "--solver", "mnewton"]),
]


def run(label: str, baseline: str | None, args: list[str], out: Path) -> dict:
    """One command in a fresh process; its wall, peak RSS and what its summary says."""
    env = dict(os.environ)
    out = out.resolve()
    if baseline:  # run from the baseline checkout: `python -m` puts the working directory first on sys.path
        env["PYTHONPATH"] = baseline
    cmd = [sys.executable, "-m", "jaxanm", "run", *args, "--out", str(out), "--no-progress"]
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            cwd=baseline or None)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    err = proc.stderr.read()
    if status != 0:
        raise RuntimeError(f"{label}: {' '.join(cmd)} failed:\n{err[-2000:]}")
    stats = json.loads((out / "summary.json").read_text())["stats"]
    return {"label": label, "dir": str(out), "command_s": wall, "run_s": stats["wall_time_s"],
            "peak_rss_gb": usage.ru_maxrss / 2**20, "steps": stats["time_steps"],
            "factorizations": stats["factorizations"], "load": os.getloadavg(), **accuracy(out)}


CHECKED = (0.1, 0.3, 0.7)
"""Saved times at which the table gives the rise error (the main job's targets)."""


def accuracy(out: Path) -> dict:
    """A run's accuracy from its files, by this checkout's code: the rise's relative L2 error
    against the axisymmetric continuum at :data:`CHECKED`, the registration points' largest
    oscillation (speed and T, per window) and the run's own time-error estimate if it made one."""
    from jaxanm.fsw.continuum_error import rise_errors
    from jaxanm.fsw.io.output import probe_oscillation
    from jaxanm.fsw.scene import load_scene

    summary = json.loads((out / "summary.json").read_text())
    fields = np.load(out / "fields.npz")
    result = SimpleNamespace(t=fields["t"], points=fields["points"], T=fields["T"],
                             scene=load_scene(summary["scene"]["name"]))
    rise = [e for e in rise_errors(result) if any(abs(e["t"] - t) < 1e-9 for t in CHECKED)]
    table = np.genfromtxt(out / "probes.csv", delimiter=",", names=True)
    names = [c[:-2] for c in table.dtype.names if c.endswith("_T")]
    result.probes = {"t": table["t"], **{n: {k: table[f"{n}_{k}"] for k in "uvT"} for n in names}}
    return {"rise_error": [{"t": e["t"], "rel_l2": e["rel_l2"]} for e in rise],
            "oscillation": probe_oscillation(result), "time_error": summary.get("time_error")}


def markdown(rows: dict, meta: dict) -> str:
    """The table: medians over the repeats, ratios to the first entry."""
    first = statistics.median(r["command_s"] for r in rows[next(iter(rows))])
    before = statistics.median(r["command_s"] for r in rows[BEFORE]) if BEFORE in rows else math.nan
    lines = [f"Back to back on {meta['cpus']} CPUs, {meta['repeats']} alternated repeats each, compile cache warm; "
             f"load averages over the runs {meta['load_min']:.1f}-{meta['load_max']:.1f}.", "",
             "| command | command wall (s, median) | / first | / fsw as it was | run wall (s) | peak RSS (GB) | "
             "steps | factorisations | rise error against the continuum | "
             "oscillation of speed / T (largest over the probes) |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |"]
    for label, runs in rows.items():
        cmd = statistics.median(r["command_s"] for r in runs)
        last = runs[-1]
        rise_text = ", ".join(f"{e['rel_l2'] * 100:.2f} % at {e['t']:g} s" for e in last["rise_error"]) or "-"
        osc = last["oscillation"] or {"windows": [], "max_speed": [], "max_T": []}  # None: too few samples
        osc_text = "; ".join(f"{w[0]:g}-{w[1]:g} s: {100 * sp:.2g} % / {100 * T:.2g} %" for w, sp, T
                             in zip(osc["windows"], osc["max_speed"], osc["max_T"])) or "-"
        lines.append(f"| {label} | {cmd:.1f} | {cmd / first:.2f} | {cmd / before:.2f} | "
                     f"{statistics.median(r['run_s'] for r in runs):.1f} | "
                     f"{max(r['peak_rss_gb'] for r in runs):.2f} | {last['steps']} | {last['factorizations']} | "
                     f"{rise_text} | {osc_text} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", default=None, help="checkout whose jaxanm runs the entries marked baseline")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--only", nargs="*", default=None, help="labels to run (default: all)")
    ap.add_argument("--work", default="results/main_job", help="where the runs write their outputs")
    ap.add_argument("--out", default=None, help="write OUT.md and OUT.json")
    ap.add_argument("--title", default="The main job against fsw_paper", help="the title of OUT.md")
    ap.add_argument("--no-warm", action="store_true", help="skip the untimed first run of each entry")
    ap.add_argument("--keep", default=None, metavar="JSON",
                    help="take the rows of the entries left out by --only from this earlier benchmark's JSON")
    ap.add_argument("--render", default=None, metavar="JSON",
                    help="rebuild the table from this finished benchmark's JSON and the runs under --work")
    args = ap.parse_args(argv)
    if args.render:
        return write(render(Path(args.render), Path(args.work)), args.out, args.title)
    entries = [e for e in ENTRIES if args.only is None or e[0] in args.only]
    work = Path(args.work)

    def go(label, base, extra, k):
        if base and args.baseline is None:
            raise SystemExit(f"{label} needs --baseline DIR (a checkout of the code to compare with)")
        return run(label, args.baseline if base else None, extra, work / f"{k}")

    if not args.no_warm:
        for k, (label, base, extra) in enumerate(entries):
            go(label, base, extra, f"warm-{k}")
    rows = {label: [] for label, _, _ in entries}
    for rep in range(args.repeats):
        for k, (label, base, extra) in enumerate(entries):
            row = go(label, base, extra, f"{rep}-{k}")
            rows[label].append(row)
            print(f"{label}: {row['command_s']:.1f} s command, {row['run_s']:.1f} s run, "
                  f"{row['factorizations']} factorisations, load {row['load'][0]:.1f}", flush=True)
    loads = [r["load"][0] for runs in rows.values() for r in runs]
    meta = {"cpus": os.cpu_count(), "repeats": args.repeats, "load_min": min(loads), "load_max": max(loads)}
    if args.keep:  # rows of an earlier benchmark, in ENTRIES' order
        kept = json.loads(Path(args.keep).read_text())
        rows = {label: rows.get(label) or kept["rows"][label] for label, _, _ in ENTRIES
                if label in rows or label in kept["rows"]}
        meta["kept"] = {"from": args.keep, "entries": [label for label in rows if label not in
                                                      [e[0] for e in entries]], "meta": kept["meta"]}
    write({"meta": meta, "rows": rows}, args.out, args.title)


def render(path: Path, work: Path) -> dict:
    """A finished benchmark's rows (``OUT.json``) with their accuracy measured again from the
    runs' files (``work/REP-K``, K the entry's place in :data:`ENTRIES`)."""
    data = json.loads(path.read_text())
    places = {label: k for k, (label, _, _) in enumerate(ENTRIES)}
    for label, runs in data["rows"].items():
        for rep, row in enumerate(runs):
            row["dir"] = row.get("dir") or str(work / f"{rep}-{places[label]}")
            row.update(accuracy(Path(row["dir"])))
    return data


def write(data: dict, out: str | None, title: str = "The main job against fsw_paper") -> None:
    """Print the table; with ``out``, write it to OUT.md and the rows to OUT.json."""
    text = markdown(data["rows"], data["meta"])
    kept = data["meta"].get("kept")
    if kept:
        text += (f"\nThe rows of {', '.join(kept['entries'])} are those of an earlier run of this benchmark on the "
                 f"same machine (load {kept['meta']['load_min']:.1f}-{kept['meta']['load_max']:.1f}); the others were "
                 "run again after a change that the kept entries do not run.\n")
    print(text)
    if out:
        Path(out + ".md").write_text(f"# {title}\n\n"
                                     "Made by `benchmarks/main_job.py`.\n\n" + text)
        Path(out + ".json").write_text(json.dumps(data, indent=1))


if __name__ == "__main__":
    main()
