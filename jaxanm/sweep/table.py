"""The results table of a sweep (CSV, one row per task) and its errors against a reference run.

Columns: ``task``, ``status`` (``ok`` | ``failed``), ``message`` (the error of a failed task),
``reused`` (the row was re-read from an earlier sweep's finished run), one column per override
key of the grid (dotted scene keys, ``solver.*`` included), the costs of the run
(:data:`jaxanm.sweep.task.COST_COLUMNS`), ``task_s`` (the whole task's wall time, compilation
and files included) and ``dir`` (the task's output directory, relative to the table).  With a
reference run, :func:`add_errors` appends :data:`ERROR_COLUMNS`.

``wall_s`` includes the JIT compilation that the task's worker had not done before: the first
task of a scene shape and solver kind on each worker compiles (seconds to minutes), later ones
reuse it.  That matters only where runs are as short as their compilation; JAX's persistent
compilation cache (on unless ``JAXANM_COMPILE_CACHE=0``) also shares compilations between the
workers and across sweeps.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

from jaxanm.checkpoint import atomic_path
from jaxanm.fsw.compare import differences, load_run
from jaxanm.sweep.task import COST_COLUMNS

__all__ = ["ERROR_COLUMNS", "TABLE_NAME", "add_errors", "columns", "error_columns", "read_table", "write_table"]

TABLE_NAME = "results.csv"
"""File name of the results table in the sweep directory."""
ERROR_COLUMNS = ("rel_err", "rel_err_V", "rel_err_T", "probe_rel_err_T", "probe_err_V", "probe_err_T_K",
                 "err_points_m", "n_field_times", "n_probe_times", "compare_note")
"""Errors against the reference (:func:`jaxanm.fsw.compare.differences`, at the times both runs
recorded): ``rel_err_V`` and ``rel_err_T`` are its ``max_rel_dV`` and ``max_rel_dT`` (fields at
the common saved times, relative to the reference's max |V| and max |T - T0| at each),
``probe_rel_err_T`` its ``probe_rel_dT`` (T at the registration points, relative to the
reference's largest |T - T0| there), ``probe_err_V`` its ``probe_max_dV_over_omegaR1`` and
``probe_err_T_K`` its ``probe_max_dT_K``; ``rel_err`` (the Pareto plot's error) is the largest of
the four relative errors that the scene has; ``err_points_m`` is ``max_dpoints_m``;
``n_field_times`` and ``n_probe_times`` count the common times compared; ``compare_note`` says
why a row has no errors (failed, or no common time with the reference)."""
_DIFFERENCE_KEYS = {"rel_err_V": "max_rel_dV", "rel_err_T": "max_rel_dT", "probe_rel_err_T": "probe_rel_dT",
                    "probe_err_V": "probe_max_dV_over_omegaR1", "probe_err_T_K": "probe_max_dT_K",
                    "err_points_m": "max_dpoints_m", "n_field_times": "n_field_times",
                    "n_probe_times": "n_probe_times"}
_RELATIVE = ("rel_err_V", "rel_err_T", "probe_rel_err_T", "probe_err_V")


def columns(keys, errors: bool = False) -> list[str]:
    """Column names of a table for override ``keys`` (with :data:`ERROR_COLUMNS` if ``errors``)."""
    cols = ["task", "status", "message", "reused", *keys, *COST_COLUMNS, "task_s", "dir"]
    return cols + list(ERROR_COLUMNS) if errors else cols


def write_table(path, rows: list[dict], keys, errors: bool = False) -> Path:
    """Write ``rows`` to the CSV file ``path`` atomically (a reader never sees half a table).

    Lists (e.g. an ``effects`` override) are written as JSON; absent values as empty cells;
    floats as Python's ``repr`` (the shortest exact round trip).
    """
    path = Path(path)
    names = columns(keys, errors)
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            writer = csv.DictWriter(f, fieldnames=names, extrasaction="ignore")
            writer.writeheader()
            for row in rows:
                writer.writerow({k: _cell(row.get(k)) for k in names})
    return path


def add_errors(rows: list[dict], reference_dir, sweep_dir) -> list[dict]:
    """``rows`` with :data:`ERROR_COLUMNS` against the run in ``reference_dir``.

    Each row's run is read from its ``dir`` (relative to ``sweep_dir``).  A failed row, or one
    whose run cannot be compared with the reference (no common time), gets NaN errors and the
    reason in ``compare_note``.
    """
    reference = load_run(reference_dir)
    out = []
    for row in rows:
        errors: dict[str, float | str] = dict.fromkeys(ERROR_COLUMNS, math.nan)
        errors["compare_note"] = ""
        if row.get("status") != "ok":
            errors["compare_note"] = "task failed"
        else:
            try:
                d = differences(load_run(Path(sweep_dir) / row["dir"]), reference)
            except (OSError, ValueError) as exc:
                errors["compare_note"] = " ".join(str(exc).split())
            else:
                errors.update(error_columns(d))
        out.append({**row, **errors})
    return out


def error_columns(d: dict) -> dict:
    """The :data:`ERROR_COLUMNS` (but ``compare_note``) of the measures ``d`` of
    :func:`jaxanm.fsw.compare.differences` (or of a Richardson estimate: the same keys)."""
    errors = {col: d[key] for col, key in _DIFFERENCE_KEYS.items()}
    # NaN only for a field the reference lacks: a finished run's own fields are finite
    # (integrate raises NonFiniteError on a non-finite accepted state)
    present = [errors[c] for c in _RELATIVE if not math.isnan(errors[c])]
    errors["rel_err"] = max(present) if present else math.nan
    return errors


def read_table(path) -> list[dict]:
    """The rows of a results table written by :func:`write_table`, cells back to Python values
    (numbers, booleans, JSON lists; empty cells dropped)."""
    with open(path, newline="", encoding="utf-8") as f:
        return [{k: _value(v) for k, v in row.items() if v != ""} for row in csv.DictReader(f)]


def _value(cell: str):
    """A CSV cell as the value :func:`_cell` wrote (text that is no number stays text)."""
    if cell in ("True", "False"):
        return cell == "True"
    if cell.startswith("["):
        return json.loads(cell)
    try:
        return int(cell)
    except ValueError:
        pass
    try:
        return float(cell)
    except ValueError:
        return cell


def _cell(value):
    """A value as a CSV cell."""
    if value is None:
        return ""
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, dict)):
        return json.dumps(value)
    return value
