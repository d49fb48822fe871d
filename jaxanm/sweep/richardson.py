"""A reference converged in time: Richardson extrapolation of three implicit-Euler runs.

Implicit Euler is first order: a value computed at step h is ``x(h) = x* + C h + O(h^2)``, so
``2 x(h/2) - x(h)`` cancels the ``C h`` term and is second order.  From runs at ``dt``,
``dt/2`` and ``dt/4`` (a grid's ``[reference.richardson]``, :mod:`jaxanm.sweep.grid`):

- the reference is the **fine** extrapolation ``2 x(dt/4) - x(dt/2)``;
- its error is estimated from the **coarse** one ``2 x(dt/2) - x(dt)``: both are second order,
  so ``coarse - fine ~ (4 - 1) (fine - x*)`` and the estimate is ``|coarse - fine| / 3``, in
  each of the error measures of :func:`jaxanm.fsw.compare.differences` (the coarse
  extrapolation measured against the fine one, divided by 3).

Values are extrapolated where all three runs recorded them: the fields at their common saved
times, the probes at those same times (the reference's probe history holds t = 0 and the save
times only, so that every task is compared with it at the same times), and the material point
positions with them (they move in Lagrangian scenes; a fixed cloud extrapolates to itself).
Extrapolation assumes the values are smooth in h: a Lagrangian run whose cloud was rezoned at
different times in the three runs is not, and the estimate then says so by being large.

The reference is written as a run directory (:func:`jaxanm.fsw.compare.write_run`) whose
``summary.json`` is the finest run's with ``solver.kind = "richardson"`` and the three runs'
counters and wall times summed (the reference's cost).
"""

from __future__ import annotations

import copy

import numpy as np

from jaxanm.fsw.compare import common_times, differences, load_run, write_run

__all__ = ["ESTIMATE_KEYS", "extrapolate", "reference", "write_reference"]

ESTIMATE_KEYS = ("max_rel_dV", "max_rel_dT", "max_dpoints_m", "probe_max_dT_K", "probe_rel_dT",
                 "probe_max_dV_over_omegaR1")
"""The measures of :func:`jaxanm.fsw.compare.differences` that the error estimate gives (each / 3)."""


def extrapolate(fine: dict, coarse: dict) -> dict:
    """``2 fine - coarse`` (runs as :func:`jaxanm.fsw.compare.load_run` returns them, ``fine`` at
    half the step of ``coarse``) at t = 0 and the saved times both have (module docstring).

    Raises ``ValueError`` when the two runs saved their fields at no common time t > 0.
    """
    f, g = fine["fields"], coarse["fields"]
    fi, fj = common_times(f["t"], g["t"])
    if fi.size == 0:
        raise ValueError(f"{fine['dir']} and {coarse['dir']} saved their fields at no common time t > 0: "
                         "run them with the same time.save and t_end")
    fi, fj = np.concatenate([[0], fi]), np.concatenate([[0], fj])  # both start from the initial state
    fields = {"t": f["t"][fi], "material": f["material"]}
    for key in ("points", "u", "v", "T"):
        fields[key] = 2 * f[key][fi] - g[key][fj]
    p, q = fine["probes"], coarse["probes"]
    pi, pj = common_times(p["t"], q["t"])
    keep = common_times(p["t"][pi], fields["t"])[0]  # the probes at the save times only
    pi, pj = np.concatenate([[0], pi[keep]]), np.concatenate([[0], pj[keep]])
    probes = np.zeros(pi.size, dtype=p.dtype)
    probes["t"] = p["t"][pi]
    for name in p.dtype.names[1:]:
        probes[name] = 2 * p[name][pi] - q[name][pj]
    return {"dir": f"2 x({fine['dir']}) - x({coarse['dir']})", "summary": fine["summary"], "fields": fields,
            "probes": probes}


def reference(runs: list[dict]) -> tuple[dict, dict]:
    """The reference from runs at dt, dt/2, dt/4 (in that order) and its estimated error.

    Returns ``(run, estimate)``: the fine extrapolation as a run (with the summary of the
    module docstring) and ``{key: value}`` for :data:`ESTIMATE_KEYS` (each a third of the coarse
    extrapolation's difference from the fine one), plus ``n_field_times`` and ``n_probe_times``.
    """
    if len(runs) != 3:
        raise ValueError(f"a Richardson reference takes three runs (dt, dt/2, dt/4), got {len(runs)}")
    coarse_run, mid, fine_run = runs
    fine, coarse = extrapolate(fine_run, mid), extrapolate(mid, coarse_run)
    d = differences(coarse, fine)
    estimate = {k: d[k] / 3 for k in ESTIMATE_KEYS}
    estimate.update(n_field_times=d["n_field_times"], n_probe_times=d["n_probe_times"])
    summary = copy.deepcopy(fine_run["summary"])
    dts = [r["summary"]["scene"]["time"]["dt"] for r in runs]
    summary["solver"] = {"kind": "richardson", "options": {"dt": dts, "solver": fine_run["summary"]["solver"]}}
    summary["stats"] = _summed([r["summary"]["stats"] for r in runs])
    summary["richardson_estimate"] = estimate
    fine["summary"] = summary
    return fine, estimate


def write_reference(run_dirs, out_dir) -> tuple[dict, dict]:
    """:func:`reference` of the run directories ``run_dirs`` (dt, dt/2, dt/4), written to ``out_dir``;
    returns ``(run, estimate)`` with the run as :func:`jaxanm.fsw.compare.load_run` reads it back."""
    run, estimate = reference([load_run(d) for d in run_dirs])
    write_run(run, out_dir)
    return load_run(out_dir), estimate


def _summed(stats: list[dict]) -> dict:
    """Counters and wall times of several runs' ``summary.json`` stats, summed (lists dropped)."""
    out = {}
    for key, value in stats[0].items():
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            out[key] = sum(s[key] for s in stats)
        elif isinstance(value, dict):
            out[key] = {k: sum(s[key].get(k, 0.0) for s in stats) for k in value}
    return out
