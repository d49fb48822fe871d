"""Profile of ANM steps: where the time of one step goes (issue 5, item 3).

On the reduced FSW scene of ``benchmarks/accuracy_cost.py`` (all paper effects on fixed points,
dr = 7.5e-4, 717 unknowns, warm state after 10 steps) and on the reaction-diffusion ODE:

1. the :class:`jaxanm.Stats` wall-time split of a steady run (compile excluded: a first run
   compiles everything), per step;
2. ``cProfile`` of the same run, top entries by cumulative time;
3. one series evaluation (the jitted jet at K = p - 1 terms) dissected: the jitted call with
   host (numpy) arguments as the solver makes it, the same call with every argument already on
   the device, and the device execution alone; per order p, to show the O(p^2) cost per call,
   hence O(p^3) per series;
4. compile time of the series function per order.

    python benchmarks/profile_anm_step.py [--orders 3,5,7] [--problem fsw_reduced|rd] \
        [--out benchmarks/results/profile_anm_step.json]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import json
import os
import pathlib
import pstats
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import accuracy_cost as ac  # noqa: E402


def series_dissection(prob, x0, orders, repeats=20) -> list:
    """Per order p: compile time, and the per-call cost of the jet series with host / device args."""
    import jax
    import jax.numpy as jnp

    import jaxanm
    from jaxanm._problem import compiled

    f = compiled(prob["residual"]).series
    rows = []
    with jaxanm.float64():
        t_, dt_ = jnp.float64(prob["t0"] + prob["dt"]), jnp.float64(prob["dt"])
        params = prob["params"]
        params_dev = jax.device_put(params)
        scale = 1.0 if prob["scale"] is None else prob["scale"]
        rng = np.random.default_rng(0)
        for p in orders:
            terms = 1e-3 * scale * rng.standard_normal((p - 1, x0.size))
            t = time.perf_counter()
            np.asarray(f(x0, terms, x0, t_, dt_, params))
            compile_s = time.perf_counter() - t
            host = ac.median_time(lambda: np.asarray(f(x0, terms, x0, t_, dt_, params)), repeats)
            xd, td = jax.device_put(x0), jax.device_put(terms)
            dev = ac.median_time(lambda: np.asarray(f(xd, td, xd, t_, dt_, params_dev)), repeats)
            exe = ac.median_time(lambda: f(xd, td, xd, t_, dt_, params_dev).block_until_ready(), repeats)
            res = jax.jit(prob["residual"])
            np.asarray(res(x0, x0, t_, dt_, params))
            res_host = ac.median_time(lambda: np.asarray(res(x0, x0, t_, dt_, params)), repeats)
            rows.append(
                {
                    "order": p,
                    "terms": p - 1,
                    "compile_s": compile_s,
                    "call_host_args_ms": 1e3 * host,
                    "call_device_args_ms": 1e3 * dev,
                    "device_execution_ms": 1e3 * exe,
                    "residual_call_host_args_ms": 1e3 * res_host,
                    "per_series_ms": 1e3 * host * (p - 1),
                }
            )
            print(
                f"p={p:2d}: compile {compile_s:6.2f}s  series call {1e3 * host:7.2f} ms (host args) "
                f"{1e3 * dev:7.2f} ms (device args) {1e3 * exe:7.2f} ms (execution)  "
                f"x{p - 1} per series = {1e3 * host * (p - 1):7.1f} ms; residual {1e3 * res_host:.2f} ms",
                flush=True,
            )
    return rows


def profile_run(prob, x0, order, tol):
    """Stats split of a steady ANM run (after a compiling run) and its cProfile top entries."""
    solver = ac.make_solver("anm", order, tol)
    _, st0, first = ac.run_implicit(prob, solver, x0)
    _, st, wall = ac.run_implicit(prob, solver, x0)
    pr = cProfile.Profile()
    pr.enable()
    ac.run_implicit(prob, solver, x0)
    pr.disable()
    buf = io.StringIO()
    pstats.Stats(pr, stream=buf).sort_stats("cumulative").print_stats(25)
    split = {k: v for k, v in st.wall_time.items()}
    steps = st.time_steps
    return {
        "order": order,
        "tol": tol,
        "first_run_s": first,
        "wall_s": wall,
        "time_steps": steps,
        "factorizations": st.factorizations,
        "series_orders": st.series_orders,
        "residual_evaluations": st.residual_evaluations,
        "substeps": st.substeps,
        "split_s": split,
        "split_share": {k: v / wall for k, v in split.items()},
        "per_step_ms": 1e3 * wall / steps,
        "cprofile_top": buf.getvalue(),
    }


def main(argv=None) -> None:
    """Command line: profile and write the JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--problem", default="fsw_reduced", choices=["fsw_reduced", "rd"])
    ap.add_argument("--orders", default="3,5,7")
    ap.add_argument("--tol", type=float, default=1e-6)
    ap.add_argument("--profile-order", type=int, default=7)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    cfg = ac.CONFIGS["small"]["problems"][args.problem]
    print("references / warm state:", ac.worker_refs(args.problem, cfg).get("cache"), flush=True)
    refs = dict(np.load(ac._cache_file(args.problem, cfg)))
    prob = ac.build_problem(args.problem, cfg)
    x0 = refs["x0"]
    result = {
        "problem": args.problem,
        "cfg": cfg,
        "loadavg_start": os.getloadavg(),
        "started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
    }
    run = profile_run(prob, x0, args.profile_order, args.tol)
    print(
        f"\nANM p={run['order']} tol={run['tol']:g}: {run['time_steps']} steps, {run['wall_s']:.3f} s "
        f"({run['per_step_ms']:.1f} ms/step), {run['factorizations']} factorizations, "
        f"{run['series_orders']} series evaluations; first (compiling) run {run['first_run_s']:.1f} s"
    )
    for k, v in run["split_s"].items():
        print(f"  {k:10s} {v:7.3f} s  {100 * run['split_share'][k]:5.1f} %")
    print(run["cprofile_top"])
    result["run"] = run
    result["series"] = series_dissection(prob, x0, [int(p) for p in args.orders.split(",")])
    result["loadavg_end"] = os.getloadavg()
    out = pathlib.Path(args.out) if args.out else ac.RESULTS / f"profile_anm_step_{args.problem}.json"
    out.write_text(json.dumps(result, indent=1, default=float))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
