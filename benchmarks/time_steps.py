"""What the time step costs and buys on an FSW scene: fixed dt against adaptive steps.

For one scene over ``--t-end`` (scene defaults otherwise), a reference converged in time is
the Richardson extrapolation of implicit Euler (first order) from fixed steps ``dt_ref`` and
``dt_ref / 2``, ``2 x(dt/2) - x(dt)``, solved with modified Newton at ``--ref-tol``; its own
error is estimated by the same extrapolation from ``2 dt_ref`` and ``dt_ref`` (the difference
of the two extrapolations).  Then every configuration runs once:

- fixed steps ``--dts`` with each solver of ``--solvers``;
- adaptive steps (``time.adaptive``, :class:`jaxanm.StepController`) at each ``--atols``
  (``time.rtol = 0``) with each solver;

and is measured against the reference at ``t_end`` at the registration points (material
points, followed as they move): ``max |T - T_ref| / max (T_ref - T0)`` and
``max |V - V_ref| / (omega R1)``.  Wall and process (CPU) times are recorded with the load;
every run starts with a short compiling run of the same configuration in the same process.

    python benchmarks/time_steps.py --scene fsw_tracers --t-end 0.05 --out benchmarks/results/time_steps_fsw_tracers

Writes ``OUT.json``, ``OUT.md`` and ``OUT.png`` (error against CPU time).
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

import jaxanm
from jaxanm.fsw.scene import load_scene
from jaxanm.fsw.simulate import run

SOLVERS = {"anm": {"solver.kind": "anm"}, "mnewton": {"solver.kind": "modified_newton"}}


def probe_values(result) -> dict:
    """T and (u, v) at every registration point at the run's last recorded time."""
    return {name: np.array([rec[k][-1] for k in ("T", "u", "v")]) for name, rec in result.probes.items() if name != "t"}


def probe_history(result, times) -> dict:
    """T, u, v (3, len(times)) at every registration point at the common ``times``.

    Runs at different step sizes record their probes at different steps; compared step by step
    (or at mismatched times) their histories give NaN or meaningless errors.  Each history is
    read at the given times: exactly where a step ended there (within 1e-9 of the span: fixed
    steps that divide the times, adaptive steps that end on the save times), else by linear
    interpolation between the two steps around it (flagged in the ``"interpolated"`` entry).
    """
    t = np.asarray(result.probes["t"], dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    idx = np.clip(np.searchsorted(t, times), 0, len(t) - 1)
    prev = np.maximum(idx - 1, 0)
    near = np.where(np.abs(t[idx] - times) <= np.abs(t[prev] - times), idx, prev)
    exact = np.abs(t[near] - times) <= 1e-9 * max(t[-1], 1e-300)
    out = {"interpolated": bool(not np.all(exact))}
    for name, rec in result.probes.items():
        if name == "t":
            continue
        out[name] = np.array([np.where(exact, np.asarray(rec[k])[near], np.interp(times, t, np.asarray(rec[k])))
                              for k in ("T", "u", "v")])
    return out


def final_fields(result) -> np.ndarray:
    """T, u, v (3, N) at every point at the run's last saved time."""
    return np.array([result.T[-1], result.u[-1], result.v[-1]])


def one_run(scene_name: str, overrides: dict, times=None) -> dict:
    """A compiling run of two steps, then the measured run; its cost and probe values.

    With ``times``, also the probe histories at those times (:func:`probe_history`) and the
    fields at the last time (``"fields"``, :func:`final_fields`).
    """
    base = load_scene(scene_name)
    warm = base.with_overrides({**overrides, "time.t_end": repr(2 * float(overrides.get("time.dt", base.time.dt))),
                                "time.save": ""})
    run(warm)
    scene = base.with_overrides(overrides)
    load0, cpu0, wall0 = os.getloadavg()[0], time.process_time(), time.perf_counter()
    result = run(scene)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    st = result.stats
    row = {"overrides": overrides, "wall_s": wall, "cpu_s": cpu, "load": [load0, os.getloadavg()[0]],
           "steps": st.time_steps, "rejected": st.rejected_steps, "factorizations": st.factorizations,
           "newton_iterations": st.newton_iterations, "series_orders": st.series_orders,
           "probes": {k: v.tolist() for k, v in probe_values(result).items()}}
    if times is not None:
        hist = probe_history(result, times)
        row["interpolated"] = hist.pop("interpolated")
        row["history"] = {k: v.tolist() for k, v in hist.items()}
        row["fields"] = final_fields(result).tolist()
    return row


def errors(row: dict, ref: dict, T0: float, U: float) -> tuple:
    """(T error relative to the largest rise, V error relative to omega R1) at the probes."""
    rise = max(v[0] - T0 for v in ref.values())
    eT = max(abs(row["probes"][k][0] - ref[k][0]) for k in ref) / rise
    eV = max(np.hypot(row["probes"][k][1] - ref[k][1], row["probes"][k][2] - ref[k][2]) for k in ref) / U
    return eT, eV


def reference(scene_name: str, t_end: float, dt_ref: float, tol: float, times=None) -> tuple:
    """Richardson-extrapolated probe values and their estimated error (module docstring).

    Implicit Euler at ``2 dt_ref``, ``dt_ref`` and ``dt_ref / 2`` (modified Newton at ``tol``);
    returns ``(fine, coarse, runs)``: the extrapolations ``2 x(dt_ref/2) - x(dt_ref)`` and
    ``2 x(dt_ref) - x(2 dt_ref)`` of the probe values at t_end, and the three runs.  With
    ``times``, ``fine`` and ``coarse`` are dicts ``{"probes", "history", "fields"}`` that also
    extrapolate the probe histories at ``times`` and the fields at t_end (the extrapolations
    are second order, so ``|fine - coarse| / 3`` estimates the error of ``fine``).
    """
    runs = {}
    for dt in (2 * dt_ref, dt_ref, dt_ref / 2):
        runs[dt] = one_run(scene_name, {"time.t_end": repr(t_end), "time.dt": repr(dt), "time.save": "",
                                        "solver.kind": "modified_newton", "solver.tol": repr(tol)}, times=times)
        print(f"reference run dt = {dt:g}: {runs[dt]['steps']} steps, {runs[dt]['wall_s']:.0f} s", flush=True)

    def extrapolate(key, fine_dt, coarse_dt):
        a, b = runs[fine_dt][key], runs[coarse_dt][key]
        if isinstance(a, dict):
            return {k: 2 * np.array(a[k]) - np.array(b[k]) for k in a}
        return 2 * np.array(a) - np.array(b)

    keys = ("probes",) if times is None else ("probes", "history", "fields")
    fine = {k: extrapolate(k, dt_ref / 2, dt_ref) for k in keys}
    coarse = {k: extrapolate(k, dt_ref, 2 * dt_ref) for k in keys}
    if times is None:
        return fine["probes"], coarse["probes"], runs
    return fine, coarse, runs


def markdown(rows: list, meta: dict) -> str:
    """The table of every run."""
    lines = [
        f"Scene `{meta['scene']}` over [0, {meta['t_end']:g}] s; reference: Richardson from dt = "
        f"{meta['dt_ref']:g} and {meta['dt_ref'] / 2:g} (modified Newton, tol {meta['ref_tol']:g}); its own "
        f"error estimate {meta['ref_error'][0]:.1e} (T), {meta['ref_error'][1]:.1e} (V).  {meta['date']}.",
        "",
        "| solver | step sizes | dt / atol | steps (rejected) | factorisations | error T | error V | CPU (s) "
        "| wall (s) | load |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for r in rows:
        ov = r["overrides"]
        mode = "adaptive" if ov.get("time.adaptive") == "true" else "fixed"
        knob = ov["time.atol"] if mode == "adaptive" else ov["time.dt"]
        lines.append(
            f"| {ov['solver.kind']} | {mode} | {knob} | {r['steps']} ({r['rejected']}) | {r['factorizations']} | "
            f"{r['error_T']:.1e} | {r['error_V']:.1e} | {r['cpu_s']:.1f} | {r['wall_s']:.1f} | "
            f"{r['load'][0]:.1f}-{r['load'][1]:.1f} |"
        )
    return "\n".join(lines) + "\n"


def plot(rows: list, path: pathlib.Path) -> None:
    """T error against CPU time, fixed and adaptive steps per solver."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4))
    for kind, color in (("anm", "C0"), ("modified_newton", "C1")):
        for mode, marker in (("fixed", "o-"), ("adaptive", "s--")):
            sel = [
                r
                for r in rows
                if r["overrides"]["solver.kind"] == kind
                and (r["overrides"].get("time.adaptive") == "true") == (mode == "adaptive")
            ]
            sel.sort(key=lambda r: r["cpu_s"])
            ax.loglog(
                [r["cpu_s"] for r in sel],
                [r["error_T"] for r in sel],
                marker,
                color=color,
                ms=4,
                label=f"{kind}, {mode} steps",
            )
    ax.set_xlabel("CPU time (s)")
    ax.set_ylabel("error of T - T0 at the probes (rel.)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> None:
    """Command line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="fsw_tracers")
    ap.add_argument("--t-end", type=float, default=0.05)
    ap.add_argument("--dt-ref", type=float, default=2.5e-5)
    ap.add_argument("--ref-tol", type=float, default=1e-10)
    ap.add_argument("--dts", default="4e-4,2e-4,1e-4,5e-5")
    ap.add_argument("--atols", default="1e-4,1e-5,1e-6,1e-7")
    ap.add_argument("--solvers", default="anm,mnewton")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    scene = load_scene(a.scene)
    T0, U = scene.thermal.T0, scene.tool.omega * scene.geometry.R1
    with jaxanm.float64():
        fine, coarse, ref_runs = reference(a.scene, a.t_end, a.dt_ref, a.ref_tol)
        ref_err = errors({"probes": {k: v.tolist() for k, v in coarse.items()}}, fine, T0, U)
        rows = []
        for kind in a.solvers.split(","):
            for dt in a.dts.split(","):
                rows.append(
                    one_run(a.scene, {"time.t_end": repr(a.t_end), "time.dt": dt, "time.save": "", **SOLVERS[kind]})
                )
            for atol in a.atols.split(","):
                rows.append(
                    one_run(
                        a.scene,
                        {
                            "time.t_end": repr(a.t_end),
                            "time.save": "",
                            "time.adaptive": "true",
                            "time.rtol": "0",
                            "time.atol": atol,
                            **SOLVERS[kind],
                        },
                    )
                )
            for r in rows:
                r["error_T"], r["error_V"] = errors(r, fine, T0, U)
            print(
                markdown(
                    rows[-len(a.dts.split(",")) - len(a.atols.split(",")) :],
                    {
                        "scene": a.scene,
                        "t_end": a.t_end,
                        "dt_ref": a.dt_ref,
                        "ref_tol": a.ref_tol,
                        "ref_error": ref_err,
                        "date": "",
                    },
                ),
                flush=True,
            )
    meta = {
        "scene": a.scene,
        "t_end": a.t_end,
        "dt_ref": a.dt_ref,
        "ref_tol": a.ref_tol,
        "ref_error": ref_err,
        "date": datetime.date.today().isoformat(),
        "argv": sys.argv[1:],
    }
    text = markdown(rows, meta)
    print(text)
    if a.out:
        out = pathlib.Path(a.out)
        out.with_suffix(".json").write_text(
            json.dumps({"meta": meta, "reference_runs": ref_runs, "rows": rows}, indent=1, default=float)
        )
        out.with_suffix(".md").write_text(
            f"<!-- made by benchmarks/time_steps.py {' '.join(sys.argv[1:])} -->\n\n" + text, encoding="utf-8"
        )
        plot(rows, out.with_suffix(".png"))
        print(f"wrote {out}.json, .md, .png")


if __name__ == "__main__":
    main()
