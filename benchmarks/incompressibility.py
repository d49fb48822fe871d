"""Incompressibility around a travelling tool: the formulations measured, and the one chosen.

Three studies, each a table of `benchmarks/results/incompressibility.md` (+ `.json`):

- **flux**: the isothermal start flow of `fsw_weld` at U = 1 mm/s, omega = 20 rad/s (the
  quasi-static flow at T0, `jaxanm.fsw.start.quasi_static_state`) under each candidate: the
  penalty of the main job (lambda = 0.1, 1, 10, 100 mu_ref) and the `incompressible` effect at
  several stabilisations alpha, on the weld's 0.06 mm cloud and on the main job's 0.085 mm
  cloud; the flux through sections x = const against the exact `2 sqrt(R2^2 - x^2) U`
  (`jaxanm.fsw.mass_flux`), in units of `2 R2 U`, and the start's Newton iterations.
- **inf-sup**: the smallest non-zero singular value of the pressure Schur complement
  `S = C - B A^-1 G` of the Newtonian (n = 1) mixed collocation on three graded clouds, for
  alpha = 0 (no stabilisation) to 0.1: an equal-order pair without stabilisation has it fall
  towards 0 under refinement (a spurious pressure mode); a stable one keeps it bounded.
- **mms**: the manufactured solution of `jaxanm.fsw.manufactured` (power-law viscosity at T0,
  a rotating and a through-flowing part, a smooth pressure) on the weld's cloud and two
  refinements (dr, band and dr_far times 1/sqrt 2 and 1/2): the largest errors of velocity and
  pressure and their observed orders.

    nice -n 19 python benchmarks/incompressibility.py --out benchmarks/results/incompressibility

(about an hour on 2 loaded cores; `--only flux|infsup|mms` runs one study).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from pathlib import Path

import numpy as np
import scipy.sparse
import scipy.sparse.linalg as spla

import jaxanm
from jaxanm import mls
from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.geometry import PLATE_EDGE, evaluate_stencils
from jaxanm.fsw.manufactured import errors, observed_orders
from jaxanm.fsw.mass_flux import section_rule
from jaxanm.fsw.physics import mu_reference
from jaxanm.fsw.scene import load_scene
from jaxanm.fsw.start import quasi_static_state
from jaxanm.internal import Problem
from jaxanm.stats import Stats

FLOW = "viscous,tracers,traverse"
SECTIONS = (0.0, -0.75e-3, -1.5e-3, -3e-3, -5e-3)


def _section_flux(scene, cloud, model, x, xs: float) -> float:
    """The flux error through x = xs, over 2 R2 U, of the MLS velocity of unknowns ``x``."""
    g, U = scene.geometry, scene.tool.traverse_speed
    points, ws = section_rule(g, xs)
    st = evaluate_stencils(cloud.points, cloud.n_tool, g, points, derivatives=False)
    u = np.asarray(mls.value(st, model.split(x)["u"]))
    return float((-np.sum(ws * u) - 2 * math.sqrt(g.R2 ** 2 - xs ** 2) * U) / (2 * g.R2 * U))


def flux_rows() -> list:
    base = load_scene("fsw_weld").with_overrides({"tool.traverse_speed": 1e-3})
    cases = []
    for dr in (6e-5, 8.5e-5):
        for lam in (0.1, 1.0, 10.0, 100.0):
            cases.append((f"penalty lambda = {lam:g} mu_ref", dr, {"effects": FLOW, "mechanics.penalty": lam}))
        for alpha in (0.003, 0.01, 0.03, 0.1):
            cases.append((f"incompressible, alpha = {alpha:g}", dr,
                          {"effects": FLOW + ",incompressible", "mechanics.penalty": 0.0,
                           "mechanics.pressure_stabilisation": alpha}))
    rows = []
    for label, dr, ov in cases:
        scene = base.with_overrides({**ov, "geometry.dr": dr})
        if "lambda" in label:  # the penalty in units of this scene's mu_ref
            scene = scene.with_overrides({"mechanics.penalty": ov["mechanics.penalty"] * mu_reference(scene)})
        cloud, st, model, params, _ = discretise(scene)
        began = time.perf_counter()
        try:
            x, report = quasi_static_state(scene, model, st)
        except jaxanm.StepFailure as exc:
            rows.append({"case": label, "dr": dr, "failed": str(exc)})
            continue
        row = {"case": label, "dr": dr, "points": cloud.size, "iterations": report.iterations,
               "wall_s": time.perf_counter() - began}
        row.update({f"x={xs * 1e3:g}mm": _section_flux(scene, cloud, model, x, xs) for xs in SECTIONS})
        rows.append(row)
        print(row, flush=True)
    return rows


def _schur_sigma(dr: float, alpha: float) -> dict:
    """The smallest non-zero singular values of the Newtonian mixed collocation's pressure
    Schur complement on the weld's graded cloud at spacing ``dr`` (band and far field scaled)."""
    base = load_scene("fsw_weld")
    f = dr / base.geometry.dr
    scene = base.with_overrides({"effects": FLOW + ",incompressible", "material.n": 1.0,
                                 "geometry.dr": dr, "geometry.dr_far": base.geometry.dr_far * f})
    cloud, st, model, params, x0 = discretise(scene)
    params = dict(params, c=dict(params["c"], alpha_p=np.float64(alpha)), pin=np.zeros(cloud.size, bool))
    problem = Problem(model.residual, model.scale(), Stats(), "sparse", model.sparsity)
    with jaxanm.float64():
        J = scipy.sparse.csc_matrix(problem.tangent(x0, x0, np.float64(1.0), np.float64(1.0), params))
    N = cloud.size
    S = scipy.sparse.diags(model.scale())
    J = (J @ S).tocsc()  # columns in scaled unknowns
    A, G = J[:2 * N, :2 * N].tocsc(), J[:2 * N, 2 * N:].toarray()
    B, C = J[2 * N:, :2 * N], J[2 * N:, 2 * N:].toarray()
    plate = cloud.kind >= PLATE_EDGE
    schur = (C - B @ spla.splu(A).solve(G))[np.ix_(plate, plate)]
    s = np.linalg.svd(schur, compute_uv=False)  # the last is the constant pressure's 0
    return {"points": N, "sigma_min": float(s[-2]), "sigma_next": float(s[-3]), "sigma_max": float(s[0]),
            "zero": float(s[-1])}


def infsup_rows() -> list:
    rows = []
    for alpha in (0.0, 1e-3, 1e-2, 1e-1):
        for dr in (1.2e-4, 8.5e-5, 6e-5):
            row = {"alpha": alpha, "dr": dr, **_schur_sigma(dr, alpha)}
            rows.append(row)
            print(row, flush=True)
    return rows


def mms_rows() -> tuple:
    base = load_scene("fsw_weld").with_overrides({"effects": FLOW + ",incompressible", "mechanics.start": "rest"})
    g = base.geometry
    rows = []
    for f in (1.0, 1 / math.sqrt(2), 0.5):
        scene = base.with_overrides({"geometry.dr": g.dr * f, "geometry.dr_far": g.dr_far * f, "geometry.band": g.band})
        began = time.perf_counter()
        row = {"factor": f, **errors(scene), "wall_s": time.perf_counter() - began}
        rows.append(row)
        print(row, flush=True)
    return rows, observed_orders(rows)


def markdown(data: dict) -> str:
    lines = ["# Incompressibility around a travelling tool", "", "Made by `benchmarks/incompressibility.py`; "
             f"load average {data['load'][0]:.1f} / {data['load'][1]:.1f} (before / after).", ""]
    if "flux" in data:
        keys = [f"x={xs * 1e3:g}mm" for xs in SECTIONS]
        lines += ["## Flux through sections x = const (isothermal start flow, U = 1 mm/s, omega = 20 rad/s)", "",
                  "Flux minus its exact value `2 sqrt(R2^2 - x^2) U`, in units of `2 R2 U`.", "",
                  "| formulation | edge spacing (mm) | points | start iterations | " + " | ".join(keys) + " |",
                  "| --- | --- | --- | --- | " + " | ".join("---" for _ in keys) + " |"]
        for r in data["flux"]:
            if "failed" in r:
                failed = r["failed"][:80]
                lines.append(f"| {r['case']} | {r['dr'] * 1e3:g} | | failed: {failed} |" + " |" * len(keys))
                continue
            lines.append(f"| {r['case']} | {r['dr'] * 1e3:g} | {r['points']} | {r['iterations']} | "
                         + " | ".join(f"{r[k]:+.4f}" for k in keys) + " |")
        lines.append("")
    if "infsup" in data:
        lines += ["## Inf-sup test: the pressure Schur complement (Newtonian, rest state)", "",
                  "Smallest non-zero singular values of `S = C - B A^-1 G` (scaled unknowns; the constant "
                  "pressure's zero left out).", "",
                  "| alpha | edge spacing (mm) | points | sigma_min | next | sigma_max |",
                  "| --- | --- | --- | --- | --- | --- |"]
        for r in data["infsup"]:
            lines.append(f"| {r['alpha']:g} | {r['dr'] * 1e3:g} | {r['points']} | {r['sigma_min']:.3g} | "
                         f"{r['sigma_next']:.3g} | {r['sigma_max']:.3g} |")
        lines.append("")
    if "mms" in data:
        lines += ["## Manufactured solution (power law at T0, fsw_weld's cloud and two refinements)", "",
                  "| cloud | points | h = sqrt(pi R2^2 / N) (mm) | velocity error / (omega R1) | "
                  "pressure error / range |",
                  "| --- | --- | --- | --- | --- |"]
        for r in data["mms"]["rows"]:
            lines.append(f"| dr x {r['factor']:.3f} | {r['points']} | {r['h'] * 1e3:.3f} | {r['velocity']:.3e} | "
                         f"{r['pressure']:.3e} |")
        o = data["mms"]["orders"]
        lines += ["", f"Observed orders (least squares in log h): velocity {o['velocity']:.2f}, pressure "
                  f"{o['pressure']:.2f}.", ""]
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="benchmarks/results/incompressibility")
    ap.add_argument("--only", choices=("flux", "infsup", "mms"), default=None)
    args = ap.parse_args(argv)
    out = Path(args.out)
    data: dict = json.loads(out.with_suffix(".json").read_text()) if out.with_suffix(".json").exists() else {}
    before = os.getloadavg()[0]
    if args.only in (None, "infsup"):
        data["infsup"] = infsup_rows()
    if args.only in (None, "mms"):
        rows, orders = mms_rows()
        data["mms"] = {"rows": rows, "orders": orders}
    if args.only in (None, "flux"):
        data["flux"] = flux_rows()
    data["load"] = [before, os.getloadavg()[0]]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(data, indent=1))
    out.with_suffix(".md").write_text(markdown(data))
    print(markdown(data))


if __name__ == "__main__":
    main()
