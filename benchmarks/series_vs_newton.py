"""What one triangular solve buys: ANM series against modified Newton on real fsw_paper steps.

Both methods apply the same factorised K* once per series order or per iteration, so their
cost per step is set by how many solves they need.  This script captures real steps of the
Lagrangian ``fsw_paper`` run (scene defaults except ``--dt``; the run's own order-adaptive ANM
up to step k, then a checkpoint holding the state, the moved cloud and the run's K*), solves
step k + 1 exactly (Newton with fresh Jacobians to 1e-13), and measures the true error
``|x - x*| / |x*|`` (scaled norm of the solvers) after each solve of

- modified Newton with that K* (``x_{k+1} = x_k - K*^-1 R(x_k)``);
- the ANM series of the paper's convex homotopy and of the Newton homotopy
  (``docs/notes/anm_homotopy.md``), summed at a = 1 to order j (j solves);
- the Padé approximant of each series at a = 1 (``jaxanm._pade``, order j >= 3);

for the run's (stale) K* and for a fresh K* (the tangent at the step's start).  It also counts
the solves each method's own acceptance uses at ``--tol`` (modified Newton: until
``|dx| <= tol |x|``; the order-adaptive ANM: the first order whose a_max reaches 1, plus the
end-point check's solve) and the true error of what it accepts.

    python benchmarks/series_vs_newton.py [--dt 1e-4] [--steps 150,400] [--orders 12] \
        [--out benchmarks/results/series_vs_newton_dt1e-4]

Writes ``OUT.json``, ``OUT.md`` and ``OUT.png`` with ``--out``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import sys
import tempfile

import numpy as np

import jaxanm
from jaxanm import ANM, Factorization
from jaxanm import _pade as pade
from jaxanm import checkpoint as ckpt
from jaxanm._problem import Problem, SeriesPath
from jaxanm._solver.anm import _ANMStep
from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.scene import load_scene
from jaxanm.fsw.simulate import run

EXACT_TOL = 1e-13
"""The reference x* of a step: full Newton until the relative correction is below this."""


def capture(dt: float, step: int, workdir: str) -> dict:
    """State, cloud (params) and K* of the scene-default ANM run after ``step`` steps of ``dt``."""
    scene = load_scene("fsw_paper").with_overrides({"time.dt": repr(dt), "time.t_end": repr(step * dt)})
    path = os.path.join(workdir, f"step{step}.ckpt")
    run(scene, checkpoint=path)
    payload = ckpt.read(path)
    _, _, model, _, _ = discretise(scene)
    return {
        "scene": scene,
        "model": model,
        "x_old": np.asarray(payload["x"]),
        "params": payload["params"],
        "kstar": payload["kstar"],
        "t": (step + 1) * dt,
        "dt": dt,
        "step": step + 1,
    }


def exact_solution(P: Problem, x_old, args) -> np.ndarray:
    """x* of the step: Newton with a fresh Jacobian per iteration, to :data:`EXACT_TOL`."""
    x = x_old.copy()
    for _ in range(30):
        dx = -Factorization(P.tangent(x, *args)).solve(P.residual(x, *args))
        x = x + dx
        if P.norm(dx) <= EXACT_TOL * P.norm(x):
            return x
    raise RuntimeError("the reference Newton solve did not converge")


def series(P: Problem, fact, d_s, args, homotopy: str, orders: int) -> np.ndarray:
    """Coefficients c_1 .. c_orders of the ANM series from ``d_s`` with K* = ``fact``."""
    newton = homotopy == "newton"
    path = SeriesPath(P, d_s, args, lookahead=newton)
    coeffs = [-fact.solve(path.start_residual())]
    for _ in range(2, orders + 1):
        coeffs.append(coeffs[-1] - fact.solve(path.next(coeffs[-1])))
    return np.array(coeffs)


def anm_acceptance(P: Problem, fact, coeffs, d_s, args, tol: float):
    """(solves, accepted state) of the order-adaptive ANM with the "state" criterion: the first
    order j >= 2 whose a_max reaches 1 and whose end point passes the end-point check (one more
    residual and solve each time it is tried), by the stepper's own acceptance
    (``jaxanm._solver.anm._ANMStep``); None if no order up to ``len(coeffs)`` passes."""
    attempt = _ANMStep(ANM.paper(order=coeffs.shape[0], tol=tol, criterion="state", adaptive=True), P, fact)
    checks = P.stats.residual_evaluations  # each end-point check evaluates one residual
    for j in range(2, coeffs.shape[0] + 1):
        accepted = attempt._accept_early(coeffs[:j], d_s, *args)
        if accepted is not None:
            return j + P.stats.residual_evaluations - checks, accepted[0]
    return None


def modified_newton_acceptance(P: Problem, fact, x_old, args, tol: float, limit: int):
    """(solves, accepted state) of modified Newton with ``fact``: iterate until ``|dx| <= tol |x|``."""
    x = x_old.copy()
    for k in range(1, limit + 1):
        dx = -fact.solve(P.residual(x, *args))
        x = x + dx
        if P.norm(dx) <= tol * P.norm(x):
            return k, x
    return None


def study(case: dict, orders: int, tol: float) -> dict:
    """Errors per solve of every method, and each method's own acceptance, at one captured step."""
    model, x_old = case["model"], case["x_old"]
    stats = jaxanm.Stats()
    P = Problem(model.residual, model.scale(), stats, "sparse", model.sparsity)
    args = (x_old, np.float64(case["t"]), np.float64(case["dt"]), case["params"])
    x_star = exact_solution(P, x_old, args)

    def err(y):
        return P.norm(y - x_star) / P.norm(x_star)

    out = {"step": case["step"], "t": case["t"], "dt": case["dt"], "start_error": err(x_old), "kstar": {}}
    for kind in ("stale", "fresh"):
        fact = Factorization(case["kstar"] if kind == "stale" else P.tangent(x_old, *args))
        rows = {}
        x, mn = x_old.copy(), []
        for _ in range(orders):
            x = x - fact.solve(P.residual(x, *args))
            mn.append(err(x))
        rows["modified Newton"] = mn
        accept = {}
        got = modified_newton_acceptance(P, fact, x_old, args, tol, 50)
        accept["modified Newton"] = None if got is None else {"solves": got[0], "error": err(got[1])}
        for homotopy in ("convex", "newton"):
            coeffs = series(P, fact, x_old, args, homotopy, orders)
            rows[f"ANM {homotopy}"] = [err(x_old + coeffs[:j].sum(axis=0)) for j in range(1, orders + 1)]
            rows[f"ANM {homotopy} + Padé"] = [
                float("nan") if j < 3 else err(x_old + pade.evaluate(pade.approximant(coeffs[:j], P.scale), 1.0))
                for j in range(1, orders + 1)
            ]
            got = anm_acceptance(P, fact, coeffs, x_old, args, tol)
            accept[f"ANM {homotopy}"] = None if got is None else {"solves": got[0], "error": err(got[1])}
        out["kstar"][kind] = {"errors": rows, "acceptance": accept}
    return out


def markdown(results: list, tol: float) -> str:
    """Tables of the errors per solve and of each method's acceptance."""
    lines = []
    for res in results:
        for kind, block in res["kstar"].items():
            n = len(next(iter(block["errors"].values())))
            lines += [
                f"### step {res['step']} (t = {res['t']:.4g} s, dt = {res['dt']:g}), {kind} K*: "
                f"|x_old - x*| / |x*| = {res['start_error']:.2e}",
                "",
                "| solves | " + " | ".join(str(j) for j in range(1, n + 1)) + " |",
                "| --- |" + " ---: |" * n,
            ]
            for name, errs in block["errors"].items():
                lines.append(f"| {name} | " + " | ".join("" if not np.isfinite(e) else f"{e:.1e}" for e in errs) + " |")
            lines += [
                "",
                f"Own acceptance at tol = {tol:g}: "
                + "; ".join(
                    f"{name}: "
                    f"{'none' if a is None else str(a['solves']) + ' solves, error ' + format(a['error'], '.1e')}"
                    for name, a in block["acceptance"].items()
                ),
                "",
            ]
    return "\n".join(lines)


def plot(results: list, path: pathlib.Path) -> None:
    """Error against solves, one panel per captured step and K*."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(res, kind) for res in results for kind in res["kstar"]]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.6), squeeze=False)
    styles = {
        "modified Newton": "k-o",
        "ANM convex": "C0-s",
        "ANM convex + Padé": "C0:s",
        "ANM newton": "C1-^",
        "ANM newton + Padé": "C1:^",
    }
    for ax, (res, kind) in zip(axes[0], panels):
        for name, errs in res["kstar"][kind]["errors"].items():
            ax.semilogy(range(1, len(errs) + 1), errs, styles[name], ms=3, label=name)
        ax.set_title(f"step {res['step']}, dt = {res['dt']:g}, {kind} K*", fontsize=9)
        ax.set_xlabel("triangular solves")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("|x - x*| / |x*|")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> None:
    """Command line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dt", type=float, default=1e-4)
    ap.add_argument("--steps", default="150,400", help="capture after these many steps")
    ap.add_argument("--orders", type=int, default=12)
    ap.add_argument("--tol", type=float, default=1e-6)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    results = []
    with tempfile.TemporaryDirectory() as work, jaxanm.float64():
        for step in (int(s) for s in args.steps.split(",")):
            results.append(study(capture(args.dt, step, work), args.orders, args.tol))
    text = markdown(results, args.tol)
    print(text)
    if args.out:
        out = pathlib.Path(args.out)
        meta = {"date": datetime.date.today().isoformat(), "argv": sys.argv[1:], "tol": args.tol}
        out.with_suffix(".json").write_text(json.dumps({"meta": meta, "results": results}, indent=1, default=float))
        out.with_suffix(".md").write_text(
            f"<!-- made by benchmarks/series_vs_newton.py {' '.join(sys.argv[1:])} -->\n\n" + text + "\n",
            encoding="utf-8",
        )
        plot(results, out.with_suffix(".png"))
        print(f"wrote {out}.json, .md, .png")


if __name__ == "__main__":
    main()
