"""What one ANM series costs on ``fsw_paper``: cold compile and run time per order (issue 18).

For each order p and each way of feeding jet, in a fresh subprocess (so that every compile is
cold and the peak memory is that variant's), on the state after ``--warm`` Newton steps of a
Lagrangian run (``benchmarks/profile_host_step.warm_state``):

- ``ladder``: what the ANM does: one jet per order, truncated at the terms known, up to
  ``jaxanm._series.EXACT_TERMS`` terms, and beyond that jets padded with zero terms to the next
  rung of a geometric ladder, capped at p - 1 (``jaxanm._series.jet_length``);
- ``exact``: one jet per order at every order (what the ANM did from 2026-12-02 until the
  ladder; the same as ``ladder`` up to EXACT_TERMS).
  (The zero-padded single jet the fixed-order ANM used before is no longer in the
  engine; its rows in benchmarks/results/series_cost.md were measured with commit cb06729.)

Each variant: the compile time of all the jets one series needs, and the time of the p - 1
calls of one series.

both for the convex homotopy (the residual's coefficient ``[R]_{j-1}`` at order j) and the
Newton homotopy (``[R]_j`` with the provisional ``c_j = c_{j-1}``, one more term), with the
affine part of the residual outside jet (``jaxanm._series.AffinePath``).  The path coefficients
are random (scaled like the unknowns): the cost does not depend on their values.  Times are
medians over ``--repeats`` series; ``os.getloadavg()`` is recorded beside them.

    python benchmarks/series_cost.py [--orders 5,7,10,15,20] [--out benchmarks/results/series_cost]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import subprocess
import sys
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent


def measure(order: int, mode: str, homotopy: str, repeats: int, warm: int) -> dict:
    """One variant, in this process: compile and per-series times (s and ms)."""
    sys.path.insert(0, str(HERE))
    import jax
    import profile_host_step

    import jaxanm
    from jaxanm import _series as series_module
    from jaxanm._problem import compiled
    from jaxanm._series import AffinePath

    if mode == "exact":
        series_module.EXACT_TERMS = 10**6

    lookahead = homotopy == "newton"
    with jaxanm.float64():
        scene, model, _, t, x, params = profile_host_step.warm_state(warm)
        args = (x, np.float64(t), np.float64(scene.time.dt), jax.device_put(params))
        rng = np.random.default_rng(0)
        cs = [1e-4 * model.scale() * rng.standard_normal(x.size) for _ in range(order - 1)]
        t0 = time.perf_counter()
        fns = compiled(model.residual).affine_functions(x, args)
        def series():
            path = AffinePath(fns, x, args, lookahead=lookahead, max_terms=order - 1)
            for c in cs:
                path.next(c)

        series()  # compiles every jet this series needs
        compile_s = time.perf_counter() - t0
        times = []
        for _ in range(repeats):
            t1 = time.perf_counter()
            series()
            times.append(time.perf_counter() - t1)
    import resource

    return {"order": order, "mode": mode, "homotopy": homotopy, "compile_s": compile_s,
            "series_ms": 1e3 * float(np.median(times)), "per_order_ms": 1e3 * float(np.median(times)) / (order - 1),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "load": os.getloadavg()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orders", default="5,7,10,15,20")
    ap.add_argument("--modes", default="exact,ladder")
    ap.add_argument("--homotopies", default="convex,newton")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--warm", type=int, default=3)
    ap.add_argument("--out", default=str(HERE / "results" / "series_cost"))
    ap.add_argument("--one", help=argparse.SUPPRESS)  # "order,mode,homotopy": run one variant here
    a = ap.parse_args(argv)
    if a.one:
        order, mode, homotopy = a.one.split(",")
        print(json.dumps(measure(int(order), mode, homotopy, a.repeats, a.warm)))
        return 0
    from jaxanm._series import EXACT_TERMS

    rows = []
    for order in (int(p) for p in a.orders.split(",")):
        for mode in a.modes.split(","):
            if mode == "exact" and order - 1 <= EXACT_TERMS and "ladder" in a.modes:
                continue  # the same jets as the ladder's
            for homotopy in a.homotopies.split(","):
                out = subprocess.run([sys.executable, __file__, "--one", f"{order},{mode},{homotopy}",
                                      "--repeats", str(a.repeats), "--warm", str(a.warm)],
                                     capture_output=True, text=True, check=True)
                row = json.loads(out.stdout.strip().splitlines()[-1])
                rows.append(row)
                print(f"p={order:2d} {mode:9s} {homotopy:6s} compile {row['compile_s']:6.1f} s  series "
                      f"{row['series_ms']:7.2f} ms ({row['per_order_ms']:.2f} ms/order)  "
                      f"rss {row['peak_rss_mb']:.0f} MB  load {row['load'][0]:.1f}", flush=True)
    out = pathlib.Path(a.out)
    payload = {"date": datetime.date.today().isoformat(), "cpus": os.cpu_count(), "rows": rows}
    out.with_suffix(".json").write_text(json.dumps(payload, indent=1))
    print(f"wrote {out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
