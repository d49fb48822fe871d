"""Point cloud of the FSW disc and its MLS stencils, split at the tool edge.

The disc r <= R2 holds the tool (r <= R1) and the plate (R1 <= r <= R2).  Velocity and
temperature have a kink at r = R1 (rigid rotation inside, power-law shear flow outside; the
conductivity jumps from 36 to 140 W/m/K), which a smooth MLS approximation across the edge
cannot represent.  So the cloud is split into two subdomains, each approximated by its own
MLS stencils (one-sided near the edge):

- the tool: ``TOOL`` points (r < R1) and ``TOOL_EDGE`` points on r = R1;
- the plate: ``PLATE_EDGE`` points on r = R1 (coincident with the ``TOOL_EDGE`` points, one
  partner each), ``PLATE`` points (R1 < r < R2) and ``RING`` points on r = R2.

A stencil never mixes the two subdomains; the coincident edge pairs carry the interface
conditions (the model's rows: equal temperature, equal heat flux, sticking velocity).

Points are ordered ``[TOOL, TOOL_EDGE | PLATE_EDGE, PLATE, RING]``: the tool subdomain is the
index range ``[0, n_tool)``, the plate ``[n_tool, N)``.

Layouts (:class:`~jaxanm.fsw.scene.Geometry`): ``polar`` and ``grid`` have one spacing ``dr``
and one MLS influence radius ``h_factor * dr``.  ``graded`` has rings whose spacing grows from
``dr`` at the tool edge (across the shear band) to ``dr_far`` (:func:`spacing`), and each
point's influence radius is ``h_factor`` times the spacing at its radius (:func:`jaxanm.mls`
takes one radius per evaluation point and scales each stencil's coordinates by it; the
neighbour search and its Verlet lists use the largest radius plus the skin, so they hold for
any radii up to it).  Targets (probes, sections) get the radius of their position.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from .. import mls
from ..internal import entry_point
from .scene import Geometry

__all__ = ["Cloud", "build_cloud", "cloud_stencils", "edge_spacing", "evaluate_stencils", "neighbour_list", "rigid",
           "spacing", "TOOL", "TOOL_EDGE", "PLATE_EDGE", "PLATE", "RING"]

TOOL, TOOL_EDGE, PLATE_EDGE, PLATE, RING = range(5)
"""Point kinds (the row each point carries in the model)."""


@dataclasses.dataclass(frozen=True)
class Cloud:
    """The initial point cloud.

    Attributes
    ----------
    points : (N, 2) float64
        Coordinates (m).
    kind : (N,) int32
        ``TOOL``, ``TOOL_EDGE``, ``PLATE_EDGE``, ``PLATE`` or ``RING``.
    partner : (N,) int32
        The coincident point across the tool edge for edge points, the point itself otherwise.
    material : (N,) int32
        0 tool, 1 plate y > 0 ("blue"), 2 plate y < 0 ("red").
    n_tool : int
        Number of tool-subdomain points (``TOOL`` and ``TOOL_EDGE``), which come first.
    """

    points: np.ndarray
    kind: np.ndarray
    partner: np.ndarray
    material: np.ndarray
    n_tool: int

    @property
    def size(self) -> int:
        """Number of points N."""
        return self.points.shape[0]


def _ring(radius: float, dr: float) -> np.ndarray:
    """An even number (about 2 pi r / dr, at least 6) of points on a circle, none on y = 0."""
    count = max(6, 2 * round(math.pi * radius / dr))
    theta = 2 * math.pi * (np.arange(count) + 0.5) / count
    return radius * np.stack([np.cos(theta), np.sin(theta)], axis=1)


def _polar_interior(g: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Tool interior (rings and centre) and plate interior rings of the polar layout."""
    k_tool = max(1, round(g.R1 / g.dr))
    tool = [np.zeros((1, 2))] + [_ring(g.R1 * j / k_tool, g.dr) for j in range(1, k_tool)]
    k_plate = round((g.R2 - g.R1) / g.dr)
    plate = [_ring(g.R1 + (g.R2 - g.R1) * j / k_plate, g.dr) for j in range(1, k_plate)]
    return np.concatenate(tool), np.concatenate(plate) if plate else np.zeros((0, 2))


def _grid_interior(g: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Square grid (nodes at half-integer multiples of dr) clipped dr/2 away from r = R1, R2."""
    k = math.ceil(g.R2 / g.dr) + 1
    axis = (np.arange(-k, k) + 0.5) * g.dr
    xy = np.stack(np.meshgrid(axis, axis, indexing="ij"), axis=-1).reshape(-1, 2)
    r = np.hypot(xy[:, 0], xy[:, 1])
    tool = xy[r < g.R1 - 0.5 * g.dr]
    plate = xy[(r > g.R1 + 0.5 * g.dr) & (r < g.R2 - 0.5 * g.dr)]
    return tool, plate


def _gaps(length: float, g: Geometry, centre: bool) -> np.ndarray:
    """Radial gaps of the graded layout over ``length`` from r = R1, outwards to R2 or (with
    ``centre``) inwards to the centre point.  Outwards: ``dr`` across the fine zone ``band``,
    then each gap ``grading`` times the previous, up to ``dr_far``; inwards the grading starts
    at R1 (the tool turns rigidly and its temperature is smooth: no fine zone).  The graded
    gaps are then scaled by one factor (within about ``grading``) so that all sum to
    ``length`` exactly; the fine zone keeps ``dr``."""
    fine = 0 if centre else round(g.band / g.dr)
    gaps = [g.dr] * fine
    last, total = g.dr, g.dr * fine
    while total < length * (1 - 1e-9):
        last = min(g.dr_far, last * g.grading)
        gaps.append(last)
        total += last
    # drop the last gap if the total then comes closer to the length
    if len(gaps) > fine + 1 and abs(total - gaps[-1] - length) < abs(total - length):
        total -= gaps.pop()
    widths = np.array(gaps)
    graded = min(fine, len(widths) - 1)
    widths[graded:] *= (length - widths[:graded].sum()) / widths[graded:].sum()
    return widths


def _graded_rings(g: Geometry) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ring radii and spacings of the graded layout: tool side ``(r_tool, d_tool)`` from R1
    inwards (ending at the centre, radius 0) and plate side ``(r_plate, d_plate)`` from R1 to
    R2.  A ring's spacing is the larger of its two radial gaps (its points are that far apart
    along it too: the MLS support ``h_factor`` times it holds both directions)."""
    out = []
    for length, sign in ((g.R1, -1.0), (g.R2 - g.R1, 1.0)):
        gaps = _gaps(length, g, centre=sign < 0)
        r = g.R1 + sign * np.concatenate([[0.0], np.cumsum(gaps)])
        r[-1] = 0.0 if sign < 0 else g.R2
        d = np.maximum(np.concatenate([gaps, gaps[-1:]]), np.concatenate([gaps[:1], gaps]))
        out += [r, d]
    return tuple(out)


def spacing(g: Geometry, r: np.ndarray, tool: np.ndarray) -> np.ndarray | float:
    """The layout's point spacing at radii ``r`` (m), on the tool side where ``tool``: ``dr``
    for the polar and grid layouts (a float: one influence radius for the whole cloud), the
    graded layout's ring spacing interpolated linearly in r between its rings otherwise."""
    if g.layout != "graded":
        return g.dr
    r_t, d_t, r_p, d_p = _graded_rings(g)
    r = np.asarray(r, dtype=np.float64)
    return np.where(tool, np.interp(r, r_t[::-1], d_t[::-1]), np.interp(r, r_p, d_p))


def edge_spacing(g: Geometry) -> float:
    """Radial point spacing (m) on the plate side of the tool edge, what resolves the shear band
    there: the ring spacing ``(R2 - R1) / round((R2 - R1) / dr)`` of the polar layout, ``dr``
    for the grid (whose points nearest r = R1 lie between dr/2 and about 1.2 dr from it) and
    the graded layout (its fine zone's spacing)."""
    if g.layout == "polar":
        return (g.R2 - g.R1) / round((g.R2 - g.R1) / g.dr)
    return g.dr


def _graded_interior(g: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Tool interior (rings and centre) and plate interior rings of the graded layout."""
    r_t, d_t, r_p, d_p = _graded_rings(g)
    tool = [np.zeros((1, 2))] + [_ring(r, d) for r, d in zip(r_t[-2:0:-1], d_t[-2:0:-1])]
    plate = [_ring(r, d) for r, d in zip(r_p[1:-1], d_p[1:-1])]
    return np.concatenate(tool), np.concatenate(plate) if plate else np.zeros((0, 2))


def rigid(kind: np.ndarray) -> np.ndarray:
    """Points that turn with the tool: the tool and both sides of its edge (sticking)."""
    return (kind == TOOL) | (kind == TOOL_EDGE) | (kind == PLATE_EDGE)


def build_cloud(g: Geometry) -> Cloud:
    """The point cloud of the scene geometry (layout ``polar``, ``grid`` or ``graded``, see
    :class:`Geometry`)."""
    interior = {"polar": _polar_interior, "grid": _grid_interior, "graded": _graded_interior}[g.layout]
    tool, plate = interior(g)
    edge = _ring(g.R1, g.dr)
    ring = _ring(g.R2, g.dr if g.layout != "graded" else _graded_rings(g)[3][-1])
    parts = [(tool, TOOL), (edge, TOOL_EDGE), (edge, PLATE_EDGE), (plate, PLATE), (ring, RING)]
    points = np.concatenate([p for p, _ in parts])
    kind = np.concatenate([np.full(len(p), k, dtype=np.int32) for p, k in parts])
    n_tool = len(tool) + len(edge)
    partner = np.arange(len(points), dtype=np.int32)
    tool_edge = np.arange(len(tool), n_tool)
    partner[tool_edge] = tool_edge + len(edge)
    partner[tool_edge + len(edge)] = tool_edge
    material = np.where(kind <= TOOL_EDGE, 0, np.where(points[:, 1] > 0, 1, 2)).astype(np.int32)
    return Cloud(points=points, kind=kind, partner=partner, material=material, n_tool=n_tool)


def _apart(points: np.ndarray, n_tool: int, g: Geometry) -> np.ndarray:
    """The cloud with the tool subdomain shifted far away, so that no stencil spans both.

    MLS works in coordinates local to each evaluation point and scaled by h, so a rigid shift
    of a subdomain changes no shape function (beyond round-off ~ 1e-16 * shift / h); it lets
    one neighbour search and one compiled kernel serve both subdomains.
    """
    shifted = np.array(points, dtype=np.float64)
    shifted[:n_tool, 0] += _shift(g)
    return shifted


def _shift(g: Geometry) -> float:
    """Distance the tool subdomain is moved: beyond the disc and any influence radius."""
    return 4.0 * (g.R2 + g.h_factor * max(g.dr, g.dr_far))


def _radius(g: Geometry, points: np.ndarray, n_tool: int):
    """Influence radius of each point ``h_factor`` times :func:`spacing` (a float for the
    uniform layouts, one per point for the graded one, tool ``[0, n_tool)``)."""
    if g.layout != "graded":
        return g.h_factor * g.dr
    points = np.asarray(points, dtype=np.float64)
    tool = np.arange(len(points)) < n_tool
    return g.h_factor * spacing(g, np.hypot(points[:, 0], points[:, 1]), tool)


@entry_point
def cloud_stencils(points: np.ndarray, n_tool: int, g: Geometry, m_max: int | None = None,
                   neighbours: mls.NeighbourList | None = None) -> mls.Stencils:
    """MLS stencils of the cloud: tool ``[0, n_tool)`` and plate nodes never share a stencil.

    ``m_max`` fixes the stencil width (pass ``st.index.shape[1]`` of the first build when
    rebuilding a moved cloud, so that shapes, and compiled code, stay the same);
    ``neighbours`` (from :func:`neighbour_list`) carries the neighbour candidates from one
    rebuild of a moving cloud to the next; those rebuilds run the compiled MLS kernel, whose
    compilation pays over the steps (a cloud built once is computed on the host:
    :func:`jaxanm.mls.build_stencils`).
    """
    return mls.build_stencils(_apart(points, n_tool, g), _radius(g, points, n_tool), m_max=m_max, c=g.c, q=g.q,
                              neighbours=neighbours, compiled=neighbours is not None)


def neighbour_list(g: Geometry) -> mls.NeighbourList:
    """Neighbour candidates for the stencils of a moving cloud (:func:`cloud_stencils`) or of
    targets moving with it (:func:`evaluate_stencils`).

    Skin h / 4: the lists hold about 1.6 times the stencil's neighbours, and are remade once
    some point has moved h / 8 (about 47 steps of the tool edge's rigid turn in fsw_paper).
    """
    return mls.NeighbourList(skin=0.25 * g.h_factor * g.dr)


@entry_point
def evaluate_stencils(points: np.ndarray, n_tool: int, g: Geometry, targets: np.ndarray,
                      derivatives: bool = True, neighbours: mls.NeighbourList | None = None) -> mls.Stencils:
    """MLS stencils at arbitrary ``targets`` (probes, sections, tracers) of the current cloud.

    Targets with r < R1 are approximated from the tool nodes, the others from the plate nodes
    (the same one-sided approximation as the model uses).  Returned stencils index the cloud.
    ``derivatives=False``: values only (see :func:`jaxanm.mls.evaluate_at`); ``neighbours``
    (from :func:`neighbour_list`) carries candidates from one call to the next for targets
    that move with the cloud (and, as in :func:`cloud_stencils`, selects the compiled kernel).
    """
    targets = np.array(targets, dtype=np.float64).reshape(-1, 2)
    r = np.hypot(targets[:, 0], targets[:, 1])
    h = g.h_factor * spacing(g, r, r < g.R1)
    targets[r < g.R1, 0] += _shift(g)
    return mls.evaluate_at(_apart(points, n_tool, g), h, targets, c=g.c, q=g.q,
                           derivatives=derivatives, neighbours=neighbours, compiled=neighbours is not None)
