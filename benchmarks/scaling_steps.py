"""Real Lagrangian steps of ``fsw_paper`` on finer clouds: time per step, factorisations and
peak memory against the number of points N (issue 14, item 3).

Where ``benchmarks/scaling.py`` composes a step from component costs, this script runs the
scene itself: for each point spacing ``dr / d`` (``--divisors``) and each solver
(``--solvers``), a fresh worker process runs ``jaxanm.fsw.run`` over ``--steps`` time steps
of the scene's dt, from rest or (``--start quasi_static``) from the stationary flow at T0,
with the scene overrides of ``--set``, and with a callback that stamps the wall time and the run's
counters after every accepted step.  Reported per run:

- the quasi-static start's factorisations and wall time, on their own;
- the first step (compilation, from `jaxanm run`'s persistent cache when a run of the same
  level came before; from rest, the impulsive start's factorisations) and the median and mean
  wall time of the later steps (the mean includes their factorisations, the median is a step
  without one when fewer than half refactorise);
- factorisations, Jacobians, series orders or Newton iterations, dt halvings, and the wall-time
  split of ``jaxanm.Stats`` (jacobian, factorize, series, solve, other = host work);
- peak resident memory of the worker (its own ``ru_maxrss``, stamped with every step: JAX
  runtime and compiler included);
- a run that exceeds ``--timeout`` is stopped and reported with the steps it completed.

Exponents are least-squares slopes of log(cost) against log(N) over the levels that finished.

    python benchmarks/scaling_steps.py --divisors 1 2 4 8 --solvers anm mnewton --steps 10 --start quasi_static

Writes ``benchmarks/results/scaling_steps.{json,md,png}`` (``--out``).  Runs go one after the other; quote the
load printed beside each (two shared cores).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from scaling import fit_exponent  # noqa: E402

SOLVER_KINDS = {"anm": "anm", "mnewton": "modified_newton", "newton": "newton"}


def _rss_mb() -> float:
    """Peak resident memory of this process so far (MB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def worker(dr: float, solver: str, steps: int, start_kind: str, overrides: dict) -> None:
    """Run fsw_paper at spacing ``dr`` with ``solver`` over ``steps`` steps, started as
    ``start_kind`` (``mechanics.start``), with the scene ``overrides``; print JSON lines (one
    per accepted step, then the summary) so that a stopped run keeps what it did."""
    from jaxanm import compile_cache
    from jaxanm.fsw import load_scene, run

    compile_cache.enable()  # as `jaxanm run` does: a repeated level compiles from the disk cache

    base = load_scene("fsw_paper")
    scene = base.with_overrides({"geometry.dr": dr, "solver.kind": SOLVER_KINDS[solver],
                                 "time.t_end": steps * base.time.dt,
                                 "mechanics.start": start_kind, **overrides})
    from jaxanm.fsw.geometry import build_cloud

    print(json.dumps({"N": int(build_cloud(scene.geometry).size)}), flush=True)
    start = time.perf_counter()

    def stamp(t, stats):
        print(json.dumps({"t": float(t), "wall": time.perf_counter() - start, "rss_mb": _rss_mb(),
                          "factorizations": stats.factorizations, "dt_halvings": stats.dt_halvings}), flush=True)

    result = run(scene, callback=stamp)
    s = result.stats
    start_cost = None if result.start is None else {
        "iterations": result.start.iterations, "factorizations": result.start.stats.factorizations,
        "wall": result.start.stats.wall_time_s}
    print(json.dumps({"done": True, "start": start_cost,
                      "stats": {k: getattr(s, k) for k in ("factorizations", "jacobian_evaluations", "series_orders",
                                                           "newton_iterations", "residual_evaluations", "dt_halvings",
                                                           "time_steps")},
                      "wall_time": dict(s.wall_time), "wall": time.perf_counter() - start, "rss_mb": _rss_mb()}),
          flush=True)


def measure(dr: float, solver: str, steps: int, timeout: float, start_kind: str, overrides: dict) -> dict:
    """One run in a fresh process; its step stamps, summary and peak memory."""
    proc = subprocess.Popen([sys.executable, __file__, "--worker", repr(dr), solver, str(steps), start_kind,
                             json.dumps(overrides)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    load0 = os.getloadavg()[0]
    try:
        out, err = proc.communicate(timeout=timeout)
        timed_out = False
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        timed_out = True
    lines = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    stamps = [x for x in lines if "t" in x]
    summary = next((x for x in lines if x.get("done")), {})
    row = {
        "N": next((x["N"] for x in lines if "N" in x), None),
        "dr": dr,
        "solver": solver,
        "start_kind": start_kind,
        "overrides": overrides,
        "steps_asked": steps,
        "steps_done": len(stamps),
        "timed_out": timed_out,
        "returncode": proc.returncode,
        "load": [load0, os.getloadavg()[0]],
        "stamps": stamps,
        **summary,
    }
    rss = [x["rss_mb"] for x in lines if "rss_mb" in x]
    if rss:
        row["rss_peak_mb"] = max(rss)
    if not summary and not timed_out:
        row["error"] = err[-2000:]
    walls = np.diff([0.0] + [x["wall"] for x in stamps])
    if len(walls):  # the first stamp also counts a quasi-static start, reported on its own
        row["first_step_s"] = float(walls[0]) - ((summary.get("start") or {}).get("wall") or 0.0)
    if len(walls) > 1:
        row["median_step_s"] = float(np.median(walls[1:]))
        row["mean_step_s"] = float(np.mean(walls[1:]))
    return row


def markdown(result: dict) -> str:
    """The table of every run and the fitted exponents."""
    lines = [
        f"<!-- made by benchmarks/scaling_steps.py {' '.join(result['argv'])} -->",
        "",
        "# Real fsw_paper steps against the number of points (issue 14, item 3)",
        "",
        f"{result['date']}, {result['cpus']} cores; each run in a fresh process, one after the "
        f"other; load average (1 min) at start and end of each run beside it.  Start: `rest` "
        f"(impulsive) or `quasi_static` (the stationary flow at T0 solved first by damped "
        f"Newton: its factorisations and wall time, compilation included, are given on their "
        f"own and are not in the first step or the step counters).",
        "",
        "| dr | N | solver | start | start: factorisations, s | steps | first step (s) | median step (s) "
        "| mean step (s) | factorisations | dt halvings | factorise (s) | solve (s) | series (s) | other (s) "
        "| peak RSS (GB) | load |",
        "| --- | ---: | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: "
        "| --- |",
    ]
    for r in result["runs"]:
        wt = r.get("wall_time", {})
        stats = r.get("stats", {})
        done = f"{r['steps_done']}/{r['steps_asked']}" + (" (stopped)" if r["timed_out"] else "")

        def f(v, fmt="{:.3g}"):
            return fmt.format(v) if isinstance(v, (int, float)) else ""

        last = r["stamps"][-1] if r["stamps"] else {}
        st = r.get("start") or {}
        start_cost = f"{st['factorizations']}, {st['wall']:.3g}" if st else ""
        label = r["solver"] + "".join(f", {k}={v}" for k, v in (r.get("overrides") or {}).items())
        lines.append(
            f"| {r['dr']:.4g} | {r.get('N') or ''} | {label} | {r.get('start_kind', 'rest')} "
            f"| {start_cost} | {done} | {f(r.get('first_step_s'))} "
            f"| {f(r.get('median_step_s'))} | {f(r.get('mean_step_s'))} "
            f"| {stats.get('factorizations', last.get('factorizations', ''))} "
            f"| {stats.get('dt_halvings', last.get('dt_halvings', ''))} | {f(wt.get('factorize'))} "
            f"| {f(wt.get('solve'))} | {f(wt.get('series'))} | {f(wt.get('other'))} "
            f"| {f(r.get('rss_peak_mb', 0) / 1024, '{:.2f}')} | {r['load'][0]:.1f} -> {r['load'][1]:.1f} |"
        )
    if result.get("exponents"):
        lines += [
            "",
            "Exponents a of cost ~ N^a (least squares over the levels that finished):",
            "",
            "| solver | median step | mean step | peak RSS |",
            "| --- | ---: | ---: | ---: |",
        ]
        for solver, e in result["exponents"].items():
            lines.append(
                f"| {solver} | "
                + " | ".join(
                    "" if e.get(k) is None else f"{e[k]:.2f}" for k in ("median_step_s", "mean_step_s", "rss_peak_mb")
                )
                + " |"
            )
    return "\n".join(lines) + "\n"


def plot(result: dict, path: pathlib.Path) -> None:
    """Median step time and peak memory against N, one line per solver."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.6))
    for solver in sorted({r["solver"] for r in result["runs"]}):
        rows = [r for r in result["runs"] if r["solver"] == solver and r.get("N") and "median_step_s" in r]
        N = [r["N"] for r in rows]
        axes[0].loglog(N, [r["median_step_s"] for r in rows], "o-", label=f"{solver}: median step")
        axes[0].loglog(N, [r["mean_step_s"] for r in rows], "s--", label=f"{solver}: mean step")
        axes[1].loglog(N, [r["rss_peak_mb"] / 1024 for r in rows], "o-", label=solver)
    axes[0].set_xlabel("points N"), axes[0].set_ylabel("wall per step (s)"), axes[0].legend(fontsize=7)
    axes[1].set_xlabel("points N"), axes[1].set_ylabel("peak RSS (GB)"), axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> None:
    """Command line: every (divisor, solver) run one after the other; JSON, table, plot."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--divisors", type=float, nargs="+", default=[1, 2, 4])
    ap.add_argument("--solvers", nargs="+", default=["anm", "mnewton"], choices=sorted(SOLVER_KINDS))
    ap.add_argument("--steps", type=int, default=20)
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds before a run is stopped")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "scaling_steps"))
    ap.add_argument(
        "--report-only",
        action="store_true",
        help="rebuild the exponents, table and plot from the runs already in OUT.json (e.g. after stopping)",
    )
    ap.add_argument(
        "--start",
        default="rest",
        choices=("rest", "quasi_static"),
        help="mechanics.start of every run: from rest (the scene's default) or from the "
        "stationary flow at T0 solved first (finer clouds need it)",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="scene override of every run (as `jaxanm run --set`), e.g. solver.max_rate=0.9",
    )
    ap.add_argument("--worker", nargs=5, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker is not None:
        worker(float(args.worker[0]), args.worker[1], int(args.worker[2]), args.worker[3], json.loads(args.worker[4]))
        return
    out = pathlib.Path(args.out)
    if args.report_only:
        report(json.loads(out.with_suffix(".json").read_text()), out)
        return
    from jaxanm.fsw import load_scene

    dr = load_scene("fsw_paper").geometry.dr
    bad = [kv for kv in args.set if "=" not in kv]
    if bad:
        ap.error(f"--set takes KEY=VALUE, got {bad[0]!r}")
    overrides = dict(kv.split("=", 1) for kv in args.set)
    result = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "cpus": os.cpu_count(),
        "argv": sys.argv[1:] if argv is None else list(argv),
        "runs": [],
    }
    for d in args.divisors:
        for solver in args.solvers:
            row = measure(dr / d, solver, args.steps, args.timeout, args.start, overrides)
            result["runs"].append(row)
            print({k: v for k, v in row.items() if k != "stamps"}, flush=True)
            out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    report(result, out)


def report(result: dict, out: pathlib.Path) -> None:
    """Fit the exponents over the finished runs; write OUT.json, OUT.md and OUT.png."""
    result["exponents"] = {}
    for solver in sorted({r["solver"] for r in result["runs"]}):
        rows = [r for r in result["runs"] if r["solver"] == solver and r.get("N") and not r["timed_out"]]
        result["exponents"][solver] = {
            k: fit_exponent([r["N"] for r in rows], [r.get(k, np.nan) for r in rows])
            for k in ("median_step_s", "mean_step_s", "rss_peak_mb")
        }
    out.with_suffix(".json").write_text(json.dumps(result, indent=1))
    out.with_suffix(".md").write_text(markdown(result))
    plot(result, out.with_suffix(".png"))
    print(markdown(result))


if __name__ == "__main__":
    main()
