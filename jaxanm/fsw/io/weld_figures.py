"""Figures of a travelling tool (the ``traverse`` effect, scenes ``fsw_weld`` and
``fsw_weld_slip``): the temperature map with the advancing and retreating sides marked, and
the paths of material points carried around the pin.

Seen from the tool, which travels along +x and turns at omega > 0 (counter-clockwise), the plate
streams in on the leading side (x > 0) and out on the trailing side (x < 0).  The advancing
side is where the tool surface moves with the travel, y < 0; the retreating side y > 0.  The
fields of the last saved time are interpolated linearly on the Delaunay triangulation of the
plate's points (as the section figures of :mod:`jaxanm.fsw.io.figures` do); the tool's
subdomain is left out of the paths' triangulation, so that the plate's own velocity at the
edge (delta omega R1 with ``slip``) is what carries the material.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator, ScalarFormatter
from matplotlib.tri import LinearTriInterpolator, Triangulation

from .figures import MM, FigureSkipped, has_temperature, section
from .figures import agg_figure as _figure

__all__ = ["material_paths", "paths", "travels", "weld_figures", "weld_temperature_map"]


def travels(result) -> bool:
    """Whether ``result``'s scene has the tool travelling (``traverse`` with U > 0)."""
    scene = getattr(result, "scene", None)
    has = getattr(scene, "has", None)
    return bool(scene is not None and has is not None and has("traverse") and scene.tool.traverse_speed > 0)


def _sides(ax, R2: float) -> None:
    """Mark the advancing (y < 0) and retreating (y > 0) sides and the travel direction."""
    lim = R2 * MM
    ax.text(0.0, -0.93 * lim, "advancing side (y < 0)", ha="center", va="bottom", fontsize=9,
            bbox=dict(boxstyle="round", fc="w", alpha=0.8))
    ax.text(0.0, 0.93 * lim, "retreating side (y > 0)", ha="center", va="top", fontsize=9,
            bbox=dict(boxstyle="round", fc="w", alpha=0.8))
    ax.annotate("tool travel", xy=(lim, 0.8 * lim), xytext=(0.45 * lim, 0.8 * lim), fontsize=8,
                va="center", arrowprops=dict(arrowstyle="->", color="k"))


def _tool_circle(ax, R1: float, colour: str) -> None:
    phi = np.linspace(0.0, 2.0 * np.pi, 181)
    ax.plot(R1 * MM * np.cos(phi), R1 * MM * np.sin(phi), "--", color=colour, lw=1)


def weld_temperature_map(result) -> Figure:
    """The temperature at the last saved time: (a) the map with the advancing and retreating
    sides marked, (b) T along y = 0, leading (x > 0) and trailing (x < 0) side."""
    if not travels(result):
        raise FigureSkipped("the tool does not travel (no 'traverse' effect, or U = 0)")
    if not has_temperature(result):
        raise FigureSkipped("no temperature field (isothermal scene)")
    scene = result.scene
    g, s = scene.geometry, len(np.asarray(result.t)) - 1
    pts = np.asarray(result.points, dtype=np.float64)[s]
    T = np.asarray(result.T, dtype=np.float64)[s]
    fig, (ax, ax_line) = _figure(2)
    cs = ax.tricontourf(Triangulation(pts[:, 0] * MM, pts[:, 1] * MM), T,
                        levels=MaxNLocator(20).tick_values(T.min(), max(T.max(), T.min() + 1e-6)), cmap="inferno")
    fig.colorbar(cs, ax=ax, label="T (K)", format=ScalarFormatter(useOffset=False))
    _tool_circle(ax, g.R1, "w")
    _sides(ax, g.R2)
    ax.set_aspect("equal")
    ax.set(xlabel="x (mm)", ylabel="y (mm)", title=f"(a) t = {float(result.t[s]):.4g} s")
    for name, label, colour in (("A-A", "trailing - leading: T(-d, 0) - T(d, 0)", "tab:red"),
                                ("B-B", "advancing - retreating: T(0, -d) - T(0, d)", "tab:blue")):
        d, diff = _asymmetry(result, s, name)
        ax_line.plot(d * MM, diff, color=colour, label=label)
    ax_line.axhline(0.0, color="0.5", lw=0.8)
    ax_line.axvspan(0.0, g.R1 * MM, color="0.9", zorder=0, label="tool")
    ax_line.set(xlabel="distance d from the axis (mm)", ylabel="temperature difference (K)",
                title="(b) asymmetry of T")
    ax_line.legend(loc="best", fontsize=8)
    tool = scene.tool
    fig.suptitle(f"travelling tool: U = {tool.traverse_speed * 1e3:g} mm/s, omega = {tool.omega:g} rad/s, "
                 f"contact state {tool.contact_state:g}")
    return fig


def _asymmetry(result, s: int, name: str) -> tuple:
    """``(d, T(-d) - T(d))`` along section ``"A-A"`` (x) or ``"B-B"`` (y) at saved index ``s``:
    the section's samples lie symmetrically about the axis, so reversing pairs them."""
    coord, f = section(result, s, name)
    T = f["T"]
    pos = coord > 0
    d = coord[pos]
    neg = np.interp(-d, coord, T)
    return d, neg - T[pos]


def paths(result, seeds: np.ndarray, step: float, max_steps: int = 4000) -> list:
    """Paths (each (K, 2), m) of material points from ``seeds`` (M, 2) through the flow of the
    last saved time seen from the tool (steady in the tool's frame once the stirring has
    started: the paths are its streamlines), by the midpoint rule at a fixed arc length
    ``step`` (m), until they leave the plate, enter the tool or take ``max_steps`` steps."""
    scene, s = result.scene, len(np.asarray(result.t)) - 1
    g = scene.geometry
    plate = np.asarray(result.material) != 0
    pts = np.asarray(result.points, dtype=np.float64)[s][plate]
    tri = Triangulation(pts[:, 0], pts[:, 1])
    centre = pts[tri.triangles].mean(axis=1)
    tri.set_mask(np.hypot(centre[:, 0], centre[:, 1]) < g.R1)  # the hull spans the pin: not plate
    u = LinearTriInterpolator(tri, np.asarray(result.u, dtype=np.float64)[s][plate])
    v = LinearTriInterpolator(tri, np.asarray(result.v, dtype=np.float64)[s][plate])

    def direction(p):
        V = np.stack([np.ma.filled(u(p[:, 0], p[:, 1]), np.nan), np.ma.filled(v(p[:, 0], p[:, 1]), np.nan)], axis=1)
        speed = np.hypot(V[:, 0], V[:, 1])
        return V / np.where(speed > 0, speed, np.nan)[:, None]

    p = np.array(seeds, dtype=np.float64)
    alive = np.ones(len(p), dtype=bool)
    out = [[q.copy()] for q in p]
    for _ in range(max_steps):
        if not alive.any():
            break
        mid = p[alive] + 0.5 * step * direction(p[alive])
        new = p[alive] + step * direction(mid)
        r = np.hypot(new[:, 0], new[:, 1])
        ok = np.isfinite(new).all(axis=1) & (r < g.R2) & (r > g.R1)
        idx = np.flatnonzero(alive)
        for j, q, good in zip(idx, new, ok):
            if good:
                out[j].append(q)
        p[idx[ok]] = new[ok]
        alive[idx[~ok]] = False
    return [np.array(o) for o in out]


def material_paths(result, count: int = 17) -> Figure:
    """Paths of material points entering on the leading side at ``count`` heights: carried
    around the pin (on the retreating side, with the rotation) and laid down behind it."""
    if not travels(result):
        raise FigureSkipped("the tool does not travel (no 'traverse' effect, or U = 0)")
    g = result.scene.geometry
    y = np.linspace(-0.9, 0.9, count) * g.R2
    seeds = np.stack([0.98 * np.sqrt(g.R2 ** 2 - y ** 2), y], axis=1)
    fig, (ax,) = _figure(1)
    for y0, path in zip(y, paths(result, seeds, step=0.02 * g.R1)):
        ax.plot(path[:, 0] * MM, path[:, 1] * MM, color="tab:blue" if y0 > 0 else "tab:red", lw=1)
        ax.plot(path[:1, 0] * MM, path[:1, 1] * MM, "o", ms=3, color="k")
    _tool_circle(ax, g.R1, "0.4")
    phi = np.linspace(0.0, 2.0 * np.pi, 181)
    ax.plot(g.R2 * MM * np.cos(phi), g.R2 * MM * np.sin(phi), "-", color="0.6", lw=0.8)
    _sides(ax, g.R2)
    ax.set_aspect("equal")
    ax.set(xlabel="x (mm)", ylabel="y (mm)",
           title=f"material paths seen from the tool\n(flow at t = {float(result.t[-1]):.4g} s; dots: entry points)")
    return fig


def weld_figures(result) -> list[tuple[str, Callable[[], Figure]]]:
    """The travelling tool's figures as ``(file name, builder)`` pairs (none if it does not travel)."""
    if not travels(result):
        return []
    return [("weld_temperature_map.png", lambda: weld_temperature_map(result)),
            ("weld_material_paths.png", lambda: material_paths(result))]
