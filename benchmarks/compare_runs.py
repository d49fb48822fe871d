"""Side by side: cost and agreement of `jaxanm run` output directories of the same scene.

Typical use, the ANM and Newton on the paper's scene (each run is a README command; the two
can run at the same time, one per core)::

    jaxanm run fsw_paper --out runs/anm
    jaxanm run fsw_paper --solver newton --out runs/newton --checkpoint-every 200
    python benchmarks/compare_runs.py runs/anm runs/newton --out docs/fsw_paper_anm_vs_newton

For every directory it reads ``summary.json`` (solver, factorisations, Newton iterations,
time steps, the wall-time split) and prints one row per run with the ratios to the first run.
It then measures how far each run is from the first one on what both saved:

- fields (``fields.npz``) at every saved time t > 0, each against its own yardstick:
  max |V - V_ref| / max V_ref, max |T - T_ref| / max |T_ref - T0|, and
  max |points - points_ref| (m); the largest over the saved times is reported;
- probe histories (``probes.csv``, every step): max |T - T_ref| (K) and
  max |(u, v) - (u, v)_ref| / (omega R1) over all steps and registration points.

Writes ``OUT.md`` and ``OUT.json`` with ``--out``.  Nothing is run here: the wall times are
those the runs measured (``summary.json``), so quote the load the runs shared.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np


def load_run(path: str | os.PathLike) -> dict:
    """Summary, fields and probe histories of one run directory."""
    path = Path(path)
    missing = [name for name in ("summary.json", "fields.npz", "probes.csv") if not (path / name).is_file()]
    if missing:
        raise FileNotFoundError(f"{path} is not the output directory of a finished `jaxanm run` (no "
                                f"{', '.join(missing)}); pass the --out DIR of each run to compare")
    summary = json.loads((path / "summary.json").read_text(encoding="utf-8"))
    fields = dict(np.load(path / "fields.npz"))
    probes = np.genfromtxt(path / "probes.csv", delimiter=",", names=True)
    return {"dir": str(path), "summary": summary, "fields": fields, "probes": probes}


def cost_row(run: dict) -> dict:
    """Solver and cost figures of one run, from its ``summary.json``."""
    s = run["summary"]
    st = s["stats"]
    solver = s["solver"]["kind"] + "".join(f" {k}={v}" for k, v in s["solver"]["options"].items()
                                           if k in ("order", "tol"))
    return {"dir": run["dir"], "solver": solver, "t_end": s["t_end"], "time_steps": st["time_steps"],
            "factorizations": st["factorizations"], "newton_iterations": st["newton_iterations"],
            "series_orders": st["series_orders"], "wall_s": st["wall_time_s"], "split_s": st["wall_time"]}


def differences(run: dict, ref: dict) -> dict:
    """How far ``run`` is from ``ref`` on the fields and probe histories both saved."""
    f, g = run["fields"], ref["fields"]
    if f["t"].shape != g["t"].shape or not np.allclose(f["t"], g["t"]):
        raise ValueError(f"{run['dir']} and {ref['dir']} saved fields at different times; "
                         "compare runs of the same scene and time settings")
    scene = ref["summary"]["scene"]
    T0, speed = scene["thermal"]["T0"], scene["tool"]["omega"] * scene["geometry"]["R1"]
    later = f["t"] > 0  # at t = 0 both hold the initial state (T - T0 = 0)
    V, V_ref = np.hypot(f["u"], f["v"]), np.hypot(g["u"], g["v"])
    dV = np.max(np.abs(V - V_ref)[later], axis=1) / np.max(V_ref[later], axis=1)
    dT = np.max(np.abs(f["T"] - g["T"])[later], axis=1) / np.max(np.abs(g["T"] - T0)[later], axis=1)
    dx = np.max(np.abs(f["points"] - g["points"]), axis=(1, 2))
    p, q = run["probes"], ref["probes"]
    if len(p) != len(q):
        raise ValueError(f"{run['dir']} and {ref['dir']} hold probe histories of different lengths")
    names = p.dtype.names
    T_cols = [c for c in names if c.endswith("_T")]
    vel = [(c[:-2] + "_u", c[:-2] + "_v") for c in T_cols]
    probe_dT = max(float(np.max(np.abs(p[c] - q[c]))) for c in T_cols)
    probe_dV = max(float(np.max(np.hypot(p[u] - q[u], p[v] - q[v]))) for u, v in vel) / speed
    return {"dir": run["dir"], "max_rel_dV": float(dV.max()), "max_rel_dT": float(dT.max()),
            "max_dpoints_m": float(dx.max()), "per_saved_time": {"t": f["t"][later].tolist(),
                                                                  "rel_dV": dV.tolist(), "rel_dT": dT.tolist()},
            "probe_max_dT_K": probe_dT, "probe_max_dV_over_omegaR1": probe_dV}


def markdown(costs: list[dict], diffs: list[dict]) -> str:
    """Cost table with ratios to the first run, then the agreement table."""
    ref = costs[0]
    lines = ["| run | solver | steps | factorisations | Newton iterations | series orders | wall (s) | "
             "wall / first | Jacobians (s) | factorise (s) | series (s) | solves (s) | other (s) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for c in costs:
        sp = c["split_s"]
        lines.append(f"| `{c['dir']}` | {c['solver']} | {c['time_steps']} | {c['factorizations']} | "
                     f"{c['newton_iterations']} | {c['series_orders']} | {c['wall_s']:.0f} | "
                     f"{c['wall_s'] / ref['wall_s']:.2f} | {sp.get('jacobian', 0):.0f} | "
                     f"{sp.get('factorize', 0):.0f} | {sp.get('series', 0):.0f} | {sp.get('solve', 0):.0f} | "
                     f"{sp.get('other', 0):.0f} |")
    if diffs:
        lines += ["", f"Agreement with `{ref['dir']}`:", "",
                  "| run | max rel. V difference (fields) | max rel. T - T0 difference (fields) | "
                  "max point shift (m) | probes: max T difference (K) | probes: max velocity difference / (omega R1) |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for d in diffs:
            lines.append(f"| `{d['dir']}` | {d['max_rel_dV']:.2e} | {d['max_rel_dT']:.2e} | "
                         f"{d['max_dpoints_m']:.1e} | {d['probe_max_dT_K']:.1e} | {d['probe_max_dV_over_omegaR1']:.1e} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="output directories of `jaxanm run`; the first is the reference")
    ap.add_argument("--out", default=None, help="write OUT.md and OUT.json")
    args = ap.parse_args(argv)
    runs = [load_run(d) for d in args.runs]
    costs = [cost_row(r) for r in runs]
    diffs = [differences(r, runs[0]) for r in runs[1:]]
    table = markdown(costs, diffs)
    print(table)
    if args.out:
        Path(args.out + ".json").write_text(json.dumps({"costs": costs, "differences": diffs}, indent=1) + "\n",
                                            encoding="utf-8")
        Path(args.out + ".md").write_text(table, encoding="utf-8")


if __name__ == "__main__":
    main()
