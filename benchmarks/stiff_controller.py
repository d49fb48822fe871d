"""The ANM and modified Newton under the step controller, on classical stiff problems.

Robertson, van der Pol (mu = 1000), HIRES and OREGO (``tests/stiff_problems.py``) are solved
as implicit-Euler step residuals by :func:`jaxanm.integrate` with
``StepController(rtol=1e-4, atol=1e-8)``, each problem's ``scale``, a dense Jacobian, and
several solvers on the same residual, in one of two sets (``--set``):

``controller`` (the controller's change, ``benchmarks/results/stiff_controller.md``):

- ``anm``: ``ANM.paper(adaptive=True)``, the order-adaptive ANM (p <= 7, tol 1e-6, the paper's
  convex homotopy and eq. 26 relative to the increment);
- ``anm_state``: ``ANM.paper(adaptive=True, criterion="state")``, the tolerance relative to the
  state (the FSW scenes' setting);
- ``anm_newton_state``: ``ANM.paper(adaptive=True, homotopy="newton", criterion="state")``,
  the ANM whose series gains one power per order from a stale K* and whose tolerance is
  relative to the state, as modified Newton's;
- ``mnewton``: ``ModifiedNewton()`` (tol 1e-6, max_rate 0.5);

each under two controllers: ``before``, the controller as it was (``hold=1``,
``refactor_ratio=inf``: a new step size at every step, K* kept whatever its step size), and
``after``, the defaults of :class:`jaxanm.StepController` (sizes held while the proposal
is within ``hold`` of the step, K* dropped before a step whose size is more than
``refactor_ratio`` away from the one it was made with).

``defaults`` (the ANM's defaults, ``benchmarks/results/anm_defaults.md``), under the
controller's defaults, against ``mnewton_8``, ``ModifiedNewton(tol=1e-8)``:

- ``anm_defaults``: ``ANM()``;
- ``anm_7_1e-8``: ``ANM(order=7, tol=1e-8)``, as a new user would try it;
- ``paper_7_1e-8``: ``ANM.paper(order=7, tol=1e-8)``, the paper's solver, the defaults before.

``causes`` (why the paper's ANM factorises more, ``benchmarks/results/anm_defaults_causes.md``):
from ``ANM.paper(order=7, tol=1e-8)`` to ``ANM(order=7, tol=1e-8)`` one option at a time
(``criterion="state"``, ``homotopy="newton"``, ``adaptive=True``, ``max_rate=0.5``), and the
paper's with ``max_rate=0.5`` alone, against ``mnewton_8`` (``--repeats 1``: the counts).

Per problem, every solver runs once first at a loose tolerance (compilation), then the
configurations run ``--repeats`` times, alternated (all of one repeat before the next), and
the medians of wall and process (CPU) time are reported with ``os.getloadavg()`` before and
after; counts are deterministic.  The error is the largest relative error at t1 against the
reference (``stiff_problems.error``: the Test Set for IVP Solvers' values for HIRES and
OREGO, Radau at rtol 1e-12 for the others).

    python benchmarks/stiff_controller.py --out benchmarks/results/stiff_controller
    python benchmarks/stiff_controller.py --set defaults --out benchmarks/results/anm_defaults
    python benchmarks/stiff_controller.py --set causes --repeats 1 --out benchmarks/results/anm_defaults_causes

Writes ``OUT.json`` (every run) and ``OUT.md`` (the tables).  With ``--grid``, instead, one
run of every solver per (``hold``, ``refactor_ratio``) of :data:`GRID`, the measurements the
defaults were chosen by (``OUT_grid.json``, ``OUT_grid.md``; counts, CPU seconds of one run).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import pathlib
import platform
import statistics
import sys
import time

import numpy as np

import jaxanm

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import stiff_problems  # noqa: E402

RTOL, ATOL = 1e-4, 1e-8
SETS = {
    "controller": {
        "anm": jaxanm.ANM.paper(adaptive=True),
        "anm_state": jaxanm.ANM.paper(adaptive=True, criterion="state"),
        "anm_newton_state": jaxanm.ANM.paper(adaptive=True, homotopy="newton", criterion="state"),
        "mnewton": jaxanm.ModifiedNewton(),
    },
    "defaults": {
        "anm_defaults": jaxanm.ANM(),
        "anm_7_1e-8": jaxanm.ANM(order=7, tol=1e-8),
        "paper_7_1e-8": jaxanm.ANM.paper(order=7, tol=1e-8),
        "mnewton_8": jaxanm.ModifiedNewton(tol=1e-8),
    },
    "causes": {  # from the paper's ANM to the defaults, one option at a time (order 7, tol 1e-8)
        "paper": jaxanm.ANM.paper(order=7, tol=1e-8),
        "+state": jaxanm.ANM.paper(order=7, tol=1e-8, criterion="state"),
        "+newton": jaxanm.ANM.paper(order=7, tol=1e-8, criterion="state", homotopy="newton"),
        "+adaptive": jaxanm.ANM.paper(order=7, tol=1e-8, criterion="state", homotopy="newton", adaptive=True),
        "+max_rate": jaxanm.ANM(order=7, tol=1e-8),
        "paper+max_rate": jaxanm.ANM.paper(order=7, tol=1e-8, max_rate=0.5),
        "mnewton_8": jaxanm.ModifiedNewton(tol=1e-8),
    },
}
"""The solvers of each ``--set``; the last of each is the reference of the ratios."""
CONTROLLERS = {
    "before": jaxanm.StepController(rtol=RTOL, atol=ATOL, hold=1.0, refactor_ratio=math.inf),
    "after": jaxanm.StepController(rtol=RTOL, atol=ATOL),
}
SET_CONTROLLERS = {"controller": ("before", "after"), "defaults": ("after",), "causes": ("after",)}
"""The controllers each ``--set`` runs under."""
GRID = [(1.0, math.inf), (1.0, 1.5), (1.5, math.inf), (1.25, 1.25), (1.5, 1.25), (1.5, 1.5), (1.5, 2.0),
        (2.0, 2.0)]
"""(hold, refactor_ratio) pairs of ``--grid``: the controller as it was, each change alone, both."""
COUNTS = ("time_steps", "rejected_steps", "dt_halvings", "factorizations", "series_orders",
          "newton_iterations", "solves", "residual_evaluations", "substeps")


def run_once(p, solver, controller) -> dict:
    """One run of problem ``p``: its counts, wall and CPU seconds, error at t1."""
    wall, cpu = time.perf_counter(), time.process_time()
    sol = jaxanm.integrate(p.residual, p.x0, None, t0=0.0, t1=p.t1, dt=p.dt0, solver=solver,
                           controller=controller, scale=p.scale, jacobian="dense",
                           saveat=jaxanm.SaveAt(ts=[]))
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    row = {k: getattr(sol.stats, k) for k in COUNTS}
    row.update(wall_s=wall, cpu_s=cpu, error=stiff_problems.error(p, sol.xs[-1]),
               wall_split={k: round(v, 4) for k, v in sol.stats.wall_time.items()})
    return row


def measure(name: str, repeats: int, solvers: dict, controllers: dict) -> list[dict]:
    """Every (controller, solver) on problem ``name``, alternated ``repeats`` times."""
    p = stiff_problems.problem(name)
    loose = jaxanm.StepController(rtol=1e-2, atol=1e-4)
    for solver in solvers.values():  # compile (series, residual, tangent) once per solver
        run_once(p, solver, loose)
    runs = {}
    for r in range(repeats):
        for cname, controller in controllers.items():
            for sname, solver in solvers.items():
                load = os.getloadavg()[0]
                row = run_once(p, solver, controller)
                row["load"] = [load, os.getloadavg()[0]]
                runs.setdefault((cname, sname), []).append(row)
                print(f"{name} {cname} {sname} #{r}: {row['factorizations']} factorisations, "
                      f"{row['time_steps']} steps, wall {row['wall_s']:.2f} s, cpu {row['cpu_s']:.2f} s, "
                      f"error {row['error']:.3g}, load {row['load'][0]:.1f}", flush=True)
    rows = []
    for (cname, sname), rs in runs.items():
        counts = {k: rs[0][k] for k in COUNTS}
        assert all({k: x[k] for k in COUNTS} == counts for x in rs), "counts differ between repeats"
        rows.append({"problem": name, "controller": cname, "solver": sname, **counts, "error": rs[0]["error"],
                     "wall_s": statistics.median(x["wall_s"] for x in rs),
                     "cpu_s": statistics.median(x["cpu_s"] for x in rs),
                     "walls": [x["wall_s"] for x in rs], "cpus": [x["cpu_s"] for x in rs],
                     "loads": [x["load"] for x in rs], "wall_split": rs[-1]["wall_split"]})
    return rows


def table(rows: list[dict], reference: str) -> str:
    """The markdown table: one line per (problem, controller, solver), ratios to ``reference``."""
    ref = {(r["problem"], r["controller"]): r for r in rows if r["solver"] == reference}
    lines = [f"| problem | controller | solver | steps | rejected | halvings | factorisations (x {reference}) | "
             f"series orders / Newton its | solves | wall s (x {reference}) | CPU s (x {reference}) | error at t1 |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        m = ref[(r["problem"], r["controller"])]
        work = r["series_orders"] if r["series_orders"] else r["newton_iterations"]
        lines.append(f"| {r['problem']} | {r['controller']} | {r['solver']} | {r['time_steps']} | "
                     f"{r['rejected_steps']} | {r['dt_halvings']} | {r['factorizations']} "
                     f"({r['factorizations'] / m['factorizations']:.2f}) | {work} | {r['solves']} | "
                     f"{r['wall_s']:.2f} ({r['wall_s'] / m['wall_s']:.2f}) | "
                     f"{r['cpu_s']:.2f} ({r['cpu_s'] / m['cpu_s']:.2f}) | {r['error']:.3g} |")
    return "\n".join(lines)


TARGETS = {"factorizations": 1.5, "wall_s": 1.2}
"""The ANM against modified Newton under the controller: at most these ratios of factorisations
and of wall time (the ``defaults`` set's solvers against its reference)."""
LABELS = {"factorizations": "factorisations", "wall_s": "wall"}


def verdict(rows: list[dict], reference: str, meta: dict, source: str) -> str:
    """Per solver, the largest ratios to ``reference`` over the problems against
    :data:`TARGETS` (CPU time beside the wall: under load the wall also holds waiting), and
    the error at t1 against the reference's (the controller's time error, which both share)."""
    ref = {(r["problem"], r["controller"]): r for r in rows if r["solver"] == reference}
    lines = [f"Against `{reference}` ({source}; load {meta['loadavg_start'][0]:.1f} to "
             f"{meta['loadavg_end'][0]:.1f}); targets: factorisations <= {TARGETS['factorizations']}x, "
             f"wall <= {TARGETS['wall_s']}x, on every problem.\n",
             "| solver | factorisations, largest ratio | wall, largest ratio | CPU, largest ratio | "
             "error at t1 / reference's, range | targets |", "| --- | --- | --- | --- | --- | --- |"]
    for solver in dict.fromkeys(r["solver"] for r in rows if r["solver"] != reference):
        mine = [(r, ref[(r["problem"], r["controller"])]) for r in rows if r["solver"] == solver]
        worst = {k: max(((r[k] / m[k], r["problem"]) for r, m in mine)) for k in ("factorizations", "wall_s", "cpu_s")}
        errors = [r["error"] / m["error"] for r, m in mine]
        missed = [f"{LABELS[k]} on {', '.join(r['problem'] for r, m in mine if r[k] / m[k] > limit)}"
                  for k, limit in TARGETS.items() if worst[k][0] > limit]
        cells = [f"{worst[k][0]:.2f} ({worst[k][1]})" for k in ("factorizations", "wall_s", "cpu_s")]
        lines.append(f"| {solver} | " + " | ".join(cells) + f" | {min(errors):.2f}-{max(errors):.2f} | "
                     + ("held" if not missed else "missed: " + "; ".join(missed)) + " |")
    return "\n".join(lines)


def _json_number(v: float):
    """``v``, or the string "inf" (JSON has no infinity)."""
    return v if math.isfinite(v) else "inf"


def grid(names, out: pathlib.Path, meta: dict, solvers: dict) -> None:
    """One run of every solver per :data:`GRID` pair on each problem; ``OUT_grid.{json,md}``."""
    rows = []
    for name in names:
        p = stiff_problems.problem(name)
        for solver in solvers.values():
            run_once(p, solver, jaxanm.StepController(rtol=1e-2, atol=1e-4))
        for hold, ratio in GRID:
            controller = jaxanm.StepController(rtol=RTOL, atol=ATOL, hold=hold, refactor_ratio=ratio)
            for sname, solver in solvers.items():
                row = {"problem": name, "hold": hold, "refactor_ratio": _json_number(ratio), "solver": sname,
                       **run_once(p, solver, controller)}
                rows.append(row)
                print(f"{name} hold {hold} refactor_ratio {ratio} {sname}: {row['factorizations']} "
                      f"factorisations, {row['time_steps']} steps, {row['rejected_steps']} rejected, "
                      f"error {row['error']:.3g}", flush=True)
    meta["loadavg_end"] = os.getloadavg()
    stem = out.parent / (out.name + "_grid")
    stem.with_suffix(".json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    lines = [f"# Holding the step size: hold x refactor_ratio (`{meta['command']}`)\n",
             f"StepController(rtol={RTOL:g}, atol={ATOL:g}, hold, refactor_ratio); one run each; "
             "factorisations / steps / rejected steps / error at t1; CPU seconds of the run (load "
             f"{meta['loadavg_start'][0]:.1f} to {meta['loadavg_end'][0]:.1f}).\n",
             "| problem | hold | refactor_ratio | " + " | ".join(solvers) + " |",
             "| --- | ---: | ---: | " + " | ".join("---" for _ in solvers) + " |"]
    for name in names:
        for hold, ratio in GRID:
            cells = []
            for sname in solvers:
                r = next(x for x in rows if (x["problem"], x["hold"], x["refactor_ratio"], x["solver"])
                         == (name, hold, _json_number(ratio), sname))
                cells.append(f"{r['factorizations']} / {r['time_steps']} / {r['rejected_steps']} / "
                             f"{r['error']:.3g} / {r['cpu_s']:.1f} s")
            lines.append(f"| {name} | {hold:g} | {ratio:g} | " + " | ".join(cells) + " |")
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", default="robertson,vanderpol,hires,orego")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "stiff_controller"))
    ap.add_argument("--grid", action="store_true", help="the hold x refactor_ratio grid instead")
    ap.add_argument("--set", default="controller", choices=sorted(SETS), help="the solvers (module docstring)")
    args = ap.parse_args()
    solvers = SETS[args.set]
    controllers = {k: CONTROLLERS[k] for k in SET_CONTROLLERS[args.set]}
    meta = {"command": " ".join(sys.argv), "machine": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(), "loadavg_start": os.getloadavg(), "rtol": RTOL, "atol": ATOL,
            "solvers": {k: repr(v) for k, v in solvers.items()},
            "controllers": {k: repr(v) for k, v in controllers.items()}, "repeats": args.repeats}
    out = pathlib.Path(args.out)
    if args.grid:
        return grid(args.problems.split(","), out, meta, solvers)
    rows = []
    for name in args.problems.split(","):
        rows.extend(measure(name, args.repeats, solvers, controllers))
    meta["loadavg_end"] = os.getloadavg()
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    md = (f"# The ANM and modified Newton under the step controller (`benchmarks/stiff_controller.py`)\n\n"
          f"`{meta['command']}`; StepController(rtol={RTOL:g}, atol={ATOL:g}); {meta['cpus']} CPUs, "
          f"load {meta['loadavg_start'][0]:.1f} at the start, {meta['loadavg_end'][0]:.1f} at the end "
          f"(per run in the JSON). Wall and CPU: medians of {args.repeats} alternated runs; "
          "counts are the same in every run.\n\n" + table(rows, list(solvers)[-1]) + "\n")
    if args.set == "defaults":
        md += "\n## The targets\n\n" + verdict(rows, list(solvers)[-1], meta, "this run") + "\n"
    defaults = out.parent / "anm_defaults.json"
    if args.set == "controller" and defaults.exists():  # the ANM's defaults, measured by --set defaults
        run = json.loads(defaults.read_text())
        md += ("\n## The ANM's defaults under this controller\n\n`ANM()` and `ANM(order=7, tol=1e-8)` "
               "against `ModifiedNewton(tol=1e-8)` under the controller's defaults ([anm_defaults.md]"
               "(anm_defaults.md): `" + run["meta"]["command"] + "`).\n\n"
               + verdict(run["rows"], list(SETS["defaults"])[-1], run["meta"], "anm_defaults.json") + "\n")
    out.with_suffix(".md").write_text(md)
    print(md)


if __name__ == "__main__":
    np.set_printoptions(precision=4)
    main()
