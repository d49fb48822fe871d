"""Calibrate the flow law (K, A, n) of the FSW model against synthetic measurements.

    python examples/calibrate.py [--out DIR] [--seed 0]

Synthetic "measurements" are simulated with the paper's AA7075 parameters (K = 2.69e16 Pa s^n
K^-A, A = -3.3155, n = 0.1324) on the small fixed-point scene ``calibration_small`` for three
experiments (initial/ambient temperature T0 and tool speed omega):

    (300 K, 20 rad/s), (300 K, 60 rad/s), (600 K, 60 rad/s)

and perturbed by seeded Gaussian noise, 0.01 K on temperatures and 1e-5 m/s on velocities u, v,
at the three probes and the 19 points of the section A-A, at every step (2178 values).  Why three:
mu = K T^A epsbar^(n-1) / 3, so one near-isothermal experiment sees only K T0^A (the
Fisher matrix of the first experiment alone has condition number ~5e8 in relative units, ~2e6
for the three; docs/notes/gradients.md); a second T0 separates
K from A, a second omega widens the strain rates that fix n.  The fit starts about 20 % away
(K x 0.8, A x 1.2, n x 1.2) and takes damped Gauss-Newton steps (an optax transformation,
``jaxanm.fsw.calibration.gauss_newton``) with gradients and Jacobians from forward
sensitivities.  It prints a table of true / start / fitted values, the loss history and the
predicted standard deviations (from the Gauss-Newton matrix at the fit), and writes
``DIR/calibration.json`` and ``DIR/calibration.png``.
"""

from __future__ import annotations

import argparse
import json
import math
import pathlib
import time

import numpy as np

import jaxanm
from jaxanm.fsw import calibration, load_scene

EXPERIMENTS = ((300.0, 20.0), (300.0, 60.0), (600.0, 60.0))
"""(T0 = Ta in K, omega in rad/s) of each synthetic experiment."""

SIGMA = {"T": 0.01, "u": 1e-5, "v": 1e-5}
"""Noise standard deviation per field (K, m/s)."""

START_FACTORS = {"K": 0.8, "A": 1.2, "n": 1.2}
"""The start is the truth times these factors (about 20 % away)."""


def experiments(scene_name: str = "calibration_small", design=EXPERIMENTS, overrides=None) -> list:
    """One scene per (T0, omega); ``overrides`` (e.g. ``{"time.t_end": 4e-3}``) apply to all."""
    base = load_scene(scene_name).with_overrides(overrides or {})
    return [base.with_overrides({"thermal.T0": T0, "thermal.Ta": T0, "tool.omega": omega})
            for T0, omega in design]


def synthetic_data(scenes, theta, sigma=SIGMA, seed: int = 0, noise: bool = True) -> list:
    """Simulated observations at ``theta`` plus seeded Gaussian noise (sigma per field)."""
    rng = np.random.default_rng(seed)
    data = []
    for scene in scenes:
        observed = calibration.simulate(scene, theta, tangents=False).observed

        def noisy(path, value):
            field = path[-1].key
            if not noise or field not in sigma:
                return value
            return value + sigma[field] * rng.standard_normal(np.shape(value))

        import jax

        data.append({"t": observed["t"],
                     **jax.tree_util.tree_map_with_path(noisy, {k: v for k, v in observed.items() if k != "t"})})
    return data


def _count(data, sigma) -> int:
    """Number of measured values that enter the loss (fields named in sigma, every time)."""
    import jax

    leaves = jax.tree_util.tree_flatten_with_path([{k: v for k, v in d.items() if k != "t"} for d in data])[0]
    return int(sum(np.size(v) for path, v in leaves if path[-1].key in sigma))


def start_theta(true: dict, factors=START_FACTORS) -> dict:
    """``{"logK", "A", "n"}`` of the truth times ``factors``."""
    return {"logK": true["logK"] + math.log(factors["K"]), "A": true["A"] * factors["A"],
            "n": true["n"] * factors["n"]}


def run(scene_name: str = "calibration_small", design=EXPERIMENTS, overrides=None, sigma=SIGMA,
        seed: int = 0, noise: bool = True, max_iter: int = 20, verbose: bool = True) -> dict:
    """The whole calibration; returns the JSON-ready summary (plus ``fit``, the FitResult)."""
    tic = time.perf_counter()
    scenes = experiments(scene_name, design, overrides)
    true = calibration.material_theta(scenes[0])
    data = synthetic_data(scenes, true, sigma, seed, noise)
    start = start_theta(true)

    def progress(i, theta, loss):
        if verbose:
            m = calibration.theta_to_material(theta)
            print(f"  simulation {i:2d}: loss {loss:12.6g}   K {m['K']:.6e}  A {m['A']:+.6f}  n {m['n']:.6f}",
                  flush=True)

    fit = calibration.fit(scenes, data, start, sigma=sigma, max_iter=max_iter, callback=progress)
    cov = np.linalg.inv(fit.gn_matrix)
    std = dict(zip(fit.theta_names, np.sqrt(np.diag(cov))))
    eig = np.linalg.eigvalsh(fit.gn_matrix)
    summary = {
        "true": calibration.theta_to_material(true),
        "start": calibration.theta_to_material(start),
        "fitted": calibration.theta_to_material(fit.theta),
        "loss_history": [float(v) for v in fit.loss_history],
        "simulations": fit.evaluations,
        "converged": fit.converged,
        "experiments": [{"T0": T0, "omega": om} for T0, om in design],
        "sigma": dict(sigma),
        "data_points": _count(data, sigma),
        "predicted_std": {"K_relative": float(std["logK"]), "A": float(std["A"]), "n": float(std["n"])},
        "gauss_newton_eigenvalues": [float(e) for e in eig],
        "wall_time_s": time.perf_counter() - tic,
    }
    summary["relative_error"] = {k: abs(summary["fitted"][k] / summary["true"][k] - 1) for k in ("K", "A", "n")}
    summary["fit"] = fit
    return summary


def print_table(summary: dict) -> None:
    """True / start / fitted values, relative errors and predicted standard deviations."""
    s = summary
    print(f"\n{'':4s}{'true':>14s}{'start':>14s}{'fitted':>14s}{'rel. error':>12s}{'pred. std':>12s}")
    pstd = {"K": s["predicted_std"]["K_relative"], "A": s["predicted_std"]["A"] / abs(s["true"]["A"]),
            "n": s["predicted_std"]["n"] / s["true"]["n"]}
    for k in ("K", "A", "n"):
        print(f"{k:4s}{s['true'][k]:14.6g}{s['start'][k]:14.6g}{s['fitted'][k]:14.6g}"
              f"{s['relative_error'][k]:12.2e}{pstd[k]:12.2e}")
    print("loss history:", " ".join(f"{v:.4g}" for v in s["loss_history"]))
    print(f"{s['simulations']} simulations with sensitivities ({'converged' if s['converged'] else 'NOT converged'}), "
          f"{s['wall_time_s']:.1f} s; Gauss-Newton "
          f"eigenvalues {', '.join(f'{e:.3g}' for e in s['gauss_newton_eigenvalues'])}")


def plot(summary: dict, path) -> None:
    """Loss history and relative parameter errors per accepted step (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fit = summary["fit"]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.5))
    a1.semilogy(summary["loss_history"], "o-")
    a1.set_xlabel("accepted Gauss-Newton step")
    a1.set_ylabel("loss 0.5 sum ((y - data) / sigma)^2")
    for k in ("K", "A", "n"):
        errs = [abs(calibration.theta_to_material(th)[k] / summary["true"][k] - 1) for th in fit.theta_history]
        a2.semilogy(errs, "o-", label=k)
    a2.axhline(0.01, color="gray", ls=":", label="1 %")
    a2.set_xlabel("accepted Gauss-Newton step")
    a2.set_ylabel("relative error")
    a2.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> dict:
    """Command line: run, print, write ``calibration.json`` and ``calibration.png`` to ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/calibration", help="output directory")
    parser.add_argument("--seed", type=int, default=0, help="noise seed")
    args = parser.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"calibrating K, A, n on {len(EXPERIMENTS)} experiments (T0, omega) = {EXPERIMENTS}")
    summary = run(seed=args.seed)
    print_table(summary)
    plot(summary, out / "calibration.png")
    (out / "calibration.json").write_text(json.dumps({k: v for k, v in summary.items() if k != "fit"}, indent=2))
    print(f"wrote {out / 'calibration.json'} and {out / 'calibration.png'}")
    return summary


if __name__ == "__main__":
    with jaxanm.float64():
        main()
