"""The Pareto plot of a sweep: error against wall time, log-log, one marker per solver kind.

Each finished task with a positive error (``rel_err`` of :mod:`jaxanm.sweep.table`) is a point
at its time loop's wall time (``wall_s``), labelled with its task id; the line joins the
points no other point beats in both error and time (the front).  The reference run itself
(error 0) cannot sit on a log axis and is named in the title instead.
"""

from __future__ import annotations

import math
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter

from jaxanm.checkpoint import atomic_path

__all__ = ["MARKERS", "cheapest", "method", "pareto_front", "plot_pareto"]

MARKERS = {"anm": "o", "newton": "s", "mnewton": "^", "modified_newton": "^", "ida": "*"}
"""Marker of each solver kind (``summary.json``'s ``solver.kind``; ``modified_newton``: the former
spelling of ``mnewton``, in older tables)."""


def pareto_front(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The ``(time, error)`` points that no other point beats in both, by increasing time."""
    front, best = [], math.inf
    for time, error in sorted(points):
        if error < best:
            front.append((time, error))
            best = error
    return front


def method(row: dict) -> str:
    """A row's method: its solver kind, with ``+adaptive dt`` when its steps are adaptive."""
    adaptive = str(row.get("time.adaptive", "")).lower() == "true"
    return f"{row['kind']}+adaptive dt" if adaptive else str(row["kind"])


def cheapest(rows: list[dict], levels=(1e-2, 1e-3, 1e-4, 1e-5)) -> list[dict]:
    """Per error level: the fastest finished row of each :func:`method` whose ``rel_err`` reaches it.

    Returns ``[{"level", "by_method": {method: row}}]``, each ``by_method`` by increasing
    ``wall_s`` (the first is the cheapest); rows without a finite error (failed, not comparable,
    the reference's own estimate) are left out.
    """
    usable = [r for r in rows if r.get("status") == "ok" and r.get("kind") != "richardson"
              and isinstance(r.get("rel_err"), float) and math.isfinite(r["rel_err"])]
    out = []
    for level in levels:
        best: dict[str, dict] = {}
        for r in usable:
            if r["rel_err"] <= level and (method(r) not in best or r["wall_s"] < best[method(r)]["wall_s"]):
                best[method(r)] = r
        out.append({"level": level, "by_method": dict(sorted(best.items(), key=lambda kv: kv[1]["wall_s"]))})
    return out


def plot_pareto(rows: list[dict], path, title: str) -> Path | None:
    """Save the Pareto plot of ``rows`` (results-table rows with errors) as a PNG at ``path``.

    Returns the path, or None (and writes nothing) when no row has a positive finite error.
    """
    rows = [r for r in rows if r.get("status") == "ok" and isinstance(r.get("rel_err"), float)
            and math.isfinite(r["rel_err"]) and r["rel_err"] > 0]
    if not rows:
        return None
    fig = Figure(figsize=(7, 5), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for kind in dict.fromkeys(r["kind"] for r in rows):
        mine = [r for r in rows if r["kind"] == kind]
        ax.plot([r["wall_s"] for r in mine], [r["rel_err"] for r in mine], linestyle="none",
                marker=MARKERS.get(kind, "D"), markersize=7, label=kind)
    for r in rows:
        ax.annotate(r["task"], (r["wall_s"], r["rel_err"]), textcoords="offset points", xytext=(5, 4), fontsize=7)
    front = pareto_front([(r["wall_s"], r["rel_err"]) for r in rows])
    ax.plot(*zip(*front), color="0.5", linewidth=1, zorder=0, label="front")
    ax.set_xscale("log")
    ax.set_yscale("log")
    for axis in (ax.xaxis, ax.yaxis):  # labels at 1, 2, 5 x 10^k: some within any span of a decade
        axis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        axis.set_major_formatter(FormatStrFormatter("%g"))
        axis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("wall time of the time loop (s)")
    ax.set_ylabel("relative error: max of V, T - T0 (fields, probes) at common times")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=150)
    return path
