"""One sweep task: run a scene on a worker, write its output directory, return its row.

A task writes what ``jaxanm run --out DIR`` writes (:func:`jaxanm.cli.write_results`), then
:data:`ROW_FILE`, its row of the results table, last: a directory whose row file says ``ok``
and whose ``summary.json`` holds the task's scene is a finished run (:func:`finished_row`), and
a rerun of the sweep re-reads that row instead of running the task again.  A failed task's row
says ``failed`` with the error message; it is run again by the next sweep.

The functions here run in Dask worker processes: they take and return plain data (the scene as
its TOML-layout dictionary), so that any worker with jaxanm installed can run them.
"""

from __future__ import annotations

import json
import time
import traceback
from pathlib import Path

from jaxanm.fsw.compare import cost_row
from jaxanm.fsw.output import atomic_path

__all__ = ["COST_COLUMNS", "ROW_FILE", "failed_row", "finished_row", "run_task", "task_spec"]

ROW_FILE = "sweep_row.json"
"""File of a task's output directory holding its row; written last."""
COST_COLUMNS = ("kind", "solver", "t_end", "time_steps", "factorizations", "newton_iterations", "series_orders",
                "wall_s", "wall_jacobian_s", "wall_factorize_s", "wall_series_s", "wall_solve_s", "wall_other_s")
"""Row columns taken from the run's ``summary.json`` (``wall_s`` is the time loop's wall time, split
into the ``jaxanm.Stats`` timers)."""


def task_spec(task, out_dir, compile_cache: bool) -> dict:
    """What a worker needs to run ``task`` (a :class:`jaxanm.sweep.grid.Task`) into ``out_dir``.

    ``compile_cache``: turn JAX's persistent compilation cache on in the worker
    (:mod:`jaxanm.compile_cache`).  The scene goes as its JSON-normalised dictionary (the form
    ``summary.json`` stores it in, so that a finished run is recognised by equality).
    """
    scene = json.loads(json.dumps(task.scene.to_dict()))
    return {"id": task.id, "overrides": dict(task.overrides), "scene": scene, "dir": str(Path(out_dir).resolve()),
            "compile_cache": bool(compile_cache)}


def run_task(spec: dict) -> dict:
    """Run the task of ``spec`` (:func:`task_spec`) and write its output directory; return its row.

    Every exception of the run or of writing its files is caught and reported in the row
    (``status`` ``failed``, ``message``), so that one failed task does not stop the sweep.
    ``task_s`` is the whole task's wall time (discretisation, compilation, run, files).
    """
    start = time.perf_counter()
    out = Path(spec["dir"])
    out.mkdir(parents=True, exist_ok=True)
    (out / ROW_FILE).unlink(missing_ok=True)  # the directory is no finished run until this task says so
    try:
        from jaxanm import compile_cache
        from jaxanm.cli import write_results
        from jaxanm.fsw.scene import Scene
        from jaxanm.fsw.simulate import run

        if spec["compile_cache"]:
            compile_cache.enable()
        scene = Scene.from_dict(spec["scene"], source=f"task {spec['id']}")
        write_results(run(scene), out, scene)
        row = _row(spec, "ok", "", _costs(out))
    except Exception as exc:  # noqa: BLE001 - reported in the row; the sweep goes on
        row = failed_row(spec, exc)
        row["traceback"] = traceback.format_exc()
    row["task_s"] = time.perf_counter() - start
    with atomic_path(out / ROW_FILE) as tmp:
        tmp.write_text(json.dumps(row, indent=1) + "\n", encoding="utf-8")
    row.pop("traceback", None)
    return row


def failed_row(spec: dict, exc: BaseException) -> dict:
    """The row of the task of ``spec`` that failed with ``exc`` (its type and message on one line)."""
    return _row(spec, "failed", " ".join(f"{type(exc).__name__}: {exc}".split()), {})


def finished_row(spec: dict) -> dict | None:
    """The row of the finished run of ``spec`` in its directory, or None if it must be (re)run.

    Finished means: the row file says ``ok``, the run's files are there, and ``summary.json``
    holds exactly the task's scene (a changed base scene or override reruns the task).
    """
    out = Path(spec["dir"])
    try:
        row = json.loads((out / ROW_FILE).read_text(encoding="utf-8"))
        summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not (isinstance(row, dict) and row.get("status") == "ok" and summary.get("scene") == spec["scene"]
            and (out / "fields.npz").is_file() and (out / "probes.csv").is_file()):
        return None
    return {**row, **spec["overrides"]}


def _costs(out: Path) -> dict:
    """The :data:`COST_COLUMNS` of the run in ``out``, from its ``summary.json`` (:func:`cost_row`)."""
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    cost = cost_row({"dir": str(out), "summary": summary})
    split = cost.pop("split_s")
    cost.update({f"wall_{k}_s": v for k, v in split.items()}, kind=summary["solver"]["kind"])
    return {k: cost[k] for k in COST_COLUMNS}


def _row(spec: dict, status: str, message: str, costs: dict) -> dict:
    """A results-table row: task id, status, message, the task's overrides, then its costs."""
    return {"task": spec["id"], "status": status, "message": message, **spec["overrides"], **costs}
