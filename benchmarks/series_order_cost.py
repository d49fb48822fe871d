"""What one ANM series order costs against one residual evaluation, on the main job's cloud.

The main job (scene ``fsw``: 1603 graded points, the paper's physics on fixed points, the
ANM under the step controller) is run over ``--t-end`` twice in one process; the first run
compiles, the second is measured.  In the measured run every call of the series engine
(``jaxanm._series.AffinePath.next``: one order, from the path coefficient on the host to the
residual's coefficient on the host) and of the residual (``jaxanm._problem.Problem.residual``,
the jitted residual with the same host arguments) is timed, wall clock, as the solver makes
it.  Reported: the median order against the median residual (the ratio), per order k of the
series and over all orders.

Then, on the run's last state, the two compiled programs are dissected: XLA's cost analysis
(flops, bytes accessed) of the residual and of one order, and device times (arguments
already on the device) of the residual, of the order, and of its parts: the linear map of the
affine part (one ``jvp``), and what the order adds to it (the Taylor arithmetic of the
non-affine rest).  The difference between the in-run and the device time of an order is the
host's: the transfer of ``c_k`` and of the coefficient, and the dispatch.

Another checkout's engine is measured by putting it first on the path, e.g. the code before
the incremental Taylor arithmetic::

    PYTHONPATH=/path/to/old/checkout python benchmarks/series_order_cost.py --label before

    python benchmarks/series_order_cost.py --label after [--t-end 0.01] [--out benchmarks/results/series_order_cost]
    python benchmarks/series_order_cost.py --label any --table-only   # OUT.md again from OUT.json

Writes ``OUT.json`` (one entry per label, earlier labels kept) and ``OUT.md`` (every label).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import statistics
import subprocess
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent


class Timed:
    """Wall times of every call of ``owner.name`` (the original restored by :meth:`restore`),
    with the number of path coefficients known before an ``AffinePath.next``."""

    def __init__(self, owner, name: str):
        self.owner, self.name, self.original = owner, name, getattr(owner, name)
        self.calls: list = []
        original, calls = self.original, self.calls

        def timed(obj, *args, **kwargs):
            start = time.perf_counter()
            out = original(obj, *args, **kwargs)
            calls.append((getattr(obj, "_known", 0), time.perf_counter() - start))
            return out

        setattr(owner, name, timed)

    def restore(self) -> None:
        setattr(self.owner, self.name, self.original)


def run_main_job(t_end: float):
    """One run of the ``fsw`` scene to ``t_end``: its stats."""
    from jaxanm.fsw import load_scene
    from jaxanm.fsw.simulate import run

    scene = load_scene("fsw").with_overrides({"time.t_end": t_end})
    return run(scene)


def in_run(t_end: float) -> dict:
    """Per-call wall times of the orders and the residuals of a warm run of the main job."""
    from jaxanm import _problem, _series

    run_main_job(t_end)  # compiles everything
    orders, residuals = Timed(_series.AffinePath, "next"), Timed(_problem.Problem, "residual")
    load = os.getloadavg()[0]
    result = run_main_job(t_end)
    orders.restore()
    residuals.restore()
    by_k: dict = {}
    for known, seconds in orders.calls:
        by_k.setdefault(known + 1, []).append(seconds)
    order_ms = 1e3 * statistics.median(s for _, s in orders.calls)
    residual_ms = 1e3 * statistics.median(s for _, s in residuals.calls)
    return {"t_end": t_end, "load": [load, os.getloadavg()[0]], "orders": len(orders.calls),
            "residuals": len(residuals.calls), "order_ms": order_ms, "residual_ms": residual_ms,
            "ratio": order_ms / residual_ms,
            "order_ms_by_k": {k: 1e3 * statistics.median(v) for k, v in sorted(by_k.items())},
            "calls_by_k": {k: len(v) for k, v in sorted(by_k.items())},
            "series_orders": result.stats.series_orders, "time_steps": result.stats.time_steps}


def median_ms(fn, repeats: int = 30) -> float:
    """Median wall time of ``fn()`` in ms (after one call)."""
    fn()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1e3 * statistics.median(times)


def dissect(order: int) -> dict:
    """Cost analysis and device times of the residual and of one series order (k = ``order``
    - 1 terms known, the main job's p = 7) on the scene's first state."""
    import jax
    import jax.numpy as jnp

    import jaxanm
    from jaxanm._problem import compiled
    from jaxanm.fsw import discretise, load_scene

    with jaxanm.float64():
        scene = load_scene("fsw")
        _, _, model, params, x0 = discretise(scene)
        x = np.asarray(x0)
        args = jax.device_put((x, np.float64(1e-4), np.float64(1e-4), params))
        xd = jax.device_put(x)
        residual = jax.jit(model.residual)
        cost = residual.lower(xd, *args).compile().cost_analysis()
        out = {"residual": {"flops": cost.get("flops"), "bytes": cost.get("bytes accessed"),
                            "device_ms": median_ms(lambda: residual(xd, *args).block_until_ready())}}
        fns = compiled(model.residual).affine_functions(x, args)
        linear = jax.jit(lambda x0, c, *a: jax.jvp(lambda y: fns.split.linear(y, *a), (x0,), (c,))[1])
        c = jnp.asarray(1e-4 * model.scale())
        cost = linear.lower(xd, c, *args).compile().cost_analysis()
        out["linear_map"] = {"flops": cost.get("flops"), "bytes": cost.get("bytes accessed"),
                             "device_ms": median_ms(lambda: jax.block_until_ready(linear(xd, c, *args)))}
        out["order"] = _order_cost(fns, xd, c, args, order)
    return out


def _order_cost(fns, xd, c, args, order: int) -> dict | None:
    """Cost analysis and device time of one order of the engine in use (None for an engine
    this script does not know)."""
    import numpy as np

    if hasattr(fns, "program"):  # incremental Taylor arithmetic
        from jaxanm._taylor import mirrored

        first, values = fns.start(xd, *args)[1]
        orders = [first] + [fns.zeros] * 6
        k = order - 1
        orders[1:k] = [first] * (k - 1)  # any values: the cost does not depend on them
        call_args = (np.int32(k), xd, c, orders, mirrored(orders, fns.zeros, k), values, *args)
        fn = fns.order(False, len(orders))
    elif hasattr(fns, "truncated"):  # a jet of the rest per number of terms (before)
        f0 = fns.frontier(xd, *args)
        stack = fns.grown(f0, None, 6)
        fn = fns.truncated[False]
        call_args = (order - 1, xd, c, f0, stack, np.int32(order - 2), *args)
    else:
        return None
    cost = fn.lower(*call_args).compile().cost_analysis()
    return {"flops": cost.get("flops"), "bytes": cost.get("bytes accessed"),
            "device_ms": median_ms(lambda: jax_ready(fn(*call_args)))}


def jax_ready(out):
    import jax

    return jax.block_until_ready(out)


TARGET = 1.5
"""At most this many residual evaluations per series order (median over the run's orders)."""


def table(entries: dict) -> str:
    """The markdown tables of every label."""
    lines = [f"Target: one order at most {TARGET} residual evaluations (the median order of the run).\n",
             "| label | commit | load | orders | order ms (median, in run) | residual ms | order / residual | "
             "target | by order k = 2 .. 7 (ms) | highest order / residual |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: | --- | --- | ---: |"]
    for label, e in entries.items():
        r = e["in_run"]
        by_k = " / ".join(f"{v:.2f}" for v in r["order_ms_by_k"].values())
        highest = list(r["order_ms_by_k"].values())[-1] / r["residual_ms"]
        lines.append(f"| {label} | {e['commit']} | {r['load'][0]:.1f}-{r['load'][1]:.1f} | {r['orders']} | "
                     f"{r['order_ms']:.2f} | {r['residual_ms']:.2f} | **{r['ratio']:.2f}** | "
                     f"{'held' if r['ratio'] <= TARGET else 'missed'} | {by_k} | {highest:.2f} |")
    lines += ["", "| label | program | flops | bytes accessed | device ms |", "| --- | --- | ---: | ---: | ---: |"]
    for label, e in entries.items():
        for name, d in e["dissection"].items():
            if d:
                lines.append(f"| {label} | {name} | {d['flops']:.3g} | {d['bytes']:.3g} | {d['device_ms']:.2f} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--label", required=True)
    ap.add_argument("--t-end", type=float, default=0.01)
    ap.add_argument("--order", type=int, default=5, help="the order whose program is dissected")
    ap.add_argument("--out", default=str(HERE / "results" / "series_order_cost"))
    ap.add_argument("--table-only", action="store_true", help="rewrite OUT.md from OUT.json, measure nothing")
    a = ap.parse_args(argv)
    out = pathlib.Path(a.out)
    if a.table_only:
        write_table(out, json.loads(out.with_suffix(".json").read_text()))
        return 0
    import jaxanm

    commit = subprocess.run(["git", "-C", str(pathlib.Path(jaxanm.__file__).parent), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    entry = {"date": datetime.date.today().isoformat(), "commit": commit, "cpus": os.cpu_count(),
             "in_run": in_run(a.t_end), "dissection": dissect(a.order)}
    r = entry["in_run"]
    print(f"{a.label}: {r['orders']} orders, median {r['order_ms']:.2f} ms against a residual's "
          f"{r['residual_ms']:.2f} ms: {r['ratio']:.2f}; by k {r['order_ms_by_k']}; load {r['load']}", flush=True)
    print(json.dumps(entry["dissection"], indent=1))
    path = out.with_suffix(".json")
    entries = json.loads(path.read_text()) if path.exists() else {}
    entries[a.label] = entry
    path.write_text(json.dumps(entries, indent=1))
    write_table(out, entries)
    print(f"wrote {path}")
    return 0


def write_table(out: pathlib.Path, entries: dict) -> None:
    """``OUT.md``: the tables of every label."""
    out.with_suffix(".md").write_text(
        "# One series order against one residual on the main job's cloud (`benchmarks/series_order_cost.py`)\n\n"
        "Wall times per call in a warm run of `fsw` (the second of two in one process), medians; "
        "device times with the arguments already on the device; flops and bytes from XLA's cost "
        "analysis of the compiled programs.\n\n" + table(entries) + "\n")


if __name__ == "__main__":
    raise SystemExit(main())
