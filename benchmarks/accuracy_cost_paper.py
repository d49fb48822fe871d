"""The accuracy-cost tables quoted by benchmarks/results/accuracy_cost_paper.md, from one `jaxanm sweep`
of a committed grid.

Nothing is computed here: every number comes from the sweep directory of
``benchmarks/grids/accuracy_cost_tracers.toml`` (or ``accuracy_cost_lagrangian.toml``), which
runs every configuration, the Richardson reference and its estimated error, and measures every
task against it at the common save times (:mod:`jaxanm.sweep`; read the grid's header)::

    jaxanm sweep benchmarks/grids/accuracy_cost_tracers.toml --workers 1 --out results/sweep-accuracy_cost_tracers
    python benchmarks/accuracy_cost_paper.py results/sweep-accuracy_cost_tracers \
        --out benchmarks/results/accuracy_cost_tracers

It replaces the loop that measured the doc's first table (commit 29c1f02): that loop's IDA
run, reference and error measures now live in :mod:`jaxanm.fsw.ida_scene`,
:mod:`jaxanm.sweep.richardson` and :func:`jaxanm.fsw.compare.differences`.

Writes ``OUT.md`` (the reference's estimated error, every row sorted by method then error,
and the cheapest row of each method per error level), ``OUT.json`` (the same rows and levels)
and ``OUT.png`` (the sweep's Pareto plot).  The row's ``error`` is the sweep's ``rel_err``:
the largest relative error of V and T - T0, over the fields and at the registration points,
at the save times (:data:`jaxanm.sweep.table.ERROR_COLUMNS`).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

from jaxanm.sweep.pareto import cheapest, method
from jaxanm.sweep.runner import PLOT_NAME, RICHARDSON_ROW
from jaxanm.sweep.table import TABLE_NAME, read_table

SETTINGS = (
    "time.dt",
    "time.atol",
    "solver.tol",
    "solver.max_rate",
    "solver.adaptive",
    "solver.order",
    "solver.rtol",
    "solver.atol",
)
"""Override columns that describe a row's settings, in the order they are shown."""
ERRORS = ("rel_err_V", "rel_err_T", "probe_rel_err_T", "probe_err_V", "rel_err")
"""Error columns of the table, in the order they are shown."""


def label(row: dict) -> str:
    """A row's settings: the overrides among :data:`SETTINGS` that it has."""
    shown = [k for k in SETTINGS if k in row and not (k == "time.dt" and row.get("time.adaptive") is True)]
    return ", ".join(
        f"{k.split('.', 1)[1]} " + (f"{row[k]:g}" if isinstance(row[k], float) else str(row[k])) for k in shown
    )


def _e(row: dict, key: str) -> str:
    """An error cell (``-`` when absent)."""
    value = row.get(key)
    return f"{value:.1e}" if isinstance(value, float) and value == value else "-"


def markdown(rows: list[dict], levels: list[dict], sweep_dir: str) -> str:
    """The reference's estimate, the table of every finished row, and the cheapest per level."""
    estimate = next((r for r in rows if r["task"] == RICHARDSON_ROW), None)
    runs = [r for r in rows if r["task"] != RICHARDSON_ROW]
    lines = [
        f"From the sweep directory `{sweep_dir}` ({len(runs)} tasks, {sum(r['status'] != 'ok' for r in runs)} failed)."
    ]
    if estimate is not None:
        lines.append(
            f"Reference: {estimate['solver']} (Richardson), estimated error {_e(estimate, 'rel_err')} "
            f"(fields: V {_e(estimate, 'rel_err_V')}, T {_e(estimate, 'rel_err_T')}; probes: T "
            f"{_e(estimate, 'probe_rel_err_T')}, V {_e(estimate, 'probe_err_V')}); its three runs "
            f"took {estimate['wall_s']:.0f} s."
        )
    lines += [
        "",
        "| method | task | settings | steps | factorisations | err V field | err T field | err T probes | "
        "err V probes | error (max) | wall (s) |",
        "|" + " --- |" * 11,
    ]
    ok = [r for r in runs if r["status"] == "ok"]
    for r in sorted(ok, key=lambda r: (method(r), -r.get("rel_err", 0.0))):
        lines.append(
            f"| {method(r)} | `{r['task']}` | {label(r)} | {r['time_steps']} | {r['factorizations']} | "
            + " | ".join(_e(r, k) for k in ERRORS)
            + f" | {r['wall_s']:.1f} |"
        )
    failed = [r for r in runs if r["status"] != "ok"]
    if failed:
        lines += ["", "Failed: " + "; ".join(f"`{r['task']}`: {r.get('message', '')}" for r in failed)]
    lines += ["", "Cheapest row of each method per error level (wall s, error):", ""]
    for level in levels:
        best = [f"{m} `{r['task']}` {r['wall_s']:.1f} s ({r['rel_err']:.1e})" for m, r in level["by_method"].items()]
        lines.append(f"- error <= {level['level']:g}: " + ("; ".join(best) if best else "none"))
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sweep_dir", help="the --out DIR of the sweep")
    ap.add_argument("--levels", default="1e-2,1e-3,1e-4,1e-5", help="error levels of the cheapest-method list")
    ap.add_argument("--out", default=None, help="write OUT.md, OUT.json and OUT.png")
    a = ap.parse_args(argv)
    sweep = Path(a.sweep_dir)
    if not (sweep / TABLE_NAME).is_file():
        raise SystemExit(f"{sweep} holds no {TABLE_NAME}: give the --out DIR of a finished `jaxanm sweep`")
    rows = read_table(sweep / TABLE_NAME)
    if "rel_err" not in {k for r in rows for k in r}:
        raise SystemExit(f"{sweep / TABLE_NAME} has no errors: the grid needs a reference (its [reference.richardson])")
    levels = cheapest(rows, [float(x) for x in a.levels.split(",") if x.strip()])
    text = markdown(rows, levels, str(sweep))
    print(text)
    if a.out:
        out = Path(a.out)
        out.with_suffix(".json").write_text(
            json.dumps(
                {
                    "sweep_dir": str(sweep),
                    "rows": rows,
                    "cheapest": [
                        {"level": lv["level"], "by_method": {m: r["task"] for m, r in lv["by_method"].items()}}
                        for lv in levels
                    ],
                },
                indent=1,
            )
            + "\n",
            encoding="utf-8",
        )
        out.with_suffix(".md").write_text(
            f"<!-- made by benchmarks/accuracy_cost_paper.py {' '.join(sys.argv[1:])} -->\n\n{text}", encoding="utf-8"
        )
        if (sweep / PLOT_NAME).is_file():
            shutil.copyfile(sweep / PLOT_NAME, out.with_suffix(".png"))
        print(f"wrote {out}.json, .md" + (", .png" if (sweep / PLOT_NAME).is_file() else ""))


if __name__ == "__main__":
    main()
