"""A run against the axisymmetric continuum: its temperature rise's error and the shear band.

Every FSW scene whose tool does not travel is axisymmetric (a disc round the turning tool,
uniform initial state), so :func:`jaxanm.fsw.axisymmetric.solve`, a 1-D reference independent
of the MLS code, gives the run's error: :func:`rise_error` and :func:`rise_errors` compare a
run's ``T - T0`` with it; :func:`shear_band_width` says how wide the tool edge's shear band is,
against which a cloud's spacing there is read.
"""

from __future__ import annotations

import math

import numpy as np

from .axisymmetric import solve
from .scene import Scene

__all__ = ["rise_error", "rise_errors", "shear_band_width"]


def shear_band_width(scene: Scene) -> float:
    """Width (m) of the shear band at the tool edge: how far from R1 the angular velocity
    ``v / r`` of the plate falls to ``omega / e``.

    From the isothermal (T0) Couette flow of the scene's regularised power law (its n, eps0,
    omega, R1, R2; K and T0 cancel), solved as :func:`~jaxanm.fsw.axisymmetric.solve` does (the midpoint rule on the
    graded mesh, second order, ``v`` within 3e-5 omega R1).  Unregularised, ``v / r`` falls
    as ``r^(-2/n)``: the width is about ``n R1 / 2`` (0.10 mm for fsw_paper, 0.27 of its dr),
    and the band holds 1 - 1/e of the velocity drop and most of the dissipation
    (``q ~ r^(-2 - 2/n)``).  A hotter plate (softening) shears in about the same band.
    """
    slip = scene.has("slip")
    iso = scene.with_overrides({"effects": "viscous,slip" if slip else "viscous", "tool.traverse_speed": 0.0})
    sol = solve(iso, [0.0])
    r = sol.plate_edges
    edge = scene.tool.contact_state * scene.tool.omega if slip else scene.tool.omega
    w = sol.v_faces[0] / (edge * r)  # 1 at R1, decreasing to 0 at R2
    j = int(np.argmax(w <= math.exp(-1.0)))
    # linear in r between the two edges around the crossing (the first cells are < 1 um)
    t = (w[j - 1] - math.exp(-1.0)) / (w[j - 1] - w[j])
    return float(r[j - 1] + t * (r[j] - r[j - 1]) - scene.geometry.R1)


def _travels(scene: Scene) -> bool:
    """Whether the tool travels (``traverse`` with U > 0): the fields are then not axisymmetric
    and the axisymmetric solution is no reference for them."""
    return scene.has("traverse") and scene.tool.traverse_speed > 0


def rise_error(result, steps_per_ms: int = 1) -> dict | None:
    """The temperature rise of a run against the axisymmetric solution, at the last saved time.

    ``result`` is a :class:`jaxanm.fsw.record.FSWResult` (``scene``, ``t``, ``points``, ``T``)
    of a scene with ``conduction`` (None otherwise, or at t = 0, or when the continuum's rise
    is zero).  The reference is :func:`~jaxanm.fsw.axisymmetric.solve` on its default mesh with ``refine=1`` and about
    ``steps_per_ms`` steps a millisecond (at least 10 in all): within 3e-3 K of the converged
    solution on fsw_paper's physics to 0.7 s (measured against ``refine=2``, dt = 1e-4; 0.7 s
    of solve).  Every FSW scene whose tool does not travel is axisymmetric (a disc round the
    turning tool, uniform initial state), so this is the run's error, the solution's own
    aside; when the tool travels (``traverse`` with U > 0) it returns None.

    Returns ``{"t", "rel_l2", "mean_ratio", "max_abs_K"}``: the relative L2 error of
    ``T - T0`` over the points, the run's mean rise over the reference's and the largest
    error (K).  If the solve's fixed point fails at that step (a scene heating much faster
    than fsw_paper) it is repeated with the scene's own time step.
    """
    t = np.asarray(result.t, dtype=np.float64)
    if not (result.scene.has("conduction") and t.size and t[-1] > 0) or _travels(result.scene):
        return None
    return _rise_errors(result, [t.size - 1], max(10, math.ceil(t[-1] * 1e3 * steps_per_ms)))[0]


def rise_errors(result, steps_per_ms: int = 1) -> list:
    """:func:`rise_error` at every saved time of ``result`` from 10 steps of the reference on
    (t >= 0.01 s at the default millisecond step), from one solve when the saved times are
    multiples of that step (else one solve per time); ``[]`` without ``conduction``."""
    t = np.asarray(result.t, dtype=np.float64)
    if not result.scene.has("conduction") or _travels(result.scene):
        return []
    dt = 1e-3 / steps_per_ms
    kept = [i for i in range(t.size) if t[i] >= 10 * dt - 1e-12]
    on_grid = all(abs(t[i] / dt - round(t[i] / dt)) < 1e-6 for i in kept)
    if kept and on_grid:
        return [e for e in _rise_errors(result, kept, round(t[kept[-1]] / dt)) if e is not None]
    return [e for i in kept for e in _rise_errors(result, [i], max(10, math.ceil(t[i] / dt))) if e is not None]


def _rise_errors(result, indices: list, steps: int) -> list:
    """Rise errors (dicts of :func:`rise_error`, None where the continuum has not risen) at
    the saved steps ``indices``, from one reference solve of ``steps`` steps to the last."""
    scene = result.scene
    t = np.asarray(result.t, dtype=np.float64)
    times = [float(t[i]) for i in indices]
    dt = times[-1] / steps
    try:
        ref = solve(scene, times, refine=1, dt=dt)
    except RuntimeError:  # the source's fixed point: smaller steps
        steps = max(steps, math.ceil(times[-1] / scene.time.dt - 1e-9))
        ref = solve(scene, times, refine=1, dt=times[-1] / steps)
    T0 = scene.thermal.T0
    out = []
    for k, i in enumerate(indices):
        r = np.hypot(*np.asarray(result.points[i], dtype=np.float64).T)
        rise = ref.temperature(r, k) - T0
        run_rise = np.asarray(result.T[i], dtype=np.float64) - T0
        norm = float(np.linalg.norm(rise))
        out.append(None if not norm > 0 else {
            "t": times[k], "rel_l2": float(np.linalg.norm(run_rise - rise)) / norm,
            "mean_ratio": float(np.mean(run_rise) / np.mean(rise)),
            "max_abs_K": float(np.max(np.abs(run_rise - rise)))})
    return out
