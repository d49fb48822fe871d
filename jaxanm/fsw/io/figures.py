"""The paper's figures (Figs 2, 3, 5-11) drawn from an FSW result.

Each builder takes an :class:`~jaxanm.fsw.record.FSWResult` (or any object with its
fields) and returns a :class:`matplotlib.figure.Figure` attached to an Agg canvas (no screen,
no pyplot global state), or raises :class:`FigureSkipped` when the data it needs is absent
(no temperature in an isothermal scene, a run that ended before the requested time, too few
registration points).  :func:`paper_figures` lists them with their file names.

Conventions:

- Registration points (1), (2), (3) are the result's probes in the order the scene lists
  them; fig. 2 uses the first two, fig. 3 the first and the third.
- Sections A-A (y = 0) and B-B (x = 0) are the scene's registration sections as the run
  recorded them (MLS values at the saved times, :func:`section`): they are sampled once, by
  the recorder, and drawn as recorded.
- A requested time (0.01 s, 0.3 s, ...) is drawn at the nearest saved time, which the panel
  title states; it is skipped if the run ended more than half a save interval before it.
- Material 0 is the tool (grey), 1 the plate y > 0 (blue), 2 the plate y < 0 (red).  The
  mixing state is drawn from the moving points of a Lagrangian result, and from the passive
  tracer particles of a fixed-point (``tracers``) result (:func:`mixing_points`).
- Lengths are plotted in mm, velocities in m/s, temperatures in K.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator, ScalarFormatter
from matplotlib.tri import Triangulation

log = logging.getLogger(__name__)

MM = 1e3
"""Metres to millimetres, for plot axes."""

MATERIALS = ((1, "tab:blue", "plate y > 0"), (2, "tab:red", "plate y < 0"), (0, "0.6", "tool"))
"""(material id, colour, label) of the mixing-state scatter plots."""

MIXING_TIMES = {"fig06": 0.01, "fig07": 0.3, "fig08": 0.5, "fig09": 0.7}
"""Times (s) of Figs 6-9: temperature along A-A and material mixing state."""


class FigureSkipped(Exception):
    """The data a figure needs is absent; the message says which."""


def has_temperature(result) -> bool:
    """Whether ``result`` carries a temperature field.

    An isothermal scene reports ``T = T0`` everywhere (or ``T = None``): a field without any
    variation over the saved times and points counts as absent.
    """
    if result.T is None:
        return False
    T = np.asarray(result.T, dtype=np.float64)
    return T.size > 0 and float(np.ptp(T)) > 0.0


def saved_index(result, t_target: float) -> int:
    """Index of the saved time nearest to ``t_target``.

    Raises :class:`FigureSkipped` if ``t_target`` lies more than half a save interval after
    the last saved time (the run ended earlier).
    """
    t = np.asarray(result.t, dtype=np.float64)
    half = 0.5 * float(np.median(np.diff(t))) if t.size > 1 else 0.0
    if t_target > t[-1] + half + 1e-12 * max(abs(t_target), 1.0):
        raise FigureSkipped(f"the run ended at t = {t[-1]:.6g} s, before t = {t_target:g} s")
    return int(np.argmin(np.abs(t - t_target)))


def section(result, s: int, name: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The recorded values of u, v, T along the scene's section ``name`` at saved index ``s``.

    The run samples its sections once, by MLS at the saved times (``result.sections``, see
    :class:`~jaxanm.fsw.record.FSWResult`); the figures draw those samples.  Returns the
    abscissa (x for a section along a line y = const, as A-A; y for one along x = const, as
    B-B; else the distance from its start, in m) and a dict of the fields there.  Raises
    :class:`FigureSkipped` when the scene records no section of that name or none at that time.
    """
    sections = getattr(result, "sections", None) or {}
    if name not in sections:
        raise FigureSkipped(f"the scene records no section {name!r} (add it to the scene's [[sections]])")
    t = float(np.asarray(result.t, dtype=np.float64)[s])
    times = np.asarray(sections["t"], dtype=np.float64)
    k = int(np.argmin(np.abs(times - t))) if times.size else -1
    if k < 0 or abs(times[k] - t) > 1e-9 * max(abs(t), 1e-3):
        raise FigureSkipped(f"section {name!r} was not recorded at t = {t:.6g} s")
    line = sections[name]
    x, y = np.asarray(line["x"], dtype=np.float64), np.asarray(line["y"], dtype=np.float64)
    coord = x if np.ptp(y) == 0.0 else y if np.ptp(x) == 0.0 else np.asarray(line["s"], dtype=np.float64)
    return coord, {key: np.asarray(line[key], dtype=np.float64)[k] for key in ("u", "v", "T")}


def agg_figure(ncols: int) -> tuple[Figure, list]:
    """A figure with ``ncols`` side-by-side axes on an Agg canvas."""
    fig = Figure(figsize=(5.5 * ncols, 4.5), layout="constrained")
    FigureCanvasAgg(fig)
    return fig, list(np.atleast_1d(fig.subplots(1, ncols)))


def _probes(result, count: int) -> list[str]:
    """The first ``count`` registration points, or :class:`FigureSkipped` if there are fewer."""
    names = [name for name in result.probes if name != "t"]
    if len(names) < count:
        raise FigureSkipped(f"needs {count} registration points, the result has {len(names)}")
    return names


def _tool_radius(result, s: int) -> float | None:
    """Radius of the tool (largest radius of a material-0 point) at saved index ``s``."""
    material = np.asarray(result.material)
    if not np.any(material == 0):
        return None
    pts = np.asarray(result.points, dtype=np.float64)[s][material == 0]
    return float(np.max(np.hypot(pts[:, 0], pts[:, 1])))


def _mark_tool_span(ax, radius: float | None) -> None:
    """Shade the tool's extent on a section plot."""
    if radius is not None:
        ax.axvspan(-radius * MM, radius * MM, color="0.9", zorder=0, label="tool")


def fig02_velocity_history(result) -> Figure:
    """Fig. 2: u(t) and v(t) at registration points (1) and (2)."""
    names = _probes(result, 2)
    t = np.asarray(result.probes["t"], dtype=np.float64)
    fig, axes = agg_figure(2)
    for ax, key, letter in zip(axes, ("u", "v"), "ab"):
        for label, name in zip(("(1)", "(2)"), names[:2]):
            ax.plot(t, np.asarray(result.probes[name][key], dtype=np.float64),
                    label=f"point {label} [{name}]")
        ax.set(xlabel="t (s)", ylabel=f"{key} (m/s)", title=f"({letter}) {key} at points (1), (2)")
        ax.legend()
        ax.grid(alpha=0.3)
    fig.suptitle("Fig. 2 - velocity components at registration points")
    return fig


def fig03_temperature_history(result) -> Figure:
    """Fig. 3: T(t) at registration points (1) and (3)."""
    if not has_temperature(result):
        raise FigureSkipped("no temperature field (isothermal scene)")
    names = _probes(result, 3)
    t = np.asarray(result.probes["t"], dtype=np.float64)
    fig, (ax,) = agg_figure(1)
    for label, name in (("(1)", names[0]), ("(3)", names[2])):
        ax.plot(t, np.asarray(result.probes[name]["T"], dtype=np.float64),
                label=f"point {label} [{name}]")
    ax.set(xlabel="t (s)", ylabel="T (K)", title="Fig. 3 - temperature at points (1), (3)")
    ax.legend()
    ax.grid(alpha=0.3)
    return fig


def fig05_velocity_sections(result) -> Figure:
    """Fig. 5: u along section B-B (x = 0) and v along A-A (y = 0) at the last saved time."""
    s = len(np.asarray(result.t)) - 1
    t = float(np.asarray(result.t, dtype=np.float64)[s])
    radius = _tool_radius(result, s)
    fig, (ax_u, ax_v) = agg_figure(2)
    y, vals = section(result, s, "B-B")
    _mark_tool_span(ax_u, radius)
    ax_u.plot(y * MM, vals["u"], "-", color="tab:blue", label="u")
    ax_u.set(xlabel="y (mm)", ylabel="u (m/s)", title="(a) u along B-B (x = 0)")
    x, vals = section(result, s, "A-A")
    _mark_tool_span(ax_v, radius)
    ax_v.plot(x * MM, vals["v"], "-", color="tab:red", label="v")
    ax_v.set(xlabel="x (mm)", ylabel="v (m/s)", title="(b) v along A-A (y = 0)")
    for ax in (ax_u, ax_v):
        ax.legend()
        ax.grid(alpha=0.3)
    fig.suptitle(f"Fig. 5 - velocity along the registration sections, t = {t:.4g} s")
    return fig


def mixing_points(result, s: int) -> tuple[np.ndarray, np.ndarray]:
    """Material positions (m) and colours at saved index ``s``: what carries the mixing state.

    Lagrangian results carry it on their moving points; fixed-point (``tracers``) results on
    their passive tracer particles (``result.tracers``), since their points never move.
    """
    tracers = getattr(result, "tracers", None)
    if tracers is not None:
        return (np.asarray(tracers["points"], dtype=np.float64)[s],
                np.asarray(tracers["material"]))
    return np.asarray(result.points, dtype=np.float64)[s], np.asarray(result.material)


def _mixing_axes(ax, result, s: int) -> None:
    """Scatter the material (points, or tracers) at saved index ``s`` coloured by material."""
    pts, material = mixing_points(result, s)
    pts = pts * MM
    for mat, colour, label in MATERIALS:
        sel = material == mat
        if np.any(sel):
            ax.scatter(pts[sel, 0], pts[sel, 1], s=8, c=colour, label=label, linewidths=0)
    ax.set_aspect("equal")
    ax.set(xlabel="x (mm)", ylabel="y (mm)")
    ax.legend(loc="upper right", fontsize="small", markerscale=2)


def mixing_figure(result, t_target: float, number: int) -> Figure:
    """Figs 6-9: T along A-A and the material mixing state at the saved time nearest ``t_target``.

    Without a temperature field only the mixing state is drawn (the T panel is left out,
    with a logged note).
    """
    s = saved_index(result, t_target)
    t = float(np.asarray(result.t, dtype=np.float64)[s])
    if has_temperature(result):
        fig, (ax_t, ax_m) = agg_figure(2)
        x, vals = section(result, s, "A-A")
        _mark_tool_span(ax_t, _tool_radius(result, s))
        ax_t.plot(x * MM, vals["T"], "-", color="tab:orange", label="T")
        ax_t.set(xlabel="x (mm)", ylabel="T (K)", title="(a) T along A-A (y = 0)")
        ax_t.legend()
        ax_t.grid(alpha=0.3)
        ax_m.set_title("(b) material mixing state")
    else:
        log.info("fig%02d: no temperature field (isothermal scene); T panel omitted", number)
        fig, (ax_m,) = agg_figure(1)
        ax_m.set_title("material mixing state")
    _mixing_axes(ax_m, result, s)
    fig.suptitle(f"Fig. {number} - t = {t:.4g} s (requested {t_target:g} s)")
    return fig


def temperature_maps(result, times: list[float | None], number: int) -> Figure:
    """Temperature maps (filled contours on the point cloud) at the saved times nearest ``times``.

    ``None`` in ``times`` means the last saved time.  The tool's edge is drawn dashed.
    """
    if not has_temperature(result):
        raise FigureSkipped("no temperature field (isothermal scene)")
    t_all = np.asarray(result.t, dtype=np.float64)
    indices = [len(t_all) - 1 if t is None else saved_index(result, t) for t in times]
    fig, axes = agg_figure(len(indices))
    for ax, s, letter in zip(axes, indices, "abcd"):
        pts = np.asarray(result.points, dtype=np.float64)[s] * MM
        T = np.asarray(result.T, dtype=np.float64)[s]
        lo, hi = float(T.min()), float(T.max())
        if hi - lo < 1e-9 * max(abs(hi), 1.0):
            lo, hi = lo - 0.5, hi + 0.5
        cs = ax.tricontourf(Triangulation(pts[:, 0], pts[:, 1]), T,
                            levels=MaxNLocator(20).tick_values(lo, hi), cmap="inferno")
        fig.colorbar(cs, ax=ax, label="T (K)", format=ScalarFormatter(useOffset=False))
        radius = _tool_radius(result, s)
        if radius is not None:
            phi = np.linspace(0.0, 2.0 * np.pi, 181)
            ax.plot(radius * MM * np.cos(phi), radius * MM * np.sin(phi), "--", color="w", lw=1)
        ax.set_aspect("equal")
        ax.set(xlabel="x (mm)", ylabel="y (mm)", title=f"({letter}) t = {t_all[s]:.4g} s")
    fig.suptitle(f"Fig. {number} - temperature distribution")
    return fig


def paper_figures(result) -> list[tuple[str, Callable[[], Figure]]]:
    """The paper's figures as ``(file name, builder)`` pairs; a builder may raise
    :class:`FigureSkipped`.  A travelling tool's figures are :mod:`jaxanm.fsw.io.weld_figures`'
    (a run writes both: :func:`jaxanm.fsw.io.output.figure_builders`)."""
    specs = [
        ("fig02_velocity_history.png", lambda: fig02_velocity_history(result)),
        ("fig03_temperature_history.png", lambda: fig03_temperature_history(result)),
        ("fig05_velocity_sections.png", lambda: fig05_velocity_sections(result)),
    ]
    for key, t in MIXING_TIMES.items():
        number = int(key[3:])
        specs.append((f"{key}_mixing_t{t:g}.png", functools.partial(mixing_figure, result, t, number)))
    specs += [
        ("fig10_temperature_maps.png", lambda: temperature_maps(result, [0.001, None], 10)),
        ("fig11_temperature_maps.png", lambda: temperature_maps(result, [0.05, 0.08], 11)),
    ]
    return specs
