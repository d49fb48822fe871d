"""The graded point layout (``geometry.layout = "graded"``): its rings, its per-point
MLS influence radius and its scene checks.  Cheap (no time stepping); what the layout buys in
accuracy is measured in docs/notes/spatial_accuracy.md."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxanm import mls
from jaxanm.fsw import geometry as G
from jaxanm.fsw.geometry import PLATE, PLATE_EDGE, RING, TOOL, TOOL_EDGE, build_cloud, cloud_stencils
from jaxanm.fsw.scene import Geometry, SceneError, load_scene

GRADED = dict(layout="graded", dr=8.5e-5, band=1.7e-4, dr_far=3.75e-4, grading=1.25, c=0.3)
PAPER_POINTS = 881  # fsw_paper's polar cloud at dr = 0.375 mm


@pytest.fixture(scope="module")
def graded():
    """(geometry, cloud, stencils) of the fsw_graded scene's layout."""
    g = Geometry(**GRADED)
    cloud = build_cloud(g)
    return g, cloud, cloud_stencils(cloud.points, cloud.n_tool, g)


def _radii(points):
    return np.hypot(points[:, 0], points[:, 1])


def test_rings_follow_the_grading(graded):
    g, cloud, _ = graded
    r = _radii(cloud.points)
    plate = np.unique(np.round(r[cloud.kind >= PLATE_EDGE], 12))
    gaps = np.diff(plate)
    # the fine zone: band / dr gaps of exactly dr (to the rounding of the radii above)
    fine = round(g.band / g.dr)
    assert np.allclose(gaps[:fine], g.dr, rtol=0, atol=1e-11), gaps[:fine]
    # then growing, each at most grading times the previous (the fit stretches the graded part
    # by less than one gap's worth: 1.1 of it), up to dr_far (times that stretch)
    assert np.all(np.diff(gaps) >= -1e-11), gaps
    assert np.all(gaps[1:] <= g.grading * 1.1 * gaps[:-1]), gaps[1:] / gaps[:-1]
    assert gaps.max() <= 1.1 * g.dr_far and gaps[-1] >= g.dr_far / 1.1, gaps
    assert plate[0] == pytest.approx(g.R1, rel=1e-12) and plate[-1] == pytest.approx(g.R2, rel=1e-12)
    # the tool: graded inwards at once, a centre point
    tool = np.unique(np.round(r[cloud.kind == TOOL], 12))
    assert tool[0] == 0.0 and tool[-1] < g.R1
    assert g.R1 - tool[-1] == pytest.approx(g.dr * g.grading, rel=0.1)
    # the graded cloud's point budget: at most twice the paper's cloud
    assert cloud.size <= 2 * PAPER_POINTS, cloud.size


def test_edge_pairs_coincide_and_kinds_are_ordered(graded):
    g, cloud, _ = graded
    kind, partner = cloud.kind, cloud.partner
    assert np.all(np.diff(kind) >= 0)  # [TOOL, TOOL_EDGE | PLATE_EDGE, PLATE, RING]
    assert cloud.n_tool == np.count_nonzero(kind <= TOOL_EDGE)
    edge = np.flatnonzero((kind == TOOL_EDGE) | (kind == PLATE_EDGE))
    assert np.array_equal(cloud.points[edge], cloud.points[partner[edge]])
    assert np.all(kind[partner[edge]] != kind[edge])
    assert np.allclose(_radii(cloud.points[edge]), g.R1, rtol=1e-14)
    # the edge ring has about 2 pi R1 / dr points: the tangential spacing is the radial one
    assert np.count_nonzero(kind == TOOL_EDGE) == 2 * round(math.pi * g.R1 / g.dr)
    assert np.allclose(_radii(cloud.points[kind == RING]), g.R2, rtol=1e-14)
    assert np.all(cloud.points[:, 1] != 0.0) or np.count_nonzero(cloud.points[:, 1] == 0) == 1  # the centre
    interior = kind == PLATE
    assert np.all((_radii(cloud.points[interior]) > g.R1) & (_radii(cloud.points[interior]) < g.R2))


def test_stencils_reproduce_quadratics_with_a_radius_per_point(graded):
    """Quadratic fields are reproduced to round-off (the quadratic basis; rcond of the one-sided
    edge stencils ~1e-5 costs about 2.5 digits, so 1e-10 of the field's scale)."""
    g, cloud, st = graded
    x, y = (cloud.points[:, 0] / g.R2, cloud.points[:, 1] / g.R2)
    f = 1 + 2 * x - 3 * y + 0.5 * x * x - x * y + 2 * y * y
    assert np.max(np.abs(np.asarray(mls.value(st, f)) - f)) < 1e-10
    lap = np.asarray(mls.laplacian(st, f)) * g.R2 ** 2
    assert np.max(np.abs(lap - 5.0)) < 1e-10 * 5 * (g.R2 / g.dr) ** 2
    # each stencil reaches no farther than h_factor times its own ring's spacing: fine near R1,
    # coarse far out (one influence radius per point)
    idx, phi = np.asarray(st.index), np.asarray(st.phi)
    reach = np.where(phi != 0, np.linalg.norm(cloud.points[idx] - cloud.points[:, None, :], axis=2), 0).max(1)
    h = G._radius(g, cloud.points, cloud.n_tool)
    assert np.all(reach <= h * (1 + 1e-12))
    r = _radii(cloud.points)
    near = (cloud.kind == PLATE) & (r < g.R1 + 1.5 * g.dr)
    far = (cloud.kind == PLATE) & (r > 0.8 * g.R2)
    assert reach[near].max() <= g.h_factor * g.dr * (1 + 1e-12) < 0.5 * reach[far].min()


def test_targets_at_the_points_get_the_points_stencils(graded):
    """evaluate_stencils uses the same radius at a position as cloud_stencils at a point there."""
    g, cloud, st = graded
    sample = np.arange(0, cloud.size, 7)
    sample = sample[np.isin(cloud.kind[sample], (TOOL, PLATE))]  # off the edge (side chosen by r)
    at = G.evaluate_stencils(cloud.points, cloud.n_tool, g, cloud.points[sample])
    # the same weights on the same nodes (their order among equidistant nodes may differ):
    # random fields through both; round-off of sums over ~90 weights of size <= 1, and of
    # second derivatives ~1/h^2 (scaled by dr^2 here)
    f = np.random.default_rng(0).standard_normal((cloud.size, 3))
    assert np.allclose(np.asarray(mls.value(at, f)), np.asarray(mls.value(st, f))[sample], rtol=0, atol=1e-12)
    assert np.allclose(np.asarray(mls.laplacian(at, f)) * g.dr ** 2,
                       np.asarray(mls.laplacian(st, f))[sample] * g.dr ** 2, rtol=0, atol=1e-9)


def test_uniform_layouts_keep_one_radius():
    g = Geometry()
    assert G.spacing(g, np.array([1e-3, 3e-3]), np.array([True, False])) == g.dr
    assert G._radius(g, np.zeros((3, 2)), 1) == g.h_factor * g.dr


@pytest.mark.parametrize("field, value, words", [
    ("geometry.dr_far", "5e-5", "far-field spacing must be in"),
    ("geometry.grading", "1.0", "ratio of successive ring spacings"),
    ("geometry.band", "1e-3", "fine zone on each side of R1"),
])
def test_bad_graded_values_are_named(field, value, words):
    base = load_scene("fsw_graded").with_overrides
    with pytest.raises(SceneError, match=words):
        base({field: value})


def test_lagrangian_on_the_graded_layout_is_refused():
    with pytest.raises(SceneError, match="'lagrangian' on geometry.layout = 'graded' is not supported"):
        load_scene("fsw_graded").with_overrides({"effects": "viscous,conduction,lagrangian"})


def _rise_error(scene, t_end: float) -> float:
    """Relative L2 error over the points of T - T0 at t_end against the axisymmetric oracle."""
    import jaxanm
    from jaxanm.fsw import axisymmetric as ax
    from jaxanm.fsw import run

    scene = scene.with_overrides({"time.t_end": repr(t_end), "time.save": "", "solver.kind": "mnewton"})
    ref = ax.solve(scene, [t_end])
    with jaxanm.float64():
        res = run(scene)
    rise = ref.temperature(np.hypot(*res.points[-1].T), 0) - scene.thermal.T0
    return float(np.linalg.norm(res.T[-1] - scene.thermal.T0 - rise) / np.linalg.norm(rise))


@pytest.mark.slow
def test_graded_cloud_beats_the_uniform_one_beyond_its_point_count():
    """fsw_graded against fsw_tracers (the same physics on the paper's 881 uniform points) over
    10 ms (about 1 min).  The uniform cloud's rise error falls at first order in the spacing
    (slope 0.7-0.9, benchmarks/results/spatial_convergence.md), so spending the graded cloud's 1603 points
    uniformly would divide it by at most sqrt(1603 / 881) = 1.35; the grading must do clearly
    better: at least 2x (measured 0.130 -> 0.039)."""
    graded = _rise_error(load_scene("fsw_graded"), 0.01)
    uniform = _rise_error(load_scene("fsw_tracers"), 0.01)
    assert 0 < graded < uniform / 2, (graded, uniform)
