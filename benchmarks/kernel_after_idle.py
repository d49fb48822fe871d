"""Why the Lagrangian hook costs more inside a run than in its profile (issue 14, item 1).

``benchmarks/hook_in_run.py`` finds every part of the hook 1.2-2.4x slower in a run than in
``benchmarks/profile_host_step.py``.  This script times the hook's XLA kernels and its SuperLU
solves on fsw_paper's cloud in four conditions, medians over ``--repeats`` calls:

- back to back (what a profile repeating one call measures);
- after 5 ms asleep (the main thread idle, as while it waits for a solve elsewhere);
- after 5 ms of a busy Python loop on the main thread (no memory traffic);
- after reading 64 MB (the caches refilled with other data, as by a solver step).

    python benchmarks/kernel_after_idle.py
    taskset -c 0 python benchmarks/kernel_after_idle.py   # the same on one CPU

The compiled MLS kernels (:func:`jaxanm.mls._kernel.run_kernel`, ``compiled=True``, as a
moving cloud runs them) are called with the inputs a stencil rebuild of the cloud gives them;
the solves are the refit's (7 solves of 3 right-hand sides with the SuperLU factors of the
value matrix).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from jaxanm._factorization import sparse_lu
from jaxanm.fsw import discretise, load_scene
from jaxanm.fsw.geometry import cloud_stencils
from jaxanm.mls import _stencils, value_matrix
from jaxanm.mls._kernel import run_kernel


def kernel_inputs(points, n_tool, geometry, m_max):
    """The arguments :func:`jaxanm.mls._kernel.run_kernel` gets in a rebuild of the cloud's stencils."""
    captured = []
    original = _stencils.run_kernel  # the name the stencil builder calls

    def capture(*args):
        captured.append(args)
        return original(*args)

    _stencils.run_kernel = capture
    try:
        cloud_stencils(points, n_tool, geometry, m_max=m_max)
    finally:
        _stencils.run_kernel = original
    return captured[0][:6]  # x, y, mask, h, c, q (without the derivatives flag)


def busy(seconds: float) -> None:
    """A Python loop on the main thread for ``seconds``."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def median_ms(fn, before, repeats: int) -> float:
    """Median wall time of ``fn()`` in ms, each call preceded by ``before()`` (not timed)."""
    times = []
    for _ in range(repeats):
        before()
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def main() -> None:
    """Command line: ``--repeats``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=200)
    args = ap.parse_args()
    scene = load_scene("fsw_paper")
    cloud, stencils, _, _, _ = discretise(scene)
    inputs = kernel_inputs(cloud.points, cloud.n_tool, scene.geometry, stencils.index.shape[1])
    lu = sparse_lu(value_matrix(stencils))
    rhs = np.random.default_rng(0).random((cloud.size, 3))
    memory = np.ones(8_000_000)  # 64 MB, more than this machine's caches

    def kernel():
        np.asarray(run_kernel(*inputs, derivatives=True, compiled=True)[0])

    def value_kernel():
        np.asarray(run_kernel(*inputs, derivatives=False, compiled=True)[0])

    def solves():
        for _ in range(7):
            lu.solve(rhs)

    parts = {"MLS kernel (value and derivatives)": kernel, "MLS kernel (values only)": value_kernel,
             "7 refit solves (3 right-hand sides)": solves}
    conditions = {"back to back": lambda: None, "after 5 ms asleep": lambda: time.sleep(0.005),
                  "after 5 ms busy": lambda: busy(0.005), "after reading 64 MB": memory.sum}
    for fn in parts.values():  # compile and warm up
        for _ in range(20):
            fn()
    load = os.getloadavg()[0]
    print(f"fsw_paper, {cloud.size} points; CPUs available: {len(os.sched_getaffinity(0))}; "
          f"median wall ms of {args.repeats} calls")
    print(f"{'':40s}" + "".join(f"{c:>22s}" for c in conditions))
    for name, fn in parts.items():
        print(f"{name:40s}" + "".join(f"{median_ms(fn, before, args.repeats):22.3f}" for before in conditions.values()))
    print(f"load average (1 min): {load:.2f} -> {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
