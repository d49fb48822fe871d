"""Calibrate the contact state delta and the consistency K from thermocouple histories.

Synthetic "thermocouples": the temperature at the three registration points of
``calibration_small`` with the ``slip`` effect (delta = 0.7, the paper's K), every 4 ms over
40 ms, with 0.5 K of Gaussian noise.  The fit (:func:`jaxanm.fsw.calibration.fit`: Gauss-Newton
on forward sensitivities through the whole run) starts from delta = 0.5 and 1.3 K, and the
Gauss-Newton matrix at the minimum gives the standard deviations.  delta and K are strongly
correlated by temperatures alone (both set the heat input), but the thermocouples separate
them: the friction heat is released at the tool edge, the plastic dissipation in the shear band.

    python examples/calibrate_weld.py
"""

from __future__ import annotations

import math

import jax
import numpy as np

from jaxanm.fsw import calibration, load_scene

NOISE_K = 0.5
"""Standard deviation (K) of the thermocouple noise."""


def weld_experiment():
    """calibration_small with a slipping contact (delta = 0.7): the experiment to fit."""
    return load_scene("calibration_small").with_overrides(
        {"effects": "viscous,softening,conduction,dissipation,robin,slip", "tool.contact_state": 0.7})


def thermocouples(scene, theta, seed: int = 7) -> dict:
    """The probe temperatures of ``scene`` at ``theta`` plus ``NOISE_K`` of noise (the other
    observations are kept but not fitted: sigma names T only)."""
    clean = calibration.simulate(scene, theta, tangents=False).observed
    data = jax.tree_util.tree_map(np.asarray, clean)
    rng = np.random.default_rng(seed)
    for probe in data["probes"].values():
        probe["T"] = probe["T"] + NOISE_K * rng.standard_normal(probe["T"].shape)
    return data


def main() -> dict:
    """Fit delta and log K; print and return ``{name: (fitted, true, sigma)}``."""
    scene = weld_experiment()
    true = {"logK": math.log(scene.material.K), "delta": scene.tool.contact_state}
    data = thermocouples(scene, true)
    start = {"logK": true["logK"] + math.log(1.3), "delta": 0.5}
    result = calibration.fit([scene], [data], start, sigma={"T": NOISE_K}, max_iter=15)
    sd = np.sqrt(np.diag(np.linalg.inv(result.gn_matrix)))
    out = {}
    for i, name in enumerate(result.theta_names):
        out[name] = (float(result.theta[name]), float(true[name]), float(sd[i]))
        print(f"{name:6s} fitted {out[name][0]:.5g} +- {out[name][2]:.2g}   true {out[name][1]:.5g}")
    print(f"{result.evaluations} simulations, converged: {result.converged}")
    return out


if __name__ == "__main__":
    main()
