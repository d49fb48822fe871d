"""Run a sweep's tasks on Dask, keep the results table up to date, then errors and the Pareto plot.

The sweep directory holds::

    results.csv          one row per task (jaxanm.sweep.table), rewritten as each task finishes
    pareto.png           error against wall time (with a reference run)
    runs/<task id>/      the task's `jaxanm run --out` files and its row (jaxanm.sweep.task)
    reference/           with a Richardson reference: the extrapolated run (jaxanm.sweep.richardson)

With a Richardson reference (``[reference.richardson]`` in the grid), its three runs are tasks
like the others (submitted first: they are the longest), listed after the grid's tasks; the
table's last row, ``richardson``, holds the reference's estimated error in the error columns
and the three runs' costs summed.

Tasks run on a ``LocalCluster`` of worker processes (one thread each) on this machine, or on
the workers of a running Dask scheduler whose address is given; they then must see the sweep
directory at the same path (a shared file system) and have jaxanm installed.
"""

from __future__ import annotations

import dataclasses
import logging
import time
import uuid
from contextlib import contextmanager
from pathlib import Path

from jaxanm.errors import InputError
from jaxanm.fsw.compare import load_run
from jaxanm.internal import integer, require
from jaxanm.sweep.grid import Grid, Richardson, read_grid
from jaxanm.sweep.pareto import plot_pareto
from jaxanm.sweep.richardson import write_reference
from jaxanm.sweep.table import TABLE_NAME, add_errors, error_columns, write_table
from jaxanm.sweep.task import COST_COLUMNS, failed_row, finished_row, run_task, task_spec

__all__ = ["PLOT_NAME", "REFERENCE_DIR", "RICHARDSON_ROW", "RUNS_DIR", "SweepResult", "run_sweep"]

RUNS_DIR = "runs"
"""Sub-directory of the sweep directory holding one output directory per task."""
PLOT_NAME = "pareto.png"
"""File name of the Pareto plot in the sweep directory."""
REFERENCE_DIR = "reference"
"""Sub-directory of the sweep directory holding a Richardson reference."""
RICHARDSON_ROW = "richardson"
"""Task column of the row holding a Richardson reference's estimated error."""


@dataclasses.dataclass
class SweepResult:
    """What :func:`run_sweep` did: the rows in grid order, the files written, the tasks that
    failed, how many rows were re-read from finished runs, notes for the user, the wall time and
    a Richardson reference's estimated error (:data:`jaxanm.sweep.table.ERROR_COLUMNS`, or None)."""

    rows: list
    table: Path
    plot: Path | None
    reference: Path | None
    failed: list
    reused: int
    notes: list
    wall_s: float
    reference_error: dict | None = None


def run_sweep(grid, out_dir=None, scheduler: str | None = None, workers: int = 2, progress: bool = True,
              reference=None, compile_cache: bool | None = None) -> SweepResult:
    """Run every task of ``grid`` (a :class:`~jaxanm.sweep.grid.Grid` or a grid file path) on Dask.

    Parameters
    ----------
    out_dir : path, optional
        Sweep directory (default ``results/sweep-<grid name>``); see the module docstring.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``); default a ``LocalCluster``
        of ``workers`` processes with one thread each, on the loopback interface.
    workers : int
        Worker processes of the local cluster (ignored with ``scheduler``).
    progress : bool
        A tqdm bar over the tasks.
    reference : path, optional
        Output directory of the run the errors are measured against; default the grid's
        ``reference`` task or its Richardson reference (whose three runs still run when this is
        given).  Without any, the table has no errors and there is no plot.
    compile_cache : bool, optional
        Keep compiled XLA code on disk in the workers (default: unless ``JAXANM_COMPILE_CACHE=0``,
        :mod:`jaxanm.compile_cache`).

    Returns
    -------
    SweepResult
        The rows, the table and plot paths, the failed and reused tasks.

    Raises
    ------
    GridError, InputError
        Bad input (grid, ``workers``, ``reference``, an unreachable scheduler, a missing extra),
        before any task runs.

    Notes
    -----
    Tasks whose output directory holds a finished run of the same scene are not run again:
    their rows are re-read (``reused``).  A failed task is reported in its row and the others go
    on.

    From a script, call it under ``if __name__ == "__main__":``: the local cluster's worker
    processes are spawned, and each imports the script's main module.
    """
    from jaxanm import compile_cache as cache

    start = time.perf_counter()
    grid = _checked_inputs(grid, scheduler, workers, reference)
    out_dir = Path(out_dir) if out_dir is not None else Path("results") / f"sweep-{grid.name}"
    out_dir.mkdir(parents=True, exist_ok=True)
    use_cache = cache.requested() if compile_cache is None else compile_cache
    reference_tasks = grid.richardson.tasks if grid.richardson is not None else ()
    specs = [task_spec(t, out_dir / RUNS_DIR / t.id, use_cache, grid.warmup) for t in (*grid.tasks, *reference_tasks)]
    rows = {}
    for spec in specs:
        row = finished_row(spec)
        if row is not None:
            rows[spec["id"]] = {**row, "reused": True}
    reused = len(rows)
    table = out_dir / TABLE_NAME
    write_table(table, _ordered(rows, specs), grid.keys)
    todo = [s for s in specs[len(grid.tasks):] + specs[:len(grid.tasks)] if s["id"] not in rows]  # longest first
    if todo:
        _run_tasks(todo, rows, specs, table, grid, scheduler, workers, progress, reused)
    result = _ordered(rows, specs)
    notes: list[str] = []
    plot = None
    ref_dir, label, estimate = _reference(reference, grid, rows, out_dir, notes)
    if ref_dir is not None:
        result, plot = _errors_and_plot(result, ref_dir, label, estimate, grid, rows, out_dir, table, notes)
    if plot is None:  # a plot left by an earlier sweep in this directory would describe other rows
        (out_dir / PLOT_NAME).unlink(missing_ok=True)
    return SweepResult(rows=result, table=table, plot=plot, reference=ref_dir,
                       failed=[r["task"] for r in result if r["status"] != "ok"], reused=reused, notes=notes,
                       wall_s=time.perf_counter() - start,
                       reference_error=None if estimate is None else {k: v for k, v in estimate.items()
                                                                      if k != "compare_note"})


def _checked_inputs(grid, scheduler: str | None, workers, reference) -> Grid:
    """The grid (read from its file if a path), after checking ``workers``, that
    ``reference`` holds a run (:class:`InputError`) and that the extras it needs are installed
    (:class:`jaxanm.internal.MissingExtraError`, an :class:`InputError`)."""
    if not isinstance(grid, Grid):
        grid = read_grid(grid)
    require("dask.distributed", "sweep", "jaxanm sweep (its tasks run on Dask)")
    tasks = (*grid.tasks, *(grid.richardson.tasks if grid.richardson is not None else ()))
    if any(t.ida is not None for t in tasks):
        require("sksundae", "ida", "a sweep task of kind \"ida\" (SUNDIALS IDA)")
    if scheduler is None:
        integer("workers", workers, 1, hint="the processes of the local Dask cluster")
    if reference is not None:
        try:
            load_run(reference)
        except FileNotFoundError as exc:
            raise InputError(f"reference {reference}: {exc}") from exc
    return grid


def _ordered(rows: dict, specs: list) -> list:
    """The rows of the tasks run so far, in the order of ``specs``, each with its directory."""
    return [{**rows[s["id"]], "dir": f"{RUNS_DIR}/{s['id']}"} for s in specs if s["id"] in rows]


def _run_tasks(todo: list, rows: dict, specs: list, table: Path, grid: Grid, scheduler, workers: int,
               progress: bool, reused: int) -> None:
    """Run the tasks ``todo`` on Dask, adding each row to ``rows`` and rewriting the table as
    each finishes, under a tqdm bar over all ``specs``."""
    from tqdm import tqdm

    bar = tqdm(total=len(specs), initial=reused, desc=f"sweep {grid.name}", unit="task",
               dynamic_ncols=True, disable=not progress)
    try:
        for spec, row in _run_on_dask(todo, scheduler, workers):
            rows[spec["id"]] = {**row, "reused": False}
            write_table(table, _ordered(rows, specs), grid.keys)
            failed = sum(r["status"] != "ok" for r in rows.values())
            bar.set_postfix_str(f"{spec['id']} {row['status']}" + (f", {failed} failed" if failed else ""),
                                refresh=False)
            bar.update(1)
    finally:
        bar.close()


def _reference(reference, grid: Grid, rows: dict, out_dir: Path, notes: list):
    """The run the errors are measured against: ``(directory, label, Richardson estimate)``;
    the given ``reference``, else the grid's reference task (None when it failed, with a note)
    or its Richardson reference (estimate None when there is none)."""
    ref_dir, label, estimate = None, None, None
    if reference is not None:
        ref_dir, label = Path(reference), str(reference)
    elif grid.reference is not None:
        if rows[grid.reference]["status"] == "ok":
            ref_dir, label = out_dir / RUNS_DIR / grid.reference, f"task {grid.reference}"
        else:
            notes.append(f"reference task {grid.reference!r} failed: no errors and no Pareto plot")
    elif grid.richardson is not None:
        ref_dir, estimate = _richardson(grid.richardson, rows, out_dir, notes)
        label = (f"Richardson reference from dt = {grid.richardson.dt:g}, /2, /4 (estimated error "
                 f"{estimate['rel_err']:.1e})" if estimate else "")
    return ref_dir, label, estimate


def _errors_and_plot(result: list, ref_dir: Path, label: str, estimate, grid: Grid, rows: dict, out_dir: Path,
                     table: Path, notes: list):
    """The rows with their errors against ``ref_dir`` (and a Richardson estimate's row), the
    table rewritten with them, and the Pareto plot (None when no error is positive, with a note)."""
    result = add_errors(result, ref_dir, out_dir)
    plot = plot_pareto(result, out_dir / PLOT_NAME, f"sweep {grid.name} ({grid.base.name}): errors against {label}")
    if estimate is not None and grid.richardson is not None:  # (an estimate comes from a Richardson reference)
        result.append(_estimate_row(grid.richardson, rows, estimate))
    write_table(table, result, grid.keys, errors=True)
    if plot is None:
        notes.append("no task has a positive error against the reference: no Pareto plot")
    return result, plot


def _richardson(richardson: Richardson, rows: dict, out_dir: Path, notes: list):
    """The grid's Richardson reference from its three finished runs, written to
    :data:`REFERENCE_DIR`: ``(directory, error columns of its estimate)``, or ``(None, None)``
    with a note when a run failed or the runs cannot be extrapolated."""
    ids = [t.id for t in richardson.tasks]
    failed = [i for i in ids if rows[i]["status"] != "ok"]
    if failed:
        notes.append(f"Richardson reference: task {failed[0]!r} failed: no errors and no Pareto plot")
        return None, None
    ref_dir = out_dir / REFERENCE_DIR
    try:
        _, estimate = write_reference([out_dir / RUNS_DIR / i for i in ids], ref_dir)
    except (OSError, ValueError) as exc:
        notes.append(f"Richardson reference: {' '.join(str(exc).split())}: no errors and no Pareto plot")
        return None, None
    return ref_dir, {**error_columns(estimate), "compare_note": "estimated error of the Richardson reference: "
                     "|coarse - fine| / 3 (jaxanm.sweep.richardson)"}


def _estimate_row(richardson: Richardson, rows: dict, estimate: dict) -> dict:
    """The table row of a Richardson reference: its estimated error and its three runs' costs summed."""
    runs = [rows[t.id] for t in richardson.tasks]
    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    summed = {k: sum(r[k] for r in runs) for k in (*COST_COLUMNS, "task_s") if all(number(r.get(k)) for r in runs)}
    steps = " ".join(f"{richardson.dt / 2 ** k:g}" for k in range(3))
    return {"task": RICHARDSON_ROW, "status": "ok", "message": "", "reused": all(r.get("reused") for r in runs),
            **summed, "t_end": runs[0].get("t_end"), "kind": RICHARDSON_ROW, "solver": f"richardson dt={steps}",
            "dir": REFERENCE_DIR, **estimate}


def _run_on_dask(specs: list[dict], scheduler: str | None, workers: int):
    """Yield ``(spec, row)`` for each task of ``specs`` as it finishes on Dask.

    A task whose worker was lost (killed, out of memory) yields a failed row.
    """
    from dask.distributed import as_completed

    with _client(scheduler, workers) as client:
        token = uuid.uuid4().hex[:8]  # keys unique on a shared scheduler
        futures = {client.submit(run_task, spec, key=f"jaxanm-sweep-{token}-{spec['id']}", pure=False): spec
                   for spec in specs}
        for future in as_completed(futures):
            spec = futures[future]
            try:
                row = future.result()
            except Exception as exc:  # noqa: BLE001 - e.g. KilledWorker: that task failed, the others go on
                row = failed_row(spec, exc)
            yield spec, row


@contextmanager
def _client(scheduler: str | None, workers: int):
    """A Dask client of the scheduler at ``scheduler``, or of a new local cluster (closed on exit)."""
    from dask.distributed import Client, LocalCluster

    if scheduler is not None:
        try:
            client = Client(scheduler)  # waits up to Dask's distributed.comm.timeouts.connect (30 s)
        except (OSError, TimeoutError, ValueError) as exc:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler!r} ({exc}); start one with "
                             "`dask scheduler` and its workers with `dask worker ADDRESS`, or leave the "
                             "scheduler out for a local cluster") from exc
        with client:
            yield client
        return
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        yield client
