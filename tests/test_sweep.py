"""``jaxanm sweep``: the grid reader (units), one 2 x 2 sweep on a local Dask cluster of 2 workers,
its rerun (nothing run again), the task's failure path and the command's errors.

The sweep's scene is couette_small at twice its spacing (4 rings, one stationary step):
nonlinear, so Newton and modified Newton at two tolerances give four different runs, and a few
seconds of compilation per worker.  No assertion depends on timing.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from run_once import shared_once

from jaxanm import cli
from jaxanm.errors import InputError
from jaxanm.fsw.scene import SCENES_DIR, SolverSpec
from jaxanm.sweep import GridError, grid_from_dict, read_grid, run_sweep, runner
from jaxanm.sweep.grid import IDA, SOLVER_KEYS
from jaxanm.sweep.pareto import pareto_front
from jaxanm.sweep.table import ERROR_COLUMNS, add_errors, columns
from jaxanm.sweep.task import COST_COLUMNS, ROW_FILE, finished_row, run_task, task_spec

RUN_FILES = ("summary.json", "fields.npz", "probes.csv", "fields.pvd", ROW_FILE)

# Tolerances 1e-3 and 1e-8 are five decades apart: from a correction of 1e-3 one quadratic
# Newton iteration reaches about 1e-6, not 1e-8, so the two runs of each solver stop at different
# iterates and every error against the reference is positive (exactly, not within a margin).
TINY_GRID = """
scene = "tiny_couette.toml"
reference = "newton-tol=1e-08"

[overrides]
"geometry.dr" = 1.125e-3

[[solvers]]
kind = ["newton", "mnewton"]
tol = [1e-3, 1e-8]
"""
TINY_IDS = ["newton-tol=0.001", "newton-tol=1e-08", "mnewton-tol=0.001", "mnewton-tol=1e-08"]


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
    assert set().union(*(keys for kind, keys in SOLVER_KEYS.items() if kind != IDA)) == fields


@pytest.mark.parametrize("data, expected", [
    ({"solvers": {"kind": "newton", "order": [5, 7]}},
     "[solvers]: 'order': it does not apply to kind = 'newton'; kind 'newton' takes tol"),
    ({"solvers": [{"kind": "anm"}, {"kind": "mnewton", "max_rate": 0.3, "pade": True}]},
     "[[solvers]] #2: 'pade': it does not apply to kind = 'mnewton'; kind 'mnewton' takes tol, max_iter, max_rate"),
    ({"solvers": {"kind": "anm", "eta": 1e-6}}, "'eta': it is not a solver setting; kind 'anm' takes order, tol"),
    ({"solvers": {"kind": "bdf"}}, "kind = 'bdf' is unknown; use one of anm, mnewton, newton"),
    ({"overrides": {"solver.tol": 1e-6}}, "'solver.tol' is a solver setting; give it under [[solvers]] as tol = ..."),
    ({"overrides": {"material.K2": 1.0}}, "unknown scene key 'material.K2'; the keys of `jaxanm run --set` are"),
    ({"overrides": {"time.dt": []}}, "time.dt = [] gives no task; list at least one value"),
    ({"overrides": {"time.dt": [1.0, 1.0]}}, "time.dt = [1.0, 1.0] lists a value twice; list each value once"),
    ({"solvers": [{"kind": "newton", "tol": 1e-6}, {"kind": "newton", "tol": [1e-6, 1e-8]}]},
     "tasks 'tol=1e-06' and 'tol=1e-06' are the same run; list each value once"),
    ({"solvers": {"kind": "anm", "tol": [1e-6, 2.0]}},
     "task 'tol=2.0': scene field 'solver.tol' = 2.0 is invalid: ANM.tol must be a number in (0, 1)"),
    ({"reference": "newton", "solvers": {"tol": [1e-6, 1e-8]}},
     "reference = 'newton' is not a task of this grid; its tasks are 'tol=1e-06', 'tol=1e-08'"),
    ({"solver": {"tol": 1e-6}},
     "unknown top-level key 'solver'; the keys are scene, reference, warmup, overrides, solvers"),
    ({"scene": "no_such_scene"}, "scene = 'no_such_scene': unknown scene"),
    ({"scene": 3}, "give the base scene as scene = \"NAME\""),
    ({"solvers": [{}]}, "[[solvers]] #1 is empty"),
])
def test_bad_grids_are_named_with_the_fix(data, expected):
    assert expected in grid_error(data)


def test_scene_keys_in_a_solver_entry_cross_that_entry_only():
    g = grid({"overrides": {"time.t_end": 1.0},
              "solvers": [{"kind": "mnewton", "tol": 1e-8, "time.dt": [1.0, 0.5]},
                          {"kind": "anm", "time": {"dt": 0.25}}]})
    assert [t.id for t in g.tasks] == ["dt=1.0-mnewton-tol=1e-08", "dt=0.5-mnewton-tol=1e-08", "dt=0.25-anm"]
    assert [(t.scene.time.dt, t.scene.solver.kind) for t in g.tasks] == [
        (1.0, "mnewton"), (0.5, "mnewton"), (0.25, "anm")]
    assert all(t.scene.time.t_end == 1.0 and t.ida is None for t in g.tasks)


def test_ida_tasks_carry_their_settings_not_a_scene_solver():
    g = grid({"scene": "conduction_small", "solvers": [{"kind": "newton"}, {"kind": "ida", "rtol": [1e-4, 1e-6]},
                                                       {"kind": "ida", "rtol": 1e-5, "atol": 1e-3, "max_order": 2}]})
    assert [t.id for t in g.tasks] == ["newton", "ida-rtol=0.0001", "ida-rtol=1e-06",
                                       "ida-rtol=1e-05-atol=0.001-max_order=2"]
    assert g.tasks[1].ida == {"rtol": 1e-4, "atol": 1e-4, "max_order": 5}  # atol defaults to rtol
    assert g.tasks[3].ida == {"rtol": 1e-5, "atol": 1e-3, "max_order": 2}
    assert g.tasks[1].scene == g.base and g.tasks[1].overrides == {"solver.kind": "ida", "solver.rtol": 1e-4}
    assert g.keys == ("solver.kind", "solver.rtol", "solver.atol", "solver.max_order")


def test_a_richardson_reference_is_three_tasks_at_dt_dt2_dt4():
    g = grid({"scene": "conduction_small", "overrides": {"time.t_end": 0.2, "time.save": [0.1]},
              "reference": {"richardson": {"dt": 0.025, "kind": "mnewton", "tol": 1e-10}},
              "solvers": {"kind": "newton", "time.dt": [0.1, 0.05]}})
    assert g.reference is None and g.richardson.dt == 0.025
    ref = g.richardson.tasks
    assert [t.id for t in ref] == ["richardson-dt=0.025", "richardson-dt=0.0125", "richardson-dt=0.00625"]
    assert [t.scene.time.dt for t in ref] == [0.025, 0.0125, 0.00625]
    assert all((t.scene.time.t_end, t.scene.time.save, t.scene.solver.kind, t.scene.solver.tol, t.scene.time.adaptive)
               == (0.2, (0.1,), "mnewton", 1e-10, False) for t in ref)


RICHARDSON = {"richardson": {"dt": 0.025, "kind": "mnewton", "tol": 1e-10}}


@pytest.mark.parametrize("data, expected", [
    ({"scene": "fsw_small", "solvers": {"kind": "ida"}}, "IDA needs fixed points and scene 'fsw_small' is Lagrangian"),
    ({"scene": "conduction_small", "solvers": {"kind": "ida", "rtol": 2.0}},
     "rtol must be a number in (0, 1), got 2.0"),
    ({"scene": "conduction_small", "solvers": {"kind": "ida", "atol": -1.0}}, "atol must be a number >= 0, got -1.0"),
    ({"scene": "conduction_small", "solvers": {"kind": "ida", "max_order": 6}},
     "max_order must be an integer from 1 to 5, got 6"),
    ({"scene": "conduction_small", "solvers": {"kind": "ida", "tol": 1e-6}},
     "'tol': it does not apply to kind = 'ida'; kind 'ida' takes rtol, atol, max_order"),
    ({"overrides": {"time.dt": 0.5}, "solvers": {"kind": "newton", "time.dt": [1.0]}},
     "'time.dt' is both in [overrides] and in a [[solvers]] entry"),
    ({"solvers": {"kind": "newton", "time.dtt": [1.0]}}, "[solvers]: unknown scene key 'time.dtt'"),
    ({"scene": "conduction_small", "reference": {"richardson": {"dt": -1.0, "kind": "mnewton"}}},
     "[reference.richardson]: dt must be a number > 0, got -1.0"),
    ({"scene": "conduction_small", "overrides": {"time.t_end": [0.2, 0.3]}, "reference": RICHARDSON},
     "the reference runs the grid's [overrides], which must then be single values"),
    ({"scene": "conduction_small", "reference": {"richardson": {"dt": 0.025, "kind": "ida"}}},
     "give one implicit-Euler solver"),
    ({"scene": "conduction_small", "reference": {"richardson": {"dt": 0.03, "kind": "mnewton"}}},
     "save time 0.1 s is no multiple of dt = 0.03"),
    ({"scene": "conduction_small", "reference": {"dt": 0.03}}, "reference must be a task id"),
    ({"warmup": "yes"}, "warmup must be True or False, got 'yes'"),
])
def test_bad_ida_richardson_and_entry_overrides_are_named(data, expected):
    assert expected in grid_error(data)


def test_grid_files_name_themselves_in_errors(tmp_path):
    missing = tmp_path / "missing.toml"
    with pytest.raises(GridError, match="missing.toml' does not exist"):
        read_grid(missing)
    broken = tmp_path / "broken.toml"
    broken.write_text("scene = 'couette_small'\n[[solvers]\n")
    with pytest.raises(GridError, match="broken.toml' is not valid TOML"):
        read_grid(broken)


def test_committed_grids_read():
    root = Path(__file__).resolve().parents[1] / "benchmarks" / "grids"
    table1 = read_grid(root / "table1.toml")
    assert [(t.scene.solver.kind, t.scene.solver.adaptive, t.scene.solver.order) for t in table1.tasks] == [
        ("anm", False, p) for p in (5, 7, 10, 15, 20)]
    assert table1.base.name == "fsw_paper" and table1.tasks[0].scene.time.t_end == 0.7
    demo = read_grid(root / "couette_demo.toml")
    assert len(demo.tasks) == 4 and demo.reference in {t.id for t in demo.tasks}
    # the configurations of benchmarks/results/accuracy_cost_paper.json (30 rows, 5 of them IDA) and the
    # Lagrangian front
    tracers = read_grid(root / "accuracy_cost_tracers.toml")
    assert len(tracers.tasks) == 30 and sum(t.ida is not None for t in tracers.tasks) == 5 and tracers.warmup
    assert tracers.richardson.dt == 5e-5 and tracers.base.name == "fsw_tracers"
    assert {t.scene.time.t_end for t in tracers.tasks} == {0.1}
    lagrangian = read_grid(root / "accuracy_cost_lagrangian.toml")
    assert lagrangian.base.has("lagrangian") and all(t.ida is None for t in lagrangian.tasks)
    assert {t.scene.time.dt for t in lagrangian.tasks} == {1e-3, 5e-4, 2e-4, 1e-4, 1e-5}


# --------------------------------------------------------------------------- table and plot helpers


def test_pareto_front_keeps_the_points_nothing_beats():
    points = [(1.0, 1e-2), (2.0, 1e-3), (3.0, 5e-3), (0.5, 1e-1), (4.0, 1e-5)]
    assert pareto_front(points) == [(0.5, 1e-1), (1.0, 1e-2), (2.0, 1e-3), (4.0, 1e-5)]


def test_columns_order():
    names = columns(("time.dt", "solver.tol"), errors=True)
    assert names[:6] == ["task", "status", "message", "reused", "time.dt", "solver.tol"]
    assert names[6:6 + len(COST_COLUMNS)] == list(COST_COLUMNS)
    assert names[-len(ERROR_COLUMNS):] == list(ERROR_COLUMNS)


def test_a_task_that_fails_reports_in_its_row_and_is_not_finished(tmp_path):
    """The worker-side failure path, run in this process: the scene cannot be built."""
    task = grid({"solvers": {"tol": [1e-6, 1e-8]}}).tasks[0]
    spec = task_spec(task, tmp_path / "t", compile_cache=False)
    spec["scene"]["geometry"]["R2"] = 1e-3  # inside the tool: the worker's scene check fails
    row = run_task(spec)
    assert row["status"] == "failed" and row["task"] == "tol=1e-06" and row["solver.tol"] == 1e-6
    assert row["message"].startswith("SceneError: ") and "geometry.R2" in row["message"]
    stored = json.loads((tmp_path / "t" / ROW_FILE).read_text())
    assert stored["status"] == "failed" and "Traceback" in stored["traceback"]
    assert finished_row(spec) is None
    errors = add_errors([{**row, "dir": "t"}], _any_run(tmp_path), tmp_path)[0]
    assert errors["compare_note"] == "task failed" and math.isnan(errors["rel_err"])


def _any_run(tmp_path: Path) -> Path:
    """A minimal run directory (the reference of a table whose rows all failed)."""
    ref = tmp_path / "ref"
    ref.mkdir()
    for name in ("summary.json", "probes.csv"):
        (ref / name).write_text("{}" if name.endswith("json") else "t\n0\n")
    np.savez(ref / "fields.npz", t=np.zeros(1))
    return ref


# --------------------------------------------------------------------------- a real sweep


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """The 2 x 2 grid run once per test run on a local cluster of 2 workers (shared by the xdist
    workers, each with its own copy): (grid path, sweep dir, result)."""

    def make(root):
        (root / "tiny_couette.toml").write_text((SCENES_DIR / "couette_small.toml").read_text()
                                                .replace('"couette_small"', '"tiny"'))
        (root / "tiny.toml").write_text(TINY_GRID)
        return run_sweep(read_grid(root / "tiny.toml"), root / "out", workers=2, progress=False,
                         compile_cache=False)

    root, result = shared_once(tmp_path_factory, "sweep", make)
    return root / "tiny.toml", root / "out", result


def test_sweep_writes_one_row_and_one_run_directory_per_task(sweep):
    _, out, result = sweep
    assert result.failed == [] and result.reused == 0 and result.notes == []
    assert [r["task"] for r in result.rows] == TINY_IDS
    with open(out / "results.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert [r["task"] for r in table] == TINY_IDS
    assert list(table[0]) == columns(("geometry.dr", "solver.kind", "solver.tol"), errors=True)
    for row, csv_row in zip(result.rows, table):
        assert row["status"] == csv_row["status"] == "ok" and row["reused"] is False
        assert row["kind"] == row["solver.kind"] and row["time_steps"] >= 1 and row["factorizations"] >= 1
        assert row["newton_iterations"] >= 1 and row["series_orders"] == 0 and row["wall_s"] > 0
        assert float(csv_row["wall_s"]) == row["wall_s"]  # repr: exact round trip
        run_dir = out / row["dir"]
        assert row["dir"] == f"runs/{row['task']}" and all((run_dir / f).is_file() for f in RUN_FILES)
        summary = json.loads((run_dir / "summary.json").read_text())
        assert summary["scene"]["solver"]["tol"] == row["solver.tol"]
        assert summary["scene"]["geometry"]["dr"] == 1.125e-3 and summary["solver"]["kind"] == row["kind"]
        assert len(list((run_dir / "vtu").glob("*.vtu"))) == summary["n_saved"]


def test_errors_against_the_reference_task_and_the_pareto_plot(sweep):
    _, out, result = sweep
    assert result.reference == out / "runs" / "newton-tol=1e-08"
    rows = {r["task"]: r for r in result.rows}
    reference = rows.pop("newton-tol=1e-08")
    assert reference["rel_err"] == reference["rel_err_V"] == reference["probe_err_V"] == 0.0  # itself
    for row in rows.values():
        assert row["compare_note"] == "" and math.isnan(row["rel_err_T"])  # isothermal: no T - T0
        assert row["rel_err"] == row["rel_err_V"] > 0 and math.isfinite(row["rel_err"])
    assert result.plot == out / "pareto.png" and result.plot.read_bytes()[:4] == b"\x89PNG"


def test_without_a_reference_the_table_has_no_errors_and_an_old_plot_goes(sweep, tmp_path):
    path, out, _ = sweep
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    plain = tmp_path / "plain.toml"
    plain.write_text(TINY_GRID.replace('reference = "newton-tol=1e-08"', "").replace(
        '"tiny_couette.toml"', f'"{path.parent / "tiny_couette.toml"}"'))
    again = run_sweep(read_grid(plain), copy, progress=False)
    assert again.reused == 4 and again.reference is None and again.plot is None
    assert not (copy / "pareto.png").exists()
    with open(copy / "results.csv", newline="") as f:
        assert next(csv.reader(f)) == columns(("geometry.dr", "solver.kind", "solver.tol"))


def test_rerun_reuses_every_finished_task_without_a_cluster(sweep, monkeypatch):
    path, out, first = sweep

    def no_cluster(*args):
        raise AssertionError("a rerun of a finished sweep must not start Dask")

    monkeypatch.setattr(runner, "_client", no_cluster)
    again = run_sweep(read_grid(path), out, progress=False)
    assert again.reused == 4 and again.failed == []

    def strip(rows):  # JSON text: NaN (absent T errors) compares equal to itself there
        return json.dumps([{k: v for k, v in r.items() if k != "reused"} for r in rows], sort_keys=True)

    assert strip(again.rows) == strip(first.rows)
    assert all(r["reused"] is True for r in again.rows)


def test_an_unfinished_task_runs_again_alone_on_a_given_scheduler(sweep, tmp_path):
    """One task's row file removed (as after an interruption): a rerun on the scheduler of a
    cluster made here (in this process: no network) runs that task and re-reads the others."""
    from dask.distributed import LocalCluster

    path, out, first = sweep
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    (copy / "runs" / TINY_IDS[2] / ROW_FILE).unlink()
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        again = run_sweep(read_grid(path), copy, scheduler=cluster.scheduler_address, progress=False,
                          compile_cache=False)
    assert again.reused == 3 and [r["reused"] for r in again.rows] == [True, True, False, True]
    rerun = again.rows[2]
    assert rerun["status"] == "ok" and rerun["task"] == TINY_IDS[2] and (copy / rerun["dir"] / ROW_FILE).is_file()
    assert rerun["time_steps"] == first.rows[2]["time_steps"] and rerun["rel_err"] > 0


def test_a_run_directory_is_finished_only_for_its_own_scene(sweep, tmp_path):
    path, out, _ = sweep
    g = read_grid(path)
    copy = tmp_path / "copy"
    shutil.copytree(out / "runs" / g.tasks[0].id, copy)
    spec = task_spec(g.tasks[0], copy, compile_cache=False)
    assert finished_row(spec)["task"] == g.tasks[0].id
    other = task_spec(g.tasks[1], copy, compile_cache=False)  # another tolerance in the same directory
    assert finished_row(other) is None
    (copy / "fields.npz").unlink()
    assert finished_row(spec) is None


def test_cli_sweep_reports_the_table_and_plot(sweep, tmp_path, capsys):
    path, out, _ = sweep
    copy = tmp_path / "out"
    shutil.copytree(out, copy)
    assert cli.main(["sweep", str(path), "--out", str(copy), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "sweep tiny: 4 tasks (0 run, 4 reused, 0 failed)" in printed
    assert f"results table: {copy / 'results.csv'}" in printed and f"Pareto plot: {copy / 'pareto.png'}" in printed


# --------------------------------------------------------------------------- command-line errors


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("jaxanm: error: "), err
    return lines[0]


def test_cli_rejects_a_bad_grid_before_any_computation(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('scene = "couette_small"\n[[solvers]]\nkind = "newton"\norder = [5, 7]\n')
    out = tmp_path / "out"
    assert cli.main(["sweep", str(bad), "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert "bad.toml': [[solvers]] #1: 'order': it does not apply to kind = 'newton'" in line
    assert "put other kinds in their own [[solvers]] entry" in line and not out.exists()


@pytest.mark.parametrize("argv, expected", [
    (["--scheduler", "tcp://127.0.0.1:8786", "--workers", "3"], "--workers sets the size of the local cluster"),
    (["--workers", "0"], "expected an integer >= 1, got 0"),
])
def test_cli_rejects_conflicting_options(argv, expected, tmp_path, capsys):
    good = tmp_path / "good.toml"
    good.write_text('scene = "couette_small"\n')
    assert cli.main(["sweep", str(good), "--out", str(tmp_path / "out"), *argv]) == 2
    assert expected in _one_error_line(capsys.readouterr().err)


def test_unusable_reference_and_unreachable_scheduler_are_input_errors(tmp_path):
    import dask

    g = grid({})
    with pytest.raises(InputError, match="workers must be an integer >= 1, got True"):
        run_sweep(g, tmp_path / "w", workers=True, progress=False)  # a bool is no process count
    with pytest.raises(InputError, match="not the output directory of a finished `jaxanm run`"):
        run_sweep(g, tmp_path / "a", reference=tmp_path, progress=False)
    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}):  # refused at once on loopback
        with pytest.raises(InputError, match="cannot reach the Dask scheduler at 'tcp://127.0.0.1:1'"):
            run_sweep(g, tmp_path / "b", scheduler="tcp://127.0.0.1:1", progress=False)
