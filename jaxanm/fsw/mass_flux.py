"""Mass conservation of an FSW result: the volume flux of the MLS velocity through sections
x = const and through circles about the tool axis, by fine quadrature.

With the ``traverse`` effect the plate streams through the disc at (-U, 0) seen from the tool:
the plate's part of every section ``x = const`` carries the through-flow ``2 sqrt(R2^2 - x^2)
U`` (the tool turns rigidly and carries none across it), and every circle about the axis
carries nothing net.  Without it, both are zero.  :func:`flux_table` measures both at every
saved time, relative to ``2 R2 U`` (sections) and to ``2 r U`` (circles: the flux crossing each
half circle), or to ``2 R2 omega R1 / 30`` when the tool does not travel (a scale of the
rotation's own through-flux, so that the table still measures something).

The flux is the line integral of the velocity the model's stencils reconstruct from the point
values (:func:`jaxanm.fsw.energy.fields_at`), on composite Gauss rules graded towards the tool
edge, where the rotating layer is thinnest: the quadrature error is far below the flux
errors measured (a rule of twice the points changes the table by less than 1e-6 of 2 R2 U).
"""

from __future__ import annotations

import math

import numpy as np

from .energy import fields_at

__all__ = ["SECTIONS", "CIRCLES", "circle_flux", "flux_table", "largest_error", "section_flux", "section_rule"]

SECTIONS = (-5.0, -3.0, -1.5, -0.75, 0.0, 0.75, 1.5, 3.0, 5.0)
"""The default table's sections ``x = f R2 / 6`` (-5 mm ... 5 mm for R2 = 6 mm)."""

CIRCLES = (1.05, 1.5, 2.5, 3.8)
"""Radii of the default table's circles, in units of R1."""


def _segment_rule(a: float, b: float, cells: int = 120, order: int = 4, towards_a: bool = True):
    """Points (M,) and weights of a composite Gauss rule on [a, b], cells graded quadratically
    towards ``a`` (or ``b``)."""
    t = np.linspace(0.0, 1.0, cells + 1) ** 2
    edges = a + (b - a) * (t if towards_a else 1.0 - t[::-1])
    xg, wg = np.polynomial.legendre.leggauss(order)
    lo, hi = edges[:-1, None], edges[1:, None]
    return ((lo + hi) / 2 + (hi - lo) / 2 * xg).ravel(), ((hi - lo) / 2 * wg).ravel()


def section_rule(geometry, x: float) -> tuple:
    """Points (M, 2) and weights (M,) of the quadrature along the plate's part of the section
    ``x`` = const (two segments from the tool edge outwards when it crosses the tool)."""
    g = geometry
    top = math.sqrt(max(g.R2 * g.R2 - x * x, 0.0))
    if abs(x) < g.R1:
        low = math.sqrt(g.R1 * g.R1 - x * x)
        y1, w1 = _segment_rule(low, top)
        ys, ws = np.concatenate([y1, -y1]), np.concatenate([w1, w1])
    else:
        ys, ws = _segment_rule(-top, top)
    return np.stack([np.full(ys.size, x), ys], axis=1), ws


def section_flux(result, s: int, x: float) -> float:
    """Volume flux (m^2/s, per unit thickness) in the direction -x through the plate's part of
    the section ``x`` = const at saved step ``s`` (the direction the plate streams past a
    travelling tool)."""
    points, ws = section_rule(result.scene.geometry, x)
    return float(-np.sum(ws * fields_at(result, s, points, derivatives=False)["u"]))


def circle_flux(result, s: int, r: float, angles: int = 720) -> float:
    """Net outward volume flux (m^2/s) through the circle of radius ``r`` about the tool axis at
    saved step ``s`` (the midpoint rule in angle, exact for the trigonometric polynomials of
    degree below ``angles``)."""
    th = 2.0 * math.pi * (np.arange(angles) + 0.5) / angles
    f = fields_at(result, s, r * np.stack([np.cos(th), np.sin(th)], axis=1), derivatives=False)
    return float(np.sum(f["u"] * np.cos(th) + f["v"] * np.sin(th)) * r * 2.0 * math.pi / angles)


def flux_table(result, sections=None, circles=None, angles: int = 720) -> dict:
    """The fluxes of ``result`` at every saved time, as errors against their exact values.

    Parameters
    ----------
    result : FSWResult
        A fixed-point result (the sections and circles are taken on its cloud).
    sections : sequence of float, optional
        Abscissae x (m); default :data:`SECTIONS` times R2 / 6.
    circles : sequence of float, optional
        Radii (m); default :data:`CIRCLES` times R1.
    angles : int
        Points of each circle's midpoint rule.

    Returns
    -------
    dict
        ``{"t": (S,), "scale": float, "sections": {x: (S,)}, "circles": {r: (S,)}}``: each
        section's flux minus ``2 sqrt(R2^2 - x^2) U`` over ``2 R2 U``, each circle's flux over
        ``2 r U`` (with U = 0, over ``2 R2 omega R1 / 30`` and ``2 r omega R1 / 30``).  All the
        lines of a saved step are evaluated at once.
    """
    scene = result.scene
    g = scene.geometry
    U = scene.tool.traverse_speed if scene.has("traverse") else 0.0
    speed = U if U > 0 else scene.tool.omega * g.R1 / 30.0
    xs = [f * g.R2 / 6.0 for f in SECTIONS] if sections is None else list(sections)
    rs = [f * g.R1 for f in CIRCLES] if circles is None else list(circles)
    th = 2.0 * math.pi * (np.arange(angles) + 0.5) / angles
    ring = np.stack([np.cos(th), np.sin(th)], axis=1)
    rules = [section_rule(g, x) for x in xs]
    targets = np.concatenate([pts for pts, _ in rules] + [r * ring for r in rs])
    bounds = np.cumsum([0] + [len(w) for _, w in rules] + [angles] * len(rs))
    out: dict = {"t": np.asarray(result.t, dtype=np.float64), "scale": 2.0 * g.R2 * speed,
                 "sections": {x: [] for x in xs}, "circles": {r: [] for r in rs}}
    for s in range(len(result.t)):
        f = fields_at(result, s, targets, derivatives=False)
        for i, (x, (_, w)) in enumerate(zip(xs, rules)):
            exact = 2.0 * math.sqrt(max(g.R2 * g.R2 - x * x, 0.0)) * U
            flux = -np.sum(w * f["u"][bounds[i]:bounds[i + 1]])
            out["sections"][x].append((flux - exact) / (2.0 * g.R2 * speed))
        for j, r in enumerate(rs):
            lo, hi = bounds[len(xs) + j], bounds[len(xs) + j + 1]
            flux = np.sum(f["u"][lo:hi] * ring[:, 0] + f["v"][lo:hi] * ring[:, 1]) * r * 2.0 * math.pi / angles
            out["circles"][r].append(flux / (2.0 * r * speed))
    out["sections"] = {x: np.array(v) for x, v in out["sections"].items()}
    out["circles"] = {r: np.array(v) for r, v in out["circles"].items()}
    return out


def largest_error(table: dict) -> float:
    """The largest flux error of a :func:`flux_table` over its lines and saved times."""
    return float(max(np.abs(v).max() for group in ("sections", "circles") for v in table[group].values()))
