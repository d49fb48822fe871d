"""Accuracy against work of each time scheme x step solver on the IVP test set, IDA beside them.

Robertson, van der Pol (mu = 1000), HIRES and OREGO (``tests/stiff_problems.py``) in
semi-discrete form ``F(u, u_dot) = u_dot - f(u)`` (``jaxanm.SemiDiscrete``) are integrated by
:func:`jaxanm.integrate` with each time scheme (implicit Euler, BDF2, ESDIRK3, ESDIRK4) and
each step solver (the ANM, Newton, modified Newton) under ``StepController(rtol, atol = rtol *
1e-4)`` (atol relative to each problem's ``scale``), for a ladder of ``rtol``; and by SUNDIALS
IDA (``jaxanm.ida.integrate_ida``, variable-order BDF 1-5) on the same ``F`` at the same
tolerances.  Every solver solves its stages to ``1e-3 rtol`` of the state (floored at 1e-10),
below the time error asked for.

The ANM is the variant that holds under the step controller
(``ANM(adaptive=True, homotopy="newton", criterion="state")``, benchmarks/results/stiff_controller.md);
its defaults under a controller are another study's.

The error is the largest relative error at t1 against the reference
(``stiff_problems.error``: the Test Set for IVP Solvers' values for HIRES and OREGO, Radau at
rtol 1e-12 for the others).  Work: steps, factorisations (IDA: its Jacobian evaluations, each
one factorisation), triangular solves (IDA: its Newton iterations) and the wall time of the
call, warm (each (problem, scheme, solver) and IDA run once first at the loosest tolerance,
which compiles).  One run per point; ``os.getloadavg()`` is recorded before and after each.
Implicit Euler stops at ``--euler-tightest`` (its steps grow as rtol^(-1/2): at 1e-5 van der
Pol takes ~20 000), BDF2 at ``--bdf2-tightest``.

    python benchmarks/scheme_front.py --out benchmarks/results/scheme_front

Writes ``OUT.json`` (every run), ``OUT.md`` (the tables: every point, and per problem the
cheapest configuration reaching each error level) and ``OUT.png`` (error against wall time,
one panel per problem).  ``--render`` redraws the table and plot from the JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import sys
import time

import jaxanm
from jaxanm.ida import IDAFailure, integrate_ida

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import stiff_problems  # noqa: E402

SCHEMES = {"euler": jaxanm.ImplicitEuler(), "bdf2": jaxanm.BDF2(), "esdirk3": jaxanm.ESDIRK(order=3),
           "esdirk4": jaxanm.ESDIRK(order=4)}
RTOLS = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7]
ATOL_FACTOR = 1e-4
LEVELS = [1e-2, 1e-3, 1e-4, 1e-5]
"""Error levels of the 'cheapest configuration' table."""


def solvers(rtol: float) -> dict:
    """The step solvers, each solving its stages to 1e-3 rtol of the state (floored at 1e-10)."""
    tol = max(1e-3 * rtol, 1e-10)
    return {"anm": jaxanm.ANM(adaptive=True, homotopy="newton", criterion="state", tol=tol),
            "newton": jaxanm.Newton(tol=tol), "mnewton": jaxanm.ModifiedNewton(tol=tol)}


def run_scheme(p, scheme, solver, rtol: float) -> dict:
    """One controlled run of problem ``p``: counts, wall, error at t1 (or the failure)."""
    load = os.getloadavg()[0]
    wall = time.perf_counter()
    try:
        sol = jaxanm.integrate(p.semi_discrete, p.x0, None, t0=0.0, t1=p.t1, dt=p.dt0, solver=solver, scheme=scheme,
                               controller=jaxanm.StepController(rtol=rtol, atol=rtol * ATOL_FACTOR), scale=p.scale,
                               jacobian="dense", saveat=jaxanm.SaveAt(ts=[]))
    except jaxanm.StepFailure as exc:
        return {"failed": str(exc)[:300], "wall_s": time.perf_counter() - wall, "load": [load, os.getloadavg()[0]]}
    wall = time.perf_counter() - wall
    s = sol.stats
    return {"steps": s.time_steps, "rejected": s.rejected_steps, "halvings": s.dt_halvings,
            "factorizations": s.factorizations, "solves": s.solves, "series_orders": s.series_orders,
            "newton_iterations": s.newton_iterations, "error": stiff_problems.error(p, sol.xs[-1]), "wall_s": wall,
            "load": [load, os.getloadavg()[0]]}


def run_ida(p, rtol: float) -> dict:
    """IDA on the same F and tolerances."""
    load = os.getloadavg()[0]
    wall = time.perf_counter()
    try:
        sol = integrate_ida(p.semi_discrete, p.x0, None, t0=0.0, t_out=[p.t1], rtol=rtol, atol=rtol * ATOL_FACTOR,
                            scale=p.scale, max_steps=1_000_000)
    except IDAFailure as exc:
        return {"failed": str(exc)[:300], "wall_s": time.perf_counter() - wall, "load": [load, os.getloadavg()[0]]}
    wall = time.perf_counter() - wall
    s = sol.stats
    return {"steps": s.steps, "factorizations": s.jacobian_evaluations, "solves": s.linear_solves,
            "error": stiff_problems.error(p, sol.xs[-1]), "wall_s": wall, "load": [load, os.getloadavg()[0]]}


def tightest(scheme: str, args) -> float:
    """The tightest rtol a scheme is run at."""
    return {"euler": args.euler_tightest, "bdf2": args.bdf2_tightest}.get(scheme, min(RTOLS))


def measure(name: str, args) -> list[dict]:
    """Every (scheme, solver) and IDA on problem ``name``, each rtol of its ladder."""
    p = stiff_problems.problem(name)
    rows = []
    for sname, scheme in SCHEMES.items():
        for kind in solvers(RTOLS[0]):
            run_scheme(p, scheme, solvers(RTOLS[0])[kind], RTOLS[0])  # compile
            for rtol in [r for r in RTOLS if r >= tightest(sname, args)]:
                row = {"problem": name, "scheme": sname, "solver": kind, "rtol": rtol,
                       **run_scheme(p, scheme, solvers(rtol)[kind], rtol)}
                rows.append(row)
                print(json.dumps(row), flush=True)
    run_ida(p, RTOLS[0])
    for rtol in RTOLS:
        row = {"problem": name, "scheme": "ida", "solver": "ida (BDF 1-5)", "rtol": rtol, **run_ida(p, rtol)}
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def _label(r) -> str:
    return "IDA" if r["scheme"] == "ida" else f"{r['scheme']} + {r['solver']}"


def table(rows: list[dict]) -> str:
    """Every run, and the cheapest configuration per error level and problem."""
    lines = ["| problem | scheme + solver | rtol | steps | rejected | factorisations | solves | wall (s) | "
             "error at t1 |", "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        if "failed" in r:
            lines.append(f"| {r['problem']} | {_label(r)} | {r['rtol']:g} | failed: {r['failed'][:80]} | | | | "
                         f"{r['wall_s']:.2f} | |")
            continue
        lines.append(f"| {r['problem']} | {_label(r)} | {r['rtol']:g} | {r['steps']} | {r.get('rejected', '')} | "
                     f"{r['factorizations']} | {r['solves']} | {r['wall_s']:.2f} | {r['error']:.2e} |")
    lines += ["", "Cheapest configuration (wall) reaching each error level, and its wall against the cheapest "
              "modified-Newton, ANM and IDA configurations reaching it:", "",
              "| problem | error level | cheapest | wall (s) | best ANM | best modified Newton | best IDA |",
              "| --- | ---: | --- | ---: | --- | --- | --- |"]
    for name in dict.fromkeys(r["problem"] for r in rows):
        ok = [r for r in rows if r["problem"] == name and "failed" not in r]
        for level in LEVELS:
            reach = sorted((r for r in ok if r["error"] <= level), key=lambda r: r["wall_s"])
            if not reach:
                lines.append(f"| {name} | {level:g} | none | | | | |")
                continue

            def best(pred):
                c = [r for r in reach if pred(r)]
                return f"{_label(c[0])} at {c[0]['rtol']:g}: {c[0]['wall_s']:.2f} s" if c else "none"

            lines.append(f"| {name} | {level:g} | {_label(reach[0])} at rtol {reach[0]['rtol']:g} | "
                         f"{reach[0]['wall_s']:.2f} | {best(lambda r: r['solver'] == 'anm')} | "
                         f"{best(lambda r: r['solver'] == 'mnewton')} | {best(lambda r: r['scheme'] == 'ida')} |")
    return "\n".join(lines)


def plot(rows: list[dict], path: pathlib.Path) -> None:
    """Error against wall time, one panel per problem, one line per scheme + solver."""
    from matplotlib.figure import Figure

    names = list(dict.fromkeys(r["problem"] for r in rows))
    fig = Figure(figsize=(12, 9))
    styles = {"anm": "-", "newton": ":", "mnewton": "--", "ida (BDF 1-5)": "-"}
    colours = {"euler": "C0", "bdf2": "C1", "esdirk3": "C2", "esdirk4": "C3", "ida": "k"}
    for i, name in enumerate(names):
        ax = fig.add_subplot(2, 2, i + 1)
        for label in dict.fromkeys(_label(r) for r in rows):
            pts = sorted(((r["wall_s"], r["error"]) for r in rows
                          if r["problem"] == name and _label(r) == label and "failed" not in r))
            if not pts:
                continue
            r0 = next(r for r in rows if _label(r) == label)
            ax.loglog(*zip(*pts), styles[r0["solver"]], marker="o", ms=3, color=colours[r0["scheme"]], label=label)
        ax.set_title(name)
        ax.set_xlabel("wall (s)")
        ax.set_ylabel("max relative error at t1")
        ax.grid(True, which="both", alpha=0.3)
    fig.axes[0].legend(fontsize=6, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def write(rows: list[dict], meta: dict, out: pathlib.Path) -> None:
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    md = (f"# Accuracy against work: time schemes x step solvers, IDA beside them (`benchmarks/scheme_front.py`)\n\n"
          f"`{meta['command']}`; StepController(rtol, atol = {ATOL_FACTOR:g} rtol); {meta['cpus']} CPUs, load "
          f"{meta['loadavg_start'][0]:.1f} at the start, {meta['loadavg_end'][0]:.1f} at the end (per run in the "
          "JSON). One warm run per point; counts are deterministic, walls are not.\n\n"
          f"![error against wall time]({out.name}.png)\n\n" + table(rows) + "\n")
    out.with_suffix(".md").write_text(md)
    plot(rows, out.with_suffix(".png"))
    print(md)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", default="robertson,vanderpol,hires,orego")
    ap.add_argument("--rtols", default=",".join(f"{r:g}" for r in RTOLS), help="the rtol ladder")
    ap.add_argument("--euler-tightest", type=float, default=1e-5)
    ap.add_argument("--bdf2-tightest", type=float, default=1e-6)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "scheme_front"))
    ap.add_argument("--render", action="store_true", help="redraw the table and the plot from OUT.json")
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    RTOLS[:] = sorted((float(r) for r in args.rtols.split(",")), reverse=True)
    if args.render:
        stored = json.loads(out.with_suffix(".json").read_text())
        return write(stored["rows"], stored["meta"], out)
    meta = {"command": " ".join(["python", *sys.argv]), "machine": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(), "loadavg_start": os.getloadavg(), "rtols": RTOLS, "atol_factor": ATOL_FACTOR,
            "solvers": {k: repr(v) for k, v in solvers(RTOLS[0]).items()}}
    rows = []
    for name in args.problems.split(","):
        rows.extend(measure(name, args))
    meta["loadavg_end"] = os.getloadavg()
    write(rows, meta, out)


if __name__ == "__main__":
    main()
