"""What each triangular solve (and residual evaluation) of an ANM step is, counted.

Every solve with K* of an ANM run is tagged by the place of the ANM step that makes it (read
off the call stack, nothing in the solver changes): ``c_1`` (the first coefficient, from the
residual at the start of a series), ``order`` (coefficients c_2 .. c_j, each after one series
order), ``check (truncated series)`` (the end-point check ``|K*^-1 R(d_end)|`` of a series accepted
before order p), ``check (full series)`` (of an order-p series), ``corrected end point`` (the
modified-Newton correction that stands for the last order), ``stale contraction`` (the test
that continues a series from a stale K*), ``check (pade)``, ``outside the steps`` (the scene's
start, e.g. its quasi-static flow).  Residual evaluations are tagged likewise (``start``: R at
the start of a series; ``loop``: the time loop's own, at an accepted state the solver did not
evaluate).  The counts are deterministic; the same
table is made for modified Newton (its solves are iterations).

    python benchmarks/anm_solve_breakdown.py --out benchmarks/results/anm_solve_breakdown \\
        [--cases hires,fsw_small,fsw]

``hires``: the stiff set's HIRES under StepController(rtol=1e-4, atol=1e-8) with ``ANM()`` and
``ANM(order=7, tol=1e-8)``; ``fsw_small``: the scene as shipped (fixed step, 30 steps);
``fsw``: the main job over its first ``--fsw-t-end`` seconds (its controller, implicit Euler),
with the scene's ANM and with ``--solver mnewton``.
"""

from __future__ import annotations

import argparse
import collections
import json
import pathlib
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import jaxanm  # noqa: E402
from jaxanm import _problem  # noqa: E402


def _tag(kind: str) -> str:
    """The tag of the solve or residual evaluation being made, from the call stack."""
    frame = caller = sys._getframe(2)
    if type(caller.f_locals.get("self")).__name__ == "_NewtonStep":
        return "iteration"
    names = []
    while frame is not None and len(names) < 12:
        names.append(frame.f_code.co_name)
        frame = frame.f_back
    if kind == "residual":
        if "_checked_residual" in names:
            return "loop"
        if "_end_point_check" in names:
            return _check_tag(names)
        if "_corrected" in names:
            return "corrected end point"
        if "_stale" in names:
            return "stale contraction"
        return "start" if "run" in names else "outside the steps"
    if "_end_point_check" in names:
        return _check_tag(names)
    if "_corrected" in names:
        return "corrected end point"
    if "_series" in names:  # c_1 is solved before _series' loop over the orders j
        return "c_1" if caller.f_locals.get("j") is None else "order"
    if "_stale" in names:
        return "stale contraction"
    return "outside the steps"


def _check_tag(names) -> str:
    if "_accept_early" in names:
        return "check (truncated series)"
    if "_try_pade" in names:
        return "check (pade)"
    return "check (full series)"


class Counting:
    """Wraps Problem.solve and Problem.residual / SeriesPath.start_residual to tag each call."""

    def __init__(self):
        self.solves, self.residuals = collections.Counter(), collections.Counter()
        self.early = collections.Counter()

    def __enter__(self):
        P, S = _problem.Problem, _problem.SeriesPath
        self._saved = (P.solve, P.residual, S.start_residual)
        solve, residual, start_residual = self._saved
        counting = self

        def counted_solve(self_, fact, rhs):
            counting.solves[_tag("solve")] += 1
            return solve(self_, fact, rhs)

        def counted_residual(self_, *args):
            counting.residuals[_tag("residual")] += 1
            return residual(self_, *args)

        def counted_start(self_):
            counting.residuals[_tag("residual")] += 1
            return start_residual(self_)

        P.solve, P.residual, S.start_residual = counted_solve, counted_residual, counted_start
        return self

    def __exit__(self, *exc):
        P, S = _problem.Problem, _problem.SeriesPath
        P.solve, P.residual, S.start_residual = self._saved


def _row(case: str, solver: str, stats, counting: Counting) -> dict:
    steps = stats.time_steps + stats.rejected_steps + stats.dt_halvings
    return {"case": case, "solver": solver, "steps accepted": stats.time_steps, "steps tried": steps,
            "factorizations": stats.factorizations, "series_orders": stats.series_orders,
            "newton_iterations": stats.newton_iterations, "solves": stats.solves,
            "residual_evaluations": stats.residual_evaluations,
            "solves by place": dict(counting.solves), "residuals by place": dict(counting.residuals),
            "orders accepted": dict(sorted(collections.Counter(stats.orders).items())),
            "wall split s (not comparable between rows)": {k: round(v, 3) for k, v in stats.wall_time.items()}}


def hires_rows() -> list[dict]:
    import stiff_problems

    p = stiff_problems.problem("hires")
    controller = jaxanm.StepController(rtol=1e-4, atol=1e-8)
    rows = []
    for name, solver in (("ANM()", jaxanm.ANM()), ("ANM(order=7, tol=1e-8)", jaxanm.ANM(order=7, tol=1e-8)),
                         ("ModifiedNewton(tol=1e-8)", jaxanm.ModifiedNewton(tol=1e-8))):
        with Counting() as c:
            sol = jaxanm.integrate(p.residual, p.x0, None, t0=0.0, t1=p.t1, dt=p.dt0, solver=solver,
                                   controller=controller, scale=p.scale, jacobian="dense",
                                   saveat=jaxanm.SaveAt(ts=[]))
        rows.append(_row("hires", name, sol.stats, c))
    return rows


def scene_rows(scene: str, t_end: float | None, solvers) -> list[dict]:
    from jaxanm import cli

    rows = []
    for solver in solvers:
        with tempfile.TemporaryDirectory() as out, Counting() as c:
            argv = ["run", scene, "--solver", solver, "--out", out, "--no-progress"]
            if t_end is not None:
                argv += ["--t-end", str(t_end)]
            status = cli.main(argv)
            if status != 0:
                raise RuntimeError(f"jaxanm {' '.join(argv)} exited with {status}")
            summary = json.loads((pathlib.Path(out) / "summary.json").read_text())
        stats = jaxanm.Stats(**{k: v for k, v in summary["stats"].items() if k in jaxanm.Stats.__dataclass_fields__})
        rows.append(_row(f"{scene}" + ("" if t_end is None else f" to {t_end} s"), solver, stats, c))
    return rows


def markdown(rows: list[dict], command: str) -> str:
    places = sorted({k for r in rows for k in r["solves by place"]})
    rplaces = sorted({k for r in rows for k in r["residuals by place"]})
    lines = ["# What each solve of an ANM step is (`benchmarks/anm_solve_breakdown.py`)", "",
             f"`{command}`. Deterministic counts (no walls). Steps tried: accepted + refused by the "
             "controller + halved. Solves and residual evaluations tagged by the place of the step "
             "that makes them (module docstring).", "",
             "| case | solver | steps (tried) | factorisations | series orders | Newton its | solves | "
             + " | ".join(f"solves: {p}" for p in places) + " | residuals | "
             + " | ".join(f"residuals: {p}" for p in rplaces) + " | orders accepted |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: | " + "---: | " * len(places) + "---: | "
             + "---: | " * len(rplaces) + "--- |"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['solver']} | {r['steps accepted']} ({r['steps tried']}) | "
                     f"{r['factorizations']} | {r['series_orders']} | {r['newton_iterations']} | {r['solves']} | "
                     + " | ".join(str(r["solves by place"].get(p, 0)) for p in places) + " | "
                     + f"{sum(r['residuals by place'].values())} | "
                     + " | ".join(str(r["residuals by place"].get(p, 0)) for p in rplaces)
                     + f" | {r['orders accepted']} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", default="hires,fsw_small,fsw")
    ap.add_argument("--fsw-t-end", type=float, default=0.02)
    ap.add_argument("--fsw-solvers", default="anm,mnewton")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "anm_solve_breakdown"))
    args = ap.parse_args()
    rows = []
    for case in args.cases.split(","):
        if case == "hires":
            rows += hires_rows()
        elif case == "fsw_small":
            rows += scene_rows("fsw_small", None, ["anm"])
        elif case == "fsw":
            rows += scene_rows("fsw", args.fsw_t_end, args.fsw_solvers.split(","))
        else:
            raise SystemExit(f"unknown case {case!r}: hires, fsw_small or fsw")
        print(json.dumps(rows[-1]), flush=True)
    command = "python benchmarks/anm_solve_breakdown.py " + " ".join(sys.argv[1:])
    out = pathlib.Path(args.out)
    out.with_suffix(".json").write_text(json.dumps({"command": command, "rows": rows}, indent=1) + "\n")
    out.with_suffix(".md").write_text(markdown(rows, command))
    print(markdown(rows, command))


if __name__ == "__main__":
    main()
