"""MLS stencils by numpy on the host against the jitted kernel: a build's time, and the compilation.

Per scene's cloud (``discretise``: its points, tool split and geometry), in one fresh process:

- ``cloud, host``: :func:`jaxanm.fsw.geometry.cloud_stencils` as a run builds its fixed cloud
  (``compiled=False``), median of ``--repeats`` builds;
- ``cloud, compiled, first``: the same build by the jitted kernel the first time in the process
  (``compiled=True``: tracing and compiling, the persistent compile cache off), then the median
  of ``--repeats`` more builds;
- ``values, host`` and ``values, compiled``: value-only stencils at the cloud's own points (as
  the tracers' evaluation asks at every step), likewise.

The whole build is timed (neighbour search, the kernel, the condition screen), so the host's
and the compiled kernel's builds differ by the kernels alone.

    python benchmarks/mls_host_kernel.py --out benchmarks/results/mls_host_kernel

Writes ``OUT.json`` and ``OUT.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import statistics
import sys
import time

import jax

from jaxanm.fsw import discretise, load_scene
from jaxanm.fsw.geometry import cloud_stencils, evaluate_stencils, neighbour_list

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCENES = ("fsw", "fsw_paper")


def seconds(build) -> float:
    """Wall of one ``build()``, its arrays ready."""
    start = time.perf_counter()
    jax.block_until_ready(jax.tree_util.tree_leaves(build()))
    return time.perf_counter() - start


def measure(name: str, repeats: int) -> dict:
    """Build times (s) of scene ``name``'s cloud stencils and of value-only stencils at its points."""
    scene = load_scene(name)
    cloud, stencils, _, _, _ = discretise(scene)
    g, points, n_tool = scene.geometry, cloud.points, cloud.n_tool

    def cloud_build(compiled):  # a moving cloud's rebuilds pass neighbours, which selects the compiled kernel
        return lambda: cloud_stencils(points, n_tool, g, m_max=stencils.index.shape[1],
                                      neighbours=neighbour_list(g) if compiled else None)

    def values(compiled):
        return lambda: evaluate_stencils(points, n_tool, g, points, derivatives=False,
                                         neighbours=neighbour_list(g) if compiled else None)

    row = {"scene": name, "points": int(points.shape[0]), "width": int(stencils.index.shape[1])}
    for label, build in (("cloud", cloud_build), ("values", values)):
        row[f"{label}, host"] = statistics.median(seconds(build(False)) for _ in range(repeats))
        row[f"{label}, compiled, first"] = seconds(build(True))
        row[f"{label}, compiled"] = statistics.median(seconds(build(True)) for _ in range(repeats))
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "mls_host_kernel"))
    a = ap.parse_args()
    jax.config.update("jax_enable_compilation_cache", False)
    load = os.getloadavg()[0]
    rows = [measure(name, a.repeats) for name in SCENES]
    meta = {"command": " ".join(["python", *sys.argv]), "jax": jax.__version__, "cpus": os.cpu_count(),
            "load": [load, os.getloadavg()[0]]}
    out = pathlib.Path(a.out)
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1) + "\n")
    keys = [k for k in rows[0] if "," in k]
    lines = ["# MLS stencils on the host against the jitted kernel (`benchmarks/mls_host_kernel.py`)", "",
             f"`{meta['command']}`; jax {meta['jax']}, {meta['cpus']} CPUs, load {load:.1f} at the start, "
             f"{meta['load'][1]:.1f} at the end. Seconds per build, medians of {a.repeats} "
             "(\"first\": the first compiled build of the process, compilation included).", "",
             "| scene | points | width | " + " | ".join(keys) + " |",
             "| --- | ---: | ---: | " + " | ".join("---:" for _ in keys) + " |"]
    for row in rows:
        lines.append(f"| {row['scene']} | {row['points']} | {row['width']} | "
                     + " | ".join(f"{row[k]:.3f}" for k in keys) + " |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(out.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()
