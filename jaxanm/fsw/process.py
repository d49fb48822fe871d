"""The process quantities of a welding run, as a weld engineer reads them: peak temperature,
torque, mechanical power, the advancing-retreating and trailing-leading temperature
differences, and how well the run conserved mass (:func:`process_summary`, the ``process``
block of ``summary.json``).

The temperature differences are taken at four points ``PROBE_OFFSET`` outside the tool edge:
leading (x > 0, where the plate arrives), trailing (x < 0), retreating (y > 0) and advancing
(y < 0; the tool surface moves with the travel there for omega > 0, against the plate's
stream seen from the tool), from the MLS temperature at the last saved time.
"""

from __future__ import annotations

import numpy as np

from .energy import dissipated_power, fields_at, tool_torque
from .mass_flux import flux_table, largest_error
from .scene import Scene

__all__ = ["PROBE_OFFSET", "process_summary"]

PROBE_OFFSET = 7.5e-4
"""Distance (m) of the four asymmetry points outside the tool edge (the weld scenes' probes)."""


def process_summary(result) -> dict | None:
    """``{"t", "peak_T", "torque", "power", "dissipation", "advancing_minus_retreating",
    "trailing_minus_leading", "mass_flux_error"}`` of a run whose tool travels (``traverse``),
    at its last saved time ``t`` (SI units; torque and powers per unit thickness), else None (also
    for a result without a :class:`~jaxanm.fsw.scene.Scene`).

    ``power`` is the torque times omega (:func:`jaxanm.fsw.energy.tool_torque`),
    ``dissipation`` the plastic dissipation ``int 3 mu epsbar^2`` of the plate
    (:func:`jaxanm.fsw.energy.dissipated_power`): with a sticking tool the dissipation takes up
    the torque's power plus the work of the ring that pushes the plate past the pin at U, so it
    exceeds the power, by a few per cent at the smallest advances per revolution and by a
    quarter at the largest (benchmarks/results/process_window.md).  ``mass_flux_error`` is the
    largest error of the fluxes through the sections and circles of
    :func:`jaxanm.fsw.mass_flux.flux_table` over the saved times, in units of the through-flow
    ``2 R2 U`` (sections) and ``2 r U`` (circles).
    """
    scene = getattr(result, "scene", None)
    if not isinstance(scene, Scene) or not scene.has("traverse") or scene.tool.traverse_speed <= 0 or len(result.t) < 1:
        return None
    g = scene.geometry
    r = g.R1 + PROBE_OFFSET
    at = np.array([[r, 0.0], [-r, 0.0], [0.0, r], [0.0, -r]])
    lead, trail, retreat, advance = fields_at(result, -1, at, derivatives=False)["T"]
    plate = np.asarray(result.material) != 0
    torque = tool_torque(result, -1)
    return {"t": float(result.t[-1]), "peak_T": float(np.asarray(result.T[-1])[plate].max()), "torque": torque,
            "power": torque * scene.tool.omega, "dissipation": dissipated_power(result, -1),
            "advancing_minus_retreating": float(advance - retreat), "trailing_minus_leading": float(trail - lead),
            "mass_flux_error": largest_error(flux_table(result))}
