"""A sweep with an IDA task, implicit Euler at two steps and a Richardson reference, end to end.

conduction_small (fixed points, T only) over 0.2 s saved at 0.1 s: the six runs take well under
a second each once compiled (not at twice its spacing: that cloud's discretisation has a
growing mode that implicit Euler damps at dt >= 0.0125 s but follows at 0.003 s); they run on
one in-process Dask worker (no process spawn), without the paper's figures (a second a task,
and nothing here reads them).  No assertion depends on timing.
"""

from __future__ import annotations

import csv
import json
import math

import pytest
from run_once import shared_once

from jaxanm.sweep import read_grid, run_sweep
from jaxanm.sweep.pareto import cheapest
from jaxanm.sweep.runner import RICHARDSON_ROW
from jaxanm.sweep.table import read_table
from jaxanm.sweep.task import finished_row, task_spec

GRID = """
scene = "conduction_small"
warmup = true

[overrides]
"time.t_end" = 0.2
"time.save" = [0.1]

[reference.richardson]
dt = 0.0125
kind = "newton"
tol = 1e-10

[[solvers]]
kind = "newton"
"time.dt" = [0.1, 0.05]

[[solvers]]
kind = "ida"
rtol = 1e-6
"""
IE = ["dt=0.1-newton", "dt=0.05-newton"]
IDA_TASK = "ida-rtol=1e-06"


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """The grid run once per test run on one in-process worker (shared by the xdist workers, each
    with its own copy): (grid, sweep dir, result)."""

    def make(root):
        from dask.distributed import LocalCluster

        (root / "tiny_ida.toml").write_text(GRID)
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr("jaxanm.fsw.io.output.write_figures", lambda result, out_dir: [])
            with LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                              dashboard_address=None) as cluster:
                return run_sweep(read_grid(root / "tiny_ida.toml"), root / "out",
                                 scheduler=cluster.scheduler_address, progress=False, compile_cache=False)

    root, result = shared_once(tmp_path_factory, "sweep_ida", make)
    return read_grid(root / "tiny_ida.toml"), root / "out", result


def test_every_task_gets_finite_errors_at_the_common_times(sweep):
    grid, out, result = sweep
    assert [t.id for t in grid.tasks] == [*IE, IDA_TASK]
    assert result.failed == [] and result.notes == []
    rows = {r["task"]: r for r in result.rows}
    assert list(rows) == [*IE, IDA_TASK, "richardson-dt=0.0125", "richardson-dt=0.00625", "richardson-dt=0.003125",
                          RICHARDSON_ROW]
    for task in (*IE, IDA_TASK):
        row = rows[task]
        assert row["status"] == "ok" and row["compare_note"] == ""
        # compared at 0.1 and 0.2 s only: the reference holds the save times, every run ends a step there
        assert (row["n_probe_times"], row["n_field_times"]) == (2, 2)
        assert math.isfinite(row["rel_err"]) and row["rel_err"] > 0 and math.isnan(row["rel_err_V"])  # no flow
        assert row["rel_err"] == max(row["rel_err_T"], row["probe_rel_err_T"])
    assert rows[IDA_TASK]["kind"] == "ida" and rows[IDA_TASK]["time_steps"] > 0
    assert rows[IDA_TASK]["factorizations"] >= 1 and rows[IDA_TASK]["solver.rtol"] == 1e-6
    # implicit Euler is first order: halving dt about halves the error (1.6-2.4 leaves room for the
    # O(dt^2) term at these coarse steps, 0.1 and 0.05 s against the ~0.1 s cooling time)
    assert 1.6 < rows[IE[0]]["rel_err"] / rows[IE[1]]["rel_err"] < 2.4


def test_the_reference_error_is_estimated_and_below_the_errors_it_measures(sweep):
    _, out, result = sweep
    estimate = result.rows[-1]
    assert estimate["task"] == RICHARDSON_ROW and estimate["kind"] == "richardson" and estimate["dir"] == "reference"
    assert result.reference == out / "reference" and result.reference_error["rel_err"] == estimate["rel_err"]
    assert 0 < estimate["rel_err"] and math.isfinite(estimate["rel_err"])
    # the reference must resolve what it measures: its estimate a tenth of the best implicit-Euler error at least
    assert estimate["rel_err"] < min(r["rel_err"] for r in result.rows if r["task"] in IE) / 10
    assert estimate["time_steps"] == 16 + 32 + 64  # the three runs' costs, summed
    with open(out / "results.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert table[-1]["task"] == RICHARDSON_ROW and float(table[-1]["rel_err"]) == estimate["rel_err"]
    assert result.plot.read_bytes()[:4] == b"\x89PNG"


def test_an_ida_run_directory_is_finished_only_for_its_own_settings(sweep):
    grid, out, _ = sweep
    task = grid.tasks[2]
    spec = task_spec(task, out / "runs" / task.id, compile_cache=False)
    assert finished_row(spec)["task"] == IDA_TASK
    summary = json.loads((out / "runs" / task.id / "summary.json").read_text())
    assert summary["solver"]["kind"] == "ida" and summary["solver"]["options"]["rtol"] == 1e-6
    assert finished_row({**spec, "ida": {**spec["ida"], "rtol": 1e-5}}) is None
    assert finished_row({**spec, "ida": None}) is None  # an implicit-Euler task of the same scene


def test_the_table_reads_back_and_names_the_cheapest_method_per_level(sweep):
    _, out, result = sweep
    table = read_table(out / "results.csv")
    assert [r["task"] for r in table] == [r["task"] for r in result.rows]
    assert all(a["rel_err"] == b["rel_err"] and a["wall_s"] == b["wall_s"] for a, b in zip(table, result.rows))
    assert table[0]["time.save"] == [0.1] and table[2]["solver.rtol"] == 1e-6
    loose, tight = cheapest(table, levels=(1.0, 1e-9))
    assert set(loose["by_method"]) == {"newton", "ida"} and tight["by_method"] == {}
    walls = [r["wall_s"] for r in loose["by_method"].values()]
    assert walls == sorted(walls) and RICHARDSON_ROW not in {r["task"] for r in loose["by_method"].values()}
