"""Each time scheme on the main job: steps, factorisations, series orders per step and wall at
the same time error.

Every entry is a whole ``jaxanm run fsw`` command (the shipped scene, its cloud, controller
and save times) with ``--set time.scheme=S --set time.atol=A`` and a step solver, run in its
own process with the compile cache warm (each scheme and solver run once untimed first, over
2 ms: what a run compiles does not depend on atol).  The time error of
a run is measured, not estimated: the relative L2 difference over the points of its T - T0
from a time-converged reference's (the same command with ESDIRK4 at ``--ref-atol``, modified
Newton, solver tol 1e-9) at 0.1, 0.3 and 0.7 s, the largest of the three.  Beside it: the
run's own estimate (``summary.json``'s ``time_error``), the rise error against the
continuum, the registration points' oscillation, steps, factorisations, series orders per
step (the ANM) or Newton iterations per step, triangular solves, the wall of the command and
of the time loop, and ``os.getloadavg()``.

Per scheme and solver, the table marks the cheapest run whose time error is at most
``--target`` (default 5e-4 of the rise: a twentieth of the 1 % the main job is held to), the
runs "at the same time error".  Entries run alternately, ``--repeats`` times (medians).

    python benchmarks/main_job_schemes.py --out benchmarks/results/main_job_schemes

``--t-end T`` runs every entry and the reference over ``[0, T]`` only (a cheaper look; the time
error is then measured at the checked times up to T, and at T).

``--render`` rebuilds the table from the JSON and the runs under ``--work``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from main_job import run  # noqa: E402

LADDER = {"euler": [1e-5, 3e-6], "bdf2": [1e-4, 3e-5, 1e-5], "esdirk3": [1e-3, 3e-4, 1e-4],
          "esdirk4": [1e-3, 3e-4, 1e-4]}
"""time.atol of each scheme's runs (implicit Euler's steps grow as atol^(-1/2): it stops earlier)."""
SOLVERS = {"anm": [], "mnewton": ["--solver", "mnewton"]}
CHECKED = (0.1, 0.3, 0.7)


def entries(schemes, solvers) -> list[tuple[str, list[str]]]:
    """(label, arguments after ``jaxanm run``) of every scheme x atol x solver."""
    out = []
    for scheme in schemes:
        for atol in LADDER[scheme]:
            for solver in solvers:
                args = ["fsw", "--set", f"time.scheme={scheme}", "--set", f"time.atol={atol:g}", *SOLVERS[solver]]
                out.append((f"{scheme} atol {atol:g} {solver}", args))
    return out


def time_error(out: Path, ref: Path, t_end: float | None = None) -> list[dict]:
    """The relative L2 difference of T - T0 from the reference's at :data:`CHECKED` (those up
    to ``t_end``, and ``t_end``, when given)."""
    f, g = np.load(out / "fields.npz"), np.load(ref / "fields.npz")
    T0 = float(json.loads((ref / "summary.json").read_text())["scene"]["thermal"]["T0"])
    checked = CHECKED if t_end is None else sorted({t for t in CHECKED if t <= t_end} | {t_end})
    errs = []
    for t in checked:
        i, j = np.flatnonzero(np.abs(f["t"] - t) < 1e-9), np.flatnonzero(np.abs(g["t"] - t) < 1e-9)
        if i.size and j.size:
            rise = g["T"][j[0]] - T0
            errs.append({"t": t, "rel_l2": float(np.linalg.norm(f["T"][i[0]] - g["T"][j[0]]) / np.linalg.norm(rise))})
    return errs


def stats_of(out: Path) -> dict:
    """Counts per step from the run's summary."""
    s = json.loads((out / "summary.json").read_text())["stats"]
    steps = s["time_steps"]
    return {"series_orders_per_step": s["series_orders"] / steps, "newton_iterations_per_step":
            s["newton_iterations"] / steps, "solves": s["solves"], "wall_split": s["wall_time"]}


def markdown(rows: dict, ref: dict, meta: dict) -> str:
    """The table (medians over repeats), the cheapest run within the target per scheme x solver."""
    best: dict = {}
    for label, runs in rows.items():
        r = runs[-1]
        key = (r["scheme"], r["solver"])
        wall = statistics.median(x["command_s"] for x in runs)
        if r["time_error_max"] <= meta["target"] and (key not in best or wall < best[key][1]):
            best[key] = (label, wall)
    lines = [f"Made by `{meta['command']}`: whole `jaxanm run fsw` commands, {meta['repeats']} alternated "
             f"repeat(s), compile cache warm; load averages over the runs {meta['load_min']:.1f}-"
             f"{meta['load_max']:.1f}; over t = 0-{meta.get('t_end') or 0.7:g} s. Time error: the relative L2 "
             f"difference of T - T0 from the reference ({ref['label']}: {ref['steps']} steps) over the points at "
             "the checked times (0.1, 0.3 and 0.7 s, those reached), the largest; "
             f"**bold**: the cheapest run of each scheme and solver within {100 * meta['target']:.3g} % of the rise.",
             "", "| scheme, time.atol, solver | command wall (s) | time loop (s) | steps | factorisations | "
             "series orders / step | Newton its / step | solves | time error (measured) | its estimate | "
             "rise error at 0.1 / 0.3 / 0.7 s | oscillation speed / T |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |"]
    for label, runs in rows.items():
        r = runs[-1]
        mark = "**" if best.get((r["scheme"], r["solver"]), (None,))[0] == label else ""
        rise = " / ".join(f"{100 * e['rel_l2']:.3f}" for e in r["rise_error"]) + " %"
        osc = r["oscillation"]
        osc_text = "; ".join(f"{100 * sp:.2g} / {100 * T:.2g} %" for sp, T in zip(osc["max_speed"], osc["max_T"])) \
            if osc else "(too few samples)"
        est = r["time_error"]["rel_l2"] if r.get("time_error") else float("nan")
        lines.append(f"| {mark}{label}{mark} | {statistics.median(x['command_s'] for x in runs):.1f} | "
                     f"{statistics.median(x['run_s'] for x in runs):.1f} | {r['steps']} | {r['factorizations']} | "
                     f"{r['series_orders_per_step']:.2f} | {r['newton_iterations_per_step']:.2f} | {r['solves']} | "
                     f"{100 * r['time_error_max']:.3f} % | {100 * est:.3f} % | {rise} | {osc_text} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--schemes", default="euler,bdf2,esdirk3,esdirk4")
    ap.add_argument("--solvers", default="anm,mnewton")
    ap.add_argument("--ref-atol", type=float, default=1e-6)
    ap.add_argument("--target", type=float, default=5e-4)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--work", default="results/main_job_schemes")
    ap.add_argument("--out", default="benchmarks/results/main_job_schemes")
    ap.add_argument("--no-warm", action="store_true")
    ap.add_argument("--t-end", type=float, default=None, help="run every entry over [0, T_END] only")
    ap.add_argument("--render", action="store_true", help="rebuild the table from OUT.json")
    args = ap.parse_args(argv)
    work, out = Path(args.work), Path(args.out)
    if args.render:
        stored = json.loads(out.with_suffix(".json").read_text())
        out.with_suffix(".md").write_text(_page(markdown(stored["rows"], stored["reference"], stored["meta"])))
        return
    span = [] if args.t_end is None else ["--t-end", f"{args.t_end:g}"]
    todo = [(label, [*extra, *span]) for label, extra in entries(args.schemes.split(","), args.solvers.split(","))]
    ref_args = ["fsw", "--set", "time.scheme=esdirk4", "--set", f"time.atol={args.ref_atol:g}", "--solver",
                "mnewton", "--set", "solver.tol=1e-9", *span]
    ref_dir = work / "reference"
    ref = run("reference", None, ref_args, ref_dir)
    ref["label"] = f"ESDIRK4, time.atol {args.ref_atol:g}, modified Newton at tol 1e-9"
    if not args.no_warm:  # what a run compiles depends on its scheme and solver, not on atol
        warmed = set()
        for k, (label, extra) in enumerate(todo):
            key = (label.split(" ")[0], label.split(" ")[-1])
            if key not in warmed:
                warmed.add(key)
                run(label, None, [*extra, "--t-end", "0.002"], work / f"warm-{k}")
    rows: dict = {label: [] for label, _ in todo}
    for rep in range(args.repeats):
        for k, (label, extra) in enumerate(todo):
            d = work / f"{rep}-{k}"
            row = run(label, None, extra, d)
            scheme, _, atol, solver = label.split(" ")
            terr = time_error(d, ref_dir, args.t_end)
            row.update(scheme=scheme, solver=solver, atol=float(atol), time_errors=terr,
                       time_error_max=max(e["rel_l2"] for e in terr), **stats_of(d))
            rows[label].append(row)
            print(f"{label}: {row['command_s']:.1f} s, {row['steps']} steps, {row['factorizations']} factorisations, "
                  f"time error {100 * row['time_error_max']:.3f} %, load {row['load'][0]:.1f}", flush=True)
    loads = [r["load"][0] for runs in rows.values() for r in runs]
    meta = {"command": " ".join(["python", *sys.argv]), "cpus": os.cpu_count(), "repeats": args.repeats,
            "target": args.target, "load_min": min(loads), "load_max": max(loads), "t_end": args.t_end}
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "reference": ref, "rows": rows}, indent=1,
                                                   default=float))
    out.with_suffix(".md").write_text(_page(markdown(rows, ref, meta)))
    print(out.with_suffix(".md").read_text())


def _page(table: str) -> str:
    return ("# Each time scheme on the main job, at the same time error (`benchmarks/main_job_schemes.py`)\n\n"
            + table)


if __name__ == "__main__":
    main()
