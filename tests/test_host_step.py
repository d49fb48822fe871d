"""The Lagrangian host step's shortcuts (candidate neighbour lists, the kernel's condition
bound, the refit on an earlier factorisation, values on the host) give what the direct
computations give."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

import jaxanm
from jaxanm import mls
from jaxanm.fsw import discretise, load_scene
from jaxanm.fsw.discretisation import Refit
from jaxanm.fsw.geometry import PLATE, _apart, cloud_stencils, neighbour_list
from jaxanm.fsw.lagrangian import RunRecorder, _rotate
from jaxanm.mls._condition import condition_screen, equilibrated_moments, reciprocal_condition
from jaxanm.mls._kernel import run_kernel
from jaxanm.mls._shape import RCOND_MIN


def _scene():
    return load_scene("fsw_small")


def _sheared_cloud(cloud, dr, seed=0, amount=0.2, angle=0.3):
    rng = np.random.default_rng(seed)
    pts = cloud.points.copy()
    free = cloud.kind == PLATE
    pts[free] += amount * dr * rng.uniform(-1, 1, (free.sum(), 2))
    pts[: cloud.n_tool] = _rotate(pts[: cloud.n_tool], angle)
    return pts


def _neighbour_sets(dist, idx, h):
    return [frozenset(i[d <= h]) for d, i in zip(dist, idx)]


def test_neighbour_list_finds_the_kdtree_neighbours_of_a_moving_cloud():
    """Sets and sorted distances as cKDTree's, over small moves (no rebuild) and a big one
    (rebuild), including the polar tool ring at exactly h from the centre as the tool turns."""
    scene = _scene()
    g = scene.geometry
    cloud, *_ = discretise(scene)
    nl = neighbour_list(g)
    h = np.full(cloud.size, g.h_factor * g.dr)
    bound = float(np.nextafter(h.max(), np.inf))
    pts = cloud.points.copy()
    rng = np.random.default_rng(1)
    for step in range(40):
        pts[: cloud.n_tool] = _rotate(pts[: cloud.n_tool], 2e-3)
        pts[cloud.n_tool:] += 1e-3 * g.dr * rng.uniform(-1, 1, (cloud.size - cloud.n_tool, 2))
        if step == 30:
            pts = _sheared_cloud(cloud, g.dr, seed=step)  # far: the lists must be remade
        a = _apart(pts, cloud.n_tool, g)
        d_ref, i_ref = cKDTree(a).query(a, k=32, distance_upper_bound=bound)
        d, i, _ = nl.query(a, h, 32)
        assert _neighbour_sets(d, i, h[0]) == _neighbour_sets(d_ref, i_ref, h[0])
        np.testing.assert_array_equal(d, d_ref)
        assert np.all(i[:, 0] == np.arange(cloud.size))  # itself first
    assert nl.rebuilds == 2


def test_stencils_with_the_neighbour_list_match_a_fresh_build():
    scene = _scene()
    g = scene.geometry
    cloud, st0, *_ = discretise(scene)
    m = st0.index.shape[1]
    nl = neighbour_list(g)
    cloud_stencils(cloud.points, cloud.n_tool, g, m_max=m, neighbours=nl)
    pts = _sheared_cloud(cloud, g.dr, amount=0.05, angle=0.01)
    ref = cloud_stencils(pts, cloud.n_tool, g, m_max=m)
    new = cloud_stencils(pts, cloud.n_tool, g, m_max=m, neighbours=nl)
    assert nl.rebuilds == 1
    f = np.random.default_rng(2).standard_normal(cloud.size)
    for op in (mls.value, mls.laplacian):
        a, b = np.asarray(op(ref, f)), np.asarray(op(new, f))
        assert np.abs(a - b).max() <= 1e-12 * np.abs(a).max()


def test_refit_iterations_give_the_direct_fit_and_checkpoint_exactly(tmp_path):
    scene = _scene()
    g = scene.geometry
    cloud, st0, model, _, _ = discretise(scene)
    m = st0.index.shape[1]
    values = np.random.default_rng(4).standard_normal((cloud.size, len(model.fields))) + [0.0, 0.0, 300.0]
    refit = Refit()
    model.fit_state(values, st0, refit)
    assert refit.iterations == [0] and refit.factorizations == 1
    pts = cloud.points.copy()
    for k in range(3):
        pts = _sheared_cloud(cloud, g.dr, seed=k, amount=0.01 * (k + 1), angle=2e-3 * (k + 1))
        st = cloud_stencils(pts, cloud.n_tool, g, m_max=m)
        direct = model.fit_state(values, st)
        x = model.fit_state(values, st, refit)
        X, D = x.reshape(len(model.fields), -1), direct.reshape(len(model.fields), -1)
        # the iterations stop at an estimated error of Refit.tol = 1e-15 max|x| per field, and
        # each solve carries cond(Phi) eps (cond_inf(Phi) = 3.6 on these clouds): about
        # 1e-15 + 2 * 3.6 eps = 2.6e-15, bounded with room for the estimate (measured 1.7e-15)
        assert np.all(np.abs(X - D).max(axis=1) <= 1e-14 * np.abs(D).max(axis=1))
    assert all(it > 0 for it in refit.iterations[1:])
    # From a guess: the state fitted on the previous stencils, as a Lagrangian run passes the
    # state it solved.  The same fixed point, to the iterations' tolerance (1e-15 of max |x|)
    # plus the direct solve's own error (cond(Phi) eps, cond ~ 3): within 1e-14.
    st_next = cloud_stencils(_sheared_cloud(cloud, g.dr, seed=5, amount=0.04, angle=8e-3), cloud.n_tool, g, m_max=m)
    direct = model.fit_state(values, st_next)
    x = model.fit_state(values, st_next, refit, guess=model.fit_state(values, st))
    X, D = x.reshape(len(model.fields), -1), direct.reshape(len(model.fields), -1)
    assert np.all(np.abs(X - D).max(axis=1) <= 1e-14 * np.abs(D).max(axis=1))
    assert refit.iterations[-1] > 0
    # through a run checkpoint (the matrix stored, its factors remade): the fits go on bit for bit
    jaxanm.checkpoint.write_atomic(tmp_path / "refit.npz", {"refit": refit})
    copy = jaxanm.checkpoint.read(tmp_path / "refit.npz")["refit"]
    st = cloud_stencils(_sheared_cloud(cloud, g.dr, seed=9, amount=0.04), cloud.n_tool, g, m_max=m)
    np.testing.assert_array_equal(model.fit_state(values, st, copy), model.fit_state(values, st, refit))


def test_shear_test_from_the_stencils_agrees_with_the_kdtree():
    scene = load_scene("fsw_small").with_overrides({"geometry.rezone": "0.9"})
    cloud, stencils, model, _, x0 = discretise(scene)
    rec = RunRecorder(scene, model, stencils, x0, save_times=frozenset())
    for amount in (0.02, 0.3):
        rec.points = _sheared_cloud(cloud, scene.geometry.dr, amount=amount)
        st = cloud_stencils(rec.points, cloud.n_tool, scene.geometry, m_max=rec.width)
        assert rec._sheared(np.asarray(st.index)) == rec._sheared()
    assert rec._sheared()  # 0.3 dr of shear is too much


def test_values_on_the_host_match_the_mls_gathers():
    scene = _scene()
    cloud, st, model, _, _ = discretise(scene)
    x = np.random.default_rng(5).standard_normal(model.size)
    got = model.values(x, st)
    for j, f in enumerate(x.reshape(len(model.fields), -1)):
        with jaxanm.float64():
            ref = np.asarray(mls.value(st, f))
        assert np.abs(got[:, j] - ref).max() <= 1e-14 * np.abs(ref).max()


def test_condition_screen_is_a_lower_bound_exact_where_it_decides():
    """The kernel's bound det / trace^6 (from its Cholesky factors) never exceeds the exact
    rcond (eigenvalues of the numpy moment matrices), by more than the round-off of the two
    (a relative 1e-12: far above eps times cond(G1) <= 1e10, far below any decision margin),
    and the screen gives the exact value wherever the bound does not clear RCOND_MIN by 1e3."""
    rng = np.random.default_rng(6)
    x, y = rng.uniform(-0.7, 0.7, (2, 50, 16))
    x[:5] = rng.uniform(-0.7, 0.7, (5, 16))
    y[:5] = 0.3 * x[:5] + 3e-3 * rng.uniform(-1, 1, (5, 16))  # nearly collinear: rcond ~ 1e-9
    mask = np.ones(x.shape, dtype=bool)
    mask[:, 12:] = False  # padding
    with jaxanm.float64():  # as mls's entry points run it
        out = run_kernel(x, y, mask, np.ones(50), 0.3, 1)
    bound, finite = out[6], out[7]
    exact = reciprocal_condition(equilibrated_moments(x, y, mask, 0.3, 1))
    assert finite.all()
    assert np.all(bound <= exact * (1 + 1e-12))
    screen = condition_screen(bound, x, y, mask, 0.3, 1)
    low = ~(bound >= 1e3 * RCOND_MIN)
    assert low[:5].all() and (~low).sum() > 25  # both ways exercised
    np.testing.assert_array_equal(screen[low], exact[low])
    np.testing.assert_array_equal(screen[~low], bound[~low])
    assert np.array_equal(screen >= RCOND_MIN, exact >= RCOND_MIN)


def test_value_only_stencils_give_the_values_of_the_full_ones():
    """derivatives=False computes phi alone (what the recorder needs at markers and sections)."""
    rng = np.random.default_rng(7)
    pts = rng.uniform(-1, 1, (300, 2))
    targets = rng.uniform(-0.8, 0.8, (50, 2))
    full = mls.evaluate_at(pts, 0.35, targets)
    val = mls.evaluate_at(pts, 0.35, targets, derivatives=False)
    np.testing.assert_array_equal(np.asarray(val.index), np.asarray(full.index))
    phi, ref = np.asarray(val.phi), np.asarray(full.phi)
    assert np.abs(phi - ref).max() <= 1e-14 * np.abs(ref).max()
    assert val.dx is None and val.dyy is None


def test_neighbour_list_follows_moving_targets():
    """Targets that move with the cloud (material points): the same neighbours and stencil
    width as a fresh cKDTree search, with the lists remade only after large moves."""
    scene = _scene()
    g = scene.geometry
    cloud, *_ = discretise(scene)
    nl = neighbour_list(g)
    rng = np.random.default_rng(8)
    pts = cloud.points.copy()
    # plate points at least 2 dr inside the rim: a jittered rim target drifting outward would
    # leave the support of the quadratic basis (fewer than 6 nodes within h), which is not
    # what this test is about
    plate = cloud.points[cloud.n_tool:]
    plate = plate[np.hypot(plate[:, 0], plate[:, 1]) < g.R2 - 2 * g.dr]
    targets = plate + 0.3 * g.dr * rng.uniform(-1, 1, plate.shape)
    for step in range(12):
        pts[cloud.n_tool:] += 1e-3 * g.dr * rng.uniform(-1, 1, (cloud.size - cloud.n_tool, 2))
        targets += 1e-3 * g.dr * rng.uniform(-1, 1, targets.shape)
        if step == 8:
            targets *= 0.85  # far (beyond the skin h/4 for the outer targets): the lists must be remade
        ref = mls.evaluate_at(_apart(pts, cloud.n_tool, g), g.h_factor * g.dr, targets, c=g.c, q=g.q,
                              derivatives=False)
        new = mls.evaluate_at(_apart(pts, cloud.n_tool, g), g.h_factor * g.dr, targets, c=g.c, q=g.q,
                              derivatives=False, neighbours=nl)
        assert new.index.shape == ref.index.shape
        a, b = np.asarray(ref.phi), np.asarray(new.phi)
        f = rng.standard_normal(cloud.size)
        va, vb = np.asarray(mls.value(ref, f)), np.asarray(mls.value(new, f))
        assert np.abs(va - vb).max() <= 1e-13 * np.abs(va).max()
        assert [frozenset(i[p != 0]) for i, p in zip(np.asarray(ref.index), a)] == \
            [frozenset(i[p != 0]) for i, p in zip(np.asarray(new.index), b)]
    assert nl.rebuilds == 2
