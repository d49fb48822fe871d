"""The Lagrangian host hook of ``fsw_paper`` timed inside a real run (issue 14, item 1).

``benchmarks/profile_host_step.py`` times each part of one hook call many times on the same
state; this script times the hook and its main parts at every step of an actual run, where
the solver's series and triangular solves run between two hooks (and take the caches).  It
wraps, for the run only, the hook (``RunRecorder.after_step``), the stencil rebuild (and
inside it the MLS kernel and the neighbour query), the refit (``Model.fit_state``), the field
values and the shear test, and prints median and mean wall time per call.

    python benchmarks/hook_in_run.py --t-end 0.05

A first run of 3 ms compiles; the timed run starts from rest like ``jaxanm run fsw_paper``.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import os
import time

import numpy as np

from jaxanm import mls
from jaxanm.fsw import discretisation, lagrangian, load_scene, run

PARTS = [  # (owner, attribute, label); indented labels are parts of the row above
    (lagrangian.RunRecorder, "after_step", "hook (after_step)"),
    (discretisation.Model, "values", "  values at the points"),
    (lagrangian.RunRecorder, "_sheared", "  shear test"),
    (lagrangian, "cloud_stencils", "  stencil rebuild"),
    (mls.NeighbourList, "query", "    neighbour query"),
    (mls, "_run_kernel", "    MLS kernel"),
    (discretisation.Model, "fit_state", "  refit"),
]


@contextlib.contextmanager
def timed(times: dict):
    """Within the block, every call of each :data:`PARTS` entry appends its wall time to
    ``times[label]``; the originals are restored on exit."""
    originals = [(owner, name, getattr(owner, name)) for owner, name, _ in PARTS]

    def wrapper(fn, label):
        def call(*args, **kwargs):
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                times[label].append(time.perf_counter() - t0)
        return call

    try:
        for (owner, name, fn), (_, _, label) in zip(originals, PARTS):
            setattr(owner, name, wrapper(fn, label))
        yield times
    finally:
        for owner, name, fn in originals:
            setattr(owner, name, fn)


def main() -> None:
    """Command line: ``--t-end`` of the timed run."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-end", type=float, default=0.05)
    args = ap.parse_args()
    run(load_scene("fsw_paper").with_overrides({"time.t_end": 0.003}))  # compile
    times = collections.defaultdict(list)
    load = os.getloadavg()[0]
    with timed(times):
        result = run(load_scene("fsw_paper").with_overrides({"time.t_end": args.t_end}))
    print(f"fsw_paper to t = {args.t_end:g} s: {result.stats.time_steps} steps, "
          f"load {load:.2f} -> {os.getloadavg()[0]:.2f}")
    for _, _, label in PARTS:
        ms = 1e3 * np.asarray(times[label])
        print(f"{label:24s} {len(ms):5d} calls  median {np.median(ms):6.3f} ms  mean {ms.mean():6.3f} ms")


if __name__ == "__main__":
    main()
