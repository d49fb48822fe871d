"""Which detector of simple branch points is robust: the sign of the bordered determinant, or
the geometric progression of the ANM series' last coefficients (Cochelin and Medale 2013).

The problem: the discretised Chafee-Infante equation ``u'' + lam (u - u^3) = 0`` on (0, 1),
u(0) = u(1) = 0, N = 23 interior points, whose trivial branch meets simple branch points at
``lam_k = (4 / h^2) sin^2(k pi h / 2)`` (k = 1, 2, 3 below lam = 100), followed by
:func:`jaxanm.continuation` (order 15, tol 1e-8) in two coordinates:

- flat: the unknowns u, the trivial branch ``u = 0``, whose series is exact (every coefficient
  beyond the tangent is zero), the steps bounded by ``max_step``;
- curved: ``v = u + sin(lam / 10) w``, ``w = 2 x (1 - x)``: the same branch points on a branch
  whose series is not exact, the steps the series' own (``max_step`` inf) or bounded.

For every step: whether the sign of ``det B`` (B the bordered matrix, factorised at every
point) differs between its ends, and whether its series shows the geometric progression
MANLAB tests for (GeomSerie: the last four coefficients aligned, ``U_(p-q) = alpha^q U_p`` to
1e-4, the ratios consistent to 1e-5; alpha is then the distance to the branch point, ahead or
behind), with where the progression puts the branch point (``lam`` of the series at
``+-alpha``).  Counted against the truth (the closed form's lam_k inside the step).  Counts
only: no wall times.

    python benchmarks/branch_points.py [--out benchmarks/results/branch_points]
"""

from __future__ import annotations

import argparse
import datetime
import json
import pathlib

import jax.numpy as jnp
import numpy as np

import jaxanm

HERE = pathlib.Path(__file__).resolve().parent
N = 23
H = 1.0 / (N + 1)
X = np.linspace(H, 1.0 - H, N)
LAM_K = 4.0 / H**2 * np.sin(np.arange(1, 4) * np.pi * H / 2) ** 2
LAM_END = 100.0
GP_ALIGNED, GP_RATIOS = 1e-4, 1e-5  # MANLAB's GeomSerie thresholds


def residual(v, lam, params):
    """Chafee-Infante in the unknowns ``v = u + sin(lam / 10) w``."""
    u = v - jnp.sin(lam / 10.0) * params["w"]
    up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
    return (up[2:] - 2.0 * u + up[:-2]) / H**2 + lam * (u - u**3)


def progression(coeffs: np.ndarray):
    """MANLAB's test on the last four coefficients: ``(detected, alpha)``, alpha signed (its
    sign that of ``<U_(p-1), U_p>``: the branch point ahead (+) or behind (-))."""
    last = coeffs[-1]
    if not np.any(last):
        return False, np.nan
    alphas, misfit = [], 0.0
    for q in (1, 2, 3):
        alpha = coeffs[-1 - q] @ last / (last @ last)
        misfit += np.linalg.norm(coeffs[-1 - q] - alpha * last) / max(np.linalg.norm(coeffs[-1 - q]), 1e-300)
        alphas.append(alpha)
    a = np.abs(alphas)
    spread = (a[1] ** 0.5 / a[0] - 1) ** 2 + (a[2] ** (1 / 3) / a[0] - 1) ** 2
    return bool(spread <= GP_RATIOS and misfit <= GP_ALIGNED), float(alphas[0])


def study(curved: bool, max_step: float) -> dict:
    """One walk: per step, the truth, the determinant's verdict and the progression's."""
    signs = []

    def watch(end):
        signs.append(end.linearisation.slogdet()[0])
        return []

    params = {"w": 2.0 * X * (1.0 - X) if curved else np.zeros(N)}
    branch = jaxanm.continuation(residual, np.zeros(N), 0.0, params, lam_end=LAM_END, max_step=max_step,
                                 max_steps=500, on_step=watch)
    rows = []
    for i in range(branch.a.size):
        lo, hi = sorted((branch.lam[i], branch.lam[i + 1]))
        truth = [k for k, lam in enumerate(LAM_K, start=1) if lo <= lam <= hi]
        gp, alpha = progression(branch.series[i])
        implied = None
        if gp:  # lam of the series at +-alpha (outside the step if behind or beyond it)
            powers = alpha ** np.arange(1, branch.series.shape[1] + 1)
            implied = float(branch.lam[i] + powers @ branch.series[i, :, -1])
        rows.append({"step": i, "lam": [float(branch.lam[i]), float(branch.lam[i + 1])], "a": float(branch.a[i]),
                     "truth": truth, "determinant": bool(signs[i] != signs[i + 1]), "progression": gp,
                     "alpha": alpha if gp else None, "within_step": bool(gp and 0 <= alpha <= branch.a[i]),
                     "implied_lam": implied})
    events = branch.events_of("branch_point")
    return {"coordinates": "curved" if curved else "flat", "max_step": max_step, "steps": int(branch.a.size),
            "factorizations": branch.stats.factorizations, "walk_factorizations": int(branch.lam.size),
            "located": [float(e.lam) for e in events],
            "located_error": float(np.max(np.abs(np.array([e.lam for e in events]) - LAM_K) / LAM_K))
            if len(events) == 3 else None,
            "rows": rows}


def summary(case: dict) -> dict:
    """Counts of a study: steps holding a branch point, flagged by each detector, right or not."""
    rows = case["rows"]
    holds = [r for r in rows if r["truth"]]
    det = [r for r in rows if r["determinant"]]
    gp = [r for r in rows if r["progression"]]
    gp_near = [r for r in gp for k in range(3)
               if r["implied_lam"] is not None and abs(r["implied_lam"] - LAM_K[k]) < 1e-3 * LAM_K[k]]
    return {"holding": len(holds), "determinant": len(det), "determinant_right": sum(bool(r["truth"]) for r in det),
            "progression": len(gp), "progression_holding": sum(bool(r["truth"]) for r in gp),
            "progression_within_step": sum(r["within_step"] for r in gp),
            "progression_points_at_a_branch_point": len(gp_near),
            "progression_worst_error": max((min(abs(r["implied_lam"] - LAM_K) / LAM_K) for r in gp), default=None)}


def markdown(results: dict) -> str:
    """The results as a markdown page."""
    lines = [
        "# Branch points: the determinant's sign against the series' geometric progression",
        "",
        f"Made by `python benchmarks/branch_points.py` on {results['date']}. Chafee-Infante, N = {N}, three "
        f"simple branch points below lam = {LAM_END:g} (lam_k = {', '.join(f'{v:.6f}' for v in LAM_K)}); ANM "
        "order 15, tol 1e-8. Per walk: the steps that hold a branch point (closed form), the steps where the "
        "sign of det B changes between the ends, the steps whose series shows MANLAB's geometric progression "
        "(of which: holding a branch point; with alpha inside the step; whose progression puts lam within "
        "1e-3 of a branch point, ahead or behind), the worst relative error of those lams, the branch points "
        "located (Newton on the augmented system) and all factorisations (those of the walk's points apart).",
        "",
        "| coordinates | max_step | steps | holding | det sign changes (right) | progressions (holding, "
        "within step, at a BP) | progression's worst lam error | located error | factorisations (walk) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for case in results["cases"]:
        s = case["summary"]
        worst = "n/a" if s["progression_worst_error"] is None else f"{s['progression_worst_error']:.1e}"
        located = "n/a" if case["located_error"] is None else f"{case['located_error']:.1e}"
        lines.append(
            f"| {case['coordinates']} | {case['max_step']:g} | {case['steps']} | {s['holding']} "
            f"| {s['determinant']} ({s['determinant_right']}) | {s['progression']} ({s['progression_holding']}, "
            f"{s['progression_within_step']}, {s['progression_points_at_a_branch_point']}) | {worst} | {located} "
            f"| {case['factorizations']} ({case['walk_factorizations']}) |")
    lines += [
        "",
        "Reading: the determinant's sign changes in exactly the steps that hold a branch point, whatever the "
        "series and the step. The exact series of the flat trivial branch has no progression at all. On the "
        "curved branch the progression shows on steps on both sides of each branch point (round-off excites "
        "the bifurcating mode, whose pole at the branch point dominates the last coefficients) and points at "
        "it to 1e-7-1e-6 of lam, a guess Newton would take; but with the series' own steps it showed on 2 of "
        "10 steps, neither holding a branch point (the steps jump over them, the progression appears behind). "
        "So `jaxanm.continuation` detects branch points by the determinant's sign, brackets them on the "
        "step's series by det B and locates them by Newton on the augmented system (`jaxanm.events`).",
    ]
    return "\n".join(lines) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(HERE / "results" / "branch_points"))
    args = parser.parse_args()
    cases = []
    for curved, max_step in ((False, 5.0), (False, 2.0), (False, 0.5), (True, np.inf), (True, 2.0), (True, 0.5)):
        case = study(curved, max_step)
        case["summary"] = summary(case)
        print(case["coordinates"], max_step, case["summary"], case["located_error"], flush=True)
        cases.append(case)
    results = {"date": datetime.date.today().isoformat(), "lam_k": LAM_K.tolist(), "cases": cases}
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(results, indent=1, default=float) + "\n")
    out.with_suffix(".md").write_text(markdown(results))
    print(f"wrote {out}.md and .json")


if __name__ == "__main__":
    main()
