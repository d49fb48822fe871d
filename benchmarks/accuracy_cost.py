"""What accuracy costs in time: ANM vs Newton vs modified Newton vs scipy BDF (issue 5).

Every solver integrates the *same* step residual ``R(x_new, x_old, t, dt, p)`` (implicit
Euler) with the same coloured sparse Jacobian.  For each configuration we record the error of
the final state against

- ``ref_same``: the same discretisation solved tightly (Newton, tol 1e-11): the nonlinear
  solver's own error;
- ``ref_fine``: the same space discretisation at dt/4 (Newton, tol 1e-11): where the time
  error of implicit Euler takes over;
- ``ref_ode`` (pure ODEs only): the semi-discrete ODE solved by scipy Radau at rtol 1e-11,
  the yardstick for BDF, which is not an implicit-Euler scheme.

and the median wall time over repeats (the first run of each group, which compiles the jitted
residual / jet / Jacobian, is timed separately as ``first_run_s``), the counts of
:class:`jaxanm.Stats` (factorisations, series evaluations, residual evaluations) or of
``solve_ivp`` (``nfev``, ``njev``, ``nlu``), and the peak resident memory (``ru_maxrss`` of a
fresh subprocess per group: everything the process touched, JAX runtime and XLA compiler
included; ``rss_base_mb`` is the same high-water mark right after building the problem).

BDF applies only to a pure ODE ``x' = F(x, t)``: :func:`ode_form` checks that the residual is
``(x_new - x_old)/dt - F(x_new, t)`` (mass matrix ``M = -dt dR/dx_old`` equal to the identity)
and reports what it finds otherwise.  The FSW collocation systems are DAEs (boundary rows have
no time derivative, and the momentum rows' mass ``rho/mu(x) Phi`` depends on the state):
``solve_ivp`` has no mass-matrix or DAE support, so BDF rows exist only for the
reaction-diffusion ODE, and the FSW rows record the measured structure of M instead.

Usage (one command per figure/table; see benchmarks/results/accuracy_cost.md)::

    python benchmarks/accuracy_cost.py --small            # ~35 min on 2 cores under load 10-13
    python benchmarks/accuracy_cost.py --config paper     # one accuracy point at the paper's dr (~15 min),
                                                          # benchmarks/results/accuracy_cost_paper_dr.*
    python benchmarks/accuracy_cost.py                    # full sweep (hours; see docs)
    python benchmarks/accuracy_cost.py --plot-only        # redraw benchmarks/results/accuracy_cost.png from the json
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import resource
import subprocess
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
CACHE = ROOT / "benchmarks" / ".cache"
RESULTS = ROOT / "benchmarks" / "results"
"""Where the committed benchmark outputs live."""

TOLS_FULL = [1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10]
ORDERS = [3, 5, 7, 10, 15, 20]

CONFIGS = {
    "small": {
        "repeats": 3,
        "budget_s": 20.0,
        "problems": {
            "rd": {
                "n": 100,
                "t1": 0.2,
                "dt": 2e-3,
                "orders": ORDERS,
                "etas": [1e-3, 1e-4, 1e-6, 1e-8, 1e-10],
                "deltas": [1e-3, 1e-4, 1e-6, 1e-8, 1e-10],
                "rtols": [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8],
            },
            # the same ODE at smaller dt: implicit Euler's time error goes down, every solver pays more steps
            "rd@dt=5e-4": {
                "n": 100,
                "t1": 0.2,
                "dt": 5e-4,
                "orders": [7, 10],
                "etas": [1e-6, 1e-8],
                "deltas": [1e-6, 1e-8],
                "rtols": [],
            },
            "rd@dt=1.25e-4": {
                "n": 100,
                "t1": 0.2,
                "dt": 1.25e-4,
                "orders": [7],
                "etas": [1e-6, 1e-8],
                "deltas": [1e-6, 1e-8],
                "rtols": [],
            },
            "fsw_reduced": {
                "dr": 7.5e-4,
                "warm_steps": 10,
                "span_steps": 10,
                "dt": 1e-4,
                "orders": [3, 5, 7],
                "etas": [1e-4, 1e-6, 1e-8],
                "deltas": [1e-4, 1e-6, 1e-8],
                "budget_s": 90.0,
            },
        },
    },
    # one accuracy point on the paper's resolution (fixed points): measured ratios at dr = 3.75e-4
    "paper": {
        "repeats": 3,
        "budget_s": 300.0,
        "problems": {
            "fsw_paper": {
                "dr": 3.75e-4,
                "warm_steps": 10,
                "span_steps": 5,
                "dt": 1e-4,
                "orders": [5, 7],
                "etas": [1e-4, 1e-6, 1e-8],
                "deltas": [1e-4, 1e-6, 1e-8],
            },
        },
    },
    "full": {
        "repeats": 5,
        "budget_s": 600.0,
        "problems": {
            "rd": {
                "n": 200,
                "t1": 1.0,
                "dt": 1e-3,
                "orders": ORDERS,
                "etas": TOLS_FULL,
                "deltas": TOLS_FULL,
                "rtols": [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9],
            },
            "fsw_reduced": {
                "dr": 7.5e-4,
                "warm_steps": 10,
                "span_steps": 50,
                "dt": 1e-4,
                "orders": ORDERS,
                "etas": TOLS_FULL,
                "deltas": TOLS_FULL,
            },
            "fsw_paper": {
                "dr": 3.75e-4,
                "warm_steps": 20,
                "span_steps": 20,
                "dt": 1e-4,
                "orders": [5, 7, 10],
                "etas": [1e-4, 1e-6, 1e-8],
                "deltas": [1e-4, 1e-6, 1e-8],
            },
        },
    },
}


# ----------------------------------------------------------------------------- problems


def median_time(fn, repeats: int) -> float:
    """Median wall time (s) of ``fn()`` over ``repeats`` calls."""
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return float(np.median(ts))


def family(name: str) -> str:
    """Problem family: ``"rd@dt=5e-4"`` (the same problem at another dt) belongs to ``"rd"``."""
    return name.split("@")[0]


def build_problem(name: str, cfg: dict) -> dict:
    """The step problem ``name`` as a dict of residual, x0, params, times, scale, sparsity, norm.

    ``rd``: the power-law reaction-diffusion ODE of ``examples/reaction_diffusion.py`` from rest.
    ``fsw_reduced`` / ``fsw_paper``: the ``fsw_tracers`` physics (all paper effects on fixed
    points, ``V . grad`` transport) at the given dr, started from the warm state after
    ``warm_steps`` steps (cached), over ``span_steps`` steps of dt.
    """
    if family(name) == "rd":
        sys.path.insert(0, str(ROOT / "examples"))
        from reaction_diffusion import make_problem

        residual, x0, params = make_problem(cfg["n"])
        return {
            "residual": residual,
            "x0": x0,
            "params": params,
            "t0": 0.0,
            "t1": cfg["t1"],
            "dt": cfg["dt"],
            "scale": None,
            "sparsity": None,
            "jacobian": "sparse",
            "values": lambda x: x,
            "value_scale": None,
        }
    from jaxanm.fsw.discretisation import discretise
    from jaxanm.fsw.scene import load_scene
    from jaxanm.mls import value_matrix

    scene = load_scene("fsw_tracers").with_overrides({"geometry.dr": cfg["dr"]})
    cloud, st, model, params, x_rest = discretise(scene)
    N = cloud.size
    Phi = value_matrix(st).tocsr()
    nf = len(model.fields)
    scale = model.scale()
    dt = cfg["dt"]
    t0 = cfg["warm_steps"] * dt
    return {
        "residual": model.residual,
        "x0": None,
        "x_rest": x_rest,
        "params": params,
        "t0": t0,
        "t1": t0 + cfg["span_steps"] * dt,
        "dt": dt,
        "scale": scale,
        "sparsity": model.sparsity,
        "jacobian": "sparse",
        "values": lambda x: np.concatenate([Phi @ f for f in np.asarray(x).reshape(nf, N)]),
        "value_scale": scale,
        "N": N,
    }


def relative_error(prob: dict, x, x_ref) -> float:
    """Max-norm error of the field *values* (MLS values for FSW), relative to the reference.

    RD: ``max|u - u_ref| / max|u_ref|``.  FSW: ``max_i |v_i - v_ref,i| / scale_i`` with the
    model's scales (omega R1 for u, v; T0 for T).
    """
    a, b = prob["values"](x), prob["values"](x_ref)
    if prob["value_scale"] is None:
        return float(np.max(np.abs(a - b)) / np.max(np.abs(b)))
    return float(np.max(np.abs(a - b) / prob["value_scale"]))


def make_solver(method: str, order, tol):
    """``jaxanm.ANM`` / ``Newton`` / ``ModifiedNewton`` options of a configuration."""
    import jaxanm

    if method == "anm":
        return jaxanm.ANM.paper(order=order, tol=tol, max_substeps=1000)
    if method == "newton":
        return jaxanm.Newton(tol=tol, max_iter=50)
    if method == "mnewton":
        return jaxanm.ModifiedNewton(tol=tol, max_iter=200)
    raise ValueError(method)


class OverBudget(RuntimeError):
    """A run exceeded its wall-time budget (recorded as a failed configuration)."""


def run_implicit(prob: dict, solver, x0, t0=None, t1=None, dt=None, budget_s=None):
    """One :func:`jaxanm.integrate` run; returns (final state, stats, wall seconds).

    The process CPU time of the run (all threads) is left in ``stats.cpu_s``: on a shared,
    overloaded machine it is less disturbed by other jobs than the wall time.

    ``budget_s``: abort (raise :class:`OverBudget`) once a run has taken longer than this.
    """
    import jaxanm

    start, cpu = time.perf_counter(), time.process_time()

    def watchdog(t, x, stats):
        if budget_s is not None and time.perf_counter() - start > budget_s:
            raise OverBudget(
                f"over the {budget_s:g} s budget at t = {float(t):.4g} ({stats.factorizations} factorizations so far)"
            )

    sol = jaxanm.integrate(
        prob["residual"],
        x0,
        prob["params"],
        t0=prob["t0"] if t0 is None else t0,
        t1=prob["t1"] if t1 is None else t1,
        dt=prob["dt"] if dt is None else dt,
        solver=solver,
        scale=prob["scale"],
        jacobian=prob["jacobian"],
        sparsity=prob["sparsity"],
        saveat=jaxanm.SaveAt(steps=10**9),
        max_dt_halvings=0,
        callback=watchdog,
    )
    wall = time.perf_counter() - start
    sol.stats.cpu_s = time.process_time() - cpu
    return sol.xs[-1], sol.stats, wall


# ----------------------------------------------------------------------------- ODE form / BDF


def ode_form(residual, params, x, t, dt, sparsity=None):
    """Check whether ``R(x_new, x_old) = (x_new - x_old)/dt - F(x_new, t)``; build F and its Jacobian.

    The mass matrix is ``M = -dt dR/dx_old`` (exact when x_old enters linearly, as in every
    implicit-Euler residual here).  Returns ``(info, f, jac)``: ``info`` reports
    ``identity_mass`` (``max|M - I|``), the number of zero rows of M (algebraic equations) and
    whether M changes with the state (``mass_state_dependent``); ``f(t, y) = -R(y, y, t, dt)``
    and ``jac(t, y)`` is its sparse Jacobian by the same coloured compressed ``jacfwd``
    (``dR/dx_new + dR/dx_old``).  ``f``/``jac`` are only meaningful when M = I.
    """
    import jax.numpy as jnp
    import scipy.sparse

    import jaxanm
    from jaxanm.jacobian import SparseJacobian

    def wrt_old(xo, xn, t_, dt_, p):
        return residual(xn, xo, t_, dt_, p)

    def diagonal(x_, xo, t_, dt_, p):
        return residual(x_, x_, t_, dt_, p)

    n = x.size
    if sparsity is None:
        pattern = jaxanm.detect_sparsity(diagonal, x, x, t, dt, params)
        pattern = (pattern + jaxanm.detect_sparsity(wrt_old, x, x, t, dt, params)).astype(bool)
    else:
        pattern = sparsity(params) if callable(sparsity) else sparsity
    rng = np.random.default_rng(1)
    scale_x = np.abs(x) + 1e-3 * (np.max(np.abs(x)) + 1.0)
    x2 = x + 0.05 * scale_x * rng.standard_normal(n)
    with jaxanm.float64():
        jold = SparseJacobian(wrt_old, pattern)
        M1 = -dt * jold(x, x, jnp.float64(t), jnp.float64(dt), params)
        M2 = -dt * jold(x, x2, jnp.float64(t), jnp.float64(dt), params)  # x_new = x2
    eye = scipy.sparse.identity(n, format="csc")
    dev = abs(M1 - eye).max()
    zero_rows = int(np.sum(np.asarray(abs(M1).sum(axis=1)).ravel() == 0.0))
    changes = abs(M1 - M2).max() / max(abs(M1).max(), 1e-300)
    info = {
        "identity_mass_deviation": float(dev),
        "algebraic_rows": zero_rows,
        "n": int(n),
        "mass_state_dependent_rel_change": float(changes),
    }
    jdiag = SparseJacobian(diagonal, pattern)
    import jax

    res = jax.jit(residual)

    def f(t_, y):
        with jaxanm.float64():
            return -np.asarray(res(y, y, jnp.float64(t_), jnp.float64(dt), params))

    def jac(t_, y):
        with jaxanm.float64():
            return -jdiag(y, y, jnp.float64(t_), jnp.float64(dt), params)

    return info, f, jac


def run_bdf(f, jac, x0, t0, t1, rtol, atol, method="BDF"):
    """``scipy.integrate.solve_ivp`` with the sparse Jacobian; returns (y(t1), counts, wall s)."""
    from scipy.integrate import solve_ivp

    start, cpu = time.perf_counter(), time.process_time()
    sol = solve_ivp(f, (t0, t1), x0, method=method, jac=jac, rtol=rtol, atol=atol, t_eval=[t1])
    wall = time.perf_counter() - start
    if not sol.success:
        raise RuntimeError(f"solve_ivp {method} failed: {sol.message}")
    return (
        sol.y[:, -1],
        {
            "nfev": int(sol.nfev),
            "njev": int(sol.njev),
            "nlu": int(sol.nlu),
            "cpu_s": time.process_time() - cpu,
            "steps": int(sol.t.size),
        },
        wall,
    )


# ----------------------------------------------------------------------------- worker side


def _maxrss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _cache_file(problem: str, cfg: dict) -> pathlib.Path:
    key = "_".join(f"{k}{cfg[k]}" for k in sorted(cfg) if k not in ("orders", "etas", "deltas", "rtols", "budget_s"))
    return CACHE / f"{problem}_{key}.npz"


def worker_refs(problem: str, cfg: dict) -> dict:
    """Warm start (FSW) and the reference solutions; cached in ``benchmarks/.cache``."""
    import jaxanm

    path = _cache_file(problem, cfg)
    if path.exists():
        info = path.with_suffix(".json")
        return {"cache": str(path), "cached": True, **(json.loads(info.read_text()) if info.exists() else {})}
    prob = build_problem(problem, cfg)
    out, info = {}, {}
    if prob["x0"] is None:  # FSW: warm state after warm_steps from rest (ANM, tight, many sub-steps)
        t = time.perf_counter()
        xw, st, _ = run_implicit(
            prob, jaxanm.ANM.paper(order=7, tol=1e-10, max_substeps=5000), prob["x_rest"], t0=0.0, t1=prob["t0"]
        )
        info["warm"] = {"wall_s": time.perf_counter() - t, **st.summary()}
        x0 = xw
    else:
        x0 = prob["x0"]
    out["x0"] = x0
    tight = jaxanm.Newton(tol=1e-11, max_iter=100)
    out["ref_same"], st, w = run_implicit(prob, tight, x0)
    info["ref_same"] = {"wall_s": w, "factorizations": st.factorizations}
    out["ref_fine"], st, w = run_implicit(prob, tight, x0, dt=prob["dt"] / 4)
    info["ref_fine"] = {"wall_s": w, "factorizations": st.factorizations}
    if family(problem) == "rd":
        mi, f, jac = ode_form(prob["residual"], prob["params"], x0, prob["t0"], prob["dt"])
        out["ref_ode"], counts, w = run_bdf(f, jac, x0, prob["t0"], prob["t1"], 1e-11, 1e-13, method="Radau")
        info["ref_ode"] = {"wall_s": w, **counts}
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **out)
    info["time_error_floor_fine"] = relative_error(prob, out["ref_same"], out["ref_fine"])
    if "ref_ode" in out:
        info["time_error_floor_ode"] = relative_error(prob, out["ref_same"], out["ref_ode"])
        info["fine_vs_ode"] = relative_error(prob, out["ref_fine"], out["ref_ode"])
    (path.with_suffix(".json")).write_text(json.dumps(info, indent=1))
    return {"cache": str(path), "cached": False, **info}


def _errors(prob, x, refs) -> dict:
    out = {f"err_{k[4:]}": relative_error(prob, x, refs[k]) for k in ("ref_same", "ref_fine", "ref_ode") if k in refs}
    return out


def worker_group(problem: str, cfg: dict, method: str, order, tols: list, repeats: int, budget_s=None) -> list:
    """All tolerances of one (problem, method, order) in this process: first run + timed repeats.

    A configuration whose first run takes longer than ``budget_s`` is recorded as failed
    (over budget); one whose first run takes more than a third of it is repeated once only.
    """
    refs = dict(np.load(_cache_file(problem, cfg)))
    prob = build_problem(problem, cfg)
    x0 = refs["x0"]
    rss_base = _maxrss_mb()
    rows = []
    if method == "bdf":
        info, f, jac = ode_form(prob["residual"], prob["params"], x0, prob["t0"], prob["dt"], sparsity=prob["sparsity"])
        if info["identity_mass_deviation"] > 1e-12:
            return [
                {
                    "problem": problem,
                    "method": "bdf",
                    "applicable": False,
                    **info,
                    "why": "M = -dt dR/dx_old is not the identity: a DAE / mass-matrix system; "
                    "scipy.integrate.solve_ivp has no mass-matrix or DAE support",
                }
            ]
        scale = np.maximum(np.abs(refs["ref_same"]), 1e-2 * np.max(np.abs(refs["ref_same"])))
        for rtol in tols:
            t = time.perf_counter()
            y, counts, first = run_bdf(f, jac, x0, prob["t0"], prob["t1"], rtol, rtol * scale)
            reps = [run_bdf(f, jac, x0, prob["t0"], prob["t1"], rtol, rtol * scale) for _ in range(repeats)]
            walls = [r_[2] for r_ in reps]
            rows.append(
                {
                    "problem": problem,
                    "method": "bdf",
                    "order": None,
                    "tol": rtol,
                    "first_run_s": first,
                    "wall_s": float(np.median(walls)),
                    "walls": walls,
                    "cpu_s": float(np.median([r_[1]["cpu_s"] for r_ in reps])),
                    "factorizations": counts["nlu"],
                    "jacobian_evaluations": counts["njev"],
                    "residual_evaluations": counts["nfev"],
                    "series_orders": 0,
                    **_errors(prob, y, refs),
                    "mass": info,
                }
            )
        rss = _maxrss_mb()
        for r in rows:
            r.update(rss_peak_mb=rss, rss_base_mb=rss_base)
        return rows
    # compile everything (residual, jet at this order, coloured Jacobian) on one step first
    t = time.perf_counter()
    try:
        run_implicit(prob, make_solver(method, order, tols[0]), x0, t1=prob["t0"] + prob["dt"])
    except Exception:  # noqa: BLE001  (the timed runs below report the failure)
        pass
    compile_s = time.perf_counter() - t
    for tol in tols:
        solver = make_solver(method, order, tol)
        try:
            x, st, first = run_implicit(prob, solver, x0, budget_s=budget_s)
        except Exception as exc:  # a failing configuration is a result, not a crash
            rows.append(
                {
                    "problem": problem,
                    "method": method,
                    "order": order,
                    "tol": tol,
                    "failed": f"{type(exc).__name__}: {str(exc)[:200]}",
                }
            )
            continue
        walls, splits, cpus = [], [], []
        n_rep = 1 if (budget_s is not None and first > budget_s / 3) else repeats
        for _ in range(n_rep):
            _, st_r, w = run_implicit(prob, solver, x0)
            walls.append(w)
            cpus.append(st_r.cpu_s)
            splits.append(st_r.wall_time)
        n_steps = st.time_steps
        split = {k: float(np.median([s[k] for s in splits])) for k in splits[0]}
        rows.append(
            {
                "problem": problem,
                "method": method,
                "order": order,
                "tol": tol,
                "first_run_s": first,
                "wall_s": float(np.median(walls)),
                "walls": walls,
                "cpu_s": float(np.median(cpus)),
                "compile_step_s": compile_s,
                "wall_split": split,
                "time_steps": n_steps,
                "factorizations": st.factorizations,
                "jacobian_evaluations": st.jacobian_evaluations,
                "series_orders": st.series_orders,
                "residual_evaluations": st.residual_evaluations,
                "newton_iterations": st.newton_iterations,
                "substeps": st.substeps,
                "min_amax": float(min(st.amax)) if st.amax else None,
                "max_residual_norm": float(max(st.residual_norm)),
                "max_residual_step": int(np.argmax(st.residual_norm)) + 1,
                **_errors(prob, x, refs),
            }
        )
    rss = _maxrss_mb()
    for r in rows:
        r.update(rss_peak_mb=rss, rss_base_mb=rss_base)
    return rows


# ----------------------------------------------------------------------------- driver side


def _spawn(payload: dict) -> dict | list:
    """Run one worker job in a fresh interpreter (its own ru_maxrss, its own JIT caches)."""
    cmd = [sys.executable, __file__, "--worker", json.dumps(payload)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.stderr.write(proc.stderr[-3000:])
        return {"error": proc.stderr[-1000:], "payload": payload}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def sweep(config: str, problems: list, out: pathlib.Path) -> dict:
    """Run every group of the configuration; write the JSON after each group (partial results survive)."""
    conf = CONFIGS[config]
    result = {
        "config": config,
        "started": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
        "machine": {"cpus": os.cpu_count(), "uname": " ".join(os.uname())},
        "loadavg_start": os.getloadavg(),
        "settings": conf,
        "refs": {},
        "rows": [],
    }
    if out.exists():  # resume: keep rows of groups already done in this configuration
        old = json.loads(out.read_text())
        if old.get("config") == config:
            result["rows"], result["refs"] = old["rows"], old["refs"]
    done = {(r["problem"], r["method"], r.get("order")) for r in result["rows"]}
    for problem in problems:
        cfg = conf["problems"][problem]
        t = time.perf_counter()
        result["refs"][problem] = _spawn({"job": "refs", "problem": problem, "cfg": cfg})
        print(f"[{problem}] references: {time.perf_counter() - t:.1f}s {result['refs'][problem]}", flush=True)
        groups = [("anm", p, cfg["etas"]) for p in cfg["orders"]]
        groups += [("newton", None, cfg["deltas"]), ("mnewton", None, cfg["deltas"])]
        if cfg.get("rtols", [1e-4]):  # FSW: one BDF job that records why it does not apply
            groups += [("bdf", None, cfg.get("rtols", [1e-4]))]
        for method, order, tols in groups:
            if (problem, method, order) in done:
                continue
            t = time.perf_counter()
            rows = _spawn(
                {
                    "job": "group",
                    "problem": problem,
                    "cfg": cfg,
                    "method": method,
                    "order": order,
                    "tols": tols,
                    "repeats": conf["repeats"],
                    "budget_s": cfg.get("budget_s", conf.get("budget_s")),
                }
            )
            load = os.getloadavg()
            if isinstance(rows, dict):
                rows = [{"problem": problem, "method": method, "order": order, "failed": rows["error"][-500:]}]
            for r in rows:
                r["loadavg"] = load
                print(_short(r), flush=True)
            print(f"  group {method} p={order}: {time.perf_counter() - t:.1f}s, load {load}", flush=True)
            result["rows"].extend(rows)
            result["loadavg_end"] = load
            out.write_text(json.dumps(result, indent=1, default=float))
    result["finished"] = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    out.write_text(json.dumps(result, indent=1, default=float))
    return result


def _short(r: dict) -> str:
    if "failed" in r or r.get("applicable") is False:
        return (
            f"  {r['problem']:12s} {r['method']:8s} p={r.get('order')} tol={r.get('tol')}: "
            f"{r.get('failed') or r.get('why')}"
        )
    errs = " ".join(f"{k}={v:.2e}" for k, v in r.items() if k.startswith("err_"))
    return (
        f"  {r['problem']:12s} {r['method']:8s} p={str(r['order']):4s} tol={r['tol']:.0e} "
        f"wall={r['wall_s']:.3f}s cpu={r['cpu_s']:.3f}s first={r['first_run_s']:.2f}s fact={r['factorizations']} "
        f"series={r['series_orders']} res={r['residual_evaluations']} rss={r['rss_peak_mb']:.0f}MB {errs}"
        f" maxres={r.get('max_residual_norm', float('nan')):.1e}"
    )


# ----------------------------------------------------------------------------- analysis


LABELS = {"anm": "ANM", "newton": "Newton", "mnewton": "modified Newton", "bdf": "scipy BDF"}
COLORS = {"anm": "C0", "newton": "C1", "mnewton": "C2", "bdf": "C3"}


def pareto(points):
    """Lower-left envelope of (wall, error) points, sorted by wall time."""
    front, best = [], np.inf
    for w, e, r in sorted(points, key=lambda p: p[0]):
        if e < best:
            front.append((w, e, r))
            best = e
    return front


def truth_key(rows) -> str:
    """The error column measured against the most accurate reference available."""
    return "err_ode" if any("err_ode" in r for r in rows) else "err_fine"


def matched_ratios(rows: list, key: str, levels=(1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-8), time_key="wall_s") -> list:
    """For each accuracy level: the cheapest run (by ``time_key``) of each method reaching error <= level."""
    out = []
    for level in levels:
        best = {}
        for r in rows:
            if r["method"] == "bdf" and key == "err_same":
                continue  # BDF is not implicit Euler at dt: "same discretisation" does not apply
            if time_key in r and r.get(key) is not None and r[key] <= level:
                if r["method"] not in best or r[time_key] < best[r["method"]][time_key]:
                    best[r["method"]] = r
        if "anm" in best:
            out.append({"level": level, **{m: (b[time_key], b.get("order"), b["tol"]) for m, b in best.items()}})
    return out


def plot(result: dict, path: pathlib.Path) -> None:
    """Pareto plot: error vs median wall time, one curve (front) per method, per problem and error kind."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in result["rows"] if "wall_s" in r]
    problems = list(dict.fromkeys(family(r["problem"]) for r in rows))
    fig, axes = plt.subplots(3, len(problems), figsize=(6 * len(problems), 13), squeeze=False)
    for j, problem in enumerate(problems):
        prs = [r for r in rows if family(r["problem"]) == problem]
        tk = truth_key(prs)
        total = "total error (vs " + ("ODE, Radau rtol 1e-11" if tk == "err_ode" else "implicit Euler at dt/4") + ")"
        for i, (key, title, time_key) in enumerate(
            [
                ("err_same", "solver error (vs tight solve, same dt)", "wall_s"),
                (tk, total, "wall_s"),
                (tk, total, "cpu_s"),
            ]
        ):
            ax = axes[i, j]
            for method in ("anm", "newton", "mnewton", "bdf"):
                pts = [
                    (r[time_key], max(r[key], 1e-17), r)
                    for r in prs
                    if r["method"] == method
                    and key in r
                    and time_key in r
                    and not (method == "bdf" and key == "err_same")
                ]
                if not pts:
                    continue
                ax.scatter([p[0] for p in pts], [p[1] for p in pts], s=12, alpha=0.35, color=COLORS[method])
                front = pareto(pts)
                ax.plot(
                    [p[0] for p in front], [p[1] for p in front], "-o", ms=4, color=COLORS[method], label=LABELS[method]
                )
                if method == "anm":
                    for w, e, r in front:
                        ax.annotate(f"p{r['order']},{r['tol']:.0e}", (w, e), fontsize=6, alpha=0.7)
            floor = (
                result["refs"]
                .get(problem, {})
                .get("time_error_floor_ode" if tk == "err_ode" else "time_error_floor_fine")
            )
            if i >= 1 and floor:
                ax.axhline(floor, color="k", ls=":", lw=1, label="implicit Euler time error at dt")
            ax.set_xscale("log")
            ax.set_yscale("log")
            lo, hi = ax.get_ylim()
            if hi / lo < 10:  # all errors at the time-error floor: show a decade around it
                mid = np.sqrt(lo * hi)
                ax.set_ylim(mid / 10, mid * 10)
            ax.set_xlabel(
                f"median {'wall' if time_key == 'wall_s' else 'process CPU'} time per run [s] (compile excluded)"
            )
            ax.set_ylabel("relative max error of final state")
            ax.set_title(f"{problem}: {title}", fontsize=9)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
    fig.suptitle(
        f"accuracy vs cost ({result['config']} configuration, {result['started']}, "
        f"load {result['loadavg_start'][0]:.1f} on {result['machine']['cpus']} cpus)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    print(f"wrote {path}")


def tables(result: dict) -> str:
    """Markdown tables of the rows (and the matched-accuracy ratios)."""
    lines = []
    rows = result["rows"]
    for problem in dict.fromkeys(family(r["problem"]) for r in rows):
        prs = [r for r in rows if family(r["problem"]) == problem]
        tk = truth_key(prs)
        lines += [
            f"\n### {problem}\n",
            f"| problem (dt) | method | p | tol | median wall [s] | first run [s] | factorizations | "
            f"series evals | residual evals | err vs same-dt ref | {tk.replace('err_', 'err vs ')} ref | "
            f"max scaled residual | "
            f"median CPU [s] | peak RSS [MB] |",
            "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        ]
        for r in prs:
            if "wall_s" not in r:
                lines.append(
                    f"| {r['problem']} | {r['method']} | {r.get('order') or ''} | {r.get('tol', '')} | "
                    f"{r.get('failed') or r.get('why')} |"
                )
                continue
            same = "n/a" if r["method"] == "bdf" else f"{r.get('err_same', float('nan')):.1e}"
            lines.append(
                f"| {r['problem']} | {LABELS[r['method']]} | {r.get('order') or ''} | {r['tol']:.0e} | "
                f"{r['wall_s']:.3f} | "
                f"{r['first_run_s']:.2f} | {r['factorizations']} | {r['series_orders']} | "
                f"{r['residual_evaluations']} | {same} | "
                f"{r.get(tk, float('nan')):.1e} | {r.get('max_residual_norm', float('nan')):.1e} | "
                f"{r.get('cpu_s', float('nan')):.3f} | {r['rss_peak_mb']:.0f} |"
            )
        for key, time_key in (("err_same", "wall_s"), (tk, "wall_s"), ("err_same", "cpu_s"), (tk, "cpu_s")):
            lines += [
                f"\nCheapest run reaching each accuracy ({key}, by median {time_key}); ratio = ANM / other:\n",
                "| error <= | ANM [s] (p, tol) | Newton | modified Newton | BDF | ANM/Newton | ANM/mNewton | ANM/BDF |",
                "| --- | --- | --- | --- | --- | --- | --- | --- |",
            ]
            for m in matched_ratios(prs, key, time_key=time_key):
                a = m["anm"][0]
                cell = lambda k: f"{m[k][0]:.3f}" if k in m else "—"  # noqa: E731
                ratio = lambda k: f"{a / m[k][0]:.2f}" if k in m else "—"  # noqa: E731
                lines.append(
                    f"| {m['level']:.0e} | {a:.3f} (p={m['anm'][1]}, {m['anm'][2]:.0e}) | {cell('newton')} | "
                    f"{cell('mnewton')} | {cell('bdf')} | {ratio('newton')} | {ratio('mnewton')} | {ratio('bdf')} |"
                )
    return "\n".join(lines)


def main(argv=None) -> None:
    """Command line: run the sweep (small or full), or redraw the plot / tables from the JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="small configuration (minutes)")
    ap.add_argument(
        "--config",
        choices=list(CONFIGS),
        default=None,
        help="configuration by name (--small is --config small; default full)",
    )
    ap.add_argument("--problems", default=None, help="comma-separated subset of the configuration's problems")
    ap.add_argument(
        "--out",
        default=None,
        help="JSON output (default benchmarks/results/accuracy_cost.json, "
        "benchmarks/results/accuracy_cost_full.json for the full configuration)",
    )
    ap.add_argument("--plot-only", action="store_true", help="redraw the PNG and print the tables from the JSON")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        job = json.loads(args.worker)
        if job["job"] == "refs":
            res = worker_refs(job["problem"], job["cfg"])
        else:
            res = worker_group(
                job["problem"],
                job["cfg"],
                job["method"],
                job["order"],
                job["tols"],
                job["repeats"],
                job.get("budget_s"),
            )
        print(json.dumps(res, default=float))
        return
    config = args.config or ("small" if args.small else "full")
    # benchmarks/results/accuracy_cost_paper.* is the fsw_tracers front of benchmarks/accuracy_cost_paper.py
    default_name = {"small": "accuracy_cost.json", "paper": "accuracy_cost_paper_dr.json"}
    out = pathlib.Path(args.out) if args.out else RESULTS / default_name.get(config, f"accuracy_cost_{config}.json")
    if not args.plot_only:
        problems = args.problems.split(",") if args.problems else list(CONFIGS[config]["problems"])
        sweep(config, problems, out)
    result = json.loads(out.read_text())
    plot(result, out.with_suffix(".png"))
    print(tables(result))


if __name__ == "__main__":
    main()
