"""What one ANM series costs on ``fsw_paper``: cold compile and run time per order (issue 18).

For each order p and each homotopy, in a fresh subprocess (so that every compile is cold and
the peak memory is that variant's), on the state after ``--warm`` Newton steps of a
Lagrangian run (``benchmarks/profile_host_step.warm_state``): the compile time of everything
one series needs (the series start and the order program of ``jaxanm._series.AffinePath``:
one program for every order, the incremental Taylor arithmetic of ``jaxanm._taylor``), and
the time of the p - 1 calls of one series, for the convex homotopy (the residual's
coefficient ``[R]_{j-1}`` at order j) and the Newton homotopy (``[R]_j`` with the provisional
``c_j = c_{j-1}``, one more order).  The path coefficients are random (scaled like the
unknowns): the cost does not depend on their values.  Times are medians over ``--repeats``
series; ``os.getloadavg()`` is recorded beside them.

(Earlier engines, jets of the rest truncated at the terms known, one compiled per order or
per rung of a ladder of lengths, are no longer in the code; their rows in
benchmarks/results/series_cost.md were measured with the commits named there.)

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


def measure(order: int, homotopy: str, repeats: int, warm: int) -> dict:
    """One variant, in this process: compile and per-series times (s and ms)."""
    sys.path.insert(0, str(HERE))
    import jax
    import profile_host_step

    import jaxanm
    from jaxanm._problem import compiled
    from jaxanm._series import AffinePath

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

    return {"order": order, "homotopy": homotopy, "compile_s": compile_s,
            "series_ms": 1e3 * float(np.median(times)), "per_order_ms": 1e3 * float(np.median(times)) / (order - 1),
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "load": os.getloadavg()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--orders", default="5,7,10,15,20")
    ap.add_argument("--homotopies", default="convex,newton")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--warm", type=int, default=3)
    ap.add_argument("--out", default=str(HERE / "results" / "series_cost"))
    ap.add_argument("--one", help=argparse.SUPPRESS)  # "order,homotopy": run one variant here
    a = ap.parse_args(argv)
    if a.one:
        order, homotopy = a.one.split(",")
        print(json.dumps(measure(int(order), homotopy, a.repeats, a.warm)))
        return 0
    rows = []
    for order in (int(p) for p in a.orders.split(",")):
        for homotopy in a.homotopies.split(","):
            out = subprocess.run([sys.executable, __file__, "--one", f"{order},{homotopy}",
                                  "--repeats", str(a.repeats), "--warm", str(a.warm)],
                                 capture_output=True, text=True, check=True)
            row = json.loads(out.stdout.strip().splitlines()[-1])
            rows.append(row)
            print(f"p={order:2d} {homotopy:6s} compile {row['compile_s']:6.1f} s  series "
                  f"{row['series_ms']:7.2f} ms ({row['per_order_ms']:.2f} ms/order)  "
                  f"rss {row['peak_rss_mb']:.0f} MB  load {row['load'][0]:.1f}", flush=True)
    out = pathlib.Path(a.out)
    payload = {"date": datetime.date.today().isoformat(), "cpus": os.cpu_count(), "rows": rows}
    out.with_suffix(".json").write_text(json.dumps(payload, indent=1))
    print(f"wrote {out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
