"""The sparse LU's two orderings on the FSW tangents of finer clouds: symmetric mode against nested dissection.

:func:`jaxanm._factorization.sparse_lu` factorises in SuperLU's symmetric mode (minimum degree on
A + A^T, diagonal pivots) up to ``SYMMETRIC_MAX_UNKNOWNS`` unknowns and by nested dissection
(METIS) above.  This script takes the first K* each run factorises (the start flow's, then the
first step's; captured by wrapping ``sparse_lu``, the runs stopped there) and factorises each
both ways, ``--repeats`` times, back to back: the median factorisation time, one solve, the
fill ``nnz(L + U)`` against ``nnz(A)``, the pivots symmetric mode took off the diagonal and the
relative residual ``|A x - b|_inf / (|A|_inf |x|_inf)`` of a random right-hand side.

Matrices: fsw_tracers (the paper's physics on fixed uniform points, from rest) at dr, dr/2 and
dr/4, and the main job on its cloud (the start flow's K* of u, v and the first step's of
u, v, T).

    python benchmarks/lu_at_size.py [--repeats 3] [--skip-dr4] [--out benchmarks/results/lu_at_size]
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import time

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

import jaxanm
from jaxanm import _factorization
from jaxanm.fsw import simulate
from jaxanm.fsw.scene import load_scene

CASES = [
    # label, scene, overrides, which of the run's factorisations (0: the first)
    ("fsw_tracers, dr (from rest)", "fsw_tracers", {"geometry.dr": 3.75e-4}, 0),
    ("fsw_tracers, dr/2 (from rest)", "fsw_tracers", {"geometry.dr": 1.875e-4}, 0),
    ("fsw_tracers, dr/4 (from rest)", "fsw_tracers", {"geometry.dr": 9.375e-5}, 0),
    ("fsw, start flow (u, v)", "fsw", {}, 0),
    ("fsw, first step (u, v, T)", "fsw", {}, "step"),
]


class _Captured(Exception):
    """Stops a run once the matrix asked for is factorised."""


def capture(scene_name: str, overrides: dict, which) -> scipy.sparse.csc_matrix:
    """The K* a run of ``scene_name`` factorises first (``which = 0``) or at its first step."""
    seen = []
    original = _factorization.sparse_lu
    shape = {}

    def wrapped(matrix):
        matrix = scipy.sparse.csc_matrix(matrix)
        seen.append(matrix)
        if which == 0 or (which == "step" and matrix.shape[0] != shape.setdefault("first", matrix.shape[0])):
            raise _Captured
        return original(matrix)

    _factorization.sparse_lu = wrapped
    try:
        simulate.run(load_scene(scene_name).with_overrides({**overrides, "time.t_end": 1e-3}))
    except _Captured:
        pass
    finally:
        _factorization.sparse_lu = original
    return seen[-1]


def measure(matrix, repeats: int) -> dict:
    """Both orderings of ``matrix``, back to back, ``repeats`` times each."""
    rhs = np.random.default_rng(0).standard_normal(matrix.shape[0])
    out = {"unknowns": matrix.shape[0], "nnz": int(matrix.nnz)}
    variants = {
        "symmetric": lambda: scipy.sparse.linalg.splu(matrix, permc_spec=_factorization.PERMC_SPEC,
                                                      diag_pivot_thresh=_factorization.DIAG_PIVOT_THRESH,
                                                      options=dict(_factorization.SUPERLU_OPTIONS)),
        "nested dissection": lambda: _factorization.NestedDissectionLU(matrix),
    }
    _factorization.nested_dissection(matrix)  # METIS once, outside the timings (kept per pattern)
    times: dict = {name: [] for name in variants}
    for _ in range(repeats):
        for name, make in variants.items():
            start = time.perf_counter()
            lu = make()
            times[name].append(time.perf_counter() - start)
            start = time.perf_counter()
            x = lu.solve(rhs)
            solve = time.perf_counter() - start
            residual = np.max(np.abs(matrix @ x - rhs)) / (abs(matrix).max() * np.max(np.abs(x)))
            entry = {"factorise_s": None, "solve_ms": 1e3 * solve, "fill": int(lu.L.nnz + lu.U.nnz),
                     "residual": float(residual)}
            if name == "symmetric":
                entry["off_diagonal_pivots"] = int(np.count_nonzero(lu.perm_r != lu.perm_c))
            out[name] = entry
    for name in variants:
        out[name]["factorise_s"] = float(np.median(times[name]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--skip-dr4", action="store_true", help="leave out fsw_tracers at dr/4 (39,519 unknowns)")
    parser.add_argument("--out", default="benchmarks/results/lu_at_size")
    args = parser.parse_args()
    rows = []
    for label, scene, overrides, which in CASES:
        if args.skip_dr4 and "dr/4" in label:
            continue
        with jaxanm.float64():
            matrix = capture(scene, overrides, which)
        rows.append({"label": label, **measure(matrix, args.repeats), "load": os.getloadavg()[0]})
        print(rows[-1], flush=True)
    out = pathlib.Path(args.out)
    out.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    lines = ["# The sparse LU's orderings on finer FSW tangents (`benchmarks/lu_at_size.py`)", "",
             f"`python benchmarks/lu_at_size.py --repeats {args.repeats}`: the first K* of each run, both orderings "
             "back to back in one process (medians of the repeats; METIS's ordering made once before the timings, as "
             "a run keeps it per pattern); `OPENBLAS_NUM_THREADS=1`; 1-minute load per row in the JSON.", "",
             "| matrix | unknowns | nnz(A) | symmetric: factorise s | fill (x nnz A) | off-diagonal pivots | solve ms "
             "| nested dissection: factorise s | fill (x nnz A) | solve ms | symmetric / ND time |",
             "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        s, n = r["symmetric"], r["nested dissection"]
        lines.append(f"| {r['label']} | {r['unknowns']} | {r['nnz'] / 1e6:.2f}e6 | {s['factorise_s']:.3f} | "
                     f"{s['fill'] / 1e6:.2f}e6 ({s['fill'] / r['nnz']:.1f}) | {s['off_diagonal_pivots']} | "
                     f"{s['solve_ms']:.2f} | {n['factorise_s']:.3f} | "
                     f"{n['fill'] / 1e6:.2f}e6 ({n['fill'] / r['nnz']:.1f}) | {n['solve_ms']:.2f} | "
                     f"{s['factorise_s'] / n['factorise_s']:.2f} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
