"""FSW scenes (TOML, overrides, validation), the point cloud and the model's structure.

Structure only: unknown layout per effect set, Jacobian pattern, jet compatibility, the
Lagrangian old-value switch.  The physics is checked in tests/test_fsw_validation.py.
"""

from __future__ import annotations

import dataclasses
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanm
from jaxanm.fsw import geometry
from jaxanm.fsw.discretisation import discretise, make_model
from jaxanm.fsw.geometry import PLATE, PLATE_EDGE, RING, TOOL, TOOL_EDGE, build_cloud, cloud_stencils
from jaxanm.fsw.physics import mu_reference
from jaxanm.fsw.scene import (
    EFFECTS,
    SOLVER_KINDS,
    Geometry,
    Material,
    Scene,
    SceneError,
    SolverSpec,
    Time,
    load_scene,
    override_keys,
    shipped_scenes,
)

ALL_EULERIAN = ("inertia", "viscous", "softening", "conduction", "tool_conduction", "dissipation",
                "robin", "tracers")


# --------------------------------------------------------------------------------- scenes

def test_shipped_scenes_load_and_paper_values():
    assert {"fsw_paper", "fsw_tracers", "fsw_small", "couette_small", "conduction_small"} <= set(shipped_scenes())
    for name in shipped_scenes():
        assert load_scene(name).name == name
    s = load_scene("fsw_paper")
    g, m, tl, th = s.geometry, s.material, s.tool, s.thermal
    # c = 0.3, not the paper's 0.2: the documented departure in fsw_paper.toml (stability)
    assert (g.R1, g.R2, g.dr, g.h_factor, g.c, g.q) == (1.5e-3, 6e-3, 3.75e-4, 3.0, 0.3, 1)
    assert (m.K, m.A, m.n, m.rho, m.Cp, m.k, m.beta) == (2.69e16, -3.3155, 0.1324, 2780, 920, 140, 0.9)
    assert (tl.rho, tl.Cp, tl.k, tl.omega) == (7800, 450, 36, 20)
    assert (th.h, th.Ta, th.T0) == (1000, 300, 300)
    assert (s.time.dt, s.time.t_end) == (1e-4, 0.7)
    assert {0.001, 0.01, 0.05, 0.08, 0.3, 0.5, 0.7} <= set(s.time.save_times)
    assert (s.solver.kind, s.solver.order, s.solver.tol, s.solver.adaptive) == ("anm", 7, 1e-6, True)
    assert [p.name for p in s.probes] == ["1", "2", "3"]
    assert [x.name for x in s.sections] == ["A-A", "B-B"]
    assert set(s.effects) == set(EFFECTS) - {"tracers", "slip", "traverse", "incompressible", "shoulder"}
    eulerian = load_scene("fsw_tracers")
    assert set(eulerian.effects) == set(EFFECTS) - {"lagrangian", "slip", "traverse", "incompressible", "shoulder"}
    assert dataclasses.replace(eulerian, name=s.name, effects=s.effects) == s
    # the penalty is 0.1 mu_ref, as its comment documents, written with three significant
    # digits (4.08e5): within half a unit of the third digit, 0.005 / 4.08 relative
    assert s.mechanics.penalty == pytest.approx(0.1 * mu_reference(s), rel=0.005 / 4.08)
    # physics sanity numbers: K T0^A ~ 1.6e8 Pa s^n
    assert m.K * th.T0 ** m.A == pytest.approx(1.65e8, rel=0.02)


def test_overrides_parse_strings_and_validate():
    s = load_scene("fsw_paper").with_overrides(
        {"material.K": "2e16", "material.n": "0.2", "effects": "conduction, robin",
         "time.dt": 5e-5, "geometry.dr": "7.5e-4", "solver.kind": "newton", "time.save": "0.1,0.2"})
    assert s.material.K == 2e16 and s.material.n == 0.2 and s.time.dt == 5e-5
    assert s.effects == ("conduction", "robin") and s.geometry.dr == 7.5e-4
    assert isinstance(s.solver.make(), jaxanm.Newton)
    assert s.time.save == (0.1, 0.2)
    for key in ("material.K", "material.A", "material.n", "material.eps0", "mechanics.penalty",
                "tool.omega", "geometry.dr", "time.dt", "time.t_end", "effects", "solver.adaptive",
                "solver.pade"):
        assert key in override_keys()


def test_solver_switches_reach_the_anm_options():
    """``solver.adaptive`` and ``solver.pade`` (TOML booleans, or true/false strings from --set)."""
    s = load_scene("fsw_small")
    setting = s.solver.setting
    assert s.solver.make() == jaxanm.ANM.paper(order=setting("order"), tol=setting("tol"),
                                               criterion=setting("criterion"), max_substeps=setting("max_substeps"),
                                               max_rate=setting("max_rate"))
    t = s.with_overrides({"solver.pade": "true", "solver.adaptive": "True"})
    assert t.solver.pade is True and t.solver.adaptive is True
    assert t.solver.make().pade is True and t.solver.make().adaptive is True
    assert s.with_overrides({"solver.pade": False}).solver.make().pade is False


def test_an_unset_solver_setting_is_the_solvers_own_default():
    """The scene keeps no solver defaults: what it leaves out is the solver's (its dataclass
    field's default), for every kind; it is not written back in the TOML layout, and the
    solvers declare the option names the scene's section offers."""
    bare = Scene.from_dict({"solver": {"kind": "anm"}})
    assert bare.solver.make() == jaxanm.ANM() and "order" not in bare.to_dict()["solver"]
    for kind, solver in (("newton", jaxanm.Newton()), ("mnewton", jaxanm.ModifiedNewton())):
        assert bare.with_overrides({"solver.kind": kind}).solver.make() == solver
    given = bare.with_overrides({"solver.order": "9", "solver.kind": "newton"})  # kept, passed to the ANM only
    assert given.solver.make() == jaxanm.Newton() and given.with_overrides({"solver.kind": "anm"}).solver.order == 9
    offered = {f.name for f in dataclasses.fields(SolverSpec)} - {"kind"}
    taken = {f.name for kind in jaxanm.solver_kinds() for f in dataclasses.fields(jaxanm.make_solver(kind))}
    assert offered == taken


def test_one_name_per_solver_kind_the_former_spelling_warns():
    """A scene's ``solver.kind`` is the registered kind (the CLI's and the sweeps' name); the
    former ``modified_newton`` still loads, as ``mnewton``, with a deprecation warning."""
    assert set(SOLVER_KINDS) == set(jaxanm.solver_kinds())
    with pytest.warns(DeprecationWarning, match="solver.kind = 'modified_newton' is deprecated: write 'mnewton'"):
        old = Scene.from_dict({"solver": {"kind": "modified_newton", "max_rate": 0.3}})
    assert old.solver.kind == "mnewton" and old.solver.make() == jaxanm.ModifiedNewton(max_rate=0.3)


def test_a_refused_solver_setting_is_named_by_its_scene_key():
    """The solver's own check, under the key of the setting it refuses (found by trying each
    setting alone, not by reading the message); a refused combination names the settings
    without which the rest is accepted."""
    with pytest.raises(SceneError, match=r"'solver.criterion' = 'bogus' is invalid: ANM.criterion must be"):
        Scene.from_dict({"solver": {"kind": "anm", "criterion": "bogus", "tol": 1e-8}})
    with pytest.raises(SceneError, match=r"'solver.order and solver.pade' = \{'order': 2, 'pade': True\} is "
                                         r"invalid: ANM.pade=True needs"):
        Scene.from_dict({"solver": {"kind": "anm", "order": 2, "pade": True, "tol": 1e-8}})


def test_max_rate_reaches_modified_newton():
    """``solver.max_rate`` (a sweep tunes modified Newton by it) reaches ``jaxanm.ModifiedNewton``."""
    s = load_scene("fsw_small").with_overrides({"solver.kind": "mnewton", "solver.max_rate": "0.3"})
    assert s.solver.make() == jaxanm.ModifiedNewton(tol=s.solver.tol, max_rate=0.3)
    assert load_scene("fsw_small").solver.setting("max_rate") == jaxanm.ModifiedNewton().max_rate
    with pytest.raises(SceneError, match=r"solver.max_rate.*\(0, 1\)"):
        s.with_overrides({"solver.max_rate": "1.5"})


@pytest.mark.parametrize("overrides, field, allowed", [
    ({"material.n": "-0.5"}, "material.n", "> 0"),
    ({"material.K": "abc"}, "material.K", "real number"),
    ({"material.K": "inf"}, "material.K", "finite"),
    ({"geometry.R2": 1e-3}, "geometry.R2", "exceed geometry.R1"),
    ({"geometry.dr": 3e-3}, "geometry.dr", "(R2 - R1) / 2"),
    ({"time.dt": 0}, "time.dt", "> 0"),
    ({"time.t_end": -1}, "time.t_end", "> 0"),
    ({"tool.omega": "0"}, "tool.omega", "> 0"),
    ({"mechanics.penalty": -1}, "mechanics.penalty", ">= 0"),
    ({"geometry.layout": "hex"}, "geometry.layout", "polar"),
    ({"solver.kind": "bdf"}, "solver.kind", "anm"),
    ({"solver.pade": "yes"}, "solver.pade", "true or false"),
    ({"solver.pade": "true", "solver.order": 2}, "solver.pade", "needs order >= 3"),
    ({"solver.adaptive": 1}, "solver.adaptive", "true or false"),
    ({"time.atol": -1e-5}, "time.atol", ">= 0"),
    ({"time.adaptive": "true", "time.atol": 0, "time.rtol": 0}, "time.atol", "must be > 0 with time.adaptive"),
    ({"effects": "viscous,magic"}, "effects", "known effects"),
    ({"effects": "dissipation,conduction"}, "effects", "needs ['viscous']"),
    ({"effects": "viscous,lagrangian,tracers"}, "effects", "exclude each other"),
    ({"effects": ""}, "effects", "at least one"),
    ({"thermal.edge_source": "midpoint"}, "thermal.edge_source", "must be one of"),
    ({"thermal.edge_rows": "flux", "thermal.edge_source": "exponential"}, "thermal.edge_source",
     'needs thermal.edge_rows = "half_cell"'),
    ({"material.nn": 1}, "override key", "known keys"),
])
def test_bad_values_name_field_value_and_rule(overrides, field, allowed):
    with pytest.raises(SceneError) as info:
        load_scene("fsw_small").with_overrides(overrides)
    msg = str(info.value)
    assert field in msg and allowed in msg
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("overrides, field, allowed", [
    # registration points outside the plate: inside the tool, on its edge, on or beyond R2
    ({"x": 1.0e-3, "y": 0.5e-3}, "probes[0] (p).x, y", "inside the tool"),
    ({"x": 0.0, "y": 0.0}, "probes[0] (p).x, y", "inside the tool"),
    ({"x": 1.5e-3, "y": 0.0}, "probes[0] (p).x, y", "on the tool edge"),
    ({"x": 0.0, "y": -6e-3}, "probes[0] (p).x, y", "outside the plate"),
    ({"x": 5e-3, "y": 5e-3}, "probes[0] (p).x, y", "move the registration point into the plate"),
    # names that would break the columns of probes.csv
    ({"name": "a,b"}, "probes.name", "letters, digits or '_'"),
    ({"name": "t"}, "probes.name", "other than 't'"),
    ({"name": "T-1"}, "probes.name", "probes.csv"),
])
def test_bad_probes_are_refused_with_the_fix(overrides, field, allowed):
    """A registration point must lie in the plate (R1 < r < R2: not in the tool, on its edge or
    beyond the ring) and be named as a CSV column; refused as a jaxanm.InputError naming the
    key and the fix, before any computation."""
    probe = {"name": "p", "x": 3e-3, "y": 0.0, **overrides}
    with pytest.raises(jaxanm.InputError) as info:
        Scene.from_dict({"probes": [probe]})
    assert isinstance(info.value, SceneError)
    assert field in str(info.value) and allowed in str(info.value)


@pytest.mark.parametrize("overrides, field, allowed", [
    ({"time.atol": 0, "time.rtol": 0}, "time.atol", "must be > 0 with time.adaptive"),
    ({"time.atol": "0.0", "time.rtol": "0"}, "time.atol", "set e.g. time.atol = 1e-5"),
    ({"time.atol": -1e-5}, "time.atol", ">= 0"),
    ({"time.rtol": -1e-3}, "time.rtol", ">= 0"),
    ({"time.atol": "nan"}, "time.atol", "finite"),
    ({"time.rtol": "inf"}, "time.rtol", "finite"),
    ({"time.atol": "-inf"}, "time.atol", "finite"),
    ({"time.atol": 1.0}, "time.atol", "must be < 1 with time.adaptive"),
    ({"time.rtol": 5.0}, "time.rtol", "must be < 1 with time.adaptive"),
])
def test_bad_controller_tolerances_are_refused(overrides, field, allowed):
    """``time.atol`` / ``time.rtol`` of an adaptive scene: finite, in [0, 1), not both 0."""
    with pytest.raises(jaxanm.InputError) as info:
        load_scene("fsw_small").with_overrides({"time.adaptive": "true", **overrides})
    assert field in str(info.value) and allowed in str(info.value)


def test_tolerances_of_a_fixed_step_scene_are_not_used():
    """Without time.adaptive the tolerances are unused: only negative or non-finite ones are
    refused (a scene may carry them for a later --set time.adaptive=true)."""
    s = load_scene("fsw_small").with_overrides({"time.atol": 0, "time.rtol": 2.0})
    assert (s.time.atol, s.time.rtol, s.time.adaptive) == (0.0, 2.0, False)
    with pytest.raises(SceneError, match="time.rtol.*>= 0"):
        s.with_overrides({"time.rtol": -1.0})


@pytest.mark.parametrize("scene, overrides, message", [
    ("fsw_small", {"effects": "viscous,lagrangian,tracers"}, "exclude each other"),
    ("fsw_graded", {"effects": "viscous,conduction,lagrangian"}, "'lagrangian' on geometry.layout = 'graded'"),
    ("fsw_small", {"effects": "conduction", "mechanics.start": "quasi_static"}, "needs the 'viscous' effect"),
    ("fsw_small", {"mechanics.start": "steady"}, "must be one of"),
    ("fsw_small", {"thermal.edge_rows": "flux", "thermal.edge_source": "exponential"}, "needs thermal.edge_rows"),
    ("fsw_small", {"effects": "conduction,tracers"}, "needs ['viscous']"),
    ("fsw_small", {"solver.pade": "true", "solver.order": 2}, "needs order >= 3"),
    # moving points: a step starts from a state refitted on another cloud, no semi-discrete residual
    ("fsw_paper", {"time.scheme": "esdirk3"}, "time.scheme"),
    ("fsw_paper", {"time.scheme": "bdf2"}, "is invalid with the 'lagrangian' effect"),
    ("fsw_small", {"time.scheme": "bdf3"}, "must be one of euler, bdf2, esdirk3, esdirk4"),
    ("fsw_small", {"time.dt_max": -1e-3}, "time.dt_max"),
    # a Lagrangian scene's probes are material points, recorded where each step takes them
    ("fsw_paper", {"time.probe_dt": 1e-3}, "time.probe_dt"),
    ("fsw_small", {"time.probe_dt": -1e-3}, "time.probe_dt"),
    ("fsw", {"time.probe_dt": 1e-8}, "probe samples"),
])
def test_formulations_the_model_cannot_take_are_refused(scene, overrides, message):
    """Combinations of options the model does not support, refused at validation as a
    :class:`jaxanm.InputError` (a :class:`SceneError`), before any computation."""
    with pytest.raises(jaxanm.InputError, match=re.escape(message)):
        load_scene(scene).with_overrides(overrides)


def test_python_construction_is_validated():
    with pytest.raises(SceneError, match="material.eps0"):
        Material(eps0=0.0)
    with pytest.raises(SceneError, match=r"probes\[0\] \(1\).*plate"):
        Scene.from_dict({"probes": [{"name": "1", "x": 0.0, "y": 0.0}]})
    with pytest.raises(SceneError, match="time.dt"):
        Time(dt=1.0, t_end=0.5)
    assert Time(dt=0.1, t_end=0.5, save=(0.2, 0.9)).save_times == (0.0, 0.2, 0.5)


def test_toml_files_and_round_trip(tmp_path):
    s = load_scene("fsw_paper")
    assert Scene.from_dict(s.to_dict()) == s
    path = tmp_path / "mine.toml"
    path.write_text('name = "mine"\neffects = ["conduction"]\n[thermal]\nT0 = 500\n')
    mine = load_scene(path)
    assert mine.name == "mine" and mine.thermal.T0 == 500.0 and isinstance(mine.thermal.T0, float)
    bad = tmp_path / "bad.toml"
    bad.write_text('[material]\nKK = 1\n')
    with pytest.raises(SceneError, match=r"\[material\] key.*'KK'.*known keys"):
        load_scene(bad)
    bad.write_text('[material\n')
    with pytest.raises(SceneError, match="not valid TOML"):
        load_scene(bad)
    with pytest.raises(SceneError, match="unknown scene 'nope'.*fsw_paper"):
        load_scene("nope")
    with pytest.raises(SceneError, match="does not exist"):
        load_scene(tmp_path / "missing.toml")


# --------------------------------------------------------------------------------- cloud

def test_paper_cloud_layout():
    g = load_scene("fsw_paper").geometry
    c = build_cloud(g)
    counts = np.bincount(c.kind, minlength=5)
    assert c.size == 881 and list(counts) == [37, 26, 26, 692, 100]
    r = np.hypot(*c.points.T)
    assert np.allclose(r[c.kind == RING], g.R2) and np.allclose(r[(c.kind == TOOL_EDGE) | (c.kind == PLATE_EDGE)], g.R1)
    assert np.all(r[c.kind == TOOL] < g.R1) and np.all((r[c.kind == PLATE] > g.R1) & (r[c.kind == PLATE] < g.R2))
    # edge pairs coincide and point at each other; the tool subdomain comes first
    edge = np.flatnonzero(c.kind == TOOL_EDGE)
    assert np.all(c.partner[c.partner[edge]] == edge)
    assert np.array_equal(c.points[edge], c.points[c.partner[edge]])
    assert np.all(c.kind[: c.n_tool] <= TOOL_EDGE) and np.all(c.kind[c.n_tool:] >= PLATE_EDGE)
    # colours: no plate point on y = 0, as many blue as red
    plate = c.kind >= PLATE_EDGE
    assert np.all(c.points[plate, 1] != 0.0)
    assert np.all(c.material[~plate] == 0)
    assert np.sum(c.material == 1) == np.sum(c.material == 2)


def test_stencils_never_cross_the_tool_edge():
    g = Geometry(dr=7.5e-4)
    c = build_cloud(g)
    st = cloud_stencils(c.points, c.n_tool, g)
    tool_side = np.asarray(st.index) < c.n_tool
    assert np.all(tool_side[: c.n_tool]) and not np.any(tool_side[c.n_tool:])
    # one-sided stencils still reproduce quadratics on each side
    f = 1.0 + 3e2 * c.points[:, 0] - 2e5 * c.points[:, 0] * c.points[:, 1]
    val = (np.asarray(st.phi) * f[np.asarray(st.index)]).sum(1)
    assert np.max(np.abs(val - f)) < 1e-10
    # evaluation at targets picks the side by radius
    targets = np.array([[0.5 * g.R1, 0.0], [1.2 * g.R1, 0.3e-3]])
    ev = geometry.evaluate_stencils(c.points, c.n_tool, g, targets)
    idx = np.asarray(ev.index)
    assert np.all(idx[0] < c.n_tool) and np.all(idx[1] >= c.n_tool)


# --------------------------------------------------------------------------------- model

def _small(effects, **kw):
    scene = Scene(effects=effects, geometry=Geometry(dr=7.5e-4), **kw)
    cloud, _, model, params, _ = discretise(scene)
    return scene, cloud, model, params


@pytest.mark.parametrize("effects, fields", [
    (("viscous",), ("u", "v")),
    (("viscous", "inertia", "lagrangian"), ("u", "v")),
    (("conduction",), ("T",)),
    (("conduction", "tool_conduction", "robin"), ("T",)),
    (ALL_EULERIAN, ("u", "v", "T")),
])
def test_unknowns_follow_effects(effects, fields):
    scene, cloud, model, params = _small(effects)
    assert model.fields == fields and model.size == len(fields) * cloud.size
    x0 = model.initial_state(cloud.points)
    with jaxanm.float64():
        r = model.residual(x0, x0, 1e-4, 1e-4, params)
    assert r.shape == (model.size,) and np.all(np.isfinite(np.asarray(r)))
    scale = model.scale().reshape(len(fields), -1)
    expected = {"u": scene.tool.omega * scene.geometry.R1, "v": scene.tool.omega * scene.geometry.R1,
                "T": scene.thermal.T0}
    for f, row in zip(fields, scale):
        assert np.all(row == expected[f])


@pytest.mark.parametrize("effects", [ALL_EULERIAN, ("inertia", "viscous", "softening", "conduction",
                                                    "tool_conduction", "dissipation", "robin", "lagrangian")])
def test_sparsity_pattern_covers_jacobian(effects):
    scene, cloud, model, params = _small(effects)
    rng = np.random.default_rng(1)
    x = model.initial_state(cloud.points) * (1 + 0.1 * rng.standard_normal(model.size))
    with jaxanm.float64():
        J = np.asarray(jax.jacfwd(lambda z: model.residual(z, x, 1e-4, 1e-4, params))(jnp.asarray(x)))
    pattern = model.sparsity(params).toarray()
    assert not np.any((J != 0) & ~pattern)
    assert pattern.sum() < 0.5 * pattern.size  # and it is sparse
    # the coupling across the tool edge is in it (flux and temperature continuity)
    N = cloud.size
    edge = np.flatnonzero(cloud.kind == PLATE_EDGE)[0]
    T = 2 * N
    assert np.any(J[T + edge, T: T + cloud.n_tool] != 0)


def test_residual_is_jet_compatible():
    """Taylor coefficients of the residual along a line agree with nested jvps (orders 1 and 2)."""
    scene, cloud, model, params = _small(("inertia", "viscous", "softening", "conduction",
                                          "tool_conduction", "dissipation", "robin", "lagrangian"))
    rng = np.random.default_rng(2)
    x = model.initial_state(cloud.points) + 0.05 * model.scale() * rng.standard_normal(model.size)
    d = 0.01 * model.scale() * rng.standard_normal(model.size)

    def f(z):
        return model.residual(z, x, 1e-4, 1e-4, params)

    coeffs = jaxanm.taylor_coefficients(f, x, [d, np.zeros_like(d)])
    assert all(np.all(np.isfinite(np.asarray(c))) for c in coeffs)
    with jaxanm.float64():
        first = jax.jvp(f, (x,), (d,))[1]
        second = jax.jvp(lambda z: jax.jvp(f, (z,), (d,))[1], (x,), (d,))[1] / 2
    assert np.allclose(coeffs[1], first, rtol=1e-9, atol=1e-9 * np.abs(first).max())
    assert np.allclose(coeffs[2], second, rtol=1e-9, atol=1e-9 * np.abs(second).max())


def test_lagrangian_refit_carries_values():
    """After a stencil rebuild the refitted state reproduces the carried values on the new stencils,
    so the heat rows see exactly the carried temperature as the old value (rho Cp dT/dt)."""
    scene, cloud, model, params = _small(("conduction",))
    lag_scene = dataclasses.replace(scene, effects=("viscous", "conduction", "lagrangian"))
    lag = make_model(lag_scene, cloud)
    st = params["st"]
    carried = lag.initial_values(cloud.points).copy()
    rng = np.random.default_rng(5)
    carried[:, 2] += 10.0 + rng.standard_normal(cloud.size)  # the points carry T0 + 10 + noise
    x_old = lag.fit_state(carried, st)
    assert np.abs(lag.values(x_old, st) - carried).max() < 1e-10 * np.abs(carried).max()
    new = carried.copy()
    new[:, 2] = scene.thermal.T0
    x_new = lag.fit_state(new, st)
    p = lag.params(cloud.points, st)
    N = cloud.size
    plate = np.flatnonzero(cloud.kind == PLATE)
    with jaxanm.float64():
        r = np.asarray(lag.residual(x_new, x_old, 1e-4, 1e-4, p))[2 * N + plate]
    dr, s = scene.geometry.dr, scene.material
    row_scale = dr ** 2 / (scene.thermal.T0 * (s.k + s.rho * s.Cp * dr ** 2 / 1e-4))
    expected = s.rho * s.Cp * (scene.thermal.T0 - carried[plate, 2]) / 1e-4 * row_scale
    assert np.allclose(r, expected, rtol=1e-6, atol=1e-9 * np.abs(expected).max())



def test_a_scene_file_can_start_from_another(tmp_path):
    # the main job is fsw_graded with its own cloud grading, steps and solver: every other value is the base's
    main, graded = load_scene("fsw"), load_scene("fsw_graded")
    assert main.name == "fsw" and main.solver.kind == "anm" and main.time.adaptive
    assert main.mechanics == graded.mechanics and main.mechanics.start == "quasi_static"
    assert main.material == graded.material
    assert dataclasses.replace(main.geometry, dr=graded.geometry.dr, band=graded.geometry.band,
                               grading=graded.geometry.grading, dr_far=graded.geometry.dr_far) == graded.geometry
    assert main.probes == graded.probes and main.effects == graded.effects
    # a user's file on a shipped scene, then one on that file (relative path); a list replaces
    (tmp_path / "mine.toml").write_text('base = "fsw_small"\nname = "mine"\n[time]\nt_end = 0.01\n'
                                        '[[probes]]\nname = "a"\nx = 3e-3\ny = 0.0\n')
    (tmp_path / "more.toml").write_text('base = "mine.toml"\nname = "more"\n[material]\nn = 0.2\n')
    more = load_scene(tmp_path / "more.toml")
    small = load_scene("fsw_small")
    assert (more.name, more.time.t_end, more.material.n) == ("more", 0.01, 0.2)
    assert more.material.K == small.material.K and more.time.dt == small.time.dt
    assert [p.name for p in more.probes] == ["a"]
    (tmp_path / "loop.toml").write_text('base = "loop.toml"\nname = "loop"\n')
    with pytest.raises(SceneError, match="cycle"):
        load_scene(tmp_path / "loop.toml")
    (tmp_path / "lost.toml").write_text('base = "nowhere"\nname = "lost"\n')
    with pytest.raises(SceneError, match="unknown scene 'nowhere'"):
        load_scene(tmp_path / "lost.toml")
