"""A manufactured solution of the stationary flow rows, for the order of convergence of the
``incompressible`` formulation on a cloud and its refinements.

The fields, on the plate ``R1 <= r <= R2`` of a scene (SI units, ``omega``, ``U`` the scene's
rotation and travel speeds, U = 0 without ``traverse``)::

    V = w(r) (-y, x) + curl(-U y h(r)),     w(r) = omega ((R2^2 - r^2) / (R2^2 - R1^2))^2,
    h = s^2 (3 - 2 s),  s = (r - R1) / (R2 - R1),
    p = P sin(pi x / R2) cos(pi y / (2 R2)),  P = mu_ref omega / 10,

are smooth, ``div V = 0`` exactly (a rotation of radial profile plus a curl), and they hold
the model's own boundary rows: the rigid turn ``omega (-y, x)`` at r = R1 (w(R1) = omega, h and
h' vanish there) and the stream ``(-U, 0)`` at r = R2 (w = h' = 0, h = 1).  The momentum rows
are held by a body force: the model's rows evaluated on the exact fields, with exact
derivatives (:func:`exact_rows`), are subtracted from the model's residual.  The continuity
rows keep no force (the continuum's ``div V = 0``), so the pressure stabilisation's own
inconsistency is part of the measured error.  The viscosity is the scene's power law at T0.

:func:`errors` solves ``R(x) = R_exact`` by Newton from the exact fields' nodal fit and
returns the largest errors of V and p at the plate points; :func:`observed_orders` fits the
orders against the clouds' point counts.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

import jaxanm

from .. import mls
from ..internal import entry_point
from .discretisation import discretise
from .geometry import PLATE, PLATE_EDGE, TOOL, TOOL_EDGE
from .physics import mu_reference

__all__ = ["errors", "exact_fields", "exact_rows", "observed_orders"]


def exact_fields(scene):
    """``f(x, y) -> (u, v, p)`` of the manufactured solution (module docstring), in jax.numpy."""
    g, om = scene.geometry, scene.tool.omega
    U = scene.tool.traverse_speed if scene.has("traverse") else 0.0
    R1, R2 = g.R1, g.R2
    P = mu_reference(scene) * om / 10.0

    def psi_t(x, y):  # the stream function of the through-flow part (used on the plate, r >= R1)
        r = jnp.sqrt(x * x + y * y + (R1 * 1e-3) ** 2 * (x * x + y * y < R1 * R1))
        s = (r - R1) / (R2 - R1)
        return -U * y * s * s * (3.0 - 2.0 * s)

    def f(x, y):
        r2 = x * x + y * y
        w = om * ((R2 * R2 - r2) / (R2 * R2 - R1 * R1)) ** 2
        dpsi = jax.grad(psi_t, argnums=(0, 1))(x, y)
        u = -w * y + dpsi[1]
        v = w * x - dpsi[0]
        p = P * jnp.sin(math.pi * x / R2) * jnp.cos(0.5 * math.pi * y / R2)
        return jnp.stack([u, v, p])

    return f


def _taylor(f, points: np.ndarray) -> np.ndarray:
    """(3, 6, N): value, d/dx, d/dy, d2/dx2, d2/dxdy, d2/dy2 of the three fields at the points."""
    def one(xy):
        x, y = xy[0], xy[1]
        val = f(x, y)
        grad = jax.jacfwd(f, argnums=(0, 1))(x, y)
        hess = jax.jacfwd(jax.jacfwd(f, argnums=(0, 1)), argnums=(0, 1))(x, y)
        return jnp.stack([val, grad[0], grad[1], hess[0][0], hess[0][1], hess[1][1]], axis=1)

    return np.asarray(jax.vmap(one)(jnp.asarray(points))).transpose(1, 2, 0)


@entry_point
def exact_rows(model, params: dict, f) -> np.ndarray:
    """The model's residual rows evaluated on the fields ``f`` with exact derivatives.

    The residual reads every field through its stencils, ``sum_k w[i, k] x[index[i, k]]``.
    Here each point's stencil has six entries whose weights pick one of six nodal slots (phi
    the first, dx the second, ... dyy the sixth), and the slots hold the fields' exact value
    and derivatives at the point: the stencil sums are then exact.  The five slots beyond the
    points are extra points of the tool kind whose own rows are discarded.
    """
    N = model.cloud.size
    pts = np.asarray(params["xy"])
    taylor = _taylor(f, pts)  # (3, 6, N)
    index = (np.arange(6)[None, :] * N + np.arange(N)[:, None]).astype(np.int32)
    index = np.concatenate([index, np.repeat(np.arange(N, 6 * N, dtype=np.int32)[:, None], 6, axis=1)])
    weights = [jnp.asarray(np.concatenate([np.tile(np.eye(6)[k], (N, 1)), np.zeros((5 * N, 6))])) for k in range(6)]
    st = mls.Stencils(index=jnp.asarray(index), phi=weights[0], dx=weights[1], dy=weights[2], dxx=weights[3],
                      dxy=weights[4], dyy=weights[5])
    order = {"u": 0, "v": 1, "p": 2}
    x = np.concatenate([taylor[order[name]].reshape(-1) for name in model.fields])

    def extend(a, fill):
        return np.concatenate([np.asarray(a), np.full((5 * N,) + np.shape(a)[1:], fill, dtype=np.asarray(a).dtype)])

    p = dict(params, st=st, xy=extend(pts, 0.0), kind=extend(params["kind"], TOOL),
             partner=np.concatenate([np.asarray(params["partner"]), np.arange(N, 6 * N, dtype=np.int32)]),
             normal=extend(params["normal"], 0.0), spacing=extend(params["spacing"], 1.0),
             pin=extend(params["pin"], False))
    one = jnp.float64(1.0)
    rows = np.asarray(model.residual(jnp.asarray(x), jnp.asarray(x), one, one, p)).reshape(len(model.fields), 6 * N)
    return rows[:, :N].reshape(-1)


@entry_point
def errors(scene, tol: float = 1e-10) -> dict:
    """Errors of the discrete stationary flow against the manufactured solution on the scene's
    cloud: ``{"points", "h", "velocity", "pressure", "iterations"}``.

    ``scene``: a scene whose effects are ``viscous``, ``incompressible`` and optionally
    ``traverse`` (with ``tracers``), no inertia.  The discrete problem ``R(x) = R_exact`` (the
    continuity rows' force set to 0) is solved by Newton to ``tol`` from the exact fields'
    nodal fit.  ``velocity``: the largest error of the MLS velocity at the plate points over
    ``omega R1``; ``pressure``: the largest error of the MLS pressure there (the exact pressure
    shifted to vanish at the pinned point) over the range of the exact pressure.
    """
    cloud, st, model, params, _ = discretise(scene)
    f = exact_fields(scene)
    force = exact_rows(model, params, f).reshape(len(model.fields), -1)
    # a body force in the plate's momentum rows only: the boundary rows hold the exact fields
    # already, and the continuum's div V = 0 puts none on the continuity rows
    force[:, cloud.kind != PLATE] = 0.0
    force[model.fields.index("p")] = 0.0
    exact = _taylor(f, cloud.points)[:, 0].copy()  # (3, N) values
    rigid = (cloud.kind == TOOL) | (cloud.kind == TOOL_EDGE)
    exact[2] = np.where(rigid, 0.0, exact[2] - exact[2][np.asarray(params["pin"])][0])
    om = scene.tool.omega
    exact[0] = np.where(rigid, -om * cloud.points[:, 1], exact[0])
    exact[1] = np.where(rigid, om * cloud.points[:, 0], exact[1])
    x0 = model.fit_state(exact.T, st)
    flat = jnp.asarray(force.reshape(-1))

    def residual(x, x_old, t, dt, p):
        return model.residual(x, x_old, t, dt, p) - flat

    sol = jaxanm.integrate(residual, x0, params, t0=0.0, t1=1.0, dt=1.0, solver=jaxanm.Newton(tol=tol),
                           scale=model.scale(), jacobian="sparse", sparsity=model.sparsity)
    values = model.values(sol.xs[-1], st).T
    plate = cloud.kind >= PLATE_EDGE
    dv = np.hypot(values[0] - exact[0], values[1] - exact[1])[plate].max() / (om * scene.geometry.R1)
    span = exact[2][plate].max() - exact[2][plate].min()
    dp = np.abs(values[2] - exact[2])[plate].max() / span
    return {"points": cloud.size, "h": math.sqrt(math.pi * scene.geometry.R2 ** 2 / cloud.size),
            "velocity": float(dv), "pressure": float(dp), "iterations": sol.stats.newton_iterations}


def observed_orders(rows: list) -> dict:
    """Least-squares slopes of log error against log h (h = sqrt(pi R2^2 / N)) over ``rows``
    (dicts of :func:`errors`): ``{"velocity": order, "pressure": order}``."""
    h = np.log([r["h"] for r in rows])
    return {k: float(np.polyfit(h, np.log([r[k] for r in rows]), 1)[0]) for k in ("velocity", "pressure")}
