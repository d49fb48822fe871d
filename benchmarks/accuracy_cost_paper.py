"""Error against wall time on the paper's scene on fixed points (fsw_tracers): the Pareto front.

One invocation runs every configuration one after the other (each after a short compiling
run of the same configuration, not timed) and measures it against a reference converged in
time:

- **reference**: Richardson extrapolation of implicit Euler at ``2 dt_ref``, ``dt_ref``,
  ``dt_ref / 2`` with modified Newton at ``--ref-tol`` (``benchmarks/time_steps.py``'s
  :func:`reference`), cached in ``benchmarks/.cache/``; its own error is estimated as
  ``|fine - coarse| / 3`` (both extrapolations are second order);
- **ANM** (order-adaptive up to p, and fixed p) over the tolerance eta, **modified Newton**
  over delta and ``max_rate``, **Newton** over delta, each at fixed dt from 1e-2 to 1e-5;
- **adaptive time steps** (``time.adaptive``, :class:`jaxanm.StepController`) over atol;
- **IDA** (:func:`jaxanm.ida.integrate_ida`, SUNDIALS BDF orders 1-5) over rtol = atol.

Errors (relative max-norms): of ``T - T0`` (by the reference's largest rise) and of V (by
omega R1), at the registration points (the scene's probes) at the common times ``--times``
(every run is read at exactly those times: fixed steps that divide them, adaptive steps and
IDA ending on them; see :func:`time_steps.probe_history`), and over all points at t_end.  A
row's ``error`` is the largest of the four.

Timing: wall seconds of the measured run (compilation excluded), with the 1-minute load
average before and after it.  The machine is shared: after the grid, the ``--repeat`` fastest
rows run once more, so that the table shows the run-to-run noise next to the differences.

    python benchmarks/accuracy_cost_paper.py --reference-only          # the reference, cached
    python benchmarks/accuracy_cost_paper.py --out docs/accuracy_cost_paper

Writes ``OUT.json`` (every row, the reference's runs and error estimate), ``OUT.md`` (the
table) and ``OUT.png`` (error against wall time, one series per method).
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

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import time_steps  # noqa: E402  (the Richardson reference and the probe histories)

import jaxanm  # noqa: E402
from jaxanm.fsw.geometry import PLATE  # noqa: E402
from jaxanm.fsw.model import discretise  # noqa: E402
from jaxanm.fsw.scene import load_scene  # noqa: E402

CACHE = pathlib.Path(__file__).resolve().parent / ".cache"


def ida_run(scene_name: str, t_end: float, times, rtol: float, atol: float) -> dict:
    """IDA on the scene's fixed-point residual: a compiling run to ``times[0] / 10``, then the
    measured run; probe histories at ``times`` and fields at t_end, as :func:`time_steps.one_run`."""
    from jaxanm.ida import integrate_ida

    scene = load_scene(scene_name).with_overrides({"time.t_end": repr(t_end)})
    if scene.has("lagrangian"):
        raise SystemExit(f"{scene_name} is Lagrangian: IDA needs fixed points (jaxanm.ida docstring)")
    _, st, model, params, x0 = discretise(scene)
    kw = dict(rtol=rtol, atol=atol, scale=model.scale(), sparsity=model.sparsity)
    integrate_ida(model.residual, x0, params, t0=0.0, t_out=[times[0] / 10], **kw)
    load0, cpu0, wall0 = os.getloadavg()[0], time.process_time(), time.perf_counter()
    sol = integrate_ida(model.residual, x0, params, t0=0.0, t_out=list(times), **kw)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    kind, pts = model.cloud.kind, model.cloud.points
    plate = np.flatnonzero(kind == PLATE)
    probe_index = {p.name: int(plate[np.argmin(np.hypot(*(pts[plate] - (p.x, p.y)).T))]) for p in scene.probes}
    col = {f: i for i, f in enumerate(model.fields)}
    vals = np.array([model.values(x, st) for x in sol.xs])  # (S, N, F)

    def field(f, v):
        return v[..., col[f]] if f in col else (np.full(v.shape[:-1], scene.thermal.T0) if f == "T" else np.zeros(v.shape[:-1]))

    s = sol.stats
    return {"method": "ida", "overrides": {"rtol": rtol, "atol": atol}, "wall_s": wall, "cpu_s": cpu,
            "load": [load0, os.getloadavg()[0]], "steps": s.steps, "rejected": None,
            "factorizations": s.jacobian_evaluations, "newton_iterations": s.linear_solves,
            "residual_evaluations": s.residual_evaluations, "ida_stats": s.summary(), "interpolated": False,
            "history": {name: [field(f, vals[:, i]).tolist() for f in ("T", "u", "v")] for name, i in probe_index.items()},
            "fields": [field(f, vals[-1]).tolist() for f in ("T", "u", "v")]}


def errors(row: dict, ref: dict, T0: float, U: float) -> dict:
    """Relative errors of a row against the reference (module docstring)."""
    names = list(ref["history"])
    hT = np.array([ref["history"][k][0] for k in names])
    rise_p = np.max(hT - T0)
    rT = np.array([np.asarray(row["history"][k][0]) for k in names])
    dV = np.array([np.hypot(np.asarray(row["history"][k][1]) - ref["history"][k][1],
                            np.asarray(row["history"][k][2]) - ref["history"][k][2]) for k in names])
    fT, ff = np.asarray(ref["fields"][0]), np.asarray(row["fields"])
    rise_f = np.max(fT - T0)
    out = {"err_T_probes": float(np.max(np.abs(rT - hT)) / rise_p), "err_V_probes": float(np.max(dV) / U),
           "err_T_fields": float(np.max(np.abs(ff[0] - fT)) / rise_f),
           "err_V_fields": float(np.max(np.hypot(ff[1] - ref["fields"][1], ff[2] - ref["fields"][2])) / U)}
    out["error"] = max(out.values())
    return out


def reference_cached(scene: str, t_end: float, dt_ref: float, tol: float, times) -> dict:
    """The Richardson reference (``fine``, ``coarse``, their runs), computed once and cached."""
    CACHE.mkdir(exist_ok=True)
    path = CACHE / f"richardson_{scene}_t{t_end:g}_dt{dt_ref:g}_tol{tol:g}_n{len(times)}.json"
    if path.exists():
        return json.loads(path.read_text())
    wall0 = time.perf_counter()
    with jaxanm.float64():
        fine, coarse, runs = time_steps.reference(scene, t_end, dt_ref, tol, times=times)

    def plain(d):
        return {k: (plain(v) if isinstance(v, dict) else np.asarray(v).tolist()) for k, v in d.items()}

    ref = {"fine": plain(fine), "coarse": plain(coarse), "wall_s": time.perf_counter() - wall0,
           "runs": {repr(dt): {k: v for k, v in r.items() if k not in ("history", "fields")} for dt, r in runs.items()}}
    path.write_text(json.dumps(ref, default=float))
    return ref


def _items(text: str) -> list:
    """The non-empty entries of a comma-separated option."""
    return [t for t in text.split(",") if t.strip()]


def grid(a) -> list:
    """The configurations of the front: ``(method, overrides)``; IDA rows as ``("ida", {rtol, atol})``."""
    rows = []
    anm = {"solver.kind": "anm"}
    mn = {"solver.kind": "modified_newton"}
    for dt in _items(a.dts):
        rows.append(("mnewton", {**mn, "solver.tol": "1e-8", "time.dt": dt}))
    for dt in _items(a.anm_dts):
        rows.append(("anm", {**anm, "solver.tol": "1e-6", "time.dt": dt}))
    for dt in _items(a.newton_dts):
        rows.append(("newton", {"solver.kind": "newton", "solver.tol": "1e-8", "time.dt": dt}))
    for dt in _items(a.knob_dts):
        for tol in ("1e-4", "1e-10"):
            rows.append(("mnewton", {**mn, "solver.tol": tol, "time.dt": dt}))
            rows.append(("anm", {**anm, "solver.tol": tol, "time.dt": dt}))
        rows.append(("mnewton", {**mn, "solver.tol": "1e-8", "solver.max_rate": "0.9", "time.dt": dt}))
        for p in ("5", "10"):
            rows.append(("anm", {**anm, "solver.tol": "1e-6", "solver.adaptive": "false", "solver.order": p, "time.dt": dt}))
    for dt in _items(a.newton_dts)[:1]:
        rows.append(("newton", {"solver.kind": "newton", "solver.tol": "1e-4", "time.dt": dt}))
    for atol in _items(a.atols):
        for method, ov in (("mnewton", mn), ("anm", anm)):
            rows.append((f"{method}+adaptive dt", {**ov, "time.adaptive": "true", "time.rtol": "0", "time.atol": atol,
                                                   "time.dt": "1e-4"}))
    for rtol in _items(a.ida_rtols):
        rows.append(("ida", {"rtol": float(rtol), "atol": float(rtol)}))
    return rows


def run_row(method: str, ov: dict, a, times) -> dict:
    """One configuration, measured (compilation excluded)."""
    if method == "ida":
        return ida_run(a.scene, a.t_end, times, ov["rtol"], ov["atol"])
    base = {"time.t_end": repr(a.t_end), "time.save": ",".join(repr(float(t)) for t in times)
            if ov.get("time.adaptive") == "true" else ""}
    row = time_steps.one_run(a.scene, {**base, **ov}, times=times)
    row["method"] = method
    return row


def label(row: dict) -> str:
    """Short description of a row's settings."""
    ov = row["overrides"]
    if row["method"] == "ida":
        return f"rtol = atol = {ov['rtol']:g}"
    parts = []
    if ov.get("time.adaptive") == "true":
        parts.append(f"atol {ov['time.atol']}")
    else:
        parts.append(f"dt {ov['time.dt']}")
    parts.append(f"tol {ov.get('solver.tol', 'scene')}")
    if "solver.max_rate" in ov:
        parts.append(f"max_rate {ov['solver.max_rate']}")
    if ov.get("solver.adaptive") == "false":
        parts.append(f"p = {ov['solver.order']} fixed")
    elif ov.get("solver.kind") == "anm":
        parts.append("p <= 7 adaptive")
    return ", ".join(parts)


def markdown(rows: list, meta: dict, previous: dict | None = None) -> str:
    """The table of every row, sorted by method then error; with ``previous`` (``{(method,
    settings): (wall, load)}`` of an earlier invocation), its wall time and load beside each row."""
    e = meta["ref_error"]
    lines = [f"Scene `{meta['scene']}` over [0, {meta['t_end']:g}] s, probes compared at t = {', '.join(f'{t:g}' for t in meta['times'])} s, "
             f"fields at t_end.  Reference: Richardson from implicit Euler at dt = {2 * meta['dt_ref']:g}, {meta['dt_ref']:g}, "
             f"{meta['dt_ref'] / 2:g} (modified Newton, tol {meta['ref_tol']:g}); its estimated error: T at the probes "
             f"{e['err_T_probes']:.1e}, V at the probes {e['err_V_probes']:.1e}, T field {e['err_T_fields']:.1e}, "
             f"V field {e['err_V_fields']:.1e}.  {meta['date']}, {meta['cpus']} cores shared with other jobs.", "",
             "| method | settings | steps | factorisations | err T probes | err V probes | err T field | err V field | "
             "error (max) | wall (s) | load before-after |" + (" earlier run: wall (s), load |" if previous else ""),
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |" + (" --- |" if previous else "")]
    for r in sorted(rows, key=lambda r: (r["method"], -r["error"])):
        rep = " (repeat)" if r.get("repeat") else ""
        lines.append(f"| {r['method']}{rep} | {label(r)} | {r['steps']} | {r['factorizations']} | {r['err_T_probes']:.1e} | "
                     f"{r['err_V_probes']:.1e} | {r['err_T_fields']:.1e} | {r['err_V_fields']:.1e} | {r['error']:.1e} | "
                     f"{r['wall_s']:.1f} | {r['load'][0]:.1f}-{r['load'][1]:.1f} |"
                     + (_earlier(previous, r) if previous else ""))
    return "\n".join(lines) + "\n"


def _earlier(previous: dict, row: dict) -> str:
    """The earlier invocation's wall time and load of the same configuration, as a table cell."""
    hit = previous.get((row["method"], label(row), bool(row.get("repeat"))))
    return f" {hit[0]:.1f} ({hit[1]:.1f}) |" if hit else " - |"


def load_previous(path) -> dict:
    """``{(method, settings, repeat): (wall, load)}`` from an earlier invocation's JSON."""
    rows = json.loads(pathlib.Path(path).read_text())["rows"]
    return {(r["method"], label(r), bool(r.get("repeat"))): (r["wall_s"], r["load"][0]) for r in rows if "failed" not in r}


def cheapest(rows: list, levels=(1e-2, 1e-3, 1e-4, 1e-5)) -> list:
    """Per accuracy level: the fastest row of each method reaching it (error <= level)."""
    out = []
    for lev in levels:
        best = {}
        for r in rows:
            if r["error"] <= lev and not r.get("repeat"):
                m = r["method"]
                if m not in best or r["wall_s"] < best[m]["wall_s"]:
                    best[m] = r
        out.append({"level": lev, "by_method": {m: {"wall_s": r["wall_s"], "error": r["error"], "settings": label(r),
                                                    "load": r["load"]} for m, r in sorted(best.items(), key=lambda kv: kv[1]["wall_s"])}})
    return out


def plot(rows: list, path: pathlib.Path) -> None:
    """Error against wall time, one series per method; the lower-left envelope is the front."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.8))
    styles = {"mnewton": ("C1", "o"), "anm": ("C0", "s"), "newton": ("C3", "v"), "mnewton+adaptive dt": ("C1", "D"),
              "anm+adaptive dt": ("C0", "P"), "ida": ("C2", "*")}
    for m, (c, mk) in styles.items():
        sel = [r for r in rows if r["method"] == m and not r.get("repeat")]
        if sel:
            ax.loglog([r["wall_s"] for r in sel], [r["error"] for r in sel], mk, color=c, ms=7 if mk == "*" else 5,
                      mfc="none" if "adaptive" in m else c, label=m)
    pts = sorted((r["wall_s"], r["error"]) for r in rows if not r.get("repeat"))
    front, best = [], np.inf
    for w, e in pts:
        if e < best:
            front.append((w, e))
            best = e
    ax.loglog(*zip(*front), "k:", lw=1, label="front")
    ax.set_xlabel("wall time (s)")
    ax.set_ylabel("error: max rel. of T - T0, V (probes, fields)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> None:
    """Command line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="fsw_tracers")
    ap.add_argument("--t-end", type=float, default=0.1)
    ap.add_argument("--times", default=None, help="common comparison times (default: every t_end / 10)")
    ap.add_argument("--dt-ref", type=float, default=2.5e-5)
    ap.add_argument("--ref-tol", type=float, default=1e-10)
    ap.add_argument("--dts", default="1e-2,2e-3,1e-3,2e-4,1e-4,1e-5", help="fixed dt of modified Newton")
    ap.add_argument("--anm-dts", default="1e-2,1e-3,1e-4", help="fixed dt of the ANM")
    ap.add_argument("--newton-dts", default="1e-2,5e-3", help="fixed dt of Newton")
    ap.add_argument("--knob-dts", default="1e-3")
    ap.add_argument("--atols", default="1e-5,1e-6,1e-7")
    ap.add_argument("--ida-rtols", default="1e-3,1e-4,1e-5,1e-6,1e-7")
    ap.add_argument("--repeat", type=int, default=4, help="rerun this many of the fastest rows (load noise)")
    ap.add_argument("--reference-only", action="store_true")
    ap.add_argument("--previous", default=None, help="JSON of an earlier invocation: its wall times beside this one's")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    times = ([float(t) for t in a.times.split(",")] if a.times else [a.t_end * k / 10 for k in range(1, 11)])
    scene = load_scene(a.scene)
    T0, U = scene.thermal.T0, scene.tool.omega * scene.geometry.R1
    ref_all = reference_cached(a.scene, a.t_end, a.dt_ref, a.ref_tol, times)
    ref = ref_all["fine"]
    ref_err = errors(ref_all["coarse"], ref, T0, U)
    ref_err = {k: v / 3 for k, v in ref_err.items()}
    print(f"reference ({ref_all['wall_s']:.0f} s): estimated error {ref_err}", flush=True)
    if a.reference_only:
        return
    started = time.perf_counter()
    rows = []
    with jaxanm.float64():
        for method, ov in grid(a):
            try:
                row = run_row(method, ov, a, times)
            except Exception as exc:  # noqa: BLE001 - a failed configuration is a row of the front too
                print(f"FAILED {method} {ov}: {exc}", flush=True)
                rows.append({"method": method, "overrides": ov, "failed": str(exc)})
                continue
            row.update(errors(row, ref, T0, U))
            rows.append(row)
            print(f"{method:22s} {label(row):40s} error {row['error']:.2e} wall {row['wall_s']:7.1f} s "
                  f"load {row['load'][0]:.1f} (elapsed {time.perf_counter() - started:.0f} s)", flush=True)
        ok = [r for r in rows if "failed" not in r]
        for r in sorted(ok, key=lambda r: r["wall_s"])[:a.repeat]:
            again = run_row(r["method"], r["overrides"], a, times)
            again.update(errors(again, ref, T0, U))
            again["repeat"] = True
            rows.append(again)
            print(f"repeat {r['method']} {label(r)}: wall {again['wall_s']:.1f} s (first {r['wall_s']:.1f} s), "
                  f"load {again['load'][0]:.1f}", flush=True)
    ok = [r for r in rows if "failed" not in r]
    meta = {"scene": a.scene, "t_end": a.t_end, "times": times, "dt_ref": a.dt_ref, "ref_tol": a.ref_tol,
            "ref_error": ref_err, "ref_wall_s": ref_all["wall_s"], "date": datetime.date.today().isoformat(),
            "cpus": os.cpu_count(), "argv": sys.argv[1:], "front_wall_s": time.perf_counter() - started}
    previous = load_previous(a.previous) if a.previous else None
    if previous:
        meta["previous"] = {f"{k[0]} | {k[1]}{' (repeat)' if k[2] else ''}": v for k, v in previous.items()}
    text = markdown(ok, meta, previous)
    failed = [r for r in rows if "failed" in r]
    if failed:
        text += "\nFailed: " + "; ".join(f"{r['method']} {r['overrides']}: {r['failed']}" for r in failed) + "\n"
    levels = cheapest(ok)
    print(text)
    for lev in levels:
        print(f"error <= {lev['level']:g}: " + ", ".join(f"{m} {v['wall_s']:.1f} s" for m, v in lev["by_method"].items()))
    if a.out:
        out = pathlib.Path(a.out)
        slim = [{k: v for k, v in r.items() if k not in ("history", "fields", "probes")} for r in rows]
        out.with_suffix(".json").write_text(json.dumps({"meta": meta, "reference": {k: v for k, v in ref_all.items()
                                                                                      if k in ("wall_s", "runs")},
                                                        "rows": slim, "cheapest": levels}, indent=1, default=float))
        out.with_suffix(".md").write_text(f"<!-- made by benchmarks/accuracy_cost_paper.py {' '.join(sys.argv[1:])} -->\n\n"
                                          + text, encoding="utf-8")
        plot(ok, out.with_suffix(".png"))
        print(f"wrote {out}.json, .md, .png")


if __name__ == "__main__":
    main()
