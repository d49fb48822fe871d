"""The cell Peclet number up to which the weld's heat step has no growing mode.

The heat rows' transport term `rho Cp V . grad T` is collocated with the MLS derivatives as they
are (no upwinding): past some cell Peclet number `|V| h / alpha` (h the spacing, alpha the
plate's diffusivity) such a discretisation may have modes that grow.  Measured on `fsw_weld`'s
cloud: the plate and tool carried by a uniform stream (-U, 0) (the tool held still: a pure
through-flow), the ring's inflow condition at U, and the rightmost modes of the implicit-Euler
heat step (`jaxanm.fsw.stability.heat_modes`: growth rate mu, 1/s) for U from 0 to 30 m/s,
against the same at U = 0.  The scene's speeds stay below `U <= 0.1` m/s and `omega R1 <= 1.5`
m/s (`tool.omega <= 1000` rad/s).

    nice -n 10 python benchmarks/heat_peclet.py --out benchmarks/results/heat_peclet
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.scene import load_scene
from jaxanm.fsw.stability import heat_modes

SPEEDS = (0.0, 0.1, 1.0, 3.0, 10.0, 30.0)
"""Stream speeds U (m/s)."""


def rows(speeds=SPEEDS) -> list:
    """The rightmost heat-step modes of fsw_weld's cloud under a uniform stream (-U, 0), per U."""
    scene = load_scene("fsw_weld").with_overrides({"tool.traverse_speed": 0.1})
    d = discretise(scene)
    g, m = scene.geometry, scene.material
    alpha = m.k / (m.rho * m.Cp)
    N, fields = d.cloud.size, d.model.fields
    out = []
    for U in speeds:
        x = np.array(d.x0, dtype=np.float64).reshape(len(fields), N)
        x[fields.index("u")], x[fields.index("v")] = -U, 0.0
        params = dict(d.params, c=dict(d.params["c"], U_tr=np.float64(U)))
        began = time.perf_counter()
        modes = heat_modes(d.model, params, x.reshape(-1), dt=1e-4, count=3)
        out.append({"U": U, "peclet_edge": U * g.dr / alpha, "peclet_ring": U * g.dr_far / alpha,
                    "mu_real": [float(mode.mu.real) for mode in modes],
                    "where": [f"{mode.kind} r = {mode.radius * 1e3:.2f} mm" for mode in modes],
                    "wall_s": time.perf_counter() - began})
        print(out[-1], flush=True)
    return out


def markdown(data: dict) -> str:
    """The results page."""
    lines = ["# The weld's heat step under a uniform stream: growing modes against the cell Peclet number", "",
             "Made by `python benchmarks/heat_peclet.py` (fsw_weld's cloud, 2363 points; load average "
             f"{data['load'][0]:.1f} / {data['load'][1]:.1f} before / after).  The three rightmost growth rates mu "
             "(1/s) of the implicit-Euler heat step at dt = 1e-4 s; a mode grows when Re mu > 0.  Cell Peclet "
             "numbers `U h / alpha` at the tool edge's spacing (0.06 mm) and at the ring's (0.375 mm).", "",
             "| U (m/s) | Pe at 0.06 mm | Pe at 0.375 mm | Re mu (1/s), three rightmost | where the first lives |",
             "| ---: | ---: | ---: | --- | --- |"]
    for r in data["rows"]:
        lines.append(f"| {r['U']:g} | {r['peclet_edge']:.3g} | {r['peclet_ring']:.3g} | "
                     + ", ".join(f"{v:.3g}" for v in r["mu_real"]) + f" | {r['where'][0]} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="benchmarks/results/heat_peclet")
    args = ap.parse_args(argv)
    out = Path(args.out)
    before = os.getloadavg()[0]
    data = {"rows": rows(), "load": [before, os.getloadavg()[0]]}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(data, indent=1) + "\n")
    out.with_suffix(".md").write_text(markdown(data))
    print(markdown(data))


if __name__ == "__main__":
    main()
