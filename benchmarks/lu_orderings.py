"""Sparse LU of the fsw_paper tangent: fill and time per column ordering, renumbering, solver.

Issue 14, item 2.  Builds the tangent ``dR/dx`` of ``fsw_paper`` once (3 Newton steps from rest,
then :class:`jaxanm.SparseJacobian` at the last state, as the solvers do) and measures, for every
variant, the factorisation time, ``nnz(L + U)`` and the time of ``p`` single right-hand-side
solves (one per series order of an ANM step), as medians over ``--repeats`` rounds in which the
variants take turns (back to back, so that the machine's load hits all alike).  Accuracy: the
relative residual ``|A x - b|_inf / (|A|_inf |x|_inf)`` of a random right-hand side and the
difference from the solution of SuperLU with MMD_ATA and partial pivoting (the choice before
issue 14; :func:`jaxanm._factorization.sparse_lu` is the variant "MMD_AT_PLUS_A symmetric, pivot 0.1").

Variants:

- SuperLU with ``permc_spec`` NATURAL, MMD_ATA, MMD_AT_PLUS_A, COLAMD; MMD_AT_PLUS_A with
  ``SymmetricMode`` and smaller ``diag_pivot_thresh`` (partial pivoting relaxed);
- the same after renumbering the points by reverse Cuthill-McKee on the point adjacency
  (a symmetric permutation of the matrix), with the unknowns field by field ("rcm") or point by
  point ("rcm-interleaved");
- KLU (``pip install pyklu``, a 0.5 MB wheel with SuiteSparse inside), if importable;
- PARDISO (``pip install pypardiso``, which pulls MKL: a 229 MB wheel, 718 MB installed, and
  intel-openmp, 50 MB), if importable; it uses the machine's threads.

    python benchmarks/lu_orderings.py [--repeats 7] [--order 7] [--out benchmarks/results/lu_orderings]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import pathlib
import sys
import time

import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import scipy.sparse.linalg

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import profile_host_step  # noqa: E402

import jaxanm  # noqa: E402

REFERENCE = "MMD_ATA"
"""The ordering the solutions are compared with (SuperLU's choice in jaxanm before issue 14)."""


def fsw_paper_tangent(warm: int = 3):
    """``(A, point_pattern, n_fields)``: the tangent (CSC) and the (N, N) point coupling pattern."""
    with jaxanm.float64():
        scene, model, _, t, x, params = profile_host_step.warm_state(warm)
        pattern = model.sparsity(params)
        jac = jaxanm.SparseJacobian(model.residual, pattern)
        dt = np.float64(scene.time.dt)
        A = scipy.sparse.csc_matrix(jac(x, x, np.float64(t), dt, params))
    N = model.cloud.size
    return A, scipy.sparse.csr_matrix(pattern[:N, :N]), len(model.fields)


def renumbering(point_pattern, n_fields: int, interleaved: bool) -> np.ndarray:
    """Unknown permutation from reverse Cuthill-McKee on the point adjacency."""
    N = point_pattern.shape[0]
    sym = scipy.sparse.csr_matrix(point_pattern + point_pattern.T)
    perm = scipy.sparse.csgraph.reverse_cuthill_mckee(sym, symmetric_mode=True).astype(np.int64)
    if interleaved:
        return (perm[:, None] + N * np.arange(n_fields)[None, :]).reshape(-1)
    return np.concatenate([f * N + perm for f in range(n_fields)])


class _SuperLU:
    def __init__(self, spec, **kw):
        self.spec, self.kw = spec, kw

    def factor(self, A):
        lu = scipy.sparse.linalg.splu(A, permc_spec=self.spec, **self.kw)
        return lu, lu.solve, lu.L.nnz + lu.U.nnz


class _KLU:
    def __init__(self):
        from PyKLU import Klu
        self.Klu = Klu

    def factor(self, A):
        A = scipy.sparse.csc_matrix(A)
        A.indices, A.indptr = A.indices.astype(np.int32), A.indptr.astype(np.int32)
        lu = self.Klu(A)
        return lu, lu.solve, None


class _Pardiso:
    def __init__(self):
        import pypardiso
        self.pypardiso = pypardiso

    def factor(self, A):
        solver = self.pypardiso.PyPardisoSolver()
        A = scipy.sparse.csr_matrix(A)
        solver.factorize(A)

        def solve(b):  # phase 33 (solve) directly: solver.solve hashes A on every call
            solver.set_phase(33)
            return solver._call_pardiso(A, np.asfortranarray(b))

        return solver, solve, None


def variants(point_pattern, n_fields):
    """``[(name, solver, permutation or None)]``."""
    perms = {"": None, "rcm": renumbering(point_pattern, n_fields, False),
             "rcm-interleaved": renumbering(point_pattern, n_fields, True)}
    out = []
    for pname, perm in perms.items():
        for spec in ("NATURAL", "MMD_ATA", "MMD_AT_PLUS_A", "COLAMD"):
            out.append(((f"{pname} " if pname else "") + spec, _SuperLU(spec), perm))
        for thresh in (1.0, 0.1, 0.01):
            out.append(((f"{pname} " if pname else "") + f"MMD_AT_PLUS_A symmetric, pivot {thresh:g}",
                        _SuperLU("MMD_AT_PLUS_A", diag_pivot_thresh=thresh, options=dict(SymmetricMode=True)), perm))
    try:
        klu = _KLU()
    except ImportError:
        print("KLU not measured: pip install pyklu", file=sys.stderr)
    else:
        out += [("KLU", klu, None), ("rcm KLU", klu, perms["rcm"]),
                ("rcm-interleaved KLU", klu, perms["rcm-interleaved"])]
    try:
        pardiso = _Pardiso()
    except (ImportError, OSError):
        print("PARDISO not measured: pip install pypardiso (pulls MKL)", file=sys.stderr)
    else:
        out += [("PARDISO (MKL)", pardiso, None)]
    return out


def measure(A, point_pattern, n_fields, repeats: int, order: int) -> list:
    """One row per variant: medians of factorise and ``order`` solves, fill and accuracy."""
    rng = np.random.default_rng(0)
    b = rng.standard_normal(A.shape[0])
    x_ref = scipy.sparse.linalg.splu(A, permc_spec=REFERENCE).solve(b)
    norm_A = scipy.sparse.linalg.norm(A, np.inf)
    rows = []
    setups = variants(point_pattern, n_fields)
    mats = {id(perm): (A if perm is None else scipy.sparse.csc_matrix(A[perm][:, perm])) for _, _, perm in setups}
    times = {name: {"factor": [], "solves": []} for name, _, _ in setups}
    results = {}
    for _ in range(repeats):
        for name, solver, perm in setups:
            M = mats[id(perm)]
            rhs = [b if perm is None else b[perm]] + [rng.standard_normal(A.shape[0]) for _ in range(order - 1)]
            t0 = time.perf_counter()
            _, solve, fill = solver.factor(M)
            t1 = time.perf_counter()
            sols = [solve(r) for r in rhs]
            t2 = time.perf_counter()
            times[name]["factor"].append(t1 - t0)
            times[name]["solves"].append(t2 - t1)
            x = sols[0] if perm is None else np.empty_like(sols[0])
            if perm is not None:
                x[perm] = sols[0]
            results[name] = (fill, x)
    for name, _, _ in setups:
        fill, x = results[name]
        f, s = np.median(times[name]["factor"]), np.median(times[name]["solves"])
        rows.append(
            {
                "variant": name,
                "factorize_ms": 1e3 * f,
                "solves_ms": 1e3 * s,
                "total_ms": 1e3 * (f + s),
                "nnz_LU": fill,
                "residual": float(np.abs(A @ x - b).max() / (norm_A * np.abs(x).max())),
                "diff_from_reference": float(np.abs(x - x_ref).max() / np.abs(x_ref).max()),
            }
        )
    return rows


def write(rows, meta, out: pathlib.Path) -> None:
    """``OUT.json`` and ``OUT.md``."""
    out.with_suffix(".json").write_text(json.dumps({**meta, "rows": rows}, indent=1) + "\n")
    p = meta["order"]
    lines = [
        "# Sparse LU of the fsw_paper tangent: orderings, renumbering, solvers",
        "",
        f"Made by `python benchmarks/lu_orderings.py` (issue 14, item 2) on {meta['date']}: the tangent "
        f"after 3 Newton steps from rest ({meta['n']} unknowns, {meta['nnz']} non-zeros); medians of "
        f"{meta['repeats']} rounds, the variants back to back in each round; load average (1 min) "
        f"{meta['loadavg']}.  `solves` is {p} single right-hand-side solves (one ANM step at order {p}); "
        "`residual` is |A x - b|_inf / (|A|_inf |x|_inf) for a random b, `diff` the largest "
        f"difference from {meta['reference']} with partial pivoting (the earlier choice) relative to max |x|.  "
        "`rcm`: points "
        "renumbered by reverse Cuthill-McKee, unknowns field by field; `rcm-interleaved`: point by point.",
        "",
        "| variant | factorise (ms) | solves (ms) | total (ms) | nnz(L+U) | residual | diff |",
        "| --- | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for r in sorted(rows, key=lambda r: r["total_ms"]):
        fill = "n/a" if r["nnz_LU"] is None else f"{r['nnz_LU'] / 1e6:.3f}e6"
        lines.append(
            f"| {r['variant']} | {r['factorize_ms']:.1f} | {r['solves_ms']:.2f} | {r['total_ms']:.1f} | "
            f"{fill} | {r['residual']:.1e} | {r['diff_from_reference']:.1e} |"
        )
    if meta.get("note"):
        lines += ["", meta["note"]]
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")


def main() -> None:
    """Command line: ``--repeats``, ``--order``, ``--out``, ``--note``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--order", type=int, default=7)
    ap.add_argument("--out", default=str(profile_host_step.RESULTS / "lu_orderings"))
    ap.add_argument("--note", default="")
    args = ap.parse_args()
    A, point_pattern, n_fields = fsw_paper_tangent()
    load0 = os.getloadavg()[0]
    rows = measure(A, point_pattern, n_fields, args.repeats, args.order)
    load = f"{load0:.2f} -> {os.getloadavg()[0]:.2f}"
    for r in sorted(rows, key=lambda r: r["total_ms"]):
        fill = "n/a" if r["nnz_LU"] is None else f"{r['nnz_LU']:9d}"
        print(
            f"{r['variant']:<50} factor {r['factorize_ms']:7.1f} ms  {args.order} solves {r['solves_ms']:6.2f} ms  "
            f"nnz(L+U) {fill}  residual {r['residual']:.1e}  diff {r['diff_from_reference']:.1e}"
        )
    print(f"load average (1 min): {load}")
    meta = {
        "date": datetime.date.today().isoformat(),
        "loadavg": load,
        "repeats": args.repeats,
        "order": args.order,
        "n": A.shape[0],
        "nnz": int(A.nnz),
        "reference": REFERENCE,
        "note": args.note,
    }
    write(rows, meta, pathlib.Path(args.out))


if __name__ == "__main__":
    main()
