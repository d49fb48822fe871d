"""Scaling of the step costs with the number of points N (issue 5, item 4).

The ``fsw_tracers`` physics (all paper effects on fixed points) at dr, dr/2 (and dr/4 with
``--levels 3``): N = 881, ~3.4k, ~13.5k points, 3N unknowns.  Each level runs in a fresh
subprocess (its own ``ru_maxrss``) and measures, median over repeats, compile excluded:

- the jitted step residual, one jet series call at K = p - 1 = 6 terms (ANM p = 7),
- one coloured compressed Jacobian (``jaxanm.SparseJacobian``), its number of colours,
- one ``splu`` factorisation of that Jacobian (and nnz of L + U), one pair of triangular solves,
- peak resident memory of the process (``ru_maxrss``; JAX runtime and compiler included).

Time per step of each method is then *composed* from these component costs and the counts per
step measured on the reduced scene in ``benchmarks/results/accuracy_cost.json`` (``--counts-from``):
Newton: iterations x (residual + Jacobian + factorisation + solve); modified Newton and ANM:
their measured factorisations, series evaluations, residual evaluations and solves per step.
(Real steps at dr/2 and dr/4 would first need the impulsive start, 50+ factorisations at dr:
too long for the time box; the composition is the stated model, not a measured full step.)
Growth exponents are least-squares slopes of log(cost) against log(N).

    python benchmarks/scaling.py [--levels 2|3] [--repeats 5] [--out benchmarks/results/scaling.json]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import subprocess
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
DR = 3.75e-4

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from accuracy_cost import median_time  # noqa: E402


def measure(dr: float, repeats: int, order: int = 7) -> dict:
    """Component costs of the fixed-point FSW step at point spacing ``dr`` (runs in a worker)."""
    import jax
    import jax.numpy as jnp

    import jaxanm
    from jaxanm._problem import compiled
    from jaxanm.fsw.discretisation import discretise
    from jaxanm.fsw.scene import load_scene

    t = time.perf_counter()
    scene = load_scene("fsw_tracers").with_overrides({"geometry.dr": dr})
    cloud, st, model, params, x0 = discretise(scene)
    build_s = time.perf_counter() - t
    rss_build = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    n = x0.size
    rng = np.random.default_rng(0)
    x = x0 + 1e-2 * model.scale() * rng.standard_normal(n)  # a generic state near rest
    out = {"dr": dr, "N": int(cloud.size), "n": int(n), "stencil_width": int(np.asarray(st.index).shape[1]),
           "build_s": build_s}
    with jaxanm.float64():
        t_, dt_ = jnp.float64(1e-4), jnp.float64(1e-4)
        res = jax.jit(model.residual)
        t = time.perf_counter()
        np.asarray(res(x, x0, t_, dt_, params))
        out["residual_compile_s"] = time.perf_counter() - t
        out["residual_s"] = median_time(lambda: np.asarray(res(x, x0, t_, dt_, params)), repeats)
        ser = compiled(model.residual).series
        terms = 1e-3 * model.scale() * rng.standard_normal((order - 1, n))
        t = time.perf_counter()
        np.asarray(ser(x, terms, x0, t_, dt_, params))
        out["series_compile_s"] = time.perf_counter() - t
        out["series_call_s"] = median_time(lambda: np.asarray(ser(x, terms, x0, t_, dt_, params)), repeats)
        pattern = model.sparsity(params)
        t = time.perf_counter()
        sj = jaxanm.SparseJacobian(model.residual, pattern)
        out["coloring_s"] = time.perf_counter() - t
        out["colors"] = int(sj.n_colors)
        t = time.perf_counter()
        J = sj(x, x0, t_, dt_, params)
        out["jacobian_compile_s"] = time.perf_counter() - t
        out["jacobian_s"] = median_time(lambda: sj(x, x0, t_, dt_, params), max(1, repeats // 2))
    out["nnz_J"] = int(J.nnz)
    stats = jaxanm.Stats()
    t = time.perf_counter()
    fact = jaxanm.factorize(J, stats)
    out["factorize_s"] = min(time.perf_counter() - t,
                             median_time(lambda: jaxanm.Factorization(J), max(1, repeats // 2)))
    lu = fact._lu if hasattr(fact, "_lu") else None
    out["nnz_LU"] = int(lu.L.nnz + lu.U.nnz) if lu is not None else None
    b = rng.standard_normal(n)
    out["solve_s"] = median_time(lambda: fact.solve(b), repeats)
    out["rss_build_mb"] = rss_build
    out["rss_peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return out


def per_step_costs(levels: list, counts: dict) -> dict:
    """Composed time per step of each method at each level from component costs x counts per step."""
    out = {}
    for method, c in counts.items():
        out[method] = [c["residual"] * lv["residual_s"] + c["series"] * lv["series_call_s"]
                       + c["jacobian"] * lv["jacobian_s"] + c["factorize"] * lv["factorize_s"]
                       + c["solve"] * lv["solve_s"] for lv in levels]
    return out


def counts_from(path: pathlib.Path, tol: float = 1e-6, order: int = 7) -> dict:
    """Counts per step of each method on the reduced FSW scene at ``tol`` (from accuracy_cost JSON)."""
    data = json.loads(path.read_text())
    counts = {}
    for r in data["rows"]:
        if r.get("problem") != "fsw_reduced" or "wall_s" not in r or r.get("tol") != tol:
            continue
        if r["method"] == "anm" and r["order"] != order:
            continue
        k = r["time_steps"]
        # solves: ANM p per series; Newton one per iteration (+ rejected ones, ignored)
        series_per = r["series_orders"] / k
        n_series = series_per / (order - 1) if r["method"] == "anm" else 0.0
        solves = n_series * order if r["method"] == "anm" else r["newton_iterations"] / k
        counts[r["method"]] = {"residual": r["residual_evaluations"] / k, "series": series_per,
                               "jacobian": r["jacobian_evaluations"] / k, "factorize": r["factorizations"] / k,
                               "solve": solves, "source": f"{path.name}: fsw_reduced, tol {tol:g}"}
    return counts


def fit_exponent(N, y) -> float | None:
    """Least-squares slope of log y against log N over the finite, positive y (None with fewer
    than two such levels)."""
    N, y = np.asarray(N, float), np.asarray(y, float)
    keep = np.isfinite(y) & (y > 0)
    return float(np.polyfit(np.log(N[keep]), np.log(y[keep]), 1)[0]) if keep.sum() >= 2 else None


def main(argv=None) -> None:
    """Command line: measure each level in a subprocess, compose, fit, write JSON and a plot."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", type=int, default=2, help="2: dr, dr/2; 3: also dr/4 (~13.5k points)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--counts-from", default=str(ROOT / "benchmarks" / "results" / "accuracy_cost.json"))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "scaling.json"))
    ap.add_argument("--compose-only", action="store_true",
                    help="reuse the levels already in --out; recompute exponents and composed per-step costs")
    ap.add_argument("--worker", type=float, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker is not None:
        print(json.dumps(measure(args.worker, args.repeats)))
        return
    result = {"started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()), "loadavg_start": os.getloadavg(),
              "levels": []}
    if args.compose_only:
        result = json.loads(pathlib.Path(args.out).read_text())
    for i in range(0 if args.compose_only else args.levels):
        dr = DR / 2**i
        t = time.perf_counter()
        proc = subprocess.run([sys.executable, __file__, "--worker", repr(dr), "--repeats", str(args.repeats)],
                              capture_output=True, text=True)
        if proc.returncode != 0:
            sys.stderr.write(proc.stderr[-2000:])
            break
        lv = json.loads(proc.stdout.strip().splitlines()[-1])
        lv["loadavg"] = os.getloadavg()
        lv["worker_wall_s"] = time.perf_counter() - t
        result["levels"].append(lv)
        print(json.dumps(lv), flush=True)
        pathlib.Path(args.out).write_text(json.dumps(result, indent=1))
    levels = result["levels"]
    N = [lv["N"] for lv in levels]
    keys = ["residual_s", "series_call_s", "jacobian_s", "factorize_s", "solve_s", "nnz_LU", "rss_peak_mb",
            "series_compile_s", "jacobian_compile_s"]
    if len(levels) >= 2:
        result["exponents"] = {k: fit_exponent(N, [lv[k] for lv in levels]) for k in keys
                               if all(lv.get(k) for lv in levels)}
    cpath = pathlib.Path(args.counts_from)
    if cpath.exists():
        counts = counts_from(cpath)
        result["counts_per_step"] = counts
        steps = per_step_costs(levels, {m: c for m, c in counts.items()})
        result["per_step_s"] = steps
        if len(levels) >= 2:
            result["per_step_exponents"] = {m: fit_exponent(N, v) for m, v in steps.items()}
    result["loadavg_end"] = os.getloadavg()
    pathlib.Path(args.out).write_text(json.dumps(result, indent=1))
    print(json.dumps({k: result.get(k) for k in ("exponents", "per_step_s", "per_step_exponents")}, indent=1))


if __name__ == "__main__":
    main()
