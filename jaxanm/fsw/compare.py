"""Cost and agreement of ``jaxanm run`` output directories of the same scene.

:func:`load_run` reads what a run wrote (``summary.json``, ``fields.npz``, ``probes.csv``),
:func:`write_run` writes such a directory from its parts (a computed reference),
:func:`cost_row` takes its solver and cost figures from the summary, and :func:`differences`
measures how far one run is from another **at the times both recorded** (runs at different
step sizes, adaptive steps and IDA compare wherever their times coincide, within
:data:`TIME_MATCH` of the span; never step by step):

- fields at every common saved time t > 0, each against its own yardstick:
  max |(u, v) - (u, v)_ref| / max |V_ref|, max |T - T_ref| / max |T_ref - T0|, and
  max |points - points_ref| (m); the largest over the common times is reported;
- probe histories at every common time t > 0 (a fixed-step run records every step, a
  computed reference only its save times): max |T - T_ref| (K), the same relative to the
  reference's largest |T - T0| over the probes and those times, and
  max |(u, v) - (u, v)_ref| / (omega R1), over the times and registration points.

Two runs with no common time t > 0 (of the fields, or of the probes) cannot be compared:
:func:`differences` raises a ``ValueError`` naming both runs' times and the fix (save both at
common times, ``time.save``).

Used by ``benchmarks/compare_runs.py`` (runs side by side) and :mod:`jaxanm.sweep` (errors of
a sweep's tasks against a reference run).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

__all__ = ["TIME_MATCH", "common_times", "cost_row", "differences", "load_run", "write_run"]

TIME_MATCH = 1e-9
"""Two recorded times are the same time when they differ by at most this fraction of the later
run's span: fixed steps accumulate rounding of ~1e-16 per step (1e-12 after 10^4 steps), while
distinct steps differ by dt >= 1e-7 of the span in any run worth comparing."""


def load_run(path: str | os.PathLike) -> dict:
    """Summary, fields and probe histories of one run directory."""
    path = Path(path)
    missing = [name for name in ("summary.json", "fields.npz", "probes.csv") if not (path / name).is_file()]
    if missing:
        raise FileNotFoundError(f"{path} is not the output directory of a finished `jaxanm run` (no "
                                f"{', '.join(missing)}); pass the --out DIR of each run to compare")
    summary = json.loads((path / "summary.json").read_text(encoding="utf-8"))
    fields = dict(np.load(path / "fields.npz"))
    probes = np.atleast_1d(np.genfromtxt(path / "probes.csv", delimiter=",", names=True))
    return {"dir": str(path), "summary": summary, "fields": fields, "probes": probes}


def write_run(run: dict, path: str | os.PathLike) -> Path:
    """Write ``run`` (the layout :func:`load_run` returns) as a run directory at ``path``.

    ``probes`` is a structured array whose first column is ``t``; floats are written with 17
    significant digits (exact round trip), as ``jaxanm run`` writes them.
    """
    from jaxanm.checkpoint import atomic_path

    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    with atomic_path(path / "fields.npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **run["fields"])
    names = run["probes"].dtype.names
    with atomic_path(path / "probes.csv") as tmp:
        np.savetxt(tmp, np.column_stack([run["probes"][c] for c in names]), fmt="%.17g", delimiter=",",
                   header=",".join(names), comments="")
    with atomic_path(path / "summary.json") as tmp:
        tmp.write_text(json.dumps(run["summary"], indent=2) + "\n", encoding="utf-8")
    return path


def cost_row(run: dict) -> dict:
    """Solver and cost figures of one run, from its ``summary.json``, and its error against the
    continuum (``continuum_err``: the temperature rise's relative L2 error at the last saved
    time, ``spatial_accuracy.rise_error``; None without one)."""
    s = run["summary"]
    st = s["stats"]
    solver = s["solver"]["kind"] + "".join(f" {k}={v}" for k, v in s["solver"]["options"].items()
                                           if k in ("order", "tol", "rtol", "atol"))
    rise = (s.get("spatial_accuracy") or {}).get("rise_error") or {}
    return {"dir": run["dir"], "solver": solver, "t_end": s["t_end"], "time_steps": st["time_steps"],
            "factorizations": st["factorizations"], "newton_iterations": st["newton_iterations"],
            "series_orders": st["series_orders"], "wall_s": st["wall_time_s"], "split_s": st["wall_time"],
            "continuum_err": rise.get("rel_l2")}


def common_times(t, t_ref) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i, j)`` with ``t[i] == t_ref[j] > 0`` within :data:`TIME_MATCH` of the span.

    Both arrays must increase (a run's saved or recorded times do).
    """
    t, t_ref = np.asarray(t, dtype=np.float64), np.asarray(t_ref, dtype=np.float64)
    if t.size == 0 or t_ref.size == 0:
        return np.zeros(0, dtype=int), np.zeros(0, dtype=int)
    tol = TIME_MATCH * max(float(np.max(np.abs(t))), float(np.max(np.abs(t_ref))), 1e-300)
    above = np.searchsorted(t_ref, t)
    lo, hi = np.clip(above - 1, 0, t_ref.size - 1), np.clip(above, 0, t_ref.size - 1)
    j = np.where(np.abs(t_ref[lo] - t) <= np.abs(t_ref[hi] - t), lo, hi)  # the nearest recorded time
    hit = (np.abs(t_ref[j] - t) <= tol) & (t > tol)
    return np.flatnonzero(hit), j[hit]


def _times_text(t) -> str:
    """A short description of recorded times for an error message."""
    t = np.asarray(t, dtype=np.float64)
    t = t[t > 0]
    if t.size == 0:
        return "none after t = 0"
    if t.size <= 4:
        return ", ".join(f"{x:.6g}" for x in t)
    return f"{t.size} times from {t[0]:.6g} to {t[-1]:.6g}"


def _matched(t, t_ref, what: str, run: dict, ref: dict) -> tuple[np.ndarray, np.ndarray]:
    """:func:`common_times`, or a ``ValueError`` naming the problem when there is none."""
    i, j = common_times(t, t_ref)
    if i.size == 0:
        raise ValueError(f"{run['dir']} and {ref['dir']} recorded {what} at no common time t > 0 "
                         f"({_times_text(t)} against {_times_text(t_ref)}); errors are measured only where both "
                         "recorded: save both runs at common times (time.save; fixed steps that divide them)")
    return i, j


def differences(run: dict, ref: dict) -> dict:
    """How far ``run`` is from ``ref`` at the times both recorded (module docstring).

    A relative difference is NaN where its yardstick is 0 (no velocity in a pure-conduction
    scene, T = T0 in an isothermal one), and its maximum over the common times is NaN only
    when the field is absent at all of them.  ``n_field_times`` and ``n_probe_times`` count the
    common times compared.
    """
    f, g = run["fields"], ref["fields"]
    fi, fj = _matched(f["t"], g["t"], "fields", run, ref)
    scene = ref["summary"]["scene"]
    T0, speed = scene["thermal"]["T0"], scene["tool"]["omega"] * scene["geometry"]["R1"]
    dV_abs = np.hypot(f["u"][fi] - g["u"][fj], f["v"][fi] - g["v"][fj])
    dV, max_dV = _relative(np.max(dV_abs, axis=1), np.max(np.hypot(g["u"][fj], g["v"][fj]), axis=1))
    dT, max_dT = _relative(np.max(np.abs(f["T"][fi] - g["T"][fj]), axis=1), np.max(np.abs(g["T"][fj] - T0), axis=1))
    dx = np.max(np.abs(f["points"][fi] - g["points"][fj]), axis=(1, 2))
    p, q = run["probes"], ref["probes"]
    pi, pj = _matched(p["t"], q["t"], "probes", run, ref)
    T_cols = [c for c in q.dtype.names if c.endswith("_T")]
    probe_dT = probe_rel_dT = probe_dV = float("nan")
    if T_cols:
        vel = [(c[:-2] + "_u", c[:-2] + "_v") for c in T_cols]
        probe_dT = max(float(np.max(np.abs(p[c][pi] - q[c][pj]))) for c in T_cols)
        rise = max(float(np.max(np.abs(q[c][pj] - T0))) for c in T_cols)
        probe_rel_dT = probe_dT / rise if rise > 0 else float("nan")
        probe_dV = max(float(np.max(np.hypot(p[u][pi] - q[u][pj], p[v][pi] - q[v][pj]))) for u, v in vel) / speed
    return {"dir": run["dir"], "max_rel_dV": max_dV, "max_rel_dT": max_dT,
            "max_dpoints_m": float(dx.max()), "per_saved_time": {"t": g["t"][fj].tolist(),
                                                                  "rel_dV": dV.tolist(), "rel_dT": dT.tolist()},
            "probe_max_dT_K": probe_dT, "probe_rel_dT": probe_rel_dT, "probe_max_dV_over_omegaR1": probe_dV,
            "n_field_times": int(fi.size), "n_probe_times": int(pi.size)}


def _relative(difference: np.ndarray, yardstick: np.ndarray) -> tuple[np.ndarray, float]:
    """``difference / yardstick`` per saved time (NaN where the yardstick is 0: the field is absent)
    and its largest value over the times where the field is present (NaN if it is absent at all).

    A NaN of the run itself (a non-finite field) where the field is present is kept.
    """
    present = yardstick > 0
    per_time = np.full(difference.shape, np.nan)
    np.divide(difference, yardstick, out=per_time, where=present)
    return per_time, float(np.max(per_time[present])) if present.any() else float("nan")
