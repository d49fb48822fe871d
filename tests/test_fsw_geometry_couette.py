"""The Couette target on a graded cloud: the isothermal power-law Couette flow at the
paper's n = 0.1324 within 1e-2 omega R1 of the axisymmetric oracle (:mod:`jaxanm.fsw.axisymmetric`).

docs/notes/spatial_accuracy.md ("Aligned spokes against the Couette error") has the
measurements: the max error is the radial resolution of the tool-edge band (first order in
the ring spacing there) and of the graded zone beyond it, so the target needs a finer band
than the shipped fsw_graded's (2.8e-2 at 0.085 mm) and a gentler grading.
"""

from __future__ import annotations

import numpy as np
import pytest

import jaxanm
from jaxanm.fsw import axisymmetric, load_scene, run
from jaxanm.fsw.energy import dissipated_power
from jaxanm.fsw.geometry import PLATE_EDGE, build_cloud


def _couette_errors(overrides: dict) -> tuple[float, float, float]:
    """fsw_graded's isothermal flow (effect ``viscous`` alone, eps0 = 0.1, the quasi-static
    start then one stationary 1 s step) against the oracle: max |V - V_oracle| / (omega R1)
    over the plate, the r - R1 (m) where it sits, and the power error (P_h - P) / P."""
    scene = load_scene("fsw_graded").with_overrides({
        "effects": "viscous", "time.dt": "1.0", "time.t_end": "1.0", "time.save": "",
        "solver.kind": "mnewton", "mechanics.start": "quasi_static", **overrides})
    with jaxanm.float64():
        res = run(scene)
    g, omega = scene.geometry, scene.tool.omega
    oracle = axisymmetric.solve(scene, [0.0])
    p = res.points[-1]
    r = np.hypot(*p.T)
    plate = build_cloud(g).kind >= PLATE_EDGE  # no point at r = 0 there
    vt = oracle.velocity(r[plate], 0)
    exact = np.stack([-vt * p[plate, 1], vt * p[plate, 0]], axis=1) / r[plate, None]
    error = np.linalg.norm(np.stack([res.u[-1], res.v[-1]], axis=1)[plate] - exact, axis=1) / (omega * g.R1)
    return float(error.max()), float(r[plate][np.argmax(error)] - g.R1), dissipated_power(res, -1) / oracle.power[0] - 1


@pytest.mark.slow
def test_couette_target_met_on_a_fine_graded_cloud():
    # dr = 0.05 mm across a 0.3 mm band, then grading 1.15 (4091 points, 20-40 s): measured
    # 7.6e-3 on the first plate ring (spread 7.4e-3 around it, mean 3.9e-3) and a power error
    # of -7e-4.  The bound is the target (a velocity error of 1 % of the tool's edge speed).
    # Its margin, 1e-2 / 7.6e-3 = 1.3, is what first order in the band's spacing gives from
    # 0.05 to 0.065 mm (measured: 9.4e-3 at 0.06 mm, 1.24 times 0.05 mm's), and the result is
    # deterministic to the solvers' tolerance (1e-6 of the state).  The power is held to 5e-3: the shipped
    # graded clouds reach 3-5e-3 (note), a finer band must not do worse.
    error, where, power = _couette_errors({"geometry.dr": "5e-5", "geometry.band": "3e-4",
                                           "geometry.grading": "1.15"})
    assert error < 1e-2, (error, where)
    assert abs(power) < 5e-3, power
