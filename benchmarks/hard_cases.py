"""The table of the hard cases (``tests/hard_problems.py``: each must end in a finite, checked
solution or in a specific named error), and the heat-step spectra of conduction_small.

Run ``python benchmarks/hard_cases.py --write`` to run every case, print the table and put it
into ``benchmarks/results/hard_cases.md`` (between its table markers; ``--fast`` runs only the
test-suite cases, which ``tests/test_hard_cases.py`` asserts).  ``--spectra`` tabulates instead
the growth rates of conduction_small's implicit-Euler heat step over spacings and
discretisation settings (:func:`spectra`, docs/notes/collocation_stability.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.geometry import build_cloud
from jaxanm.fsw.scene import load_scene
from jaxanm.fsw.stability import heat_modes

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from hard_problems import CASES  # noqa: E402


def table(outcomes) -> str:
    """Markdown table of the outcomes."""
    lines = [
        "| case | outcome | factorizations | sub-steps | dt halvings | steps | check | wall s | error message / note |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for o in outcomes:
        check = "" if o.check_ratio is None else f"{o.check_ratio:.2g}"
        note = (o.note or ("" if o.converged else (o.message or ""))).replace("|", "\\|")
        lines.append(
            f"| {o.case} | {o.outcome} | {o.factorizations} | {o.substeps} | {o.dt_halvings} | "
            f"{o.time_steps} | {check} | {o.wall_s:.1f} | {note} |"
        )
    return "\n".join(lines)


SPECTRA_SETTINGS = {
    "c = 0.2, flux": {"geometry.c": "0.2", "thermal.edge_rows": "flux"},
    "c = 0.25, flux": {"geometry.c": "0.25", "thermal.edge_rows": "flux"},
    "c = 0.3, flux": {"geometry.c": "0.3", "thermal.edge_rows": "flux"},
    "c = 0.2, half cell": {"geometry.c": "0.2", "thermal.edge_rows": "half_cell"},
    "c = 0.3, half cell": {"geometry.c": "0.3", "thermal.edge_rows": "half_cell"},
    "c = 0.2, flux, h = 3.5 dr": {"geometry.c": "0.2", "thermal.edge_rows": "flux", "geometry.h_factor": "3.5"},
    "c = 0.2, flux, h = 4 dr": {"geometry.c": "0.2", "thermal.edge_rows": "flux", "geometry.h_factor": "4.0"},
}
"""The discretisation settings whose heat-step spectra :func:`spectra` tabulates."""

SPECTRA_K = (2, 3, 4, 5, 6, 7, 8, 10, 12, 16)
"""conduction_small's spacings dr = (R2 - R1) / K of the spectra (K = 8: the scene's, 4: twice it)."""


def spectrum_cell(overrides: dict) -> str:
    """One cell of :func:`spectra`: the rightmost ``mu`` (1/s) of conduction_small's heat step
    with ``overrides`` at t = 0, tagged ``E`` when its mode lies on the tool/plate edge pairs
    (over half of its |values|^2 there) or ``I`` elsewhere, and the largest |amplification| of
    the scene's step (dt = 0.05 s), bold where it exceeds 1."""
    scene = load_scene("conduction_small").with_overrides({"time.save": "", **overrides})
    _, _, model, params, x0 = discretise(scene)
    right = heat_modes(model, params, x0, scene.time.dt, count=1)[0]
    worst = abs(heat_modes(model, params, x0, scene.time.dt, count=1, by="amplification")[0].amplification)
    where = "E" if right.share["TOOL_EDGE"] + right.share["PLATE_EDGE"] > 0.5 else "I"
    amp = f"**{worst:.3g}**" if worst > 1 else f"{worst:.3g}"
    return f"{right.mu.real:+.4g} {where} / {amp}"


def spectra() -> str:
    """Markdown table: :func:`spectrum_cell` for each setting of :data:`SPECTRA_SETTINGS` (columns)
    and spacing of :data:`SPECTRA_K` (rows)."""
    gap = 4.5e-3  # R2 - R1 of conduction_small
    lines = [
        "| K | dr (mm) | N | " + " | ".join(SPECTRA_SETTINGS) + " |",
        "| --- | --- | --- | " + " | ".join("---" for _ in SPECTRA_SETTINGS) + " |",
    ]
    for K in SPECTRA_K:
        dr = {"geometry.dr": repr(gap / K)}
        n = build_cloud(load_scene("conduction_small").with_overrides(dr).geometry).size
        cells = [spectrum_cell({**dr, **over}) for over in SPECTRA_SETTINGS.values()]
        lines.append(f"| {K} | {gap / K * 1e3:.4g} | {n} | " + " | ".join(cells) + " |")
        print(lines[-1], flush=True)
    return "\n".join(lines)


def main(argv=None) -> int:
    """Run every case (``--fast``: the test-suite ones), print the table; ``--write`` also puts it
    into benchmarks/results/hard_cases.md.  ``--spectra``: the heat-step spectra of
    :func:`spectra` instead (``--write`` puts them between that file's spectra markers)."""
    argv = sys.argv[1:] if argv is None else argv
    if "--spectra" in argv:
        text = spectra()
        if "--write" in argv:
            write_table(ROOT / "benchmarks" / "results" / "hard_cases.md", text, SPECTRA_MARKERS)
        return 0
    outcomes = []
    for key, (fast, make) in CASES.items():
        if "--fast" in argv and not fast:
            continue
        o = make()
        o.key = key
        print(f"{o.case}: {o.outcome} ({o.wall_s:.1f} s) {o.message or ''} {o.note}", flush=True)
        outcomes.append(o)
    text = table(outcomes)
    print(text)
    if "--write" in argv:
        write_table(ROOT / "benchmarks" / "results" / "hard_cases.md", text)
    return 0


BEGIN, END = "<!-- hard-cases-table -->", "<!-- /hard-cases-table -->"
SPECTRA_MARKERS = ("<!-- heat-spectra-table -->", "<!-- /heat-spectra-table -->")


def write_table(path: Path, text: str, markers: tuple = (BEGIN, END)) -> None:
    """Put ``text`` between the ``markers`` (begin, end) of ``path`` (the prose around it is kept)."""
    begin, end = markers
    doc = path.read_text() if path.exists() else f"# Hard cases\n\n{begin}\n{end}\n"
    if begin not in doc or end not in doc:
        doc += f"\n{begin}\n{end}\n"
    head, rest = doc.split(begin, 1)
    tail = rest.split(end, 1)[1]
    path.write_text(f"{head}{begin}\n{text}\n{end}{tail}")


if __name__ == "__main__":
    raise SystemExit(main())
