"""``jaxanm sweep``'s grid reader: grid files expanded into validated tasks with ids."""

from __future__ import annotations

import dataclasses

import pytest

from jaxanm.fsw.scene import SolverSpec
from jaxanm.sweep import GridError, grid_from_dict, read_grid
from jaxanm.sweep.grid import SOLVER_KEYS


def grid(data: dict, **kw):
    """``grid_from_dict`` with a shipped base scene unless ``data`` names one."""
    return grid_from_dict({"scene": "couette_small", **data}, **kw)


def grid_error(data: dict) -> str:
    """The message of the :class:`GridError` that ``data`` raises."""
    with pytest.raises(GridError) as info:
        grid(data)
    return str(info.value)


# --------------------------------------------------------------------------- grid reader


def test_product_of_overrides_and_solver_entries():
    g = grid({"reference": "dt=0.5-newton-tol=1e-10",
              "overrides": {"time.t_end": 1.0, "time.dt": [1.0, 0.5]},
              "solvers": [{"kind": "anm", "order": [5, 7], "tol": 1e-6},
                          {"kind": "newton", "tol": [1e-6, 1e-10]}]})
    assert [t.id for t in g.tasks] == [
        "dt=1.0-anm-order=5-tol=1e-06", "dt=1.0-anm-order=7-tol=1e-06", "dt=1.0-newton-tol=1e-06",
        "dt=1.0-newton-tol=1e-10", "dt=0.5-anm-order=5-tol=1e-06", "dt=0.5-anm-order=7-tol=1e-06",
        "dt=0.5-newton-tol=1e-06", "dt=0.5-newton-tol=1e-10"]
    assert g.keys == ("time.t_end", "time.dt", "solver.kind", "solver.order", "solver.tol")
    assert g.reference == "dt=0.5-newton-tol=1e-10" and g.name == "grid"
    task = g.tasks[5]
    assert task.overrides == {"time.t_end": 1.0, "time.dt": 0.5, "solver.kind": "anm", "solver.order": 7,
                              "solver.tol": 1e-6}
    assert (task.scene.time.dt, task.scene.solver.kind, task.scene.solver.order) == (0.5, "anm", 7)
    assert g.tasks[3].scene.solver == dataclasses.replace(g.base.solver, kind="newton", tol=1e-10)


def test_dotted_keys_sub_tables_and_quoted_keys_mean_the_same(tmp_path):
    quoted = tmp_path / "quoted.toml"
    quoted.write_text('scene = "couette_small"\n[overrides]\n"material.n" = [0.3, 0.5]\n"time.dt" = 0.5\n')
    dotted = tmp_path / "dotted.toml"
    dotted.write_text('scene = "couette_small"\n[overrides]\nmaterial.n = [0.3, 0.5]\n[overrides.time]\ndt = 0.5\n')
    a, b = read_grid(quoted), read_grid(dotted)
    assert [t.overrides for t in a.tasks] == [t.overrides for t in b.tasks]
    assert [t.id for t in a.tasks] == ["n=0.3", "n=0.5"] and a.name == "quoted"


def test_list_fields_take_a_list_as_one_value_and_a_list_of_lists_as_an_axis():
    one = grid({"scene": "conduction_small", "overrides": {"effects": ["conduction", "robin"]}})
    assert [t.scene.effects for t in one.tasks] == [("conduction", "robin")] and one.tasks[0].id == "run"
    axis = grid({"scene": "conduction_small", "overrides": {"effects": [["conduction"], ["conduction", "robin"]]}})
    assert [t.id for t in axis.tasks] == ["effects=conduction", "effects=conduction+robin"]
    assert "list of lists for an axis" in grid_error({"overrides": {"effects": [["viscous"], "viscous"]}})


def test_overrides_entries_are_a_union_and_the_solver_defaults_to_the_scene():
    g = grid({"overrides": [{"material.n": 0.3}, {"material.n": 0.5, "material.eps0": [1e-2, 1e-3]}]})
    assert [t.id for t in g.tasks] == ["n=0.3", "n=0.5-eps0=0.01", "n=0.5-eps0=0.001"]
    assert all(t.scene.solver == g.base.solver for t in g.tasks)


def test_keys_sharing_a_last_name_keep_their_section_in_the_id():
    g = grid({"scene": "conduction_small", "overrides": {"material.k": [100.0, 140.0], "tool.k": [36.0, 50.0]}})
    assert g.tasks[0].id == "material.k=100.0-tool.k=36.0"


def test_solver_keys_cover_the_scene_solver_fields():
    fields = {f.name for f in dataclasses.fields(SolverSpec)} - {"kind"}
    assert set().union(*SOLVER_KEYS.values()) == fields


@pytest.mark.parametrize("data, expected", [
    ({"solvers": {"kind": "newton", "order": [5, 7]}},
     "[solvers]: 'order': it does not apply to kind = 'newton'; kind 'newton' takes tol"),
    ({"solvers": [{"kind": "anm"}, {"kind": "mnewton", "max_rate": 0.3, "pade": True}]},
     "[[solvers]] #2: 'pade': it does not apply to kind = 'mnewton'; kind 'mnewton' takes tol, max_rate"),
    ({"solvers": {"kind": "anm", "eta": 1e-6}}, "'eta': it is not a solver setting; kind 'anm' takes order, tol"),
    ({"solvers": {"kind": "bdf"}}, "kind = 'bdf' is unknown; use one of anm, newton, mnewton"),
    ({"overrides": {"solver.tol": 1e-6}}, "'solver.tol' is a solver setting; give it under [[solvers]] as tol = ..."),
    ({"overrides": {"material.K2": 1.0}}, "unknown scene key 'material.K2'; the keys of `jaxanm run --set` are"),
    ({"overrides": {"time.dt": []}}, "time.dt = [] gives no task; list at least one value"),
    ({"overrides": {"time.dt": [1.0, 1.0]}}, "time.dt = [1.0, 1.0] lists a value twice; list each value once"),
    ({"solvers": [{"kind": "newton", "tol": 1e-6}, {"kind": "newton", "tol": [1e-6, 1e-8]}]},
     "tasks 'tol=1e-06' and 'tol=1e-06' are the same run; list each value once"),
    ({"solvers": {"kind": "anm", "tol": [1e-6, 2.0]}},
     "task 'tol=2.0': scene field 'solver.tol' = 2.0 is invalid: must be in (0, 1)"),
    ({"reference": "newton", "solvers": {"tol": [1e-6, 1e-8]}},
     "reference = 'newton' is not a task of this grid; its tasks are 'tol=1e-06', 'tol=1e-08'"),
    ({"solver": {"tol": 1e-6}}, "unknown top-level key 'solver'; the keys are scene, reference, overrides, solvers"),
    ({"scene": "no_such_scene"}, "scene = 'no_such_scene': unknown scene"),
    ({"scene": 3}, "give the base scene as scene = \"NAME\""),
    ({"solvers": [{}]}, "[[solvers]] #1 is empty"),
])
def test_bad_grids_are_named_with_the_fix(data, expected):
    assert expected in grid_error(data)


def test_grid_files_name_themselves_in_errors(tmp_path):
    missing = tmp_path / "missing.toml"
    with pytest.raises(GridError, match="missing.toml' does not exist"):
        read_grid(missing)
    broken = tmp_path / "broken.toml"
    broken.write_text("scene = 'couette_small'\n[[solvers]\n")
    with pytest.raises(GridError, match="broken.toml' is not valid TOML"):
        read_grid(broken)
