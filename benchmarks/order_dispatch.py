"""What one series order costs against a residual on the stiff set, where a call's dispatch is the work.

On the 2-20 unknowns of Robertson, van der Pol, HIRES and OREGO (``tests/stiff_problems.py``,
implicit-Euler step residuals as ``benchmarks/stiff_controller.py`` solves them) a call into
XLA is mostly its fixed cost.  Per problem, medians over ``--calls`` calls (after warm-up):

- ``residual``: the jitted residual, its result read on the host (what modified Newton pays per
  iteration besides the solve);
- ``series start``: the start program of a series (the residual and the state a path starts
  from, :meth:`jaxanm._series.AffineFunctions.start`);
- ``order``: one order of a path, :meth:`jaxanm._series.AffinePath.next` as the ANM calls it
  (the Newton homotopy's lookahead, room for an order-7 series), its result on the host;
- ``order program``: the jitted order program alone on the same arguments;
- ``empty, order's arguments`` and ``empty, one argument``: a jitted function returning its
  first argument, called with the order program's flattened arguments and with one array: the
  floor of a call with that many arguments.

From the counts of ``benchmarks/results/anm_defaults.json`` (``ANM(order=7, tol=1e-8)``
against ``ModifiedNewton(tol=1e-8)`` under the step controller), the table also gives the
ANM's wall there if every order cost a residual instead (its wall less ``orders x (order -
residual)``), over modified Newton's: how far the target of 1.2x is from the per-call cost.

    python benchmarks/order_dispatch.py --out benchmarks/results/order_dispatch

Writes ``OUT.json`` and ``OUT.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import statistics
import sys
import time

import jax
import numpy as np

import jaxanm
from jaxanm._series import AffineFunctions, AffinePath
from jaxanm._taylor import mirrored

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
import stiff_problems  # noqa: E402

PROBLEMS = ("robertson", "vanderpol", "hires", "orego")
ORDER = 7  # the series' most orders, as ANM(order=7) asks room for: p - 1 path terms


def per_call_us(fn, calls: int, rounds: int = 5) -> float:
    """Median over ``rounds`` of the mean time of ``calls`` calls of ``fn()``, in microseconds."""
    for _ in range(100):
        fn()
    means = []
    for _ in range(rounds):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        means.append((time.perf_counter() - start) / calls * 1e6)
    return statistics.median(means)


def measure(name: str, calls: int) -> dict:
    """The per-call times (us) of :data:`PROBLEMS` ``name``'s residual, series start and order."""
    p = stiff_problems.problem(name)
    x0 = np.asarray(p.x0, dtype=np.float64)
    args = (x0, 0.0, float(p.dt0), None)
    with jax.enable_x64(True):
        fns = AffineFunctions(p.residual, x0, *args)
        path = AffinePath(fns, x0, args, lookahead=True, max_terms=ORDER - 1)
        c = 1e-6 * np.maximum(np.abs(x0), 1e-3)
        path.next(c)

        def order():
            path._known = 1  # order 2 again: the same program whatever k
            path.next(c)

        program = fns.order(True, len(path._orders))
        k = np.int32(2)
        program_args = (k, x0, c, path._orders, mirrored(path._orders, fns.zeros, 2), path._values, *args)
        leaves = jax.tree_util.tree_leaves(program_args)
        empty = jax.jit(lambda *a: a[0])
        residual = jax.jit(p.residual)
        times = {
            "residual": per_call_us(lambda: np.asarray(residual(x0, *args)), calls),
            "series start": per_call_us(lambda: np.asarray(fns.start(x0, *args)[0]), calls),
            "order": per_call_us(order, calls),
            "order program": per_call_us(lambda: program(*program_args), calls),
            "empty, order's arguments": per_call_us(lambda: empty(*leaves), calls),
            "empty, one argument": per_call_us(lambda: empty(x0), calls),
        }
    return {"problem": name, "unknowns": int(x0.size), "order_arguments": len(leaves), "us": times}


def projection(row: dict, runs: list[dict]) -> dict:
    """The ANM's wall if each of its orders cost a residual, over modified Newton's (anm_defaults.json)."""
    anm = next(r for r in runs if r["problem"] == row["problem"] and r["solver"] == "anm_7_1e-8")
    mn = next(r for r in runs if r["problem"] == row["problem"] and r["solver"] == "mnewton_8")
    saved = anm["series_orders"] * (row["us"]["order"] - row["us"]["residual"]) * 1e-6
    return {"anm_wall_s": anm["wall_s"], "mnewton_wall_s": mn["wall_s"], "orders": anm["series_orders"],
            "ratio": anm["wall_s"] / mn["wall_s"],
            "ratio_if_order_cost_a_residual": (anm["wall_s"] - saved) / mn["wall_s"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=2000)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "order_dispatch"))
    a = ap.parse_args()
    load = os.getloadavg()[0]
    rows = [measure(name, a.calls) for name in PROBLEMS]
    runs = json.loads((ROOT / "benchmarks" / "results" / "anm_defaults.json").read_text())["rows"]
    for row in rows:
        row["projection"] = projection(row, runs)
    meta = {"command": " ".join(["python", *sys.argv]), "jax": jax.__version__, "jaxanm": jaxanm.__version__,
            "machine": platform.machine(), "cpus": os.cpu_count(), "load": [load, os.getloadavg()[0]]}
    out = pathlib.Path(a.out)
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    names = list(rows[0]["us"])
    lines = ["# One series order against a residual on the stiff set (`benchmarks/order_dispatch.py`)", "",
             f"`{meta['command']}`; jax {meta['jax']}, {meta['cpus']} CPUs, load {load:.1f} at the start, "
             f"{meta['load'][1]:.1f} at the end. Microseconds per call, medians of 5 rounds of {a.calls} calls.", "",
             "| problem | unknowns | " + " | ".join(names) + " | order program's arguments |",
             "| --- | ---: | " + " | ".join("---:" for _ in names) + " | ---: |"]
    for row in rows:
        lines.append(f"| {row['problem']} | {row['unknowns']} | "
                     + " | ".join(f"{row['us'][k]:.1f}" for k in names) + f" | {row['order_arguments']} |")
    lines += ["", "`ANM(order=7, tol=1e-8)` against `ModifiedNewton(tol=1e-8)` under the step controller "
              "([anm_defaults](anm_defaults.md): walls and counts), and the ANM's wall if each of its orders "
              "cost what a residual does here:", "",
              "| problem | orders | ANM wall s | modified Newton wall s | ratio | ratio if an order cost a residual |",
              "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for row in rows:
        pr = row["projection"]
        lines.append(f"| {row['problem']} | {pr['orders']} | {pr['anm_wall_s']:.2f} | {pr['mnewton_wall_s']:.2f} | "
                     f"{pr['ratio']:.2f} | {pr['ratio_if_order_cost_a_residual']:.2f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(out.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()
