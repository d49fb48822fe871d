"""Cost and agreement of ``jaxanm run`` output directories of the same scene.

:func:`load_run` reads what a run wrote (``summary.json``, ``fields.npz``, ``probes.csv``),
:func:`cost_row` takes its solver and cost figures from the summary, and :func:`differences`
measures how far one run is from another on what both saved:

- fields at every saved time t > 0, each against its own yardstick:
  max |V - V_ref| / max V_ref, max |T - T_ref| / max |T_ref - T0|, and
  max |points - points_ref| (m); the largest over the saved times is reported;
- probe histories (every step): max |T - T_ref| (K) and
  max |(u, v) - (u, v)_ref| / (omega R1) over all steps and registration points.

Used by ``benchmarks/compare_runs.py`` (runs side by side) and :mod:`jaxanm.sweep` (errors of
a sweep's tasks against a reference run).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

__all__ = ["cost_row", "differences", "load_run"]


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
    """How far ``run`` is from ``ref`` on the fields and probe histories both saved.

    A relative field difference is NaN at a saved time where the reference's yardstick is 0
    (no velocity in a pure-conduction scene, T = T0 in an isothermal one), and its maximum over
    the saved times is NaN only when the field is absent at all of them.
    """
    f, g = run["fields"], ref["fields"]
    if f["t"].shape != g["t"].shape or not np.allclose(f["t"], g["t"]):
        raise ValueError(f"{run['dir']} and {ref['dir']} saved fields at different times; "
                         "compare runs of the same scene and time settings")
    scene = ref["summary"]["scene"]
    T0, speed = scene["thermal"]["T0"], scene["tool"]["omega"] * scene["geometry"]["R1"]
    later = f["t"] > 0  # at t = 0 both hold the initial state (T - T0 = 0)
    V, V_ref = np.hypot(f["u"], f["v"]), np.hypot(g["u"], g["v"])
    dV, max_dV = _relative(np.max(np.abs(V - V_ref)[later], axis=1), np.max(V_ref[later], axis=1))
    dT, max_dT = _relative(np.max(np.abs(f["T"] - g["T"])[later], axis=1), np.max(np.abs(g["T"] - T0)[later], axis=1))
    dx = np.max(np.abs(f["points"] - g["points"]), axis=(1, 2))
    p, q = run["probes"], ref["probes"]
    if len(p) != len(q):
        raise ValueError(f"{run['dir']} and {ref['dir']} hold probe histories of different lengths")
    names = p.dtype.names
    T_cols = [c for c in names if c.endswith("_T")]
    vel = [(c[:-2] + "_u", c[:-2] + "_v") for c in T_cols]
    probe_dT = max(float(np.max(np.abs(p[c] - q[c]))) for c in T_cols)
    probe_dV = max(float(np.max(np.hypot(p[u] - q[u], p[v] - q[v]))) for u, v in vel) / speed
    return {"dir": run["dir"], "max_rel_dV": max_dV, "max_rel_dT": max_dT,
            "max_dpoints_m": float(dx.max()), "per_saved_time": {"t": f["t"][later].tolist(),
                                                                  "rel_dV": dV.tolist(), "rel_dT": dT.tolist()},
            "probe_max_dT_K": probe_dT, "probe_max_dV_over_omegaR1": probe_dV}


def _relative(difference: np.ndarray, yardstick: np.ndarray) -> tuple[np.ndarray, float]:
    """``difference / yardstick`` per saved time (NaN where the yardstick is 0: the field is absent)
    and its largest value over the times where the field is present (NaN if it is absent at all).

    A NaN of the run itself (a non-finite field) where the field is present is kept.
    """
    present = yardstick > 0
    per_time = np.full(difference.shape, np.nan)
    np.divide(difference, yardstick, out=per_time, where=present)
    return per_time, float(np.max(per_time[present])) if present.any() else float("nan")
