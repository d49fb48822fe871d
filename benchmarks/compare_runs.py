"""Side by side: cost and agreement of `jaxanm run` output directories of the same scene.

Typical use, the ANM and Newton on the paper's scene (each run is one `jaxanm run` command; the
two can run at the same time, one per core)::

    jaxanm run fsw_paper --out runs/anm
    jaxanm run fsw_paper --solver newton --out runs/newton --checkpoint-every 200
    python benchmarks/compare_runs.py runs/anm runs/newton --out benchmarks/results/fsw_paper_anm_vs_newton

For every directory it reads ``summary.json`` (solver, factorisations, Newton iterations,
time steps, the wall-time split) and prints one row per run with the ratios to the first run.
It then measures how far each run is from the first one on what both saved (fields at every
saved time t > 0, probe histories at every step; the measures are
:func:`jaxanm.fsw.compare.differences`).

Writes ``OUT.md`` and ``OUT.json`` with ``--out``.  Nothing is run here: the wall times are
those the runs measured (``summary.json``), so quote the load the runs shared.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from jaxanm.fsw.compare import cost_row, differences, load_run


def markdown(costs: list[dict], diffs: list[dict]) -> str:
    """Cost table with ratios to the first run, then the agreement table."""
    ref = costs[0]
    lines = ["| run | solver | steps | factorisations | Newton iterations | series orders | wall (s) | "
             "wall / first | Jacobians (s) | factorise (s) | series (s) | solves (s) | other (s) |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for c in costs:
        sp = c["split_s"]
        lines.append(f"| `{c['dir']}` | {c['solver']} | {c['time_steps']} | {c['factorizations']} | "
                     f"{c['newton_iterations']} | {c['series_orders']} | {c['wall_s']:.0f} | "
                     f"{c['wall_s'] / ref['wall_s']:.2f} | {sp.get('jacobian', 0):.0f} | "
                     f"{sp.get('factorize', 0):.0f} | {sp.get('series', 0):.0f} | {sp.get('solve', 0):.0f} | "
                     f"{sp.get('other', 0):.0f} |")
    if diffs:
        lines += ["", f"Agreement with `{ref['dir']}`:", "",
                  "| run | max rel. V difference (fields) | max rel. T - T0 difference (fields) | "
                  "max point shift (m) | probes: max T difference (K) | probes: max velocity difference / (omega R1) |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for d in diffs:
            lines.append(
                f"| `{d['dir']}` | {d['max_rel_dV']:.2e} | {d['max_rel_dT']:.2e} | "
                f"{d['max_dpoints_m']:.1e} | {d['probe_max_dT_K']:.1e} | {d['probe_max_dV_over_omegaR1']:.1e} |"
            )
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="output directories of `jaxanm run`; the first is the reference")
    ap.add_argument("--out", default=None, help="write OUT.md and OUT.json")
    args = ap.parse_args(argv)
    runs = [load_run(d) for d in args.runs]
    costs = [cost_row(r) for r in runs]
    diffs = [differences(r, runs[0]) for r in runs[1:]]
    table = markdown(costs, diffs)
    print(table)
    if args.out:
        Path(args.out + ".json").write_text(
            json.dumps({"costs": costs, "differences": diffs}, indent=1) + "\n", encoding="utf-8"
        )
        Path(args.out + ".md").write_text(table, encoding="utf-8")


if __name__ == "__main__":
    main()
