"""How far the paper's point spacing is from the continuum: fsw_paper physics at dr, dr/sqrt(2), dr/2.

For each scene of ``--scenes`` (``name:t_end``; by default ``fsw_tracers`` on fixed points to
0.3 s and the Lagrangian ``fsw_paper`` to 0.1 s) and each refinement factor ``f`` of
``--levels`` (``geometry.dr = dr / f``, the scene's other values unchanged), one run with the
fastest solver (modified Newton, ``solver.kind = modified_newton``) records at 0.05, 0.1 and
0.3 s (those within ``t_end``):

- ``T - T0`` at the registration points: the MLS temperature of the solution at the scene's
  probe positions, read from the registration sections (each probe lies on a section sample;
  the nearest *point* would sit at another radius on each cloud);
- the dissipated power ``P_h = int 3 mu epsbar^2 dA`` of the discrete flow (fine quadrature,
  :func:`jaxanm.fsw.energy.dissipated_power`) and ``omega`` times the torque the plate exerts
  on the tool, ``M = R1^2 int tau_rtheta(R1+) dtheta`` (per unit thickness); in the
  quasi-static continuum both equal the mechanical power ``P``;
- the temperature rise along the sections (4 half-lines from the axis), for a relative L2
  error of the profile against the oracle.

Each quantity Q(h), with h the plate's ring spacing (R2 - R1) / round((R2 - R1) / dr), gets a
fitted order p from its three values (``(Q1 - Q2) / (Q2 - Q3) = (h1^p - h2^p) / (h2^p - h3^p)``,
none when the differences change sign) and the Richardson estimate of the continuum value
``Q3 - (Q2 - Q3) h3^p / (h2^p - h3^p)``; beside it the value of the independent axisymmetric
oracle (:mod:`jaxanm.fsw.axisymmetric`, converged in cells and time step) and the slope of
the errors against it.

Every run's raw record is kept in ``--cache`` (one JSON per run, reused when present: delete
it to re-run); ``--analyse-only`` redraws the table from the cache.

    nice -n 10 python benchmarks/spatial_convergence.py --out benchmarks/results/spatial_convergence

Writes ``OUT.json``, ``OUT.md`` and ``OUT.png``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import pathlib
import time

import numpy as np

import jaxanm
from jaxanm.fsw.scene import load_scene

TIMES = (0.05, 0.1, 0.3)
DEFAULT_SCENES = "fsw_tracers:0.3,fsw_paper:0.1"
DEFAULT_LEVELS = "1,1.4142135623730951,2"


def plate_spacing(scene) -> float:
    """Ring spacing of the polar layout's plate, ``(R2 - R1) / round((R2 - R1) / dr)`` (m):
    the h of the convergence fits (it differs from ``dr`` when dr does not divide the gap)."""
    g = scene.geometry
    return (g.R2 - g.R1) / round((g.R2 - g.R1) / g.dr)


def _section_value(result, s: int, x: float, y: float) -> float:
    """T at (x, y) at saved step s, from the section sample at that position."""
    for name, sec in result.sections.items():
        if name == "t":
            continue
        d = np.hypot(sec["x"] - x, sec["y"] - y)
        j = int(np.argmin(d))
        if d[j] < 1e-9:
            return float(sec["T"][s][j])
    raise ValueError(f"no registration-section sample at ({x}, {y}): put the probe on a section")


def _radial_profile(result, s: int) -> tuple[list, list]:
    """(radii, mean T over the section half-lines at that radius) at saved step s."""
    rs, Ts = [], []
    for name, sec in result.sections.items():
        if name == "t":
            continue
        rs.append(np.hypot(sec["x"], sec["y"]))
        Ts.append(np.asarray(sec["T"][s]))
    r, T = np.concatenate(rs), np.concatenate(Ts)
    key = np.round(r / 1e-9).astype(np.int64)
    uniq, inv = np.unique(key, return_inverse=True)
    mean = np.bincount(inv, weights=T) / np.bincount(inv)
    return (uniq * 1e-9).tolist(), mean.tolist()


def tool_torque(result, s: int, angles: int = 256) -> float:
    """Torque per unit thickness (N m / m) the tool exerts on the plate at saved step s:
    ``-R1^2 int tau_rtheta dtheta`` at r = R1 (plate side) of the refitted MLS fields
    (``tau_rtheta < 0`` where v / r falls outwards)."""
    from jaxanm.fsw.energy import _fields  # the refit and evaluation dissipated_power uses

    scene = result.scene
    g, m = scene.geometry, scene.material
    r = g.R1 * (1 + 1e-9)
    th = 2 * math.pi * (np.arange(angles) + 0.5) / angles
    c, sn = np.cos(th), np.sin(th)
    f = _fields(result, s, np.stack([r * c, r * sn], axis=1))
    exx, eyy, exy = f["ux"], f["vy"], 0.5 * (f["uy"] + f["vx"])
    e2 = (2.0 / 3.0) * (exx ** 2 + eyy ** 2 + 2.0 * exy ** 2)
    T = f["T"] if scene.has("softening") else scene.thermal.T0
    mu = m.K / 3.0 * T ** m.A * (e2 + m.eps0 ** 2) ** (0.5 * (m.n - 1.0))
    # e_rtheta = n . e . t with n = (c, s), t = (-s, c)
    e_rt = (eyy - exx) * c * sn + exy * (c * c - sn * sn)
    return float(-r * r * np.mean(2 * mu * e_rt) * 2 * math.pi)


def one_run(scene_name: str, factor: float, t_end: float) -> dict:
    """One measured run at ``dr / factor`` with modified Newton; its record (module docstring)."""
    from jaxanm.fsw.energy import dissipated_power
    from jaxanm.fsw.simulate import run

    base = load_scene(scene_name)
    times = [t for t in TIMES if t <= t_end + 1e-12]
    scene = base.with_overrides({"geometry.dr": repr(base.geometry.dr / factor), "time.t_end": repr(t_end),
                                 "time.save": ",".join(repr(t) for t in times),
                                 "solver.kind": "modified_newton"})
    load0, cpu0, wall0 = os.getloadavg()[0], time.process_time(), time.perf_counter()
    with jaxanm.float64():
        res = run(scene)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    T0, omega = scene.thermal.T0, scene.tool.omega
    rec = {"scene": scene_name, "factor": factor, "dr": scene.geometry.dr, "h": plate_spacing(scene),
           "t_end": t_end, "points": int(res.points.shape[1]), "wall_s": wall, "cpu_s": cpu,
           "load": [load0, os.getloadavg()[0]], "steps": res.stats.time_steps,
           "factorizations": res.stats.factorizations, "wall_time_split": dict(res.stats.wall_time),
           "rezone_times": [float(t) for t in res.rezone_times], "times": {}}
    for t in times:
        s = int(np.argmin(np.abs(res.t - t)))
        assert abs(res.t[s] - t) < 1e-9, (res.t, t)
        radii, prof = _radial_profile(res, s)
        P = dissipated_power(res, s)
        M = tool_torque(res, s)
        pts = res.points[s]
        rec["times"][repr(t)] = {
            "probes": {p.name: _section_value(res, s, p.x, p.y) - T0 for p in scene.probes},
            "P_h": P, "M_omega": M * omega, "M": M,
            "T_edge": _section_value(res, s, scene.geometry.R1, 0.0) - T0,
            "profile_r": radii, "profile_rise": [v - T0 for v in prof],
            "point_r": np.hypot(pts[:, 0], pts[:, 1]).tolist(), "point_rise": (res.T[s] - T0).tolist()}
    return rec


def cached_run(cache: pathlib.Path, scene_name: str, factor: float, t_end: float) -> dict:
    """:func:`one_run`, or its record from ``cache`` if there."""
    path = cache / f"{scene_name}_f{factor:.4f}_t{t_end:g}.json"
    if path.exists():
        return json.loads(path.read_text())
    rec = one_run(scene_name, factor, t_end)
    cache.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(rec))
    print(f"{scene_name} dr/{factor:.4g}: {rec['points']} points, {rec['steps']} steps, {rec['wall_s']:.0f} s, "
          f"rezonings at {rec['rezone_times']}", flush=True)
    return rec


# ------------------------------------------------------------------ analysis

def fitted_order(h, Q) -> float | None:
    """Order p with ``(Q1 - Q2) / (Q2 - Q3) = (h1^p - h2^p) / (h2^p - h3^p)`` for h1 > h2 > h3,
    or None when the differences change sign (no monotone convergence to fit) or p > 8."""
    import scipy.optimize

    d1, d2 = Q[0] - Q[1], Q[1] - Q[2]
    if d1 == 0 or d2 == 0 or np.sign(d1) != np.sign(d2):
        return None
    ratio = d1 / d2

    def g(p):
        return (h[0] ** p - h[1] ** p) / (h[1] ** p - h[2] ** p) - ratio

    lo, hi = 0.05, 8.0
    if g(lo) * g(hi) > 0:
        return None
    return float(scipy.optimize.brentq(g, lo, hi, xtol=1e-10))


def richardson(h, Q, p) -> float | None:
    """Continuum estimate from the two finest values with order p (``Q3 - (Q2 - Q3) h3^p / (h2^p - h3^p)``)."""
    if p is None:
        return None
    return float(Q[2] - (Q[1] - Q[2]) * h[2] ** p / (h[1] ** p - h[2] ** p))


def slope(h, err) -> float | None:
    """Least-squares slope of log err against log h."""
    if min(err) <= 0:
        return None
    return float(np.polyfit(np.log(h), np.log(err), 1)[0])


def oracle_values(scene_name: str, t_end: float) -> dict:
    """The oracle's probe rises, T(R1) rise, power and radial profile at the study's times."""
    from jaxanm.fsw import axisymmetric

    scene = load_scene(scene_name)
    times = [t for t in TIMES if t <= t_end + 1e-12]
    sol = axisymmetric.solve(scene, times, estimate=True)
    out = {}
    for i, t in enumerate(times):
        probes = {p.name: float(sol.temperature(math.hypot(p.x, p.y), i)) - scene.thermal.T0 for p in scene.probes}
        out[repr(t)] = {"probes": probes, "P": float(sol.power[i]),
                        "T_edge": float(sol.temperature(scene.geometry.R1, i)) - scene.thermal.T0,
                        "sol": sol, "index": i}
    out["error"] = sol.error_estimate
    return out


def analyse(records: list, oracle: dict) -> dict:
    """Orders, Richardson estimates and errors against the oracle, per scene, time, quantity."""
    table = {}
    for name in sorted({r["scene"] for r in records}):
        runs = sorted([r for r in records if r["scene"] == name], key=lambda r: -r["h"])
        h = [r["h"] for r in runs]
        orc = oracle[name]
        times = sorted({t for r in runs for t in r["times"]}, key=float)
        table[name] = {"h": h, "points": [r["points"] for r in runs], "wall_s": [r["wall_s"] for r in runs],
                       "rezone_times": [r["rezone_times"] for r in runs], "times": {}}
        for t in times:
            rows = {}
            quantities = [(f"T-T0 at probe {k}", [r["times"][t]["probes"][k] for r in runs], orc[t]["probes"][k])
                          for k in runs[0]["times"][t]["probes"]]
            quantities += [("T-T0 at r = R1", [r["times"][t]["T_edge"] for r in runs], orc[t]["T_edge"]),
                           ("P_h (W/m)", [r["times"][t]["P_h"] for r in runs], orc[t]["P"]),
                           ("omega M (W/m)", [r["times"][t]["M_omega"] for r in runs], orc[t]["P"])]
            if len(runs) == 3 and all(t in r["times"] for r in runs):
                for label, Q, ref in quantities:
                    p = fitted_order(h, Q)
                    err = [abs(q - ref) for q in Q]
                    rows[label] = {"values": Q, "order": p, "richardson": richardson(h, Q, p),
                                   "richardson_p1": richardson(h, Q, 1.0), "oracle": ref,
                                   "rel_error_vs_oracle": [e / abs(ref) for e in err], "slope_vs_oracle": slope(h, err)}
                # relative L2 errors of the rise against the oracle: over the section profile and
                # over the points (the measure)
                sol, i = orc[t]["sol"], orc[t]["index"]
                l2_prof, l2_pts = [], []
                for r in runs:
                    rec = r["times"][t]
                    ref_p = sol.temperature(np.asarray(rec["profile_r"]), i) - sol.T0
                    got = np.asarray(rec["profile_rise"])
                    l2_prof.append(float(np.linalg.norm(got - ref_p) / np.linalg.norm(ref_p)))
                    ref_q = sol.temperature(np.asarray(rec["point_r"]), i) - sol.T0
                    got = np.asarray(rec["point_rise"])
                    l2_pts.append(float(np.linalg.norm(got - ref_q) / np.linalg.norm(ref_q)))
                rows["rel. L2 error of the rise, sections"] = {"values": l2_prof, "slope": slope(h, l2_prof)}
                rows["rel. L2 error of the rise, points"] = {"values": l2_pts, "slope": slope(h, l2_pts)}
            table[name]["times"][t] = rows
    return table


def _fmt(x, spec=".4g"):
    return "—" if x is None else format(x, spec)


def markdown(table: dict, meta: dict) -> str:
    """The tables of the study."""
    lines = ["# Spatial convergence of the fsw_paper physics", "",
             f"{meta['date']}; `python benchmarks/spatial_convergence.py` (modified Newton, the scenes' dt = 1e-4); "
             f"oracle: `jaxanm.fsw.axisymmetric` (estimated error {meta['oracle_error']}).  h is the plate's ring "
             "spacing; p the order fitted to the three values, 'continuum (p)' the Richardson estimate with that p "
             "('—' where the three values do not converge monotonically), 'continuum (1)' the one with p = 1 from "
             "the two finest; 'rel. err.' is |Q - oracle| / |oracle| at dr, dr/sqrt 2, dr/2 and 'slope' the fitted "
             "slope of those errors against h.", ""]
    for name, sc in table.items():
        lines += [f"## {name}", "",
                  "h (mm): " + ", ".join(f"{x * 1e3:.4g}" for x in sc["h"]) + "; points: "
                  + ", ".join(str(x) for x in sc["points"]) + "; wall (s): "
                  + ", ".join(f"{x:.0f}" for x in sc["wall_s"]) + "; rezonings at (s): "
                  + "; ".join(", ".join(f"{t:.4f}" for t in z) or "none" for z in sc["rezone_times"]), ""]
        for t, rows in sc["times"].items():
            if not rows:
                continue
            lines += [
                f"### t = {float(t):g} s",
                "",
                "| quantity | dr | dr/√2 | dr/2 | p | continuum (p) | continuum (1) | oracle "
                "| rel. err. (dr, dr/√2, dr/2) | slope |",
                "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
            ]
            for label, row in rows.items():
                if "oracle" in row:
                    v = row["values"]
                    lines.append(
                        f"| {label} | {v[0]:.4g} | {v[1]:.4g} | {v[2]:.4g} | {_fmt(row['order'], '.2f')} | "
                        f"{_fmt(row['richardson'])} | {_fmt(row['richardson_p1'])} | {row['oracle']:.4g} | "
                        + ", ".join(f"{e:.3f}" for e in row["rel_error_vs_oracle"])
                        + f" | {_fmt(row['slope_vs_oracle'], '.2f')} |"
                    )
                else:
                    v = row["values"]
                    lines.append(
                        f"| {label} | {v[0]:.3f} | {v[1]:.3f} | {v[2]:.3f} | | | | 0 | | {_fmt(row['slope'], '.2f')} |"
                    )
            lines.append("")
    return "\n".join(lines) + "\n"


def plot(table: dict, path: pathlib.Path) -> None:
    """Relative error against the oracle vs h: probe rises and power, per scene and time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(table), figsize=(5.2 * len(table), 4.2), squeeze=False)
    for ax, (name, sc) in zip(axes[0], table.items()):
        h = np.asarray(sc["h"]) * 1e3
        for ti, (t, rows) in enumerate(sc["times"].items()):
            if not rows:
                continue
            for qi, label in enumerate(["T-T0 at probe 1", "T-T0 at probe 2", "T-T0 at probe 3", "P_h (W/m)"]):
                if label in rows:
                    ax.loglog(
                        h,
                        rows[label]["rel_error_vs_oracle"],
                        ["o-", "s-", "^-", "d--"][qi],
                        color=f"C{ti}",
                        ms=4,
                        label=f"{label.split(' (')[0]}, t = {float(t):g} s",
                    )
        ax.loglog(h, 0.15 * (h / h[0]), "k:", lw=1, label="slope 1")
        ax.set_title(name)
        ax.set_xlabel("plate ring spacing h (mm)")
        ax.set_ylabel("|Q - oracle| / |oracle|")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None) -> None:
    """Command line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default=DEFAULT_SCENES, help="name:t_end,... (default %(default)s)")
    ap.add_argument("--levels", default=DEFAULT_LEVELS, help="refinement factors f, dr / f")
    ap.add_argument("--cache", default="results/spatial_convergence")
    ap.add_argument("--analyse-only", action="store_true")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    cache = pathlib.Path(a.cache)
    scenes = [(s.split(":")[0], float(s.split(":")[1])) for s in a.scenes.split(",")]
    levels = [float(f) for f in a.levels.split(",")]
    records = []
    for name, t_end in scenes:
        for f in levels:
            path = cache / f"{name}_f{f:.4f}_t{t_end:g}.json"
            if a.analyse_only:
                if path.exists():
                    records.append(json.loads(path.read_text()))
            else:
                records.append(cached_run(cache, name, f, t_end))
    oracle = {name: oracle_values(name, t_end) for name, t_end in scenes}
    table = analyse(records, oracle)
    meta = {
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "oracle_error": "; ".join(f"{n}: {oracle[n]['error']}" for n in oracle),
        "scenes": a.scenes,
        "levels": levels,
    }
    text = markdown(table, meta)
    print(text)
    if a.out:
        out = pathlib.Path(a.out)
        out.with_suffix(".md").write_text(text)
        out.with_suffix(".json").write_text(
            json.dumps(
                {"meta": meta, "table": table, "runs": [{k: v for k, v in r.items() if k != "times"} for r in records]},
                indent=1,
            )
        )
        plot(table, out.with_suffix(".png"))


if __name__ == "__main__":
    main()
