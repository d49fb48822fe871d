"""One sweep task: run a scene on a worker, write its output directory, return its row.

A task writes what ``jaxanm run --out DIR`` writes (:func:`jaxanm.fsw.io.output.write_run`), then
:data:`ROW_FILE`, its row of the results table, last: a directory whose row file says ``ok``
and whose ``summary.json`` holds the task's scene is a finished run (:func:`finished_row`), and
a rerun of the sweep re-reads that row instead of running the task again.  A failed task's row
says ``failed`` with the error message; it is run again by the next sweep.  An IDA task
(``spec["ida"]``) runs :func:`jaxanm.fsw.ida_scene.run_ida` and writes the same files, its
``summary.json`` naming the solver ``ida`` with its settings.

The functions here run in Dask worker processes: they take and return plain data (the scene as
its TOML-layout dictionary), so that any worker with jaxanm installed can run them.
"""

from __future__ import annotations

import json
import time
import traceback
from pathlib import Path

from jaxanm.checkpoint import atomic_path
from jaxanm.fsw.compare import cost_row

__all__ = ["COST_COLUMNS", "ROW_FILE", "failed_row", "finished_row", "run_task", "task_spec", "warmup_scene"]

ROW_FILE = "sweep_row.json"
"""File of a task's output directory holding its row; written last."""
COST_COLUMNS = ("kind", "solver", "t_end", "time_steps", "factorizations", "newton_iterations", "series_orders",
                "wall_s", "wall_jacobian_s", "wall_factorize_s", "wall_series_s", "wall_solve_s", "wall_other_s",
                "continuum_err")
"""Row columns taken from the run's ``summary.json`` (``wall_s`` is the time loop's wall time, split
into the ``jaxanm.Stats`` timers; ``continuum_err`` the rise error against the axisymmetric
continuum at the last saved time, :func:`jaxanm.fsw.compare.cost_row`)."""


def task_spec(task, out_dir, compile_cache: bool, warmup: bool = False) -> dict:
    """What a worker needs to run ``task`` (a :class:`jaxanm.sweep.grid.Task`) into ``out_dir``.

    ``compile_cache``: turn JAX's persistent compilation cache on in the worker
    (:mod:`jaxanm.compile_cache`); ``warmup``: an untimed compiling run first (:func:`run_task`).
    The scene goes as its JSON-normalised dictionary (the form
    ``summary.json`` stores it in, so that a finished run is recognised by equality).
    """
    scene = json.loads(json.dumps(task.scene.to_dict()))
    return {"id": task.id, "overrides": dict(task.overrides), "scene": scene, "dir": str(Path(out_dir).resolve()),
            "compile_cache": bool(compile_cache), "ida": None if task.ida is None else dict(task.ida),
            "warmup": bool(warmup)}


def run_task(spec: dict) -> dict:
    """Run the task of ``spec`` (:func:`task_spec`) and write its output directory; return its row.

    Every exception of the run or of writing its files is caught and reported in the row
    (``status`` ``failed``, ``message``), so that one failed task does not stop the sweep.
    ``task_s`` is the whole task's wall time (discretisation, compilation, run, files).  With
    ``spec["warmup"]`` the configuration first runs briefly, untimed (:func:`warmup_scene`), so
    that the run's ``wall_s`` excludes the JIT compilation as far as that run reached it.
    """
    start = time.perf_counter()
    out = Path(spec["dir"])
    out.mkdir(parents=True, exist_ok=True)
    (out / ROW_FILE).unlink(missing_ok=True)  # the directory is no finished run until this task says so
    try:
        from jaxanm import compile_cache
        from jaxanm.fsw.io.output import write_outputs, write_run
        from jaxanm.fsw.scene import Scene
        from jaxanm.fsw.simulate import run

        if spec["compile_cache"]:
            compile_cache.enable()
        scene = Scene.from_dict(spec["scene"], source=f"task {spec['id']}")
        if spec.get("ida"):
            from jaxanm.fsw.ida_scene import run_ida

            if spec.get("warmup"):
                run_ida(warmup_scene(scene, ida=True), **spec["ida"])
            result = run_ida(scene, **spec["ida"])
            write_outputs(result, out, {"kind": "ida", "options": result.solver})
        else:
            if spec.get("warmup"):
                run(warmup_scene(scene, ida=False))
            write_run(run(scene), out, scene)
        row = _row(spec, "ok", "", _costs(out))
    except Exception as exc:  # noqa: BLE001 - reported in the row; the sweep goes on
        row = failed_row(spec, exc)
        row["traceback"] = traceback.format_exc()
    row["task_s"] = time.perf_counter() - start
    with atomic_path(out / ROW_FILE) as tmp:
        tmp.write_text(json.dumps(row, indent=1) + "\n", encoding="utf-8")
    row.pop("traceback", None)
    return row


def warmup_scene(scene, ida: bool):
    """The brief compiling run of ``scene``: two steps of its (first) dt, or for IDA a tenth of its
    first output time (IDA's consistent start and first steps); no saves but the end."""
    first = min(t for t in scene.time.save_times if t > 0)
    t_end = first / 10 if ida else min(2 * scene.time.dt, scene.time.t_end)
    return scene.with_overrides({"time.t_end": t_end, "time.dt": min(scene.time.dt, t_end), "time.save": []})


def failed_row(spec: dict, exc: BaseException) -> dict:
    """The row of the task of ``spec`` that failed with ``exc`` (its type and message on one line)."""
    return _row(spec, "failed", " ".join(f"{type(exc).__name__}: {exc}".split()), {})


def finished_row(spec: dict) -> dict | None:
    """The row of the finished run of ``spec`` in its directory, or None if it must be (re)run.

    Finished means: the row file says ``ok``, the run's files are there, and ``summary.json``
    holds exactly the task's scene and, for an IDA task, its settings (a changed base scene,
    override or IDA setting reruns the task).
    """
    out = Path(spec["dir"])
    try:
        row = json.loads((out / ROW_FILE).read_text(encoding="utf-8"))
        summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not (isinstance(row, dict) and row.get("status") == "ok" and summary.get("scene") == spec["scene"]
            and _same_solver(spec.get("ida"), summary.get("solver", {}))
            and (out / "fields.npz").is_file() and (out / "probes.csv").is_file()):
        return None
    return {**row, **spec["overrides"]}


def _same_solver(ida: dict | None, solver: dict) -> bool:
    """Whether ``summary.json``'s ``solver`` is the task's: IDA with the same settings, or not IDA."""
    if ida is None:
        return solver.get("kind") != "ida"
    options = solver.get("options", {})
    return solver.get("kind") == "ida" and all(options.get(k) == v for k, v in ida.items())


def _costs(out: Path) -> dict:
    """The :data:`COST_COLUMNS` of the run in ``out``, from its ``summary.json`` (:func:`cost_row`)."""
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    cost = cost_row({"dir": str(out), "summary": summary})
    split = cost.pop("split_s")
    cost.update({f"wall_{k}_s": v for k, v in split.items()}, kind=summary["solver"]["kind"])
    return {k: cost.get(k) for k in COST_COLUMNS}


def _row(spec: dict, status: str, message: str, costs: dict) -> dict:
    """A results-table row: task id, status, message, the task's overrides, then its costs."""
    return {"task": spec["id"], "status": status, "message": message, **spec["overrides"], **costs}
