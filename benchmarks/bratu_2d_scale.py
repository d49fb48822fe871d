"""The 2D Bratu problem at scale: the ANM (:func:`jaxanm.continuation`) against Keller's
pseudo-arclength Newton (:func:`jaxanm.newton_continuation`) through the fold, on m x m grids up
to 500 x 500 (250,000 unknowns), sparse Jacobian, no pattern given (found from the jaxpr).

Problem: ``Delta u + lam e^u = 0`` on the unit square, u = 0 on the boundary, 5-point Laplacian
on m x m interior points (h = 1 / (m + 1)), unknowns unscaled (``scale=None``: the defaults a
user starts with), tol 1e-8 for both methods; from rest to u(centre) = 1.5 (``stop_at``), past
the fold (u(centre) about 1.39 there).

Folds, each method's own way:

- ANM: the root of ``d lam / d a`` of the step's series (:meth:`jaxanm.Branch.limit_points`;
  lam is stationary there, so the series' truncation error barely reaches it);
- Newton: a fold event polished by Newton on the augmented system when the library reports
  events (``branch.events``), else the root of ``d lam / d a`` of its cubic Hermite interpolant
  (accurate only to the interpolation over the step holding it: then only the ``ds_max`` whose
  steps are short enough near the fold meet the accuracy).

Reference: the discrete fold solved directly, Newton on the Moore-Spence system ``R = 0``,
``R_u phi = 0``, ``l . phi = 1`` with the analytic Jacobian assembled in scipy (nothing of jaxanm
but its LU, :func:`jaxanm.factorize`), started from the ANM's fold.  A method's fold counts as
located when it is within ``ACCURACY`` (1e-6 relative) of it; Newton's best ``ds_max`` at a size
is the fastest of those that are.  The folds also converge to the continuum's, 6.808124 (the
unit square; Bratu-Gelfand), at second order: the fitted ``lam_h = lam* + C h^2`` is reported.

Each (size, method, ds_max) runs in a fresh process (``--case``): one run of one step compiles
what the timed run needs, then the timed run (warm: compiled, the nested-dissection ordering
kept from the one-step run dropped); the process's peak RSS (``ru_maxrss``, before the
reference is solved) and the load averages before and after go with it.  OpenBLAS's threads are
set by the command (``OPENBLAS_NUM_THREADS=1`` below, recorded): on this shared 2-core machine
its second thread waits for a core other work holds, which made a SuperLU solve and a dot
product 5x slower under a load of 5 (and the ANM's run at 14,400 unknowns 7x, Newton's 3.6x).  The ANM's
run at the largest size is profiled (cProfile: METIS ordering, SuperLU factorisation and solves,
jets, Jacobian, pattern, colouring).  Run under the machine's timing lock:

    OPENBLAS_NUM_THREADS=1 flock /work/timing.lock python benchmarks/bratu_2d_scale.py [--sizes 100 200 300 500]
        [--ds-max inf 30 10] [--out benchmarks/results/bratu_2d_scale]
"""

from __future__ import annotations

import argparse
import cProfile
import datetime
import functools
import json
import os
import pathlib
import pstats
import re
import resource
import subprocess
import sys
import time

import jax.numpy as jnp
import numpy as np
import scipy.sparse

import jaxanm
from jaxanm import _factorization

HERE = pathlib.Path(__file__).resolve().parent
TOL = 1e-8
STOP_U = 1.5
LAM_CONTINUUM = 6.808124  # the unit square's fold, to the digits quoted (+-5e-7)
ACCURACY = 1e-6  # relative error in the fold's lam that counts as located
PROFILED = {  # cProfile entries of the ANM's step: what each costs
    "METIS ordering": "nested_dissection",
    "SuperLU factorisation": "gstrf",
    "SuperLU solves": "'solve' of 'SuperLU' objects",
    "series (jets)": "_series.py:.*\\(next\\)",
    "Jacobian (coloured jvp)": "jacobian.py:.*\\(__call__\\)",
    "pattern from the jaxpr": "jacobian_pattern",
    "column colouring": "color_columns",
}


@functools.lru_cache(maxsize=None)
def residual_2d(m: int):
    """The discrete Bratu residual on m x m interior points of the unit square (one object per m,
    so that what a run compiled for it is found again by the next run)."""
    h = 1.0 / (m + 1)

    def residual(u, lam, params):
        grid = jnp.pad(u.reshape(m, m), 1)
        lap = (grid[2:, 1:-1] + grid[:-2, 1:-1] + grid[1:-1, 2:] + grid[1:-1, :-2] - 4.0 * grid[1:-1, 1:-1]) / h**2
        return (lap + lam * jnp.exp(grid[1:-1, 1:-1])).ravel()

    return residual


def centre(m: int) -> int:
    """The unknown at (or next to) the centre of the square."""
    return (m // 2) * m + m // 2


def run(method: str, m: int, ds_max: float, max_steps: int = 200) -> jaxanm.Branch:
    """One branch from rest to u(centre) = STOP_U (or ``max_steps``)."""
    residual = residual_2d(m)
    kwargs = dict(stop_at=(centre(m), STOP_U), max_steps=max_steps, tol=TOL, jacobian="sparse")
    if method == "anm":
        return jaxanm.continuation(residual, np.zeros(m * m), 0.0, **kwargs)
    return jaxanm.newton_continuation(residual, np.zeros(m * m), 0.0, ds_max=ds_max, **kwargs)


def fold(branch: jaxanm.Branch) -> tuple[float, str]:
    """The branch's fold lam and how it was located (module docstring)."""
    events = [e for e in getattr(branch, "events", ()) if e.kind == "fold"]
    if events:
        return float(events[0].lam), f"event ({events[0].data.get('located', 'series')})"
    folds = branch.limit_points()
    return (float(folds.lam[0]) if folds.lam.size else float("nan")), (
        "series" if branch.method == "anm" else "hermite")


def laplacian(m: int) -> scipy.sparse.csr_matrix:
    """The 5-point Laplacian on m x m interior points (Dirichlet), scipy."""
    h = 1.0 / (m + 1)
    line = scipy.sparse.diags([1.0, -2.0, 1.0], [-1, 0, 1], shape=(m, m))
    eye = scipy.sparse.identity(m)
    return ((scipy.sparse.kron(line, eye) + scipy.sparse.kron(eye, line)) / h**2).tocsr()


def reference_fold(m: int, branch: jaxanm.Branch) -> tuple[float, int]:
    """The discrete fold by Newton on the Moore-Spence system (module docstring), from the fold
    of the ANM ``branch``: ``(lam, iterations)``."""
    found = branch.limit_points()
    s = float(found.s[0])
    lam, u = float(found.lam[0]), found.u[0]
    ahead, behind = branch.evaluate([s + 1e-3, s - 1e-3])[1]
    phi = (ahead - behind) / np.linalg.norm(ahead - behind)
    ell, lap, n = phi.copy(), laplacian(m), m * m
    stats = jaxanm.Stats()
    for iteration in range(1, 21):
        e = np.exp(u)
        jac = lap + scipy.sparse.diags(lam * e)
        rhs = np.concatenate([lap @ u + lam * e, jac @ phi, [ell @ phi - 1.0]])
        system = scipy.sparse.bmat([
            [jac, None, e[:, None]],
            [scipy.sparse.diags(lam * e * phi), jac, (e * phi)[:, None]],
            [None, ell[None, :], None]], format="csc")
        step = jaxanm.factorize(system, stats).solve(-rhs)
        u, phi, lam = u + step[:n], phi + step[n:2 * n], lam + step[-1]
        if abs(step[-1]) <= 1e-14 * abs(lam) and np.max(np.abs(step[:n])) <= 1e-12 * np.max(np.abs(u)):
            return lam, iteration
    raise RuntimeError(f"Moore-Spence Newton did not converge at m = {m}")


def profiled_run(method: str, m: int, ds_max: float) -> tuple[jaxanm.Branch, float, dict]:
    """The timed run under cProfile: the branch, its wall and the seconds of :data:`PROFILED`."""
    profile = cProfile.Profile()
    start = time.perf_counter()
    profile.enable()
    branch = run(method, m, ds_max)
    profile.disable()
    wall = time.perf_counter() - start
    table = pstats.Stats(profile).stats
    split = {}
    for name, pattern in PROFILED.items():
        keys = [k for k in table if re.search(pattern, f"{k[0]}:{k[1]}({k[2]})") or re.search(pattern, k[2])]
        split[name] = round(max((table[k][3] for k in keys), default=0.0), 3)
    return branch, wall, split


def case(method: str, m: int, ds_max: float, profile: bool, reference: bool) -> dict:
    """One (size, method, ds_max) in this process: warm-up, timed run, peak RSS, fold."""
    load = [os.getloadavg()[0]]
    start = time.perf_counter()
    run(method, m, ds_max, max_steps=1)  # compiles what the timed run needs (one step)
    compile_s = time.perf_counter() - start
    _factorization._ORDERINGS.clear()  # the timed run orders its matrices itself, as a first call does
    if profile:
        branch, wall, split = profiled_run(method, m, ds_max)
    else:
        start = time.perf_counter()
        branch = run(method, m, ds_max)
        wall, split = time.perf_counter() - start, {}
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    load.append(os.getloadavg()[0])
    lam, located = fold(branch)
    st = branch.stats
    out = {
        "m": m, "n": m * m, "method": method, "ds_max": ds_max, "wall_s": wall, "first_step_s": compile_s,
        "factorizations": st.factorizations, "steps": int(branch.a.size), "newton_iterations": st.newton_iterations,
        "series_orders": st.series_orders, "solves": st.solves, "rejected_steps": st.rejected_steps,
        "stopped": branch.stopped, "fold_lam": lam, "fold_located": located, "peak_rss_bytes": rss,
        "wall_split_s": {k: round(v, 3) for k, v in st.wall_time.items()}, "profile_s": split, "loadavg": load,
    }
    if reference:
        out["reference_lam"], out["reference_iterations"] = reference_fold(m, branch)
    return out


def spawn(args: list[str]) -> dict:
    """A case in a fresh process; its last line of output is the case's JSON."""
    done = subprocess.run([sys.executable, __file__, *args], check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def fit_continuum(rows: list) -> dict:
    """``lam_h = lam* + C h^2 + D h^4`` fitted to the reference folds (least squares)."""
    h = np.array([1.0 / (r["m"] + 1) for r in rows])
    lam = np.array([r["reference_lam"] for r in rows])
    coeffs, *_ = np.linalg.lstsq(np.column_stack([np.ones_like(h), h**2, h**4]), lam, rcond=None)
    return {"lam_star": float(coeffs[0]), "C": float(coeffs[1]), "D": float(coeffs[2]),
            "lam_star_minus_continuum": float(coeffs[0] - LAM_CONTINUUM)}


def markdown(results: dict) -> str:
    """The results as a markdown page."""
    lines = [
        "# The 2D Bratu problem at scale: ANM against Keller's Newton through the fold",
        "",
        f"Made by `{results['command']}` on {results['date']} ({results['cpus']} CPUs; 1-minute load average "
        "before and after each case in the table). `Delta u + lam e^u = 0` on the unit square, 5-point "
        f"Laplacian on m x m points, sparse Jacobian with its pattern found from the residual's jaxpr, "
        f"unscaled unknowns, tol {TOL:g}, from rest to u(centre) = {STOP_U}. Each row is a fresh process: "
        "a one-step run compiles, then the timed (warm) run; peak RSS is that process's. The fold's lam "
        "against the discrete fold solved directly (Moore-Spence Newton, scipy's analytic Jacobian); "
        f"Newton's best ds_max is its fastest run within {ACCURACY:g} of it.",
        "",
        "| m | N | method | ds_max | wall (s) | factorisations | steps | Newton it. | fold lam | located | "
        "rel. error | peak RSS (MB) | RSS / N (kB) | load |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results["cases"]:
        error = abs(r["fold_lam"] - r["reference_lam"]) / r["reference_lam"]
        lines.append(
            f"| {r['m']} | {r['n']} | {r['method']} | {'' if r['method'] == 'anm' else r['ds_max']} "
            f"| {r['wall_s']:.2f} | {r['factorizations']} | {r['steps']} | {r['newton_iterations']} "
            f"| {r['fold_lam']:.9f} | {r['fold_located']} | {error:.1e} | {r['peak_rss_bytes'] / 2**20:.0f} "
            f"| {r['peak_rss_bytes'] / r['n'] / 1024:.1f} | {r['loadavg'][0]:.1f}-{r['loadavg'][1]:.1f} |")
    lines += ["", "Per size: the ANM against Newton at its best ds_max (fastest within the accuracy).", "",
              "| N | reference fold | ANM wall (s) | Newton best ds_max | Newton wall (s) | Newton / ANM "
              "| factorisations ANM / Newton |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for s in results["summary"]:
        lines.append(f"| {s['n']} | {s['reference_lam']:.9f} | {s['anm_wall_s']:.2f} | {s['newton_ds_max']} "
                     f"| {s['newton_wall_s']:.2f} | {s['ratio']:.1f} | {s['anm_factorizations']} / "
                     f"{s['newton_factorizations']} |")
    fit = results["continuum_fit"]
    largest = max(results["cases"], key=lambda r: (r["n"], r["method"] == "anm"))
    lines += [
        "", f"Continuum: the reference folds fit `lam_h = {fit['lam_star']:.7f} + ({fit['C']:.4f}) h^2 + "
        f"({fit['D']:.3g}) h^4`; the extrapolated fold is {fit['lam_star_minus_continuum']:+.1e} from 6.808124.",
        "", f"Where the ANM's timed run spends its time at N = {largest['n']} (cProfile, cumulative seconds; "
        f"wall {largest['wall_s']:.2f} s; Stats split {largest['wall_split_s']}):", "",
        "| part | s |", "| --- | --- |"]
    lines += [f"| {k} | {v} |" for k, v in largest["profile_s"].items()]
    return "\n".join(lines) + "\n"


def summary(cases: list) -> list:
    """Per size: the ANM and the fastest Newton within ACCURACY of the reference."""
    rows = []
    for n in sorted({c["n"] for c in cases}):
        anm = next(c for c in cases if c["n"] == n and c["method"] == "anm")
        located = [c for c in cases if c["n"] == n and c["method"] == "newton"
                   and abs(c["fold_lam"] - c["reference_lam"]) <= ACCURACY * c["reference_lam"]]
        best = min(located, key=lambda c: c["wall_s"]) if located else None
        rows.append({"n": n, "reference_lam": anm["reference_lam"], "anm_wall_s": anm["wall_s"],
                     "anm_factorizations": anm["factorizations"],
                     "newton_ds_max": best["ds_max"] if best else "none within accuracy",
                     "newton_wall_s": best["wall_s"] if best else float("nan"),
                     "newton_factorizations": best["factorizations"] if best else -1,
                     "ratio": best["wall_s"] / anm["wall_s"] if best else float("nan")})
    return rows


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 200, 300, 500])
    parser.add_argument("--ds-max", type=float, nargs="+", default=[np.inf, 30.0, 10.0])
    parser.add_argument("--out", default=str(HERE / "results" / "bratu_2d_scale"))
    parser.add_argument("--case", choices=["anm", "newton"], help=argparse.SUPPRESS)
    parser.add_argument("--m", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--profile", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--reference", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:  # one case, in this fresh process
        print(json.dumps(case(args.case, args.m, args.ds_max[0], args.profile, args.reference)))
        return
    cases = []
    for m in args.sizes:
        anm = spawn(["--case", "anm", "--m", str(m), "--reference"]
                    + (["--profile"] if m == max(args.sizes) else []))
        cases.append(anm)
        print(f"m = {m}: anm {anm['wall_s']:.2f} s, {anm['factorizations']} LU, fold {anm['fold_lam']:.9f} "
              f"(reference {anm['reference_lam']:.9f})", flush=True)
        for ds_max in args.ds_max:
            newton = spawn(["--case", "newton", "--m", str(m), "--ds-max", str(ds_max)])
            newton["reference_lam"] = anm["reference_lam"]
            cases.append(newton)
            print(f"m = {m}: newton ds_max {ds_max:g} {newton['wall_s']:.2f} s, {newton['factorizations']} LU, "
                  f"fold {newton['fold_lam']:.9f} ({newton['fold_located']})", flush=True)
    threads = os.environ.get("OPENBLAS_NUM_THREADS")
    command = (f"OPENBLAS_NUM_THREADS={threads} " if threads else "") + \
        "flock /work/timing.lock python benchmarks/bratu_2d_scale.py " + " ".join(sys.argv[1:])
    results = {"date": datetime.date.today().isoformat(), "cpus": os.cpu_count(), "command": command.strip(),
               "tol": TOL, "accuracy": ACCURACY, "cases": cases, "summary": summary(cases),
               "continuum_fit": fit_continuum([c for c in cases if c["method"] == "anm"])}
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(results, indent=1) + "\n")
    out.with_suffix(".md").write_text(markdown(results))
    print(f"wrote {out}.md and .json")


if __name__ == "__main__":
    main()
