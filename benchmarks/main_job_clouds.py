"""Which graded cloud puts the main job within 1 % of the continuum: the rise error of each.

Each entry is ``jaxanm run fsw`` over the whole 0.7 s with the cloud's geometry overrides
(``geometry.dr``: the spacing at the tool edge and across the fine ``band`` beyond it,
``grading``: the growth of each ring gap beyond, ``dr_far``: the far-field spacing), with
ESDIRK3 at ``time.atol = 3e-4`` and modified Newton: a time error far below the spatial one
(``main_job_schemes.py`` measures it on the shipped cloud), so the rise error
against the axisymmetric continuum at 0.1, 0.3 and 0.7 s (relative L2 over the points) is
the cloud's.  Counts and rise errors are deterministic; no wall time is reported (the cost
is measured by main_job.py and main_job_schemes.py).

    python benchmarks/main_job_clouds.py --out benchmarks/results/main_job_clouds
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from main_job import run  # noqa: E402

CLOUDS = [
    # (dr, band, grading, dr_far), metres
    (8.5e-5, 1.7e-4, 1.25, 3.75e-4),  # fsw_graded's
    (7e-5, 2.1e-4, 1.2, 3.75e-4),
    (7e-5, 2.8e-4, 1.2, 3.75e-4),
    (6e-5, 2.4e-4, 1.2, 3.75e-4),
    (7e-5, 3e-4, 1.15, 3.75e-4),
    (6e-5, 2.4e-4, 1.15, 3.75e-4),
    (6e-5, 3e-4, 1.15, 4.5e-4),
    (6e-5, 3e-4, 1.15, 3.75e-4),
]
TIME = ["--solver", "mnewton", "--set", "time.scheme=esdirk3", "--set", "time.atol=3e-4", "--set", "time.dt_max=0"]


def points(cloud) -> int:
    from jaxanm.fsw.geometry import build_cloud
    from jaxanm.fsw.scene import load_scene

    dr, band, grading, far = cloud
    scene = load_scene("fsw").with_overrides({"geometry.dr": dr, "geometry.band": band, "geometry.grading": grading,
                                              "geometry.dr_far": far})
    return int(build_cloud(scene.geometry).points.shape[0])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="results/main_job_clouds")
    ap.add_argument("--out", default="benchmarks/results/main_job_clouds")
    args = ap.parse_args(argv)
    rows = []
    for k, cloud in enumerate(CLOUDS):
        dr, band, grading, far = cloud
        extra = ["fsw", *TIME, "--set", f"geometry.dr={dr:g}", "--set", f"geometry.band={band:g}",
                 "--set", f"geometry.grading={grading:g}", "--set", f"geometry.dr_far={far:g}"]
        row = run(f"cloud {k}", None, extra, Path(args.work) / f"{k}")
        row.update(cloud=cloud, points=points(cloud))
        rows.append(row)
        print(json.dumps({key: row[key] for key in ("cloud", "points", "steps", "rise_error")}), flush=True)
    lines = ["# Which graded cloud puts the main job within 1 % of the continuum (`benchmarks/main_job_clouds.py`)",
             "", f"`{' '.join(['python', *sys.argv])}`: `jaxanm run fsw {' '.join(TIME)}` with each cloud's "
             "geometry; the rise error against the axisymmetric continuum (relative L2 over the points).", "",
             "| edge spacing dr (mm) | band (mm) | grading | far spacing (mm) | points | steps | rise error at 0.1 / "
             "0.3 / 0.7 s | within 1 % |", "| ---: | ---: | ---: | ---: | ---: | ---: | --- | --- |"]
    for r in rows:
        dr, band, grading, far = r["cloud"]
        errs = [e["rel_l2"] for e in r["rise_error"]]
        lines.append(f"| {dr * 1e3:g} | {band * 1e3:g} | {grading:g} | {far * 1e3:g} | {r['points']} | {r['steps']} | "
                     + " / ".join(f"{100 * e:.2f}" for e in errs) + f" % | {'yes' if max(errs) < 0.01 else 'no'} |")
    out = Path(args.out)
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    out.with_suffix(".json").write_text(json.dumps(rows, indent=1, default=float))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
