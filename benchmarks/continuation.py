"""Path following by the ANM against pseudo-arclength Newton: factorisations, steps, series
orders and wall time, cold and warm, on the problems of ``tests/test_continuation.py``.

- Bratu 1D, ``u'' + lam e^u = 0`` by central differences on N = 19, 39, 63, 79 interior points,
  from rest through the fold to u(1/2) = 2 (``stop_at``), u scaled by sqrt(N);
- the two-bar truss (half-span 1, rise 0.1, EA = 1) from rest through both limit points to
  P = 2 P* on the stiffening branch (``lam_end``);
- Bratu 2D on the unit square, 5-point Laplacian on 20 x 20 points (400 unknowns, dense) and
  on 50 x 50 points (2500 unknowns, sparse: coloured Jacobian with its pattern found from the
  residual's jaxpr, no pattern given; SuperLU of the bordered CSC matrix), from rest through
  the fold to u = 3 at the centre, u scaled by m.

Methods: :func:`jaxanm.continuation` at orders 8 and 15 (the default), tol 1e-8 (eq. 26), and
:func:`jaxanm.newton_continuation` with its defaults (tol 1e-8, ds 0.1, no ds_max, target 4
iterations) and with ds_max 0.25 (shorter steps: more factorisations, a closer interpolant).
Accuracy beside the cost: the Bratu fold from each branch (``limit_points``: the fold events,
the ANM's from its series, polished on the fold's augmented system where the series is not
accurate enough and always for Newton) against the discrete fold solved directly (Newton
on R = 0, R_u phi = 0, |phi| = 1), the truss's limit loads against the closed form, and the
largest residual at the points.

Cold: each case once in a fresh process (``--cold-case``), the wall of its first call, JAX's
compilation included (``cold_s``; the import of jaxanm before it, ``import_s``, apart).  Warm:
in this process, after one untimed call, ``--repeats`` calls (``wall_s``: the median;
``wall_spread_s``: min and max).  ``os.getloadavg()`` is recorded before each case.  Counts are
what matters: other work shares the machine.  Run under the machine's timing lock, with
OpenBLAS on one thread (its second thread waits for a core other work holds on a shared machine:
benchmarks/bratu_2d_scale.py):

    OPENBLAS_NUM_THREADS=1 flock /work/timing.lock python benchmarks/continuation.py [--repeats 3]
        [--out benchmarks/results/continuation]
"""

from __future__ import annotations

import argparse
import datetime
import functools
import json
import os
import pathlib
import statistics
import subprocess
import sys
import time

import jax.numpy as jnp
import numpy as np

import jaxanm

HERE = pathlib.Path(__file__).resolve().parent
TOL = 1e-8
L, H, EA = 1.0, 0.1, 1.0
L0 = np.hypot(L, H)
L_STAR = (L**2 * L0) ** (1 / 3)
Y_STAR = np.sqrt(L_STAR**2 - L**2)
P_STAR = 2 * EA * Y_STAR * (1 / L_STAR - 1 / L0)  # closed-form limit load (tests/test_continuation.truss_load)


@functools.lru_cache(maxsize=None)
def bratu(n: int):
    """The discrete Bratu residual on ``n`` interior points."""
    h = 1.0 / (n + 1)

    def residual(u, lam, params):
        up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
        return (up[2:] - 2.0 * u + up[:-2]) / h**2 + lam * jnp.exp(u)

    return residual


def truss(u, lam, params):
    """Apex equilibrium of the two-bar truss (u = horizontal displacement, deflection down)."""
    dx = u[0] - np.array([-L, L])
    dy = (H - u[1]) * jnp.ones(2)
    n_over_l = EA * (1.0 / L0 - 1.0 / jnp.sqrt(dx**2 + dy**2))
    return jnp.stack([jnp.sum(n_over_l * dx), -jnp.sum(n_over_l * dy) - lam])


@functools.lru_cache(maxsize=None)
def discrete_fold(n: int) -> float:
    """The discrete Bratu fold by Newton on the extended system (dense numpy)."""
    h = 1.0 / (n + 1)
    lap = (np.diag(np.full(n, -2.0)) + np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1)) / h**2
    x = np.linspace(h, 1.0 - h, n)
    u, phi, lam = 1.2 * np.sin(np.pi * x), np.sin(np.pi * x) / np.sqrt(n / 2), 3.5
    for _ in range(30):
        e = np.exp(u)
        jac = lap + np.diag(lam * e)
        rows = np.block(
            [
                [jac, np.zeros((n, n)), e[:, None]],
                [np.diag(lam * e * phi), jac, (e * phi)[:, None]],
                [np.zeros((1, n)), 2.0 * phi[None, :], np.zeros((1, 1))],
            ]
        )
        step = np.linalg.solve(rows, -np.concatenate([lap @ u + lam * e, jac @ phi, [phi @ phi - 1.0]]))
        u, phi, lam = u + step[:n], phi + step[n : 2 * n], lam + step[-1]
        if np.max(np.abs(step)) < 1e-14:
            break
    return float(lam)


@functools.lru_cache(maxsize=None)
def bratu_2d(m: int):
    """The 2D Bratu residual on the unit square, 5-point Laplacian on m x m interior points."""
    h = 1.0 / (m + 1)

    def residual(u, lam, params):
        grid = jnp.pad(u.reshape(m, m), 1)
        lap = (grid[2:, 1:-1] + grid[:-2, 1:-1] + grid[1:-1, 2:] + grid[1:-1, :-2] - 4.0 * grid[1:-1, 1:-1]) / h**2
        return (lap + lam * jnp.exp(grid[1:-1, 1:-1])).ravel()

    return residual


METHODS = [
    ("anm p=8", dict(order=8)),
    ("anm p=15", dict(order=15)),
    ("newton", {}),
    ("newton ds_max=0.25", dict(ds_max=0.25)),
]


def problems():
    """``(name, residual, u0, kwargs, reference limit loads or None, methods)`` of each problem."""
    for n in (19, 39, 63, 79):
        kwargs = dict(stop_at=(n // 2, 2.0), max_steps=500, scale=np.append(np.full(n, np.sqrt(n)), 1.0))
        yield f"bratu N={n}", bratu(n), np.zeros(n), kwargs, [discrete_fold(n)], METHODS
    kwargs = dict(lam_end=2 * P_STAR, max_steps=500, scale=[H, H, 2 * EA * H**3 / (3 * np.sqrt(3) * L**3)])
    yield "truss", truss, np.zeros(2), kwargs, [P_STAR, -P_STAR], METHODS
    for m, jacobian in ((20, "dense"), (50, "sparse")):
        kwargs = dict(stop_at=(m * m // 2 + m // 2, 3.0), max_steps=500, jacobian=jacobian,
                      scale=np.append(np.full(m * m, m), 1.0))
        yield f"bratu 2D {m}x{m} ({jacobian})", bratu_2d(m), np.zeros(m * m), kwargs, None, [METHODS[1], METHODS[2]]


def cases():
    """Every (problem, method) pair, in the table's order."""
    for name, residual, u0, kwargs, reference, methods in problems():
        for method, options in methods:
            yield name, residual, u0, kwargs, reference, method, options


def run(residual, u0, kwargs, method: str, options: dict):
    """One branch (ANM or Newton)."""
    if method.startswith("anm"):
        return jaxanm.continuation(residual, u0, 0.0, tol=TOL, **options, **kwargs)
    return jaxanm.newton_continuation(residual, u0, 0.0, tol=TOL, **options, **kwargs)


def cold(index: int) -> dict:
    """Case ``index`` run once in a fresh process: the import and first-call walls."""
    command = [sys.executable, "-c", "import time; start = time.perf_counter(); import jaxanm, sys; "
               "sys.path.insert(0, sys.argv[1]); import continuation as c; "
               "imported = time.perf_counter() - start; print(c.first_call(int(sys.argv[2]), imported))",
               str(HERE), str(index)]
    done = subprocess.run(command, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def first_call(index: int, imported: float) -> str:
    """The wall of case ``index``'s first call in this (fresh) process, as JSON."""
    name, residual, u0, kwargs, reference, method, options = list(cases())[index]
    start = time.perf_counter()
    run(residual, u0, kwargs, method, options)
    return json.dumps({"cold_s": time.perf_counter() - start, "import_s": imported})


def measure(index: int, repeats: int) -> dict:
    """Counts, accuracy and times (cold in a fresh process, warm here) of case ``index``."""
    name, residual, u0, kwargs, reference, method, options = list(cases())[index]
    load = os.getloadavg()
    first = cold(index)
    branch = run(residual, u0, kwargs, method, options)
    walls = []
    for _ in range(repeats):
        start = time.perf_counter()
        run(residual, u0, kwargs, method, options)
        walls.append(time.perf_counter() - start)
    limits = branch.limit_points().lam
    st = branch.stats
    return {
        "problem": name,
        "method": method,
        "steps": int(branch.a.size),
        "factorizations": st.factorizations,
        "series_orders": st.series_orders,
        "solves": st.solves,
        "newton_iterations": st.newton_iterations,
        "residual_evaluations": st.residual_evaluations,
        "rejected_steps": st.rejected_steps,
        "limit_loads": [float(v) for v in limits],
        "limit_error": (
            float(np.max(np.abs(limits - np.array(reference))))
            if reference is not None and limits.size == len(reference)
            else None
        ),
        "limit_scale": float(max(abs(r) for r in reference)) if reference is not None else None,
        "max_residual": float(np.max(branch.residual_norm)),
        "end_lam": float(branch.lam[-1]),
        "cold_s": first["cold_s"],
        "import_s": first["import_s"],
        "wall_s": statistics.median(walls),
        "wall_spread_s": [min(walls), max(walls)],
        "wall_split_s": {k: round(v, 4) for k, v in st.wall_time.items()},
        "loadavg": list(load),
    }


def markdown(results: dict) -> str:
    """The results as a markdown page."""
    lines = [
        "# Path following: ANM against pseudo-arclength Newton",
        "",
        f"Made by `{results['command']}` on {results['date']} ({results['cpus']} CPUs; "
        f"load average before each case in the JSON). tol = {TOL:g} for both methods; Newton with its "
        "defaults (ds 0.1, no ds_max, 4 iterations targeted). Bratu from rest through the fold to "
        "u(1/2) = 2 (2D: u = 3 at the centre); truss from rest through both limit points to P = 2 P*. "
        "`limit error`: the fold's lam against the discrete fold solved directly (Bratu), the limit loads "
        "against the closed form (truss), relative to the largest; the folds are the branch's fold events "
        "(the ANM's from its series unless polished, Newton's polished on the fold's augmented system). "
        "Cold: the first call in a fresh process (each case its own; compilation included, "
        "the import of jaxanm before it not: `import (s)`); warm: the median of the repeats after one "
        "untimed call. The 2D 50 x 50 case gives no pattern: it is found from the residual's jaxpr.",
        "",
        "`first limit`: the first limit point's lam (the 2D fold has no direct reference here; the "
        "continuum's is 6.808124 on the unit square).",
        "",
        "| problem | method | steps | factorisations | series orders | solves | Newton iterations "
        "| first limit | limit error (rel.) | max abs R | import (s) | cold (s) | warm (s) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in results["cases"]:
        error = "n/a" if r["limit_error"] is None else f"{r['limit_error'] / r['limit_scale']:.1e}"
        lines.append(
            f"| {r['problem']} | {r['method']} | {r['steps']} | {r['factorizations']} | {r['series_orders']} "
            f"| {r['solves']} | {r['newton_iterations']} | {r['limit_loads'][0]:.9g} | {error} "
            f"| {r['max_residual']:.1e} "
            f"| {r['import_s']:.2f} | {r['cold_s']:.2f} | {r['wall_s']:.3f} |"
        )
    loads = [r["loadavg"][0] for r in results["cases"]]
    lines += [
        "",
        f"Counts are deterministic; the times move with the machine's load (1-minute load average "
        f"{min(loads):.1f}-{max(loads):.1f} before the cases of this run; JSON: `loadavg` per case, the "
        "spread of the repeats).",
    ]
    return "\n".join(lines) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", default=str(HERE / "results" / "continuation"))
    args = parser.parse_args()
    results = []
    for index in range(len(list(cases()))):
        case = measure(index, args.repeats)
        print(
            f"{case['problem']:12s} {case['method']:18s} steps {case['steps']:4d} factorisations "
            f"{case['factorizations']:4d} series orders {case['series_orders']:5d} limit {case['limit_loads']} "
            f"cold {case['cold_s']:.2f} s warm {case['wall_s']:.3f} s",
            flush=True,
        )
        results.append(case)
    threads = os.environ.get("OPENBLAS_NUM_THREADS")
    command = (f"OPENBLAS_NUM_THREADS={threads} " if threads else "") + \
        "flock /work/timing.lock python benchmarks/continuation.py " + " ".join(sys.argv[1:])
    summary = {"date": datetime.date.today().isoformat(), "cpus": os.cpu_count(), "command": command.strip(),
               "tol": TOL, "cases": results}
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(summary, indent=1) + "\n")
    out.with_suffix(".md").write_text(markdown(summary))
    print(f"wrote {out}.md and .json")


if __name__ == "__main__":
    main()
