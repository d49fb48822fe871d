"""Energy budget of an FSW result: stored heat and dissipated power, by fine quadrature.

The continuum balance of a scene with ``dissipation`` is ``d/dt int rho Cp (T - T0) dA =
beta int 3 mu epsbar^2 dA - (Robin losses)`` (per unit thickness).  The point values of a
result sample a source that varies like ``r^-17`` next to the tool for the paper's n, so both
integrals are taken here on a fine polar Gauss grid of the MLS fields, not on the points:
the fields are refitted on the result's points (:meth:`Model.fit_state`) and evaluated there.

- :func:`stored_heat`: ``int rho Cp (T - T0) dA`` over plate and tool.
- :func:`tool_torque`: the torque the tool exerts on the plate, from the shear stress of the
  MLS velocity on the plate's side of the tool edge; times omega, the mechanical power.
- :func:`dissipated_power`: ``int 3 mu epsbar^2 dA`` of the discrete velocity field, with the
  scene's viscosity law (``beta`` times it heats the material).  It is computed from the
  velocity and the constitutive law alone, independently of the heat rows, so
  ``stored_heat <= beta * max_t dissipated_power * t`` checks that the heat equation creates
  no heat (docs/notes/energy_balance.md).
"""

from __future__ import annotations

import math

import numpy as np

from .. import mls
from .discretisation import make_model
from .geometry import build_cloud, cloud_stencils, evaluate_stencils
from .physics import complete_fields, viscosity

__all__ = ["annulus_quadrature", "dissipated_power", "fields_at", "stored_heat", "tool_torque"]


def annulus_quadrature(r_in: float, r_out: float, cells: int = 60, angles: int = 64):
    """Points (M, 2) and weights (M,) of a polar Gauss rule on ``r_in < r < r_out``.

    Three Gauss points per radial cell, cells clustered quadratically towards ``r_in`` (where
    the FSW source concentrates), ``angles`` equally spaced angles.  ``r_in = 0`` gives a disc.
    The defaults integrate the Newtonian Couette flow's dissipation, a smooth density steepest
    at ``r_in``, to round-off (tests/test_fsw_energy.py).
    """
    edges = r_in + (r_out - r_in) * np.linspace(0.0, 1.0, cells + 1) ** 2
    xg, wg = np.polynomial.legendre.leggauss(3)
    a, b = edges[:-1, None], edges[1:, None]
    r = ((a + b) / 2 + (b - a) / 2 * xg).ravel()
    wr = ((b - a) / 2 * wg).ravel() * r
    th = 2 * math.pi * (np.arange(angles) + 0.5) / angles
    pts = np.stack([np.outer(r, np.cos(th)), np.outer(r, np.sin(th))], axis=-1).reshape(-1, 2)
    return pts, np.outer(wr, np.full(angles, 2 * math.pi / angles)).ravel()


def fields_at(result, s: int, targets: np.ndarray, derivatives: bool = True) -> dict:
    """u, v, T (and with ``derivatives`` the gradients of the scene's fields, ``ux``, ``uy``, ...)
    at ``targets`` (M, 2), the MLS fields of saved step ``s`` refitted from its point values
    (the fields the scene lacks filled, :func:`~jaxanm.fsw.physics.complete_fields`)."""
    scene = result.scene
    cloud = build_cloud(scene.geometry)
    model = make_model(scene, cloud)
    points = np.asarray(result.points[s], dtype=np.float64)
    st = cloud_stencils(points, cloud.n_tool, scene.geometry)
    columns = {"u": result.u[s], "v": result.v[s], "T": result.T[s]}
    recorded = [f for f in model.fields if f in columns]  # a pressure is not recorded
    values = np.stack([np.asarray(columns[f], dtype=np.float64) for f in recorded], axis=1)
    nodal = dict(zip(recorded, model.fit_state(values, st).reshape(len(recorded), -1)))
    at = evaluate_stencils(points, cloud.n_tool, scene.geometry, targets, derivatives=derivatives)
    out = {}
    for f in ("u", "v", "T"):
        if f in nodal:
            out[f] = np.asarray(mls.value(at, nodal[f]))
            if derivatives:
                out[f + "x"], out[f + "y"] = np.asarray(mls.grad(at, nodal[f])).T
    return {**out, **complete_fields(out, targets.shape[0], scene.thermal.T0)}


def stored_heat(result, s: int = -1) -> float:
    """``int rho Cp (T - T0) dA`` (J/m) over plate and tool at saved step ``s``."""
    scene = result.scene
    g, m, tl, T0 = scene.geometry, scene.material, scene.tool, scene.thermal.T0
    total = 0.0
    for (r_in, r_out), rho_cp in (((g.R1, g.R2), m.rho * m.Cp), ((0.0, g.R1), tl.rho * tl.Cp)):
        pts, w = annulus_quadrature(r_in, r_out)
        total += float(np.sum(w * rho_cp * (fields_at(result, s, pts)["T"] - T0)))
    return total


def dissipated_power(result, s: int = -1) -> float:
    """``int 3 mu epsbar^2 dA`` (W/m) over the plate of the velocity field at saved step ``s``.

    ``mu = K T^A (epsbar^2 + eps0^2)^((n-1)/2) / 3`` with ``T = T0`` unless the scene has
    ``softening`` (the model's law, :func:`~jaxanm.fsw.physics.viscosity`), ``epsbar^2 = 2/3
    epsdot : epsdot``.
    """
    scene = result.scene
    g, m = scene.geometry, scene.material
    pts, w = annulus_quadrature(g.R1, g.R2)
    f = fields_at(result, s, pts)
    if "ux" not in f:
        return 0.0
    exy = 0.5 * (f["uy"] + f["vx"])
    e2 = (2.0 / 3.0) * (f["ux"] ** 2 + f["vy"] ** 2 + 2.0 * exy ** 2)
    T = f["T"] if scene.has("softening") else scene.thermal.T0
    mu = viscosity(T, e2 + scene.eps0 ** 2, m.K, m.A, m.n)
    return float(np.sum(w * 3.0 * mu * e2))


def tool_torque(result, s: int = -1, angles: int = 720) -> float:
    """The torque (N m/m, per unit thickness) the tool exerts on the plate at saved step ``s``:
    ``-int R1^2 tau_r_theta dtheta`` on the plate's side of the tool edge, ``tau_r_theta = 2 mu
    e_r_theta`` from the one-sided MLS derivatives there and the scene's viscosity law (T at the
    edge with ``softening``).  Times omega it is the tool's mechanical power, which the plastic
    dissipation (:func:`dissipated_power`) and, with ``slip``, the interface's friction take up.
    """
    scene = result.scene
    g, m = scene.geometry, scene.material
    th = 2.0 * math.pi * (np.arange(angles) + 0.5) / angles
    nx, ny = np.cos(th), np.sin(th)
    f = fields_at(result, s, g.R1 * (1.0 + 1e-9) * np.stack([nx, ny], axis=1))
    if "ux" not in f:
        return 0.0
    exy = 0.5 * (f["uy"] + f["vx"])
    e_rt = nx * ny * (f["vy"] - f["ux"]) + exy * (nx * nx - ny * ny)
    e2 = (2.0 / 3.0) * (f["ux"] ** 2 + f["vy"] ** 2 + 2.0 * exy ** 2)
    T = f["T"] if scene.has("softening") else scene.thermal.T0
    mu = viscosity(T, e2 + scene.eps0 ** 2, m.K, m.A, m.n)
    return float(-np.sum(2.0 * mu * e_rt) * g.R1 ** 2 * 2.0 * math.pi / angles)
