"""The FSW physics: the rows of the step residual (strong-form MLS collocation of the effects a
scene lists) and the constitutive laws, each once.

Unknowns are the MLS nodal parameters of the fields the effects need, stacked field by field
in a flat vector ``[u (N), v (N), T (N)]`` (an isothermal scene has only ``[u, v]``, a pure
conduction scene only ``[T]``).  Values and derivatives at the collocation points (every point
of the cloud) come from the stencils: ``sum_k w[i, k] f[index[i, k]]``.

Momentum (effect ``viscous``, paper eqs. 1, 2, 8-10), written pointwise with second
derivatives so that the Jacobian is one stencil wide::

    rho dV/dt = div sigma = (lambda + mu) grad(div V) + mu Lap V + 2 epsdot . grad mu
    mu = K T^A epsbar_reg^(n-1) / 3,   epsbar_reg^2 = epsbar^2 + eps0^2,
    epsbar^2 = 2/3 epsdot : epsdot,
    grad mu = mu [ (n-1)/2 grad(epsbar^2) / epsbar_reg^2 + A grad T / T ]

The momentum rows are this balance divided by the local viscosity mu (> 0), which leaves the
discrete solution unchanged but removes the factor mu ~ epsbar^(n-1) that spans orders of
magnitude: ``div sigma / mu = (lambda/mu + 1) grad div V + Lap V + 2 epsdot . grad(ln mu)`` is
(for eps0 -> 0 and lambda = 0) homogeneous of degree one in V.  Measured on the isothermal
Couette flow: with the balance itself, Newton diverges for n = 0.3 even from the n = 0.4
solution (the concave stress epsbar^n makes it overshoot where the flow is slow); divided by
mu, it converges from rest for n = 0.3 (9 iterations) and n = 0.1324 (17) at the paper's dr.

Heat (effect ``conduction``, eq. 4-6)::

    rho Cp dT/dt = k Lap T + 3 beta mu epsbar^2          (plate; tool: rho_t, Cp_t, k_t, no source)

``d/dt`` is the implicit Euler difference at material points: with ``lagrangian`` the points
move and the old values are those the points carry; with ``tracers`` (fixed points) the
transport terms ``V . grad`` are added; with neither, points are fixed and there is no
transport term.

Rows per point kind (see :mod:`jaxanm.fsw.geometry`):

============  ====================================  ============================================
kind          velocity rows                         temperature row
============  ====================================  ============================================
TOOL          V = omega (-y, x)                     tool heat equation (or T = T0)
TOOL_EDGE     V = omega (-y, x)                     T_tool = T_plate (or T = T0)
PLATE_EDGE    V = omega (-y, x) (sticking)          k dT/dr = k_t dT_tool/dr (or k dT/dr = 0),
                                                    or the edge half-cell balance (below)
PLATE         momentum balance                      plate heat equation
RING          V = 0                                 -k dT/dN = h (T - Ta) (or dT/dN = 0)
============  ====================================  ============================================

(alternatives in brackets when ``tool_conduction`` / ``robin`` are absent).  With ``slip`` the
plate edge moves at ``delta omega (-y, x)`` and its temperature row gains the interface's
frictional heat (:func:`_friction_heat`); with ``shoulder`` the plate's heat equation gains the
source ``q_sh / H`` under the shoulder (r <= R_sh); with ``traverse`` the ring moves at (-U_tr, 0) and its
row gains the inflow term ``rho Cp max(-V.N, 0) (T - T0)`` (docs/notes/traverse_and_slip.md).  The coincident
tool-edge / plate-edge pair makes the conductivity jump exact in strong form: each side has
its own one-sided approximation, and the pair carries the two interface conditions.

Edge rows (``scene.thermal.edge_rows``).  ``"flux"`` (the default) collocates the flux condition alone at
the plate-edge points, so the heat equation is collocated nowhere within half a spacing of the
tool edge, and the heat the flow dissipates there never enters the discrete balance.  With the
paper's n = 0.1324 the dissipation ``q ~ r^-17`` lies almost all in that layer: the plate-edge
points carry 0.5-0.75 of the dissipated power (nodal quadrature) and the run stores only
0.65-0.85 of ``beta P t`` after one step, about 0.6 after 20 ms
(docs/notes/energy_balance.md).  ``"half_cell"`` replaces the flux row by the heat balance of
the edge cell ``[R1 - d, R1 + d]``, ``d = dr / 2`` (the plate half cell, plus the tool half
cell with ``tool_conduction``), its outer and inner face fluxes expanded to first order about
r = R1::

    d (rho Cp dT/dt - k Lap T - q) + d (rho_t Cp_t dT/dt - k_t Lap T_tool) = k dT/dr - k_t dT_tool/dr
    (insulated tool: d (rho Cp dT/dt - k Lap T - q) = k dT/dr)

with the source and both heat equations at the edge points.  It reduces to the flux
condition as dr -> 0, keeps the edge half cell's heat capacity and source in the balance, and
is stable where the flux rows are not (the insulated edge; docs/notes/energy_balance.md).
It relies on the one-sided MLS Laplacian at the edge points, which converges with the FSW
scenes' weight c = 0.3 but not with c = 0.2 (conduction_small then stalls at ~2e-3 of the
range); so the FSW scenes (c = 0.3) choose it and the default stays ``"flux"``.

Rows are scaled to comparable magnitudes (the discrete solution does not depend on it): Dirichlet rows by the
field scale, balance rows by their largest diagonal term, flux rows by ``k T_s / dr``.

The residual is jet-compatible: gathers, ``.at``-free elementwise algebra, ``jnp.where`` and
non-integer powers only of strictly positive quantities (``epsbar_reg^2 >= eps0^2 > 0``,
``T > 0``).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from .. import mls
from .effects import CONSTANTS, Effects
from .geometry import PLATE, PLATE_EDGE, RING, TOOL, TOOL_EDGE
from .scene import Scene

__all__ = ["CONSTANTS", "Effects", "complete_fields", "mu_reference", "residual_for", "viscosity"]


def mu_reference(scene: Scene) -> float:
    """Viscosity scale ``K T0^A omega^(n-1) / 3`` (Pa s): mu at T0 and strain rate omega."""
    m, th, tl = scene.material, scene.thermal, scene.tool
    return m.K * th.T0 ** m.A * tl.omega ** (m.n - 1) / 3


def viscosity(T, er2, K, A, n):
    """The viscosity law ``mu = K T^A epsbar_reg^(n-1) / 3`` (Pa s) at temperature ``T`` and
    ``er2 = epsbar_reg^2 = epsbar^2 + eps0^2``; numpy or jax arrays (the residual's own law)."""
    return K / 3.0 * T ** A * er2 ** (0.5 * (n - 1.0))


def complete_fields(values: dict, n: int | tuple, T0, xp=np) -> dict:
    """``{"u", "v", "T"}`` at n points (or of array shape n) from the fields a scene has
    (``values``), those it lacks filled as the model holds them: V = 0 without ``viscous``,
    T = T0 without ``conduction`` (``xp``: numpy, or ``jax.numpy`` inside traced code)."""
    zero = xp.zeros(n)
    return {"u": values.get("u", zero), "v": values.get("v", zero), "T": values.get("T", zero + T0)}


def _gather(st: mls.Stencils, f, weights):
    """Values of several stencil operators applied to nodal parameters ``f`` (N,)."""
    g = f[st.index]
    return [jnp.sum(w * g, axis=1) for w in weights]


def _old_value(st, fold):
    """Value at the points, at the previous time level, of a field with old nodal parameters ``fold``.

    Fixed points: the old nodal parameters on the (unchanged) stencils.  Lagrangian points: the
    run refits the nodal parameters to the values the points carry each time it rebuilds the
    stencils (:meth:`Model.fit_state`), so the old parameters on the current stencils are
    those carried values.
    """
    return _gather(st, fold, [st.phi])[0]


def _momentum_rows(flags: Effects, st, p, dt, vel_nodal, vel_old_nodal, temp, pressure):
    """u and v rows, velocity, ``mu epsbar^2`` and its gradient at the points (the dissipation),
    and the continuity rows (``incompressible``, else None).

    ``pressure``: p, its gradient and Laplacian at the points (``incompressible``, else None)."""
    c, kind = p["c"], p["kind"]
    ops = [st.phi, st.dx, st.dy, st.dxx, st.dxy, st.dyy]
    u, ux, uy, uxx, uxy, uyy = _gather(st, vel_nodal[0], ops)
    v, vx, vy, vxx, vxy, vyy = _gather(st, vel_nodal[1], ops)
    exx, eyy, exy = ux, vy, 0.5 * (uy + vx)
    e2 = (2.0 / 3.0) * (exx * exx + eyy * eyy + 2.0 * exy * exy)
    er2 = e2 + c["eps0"] ** 2
    mu = viscosity(temp[0] if flags.softening else c["T0"], er2, c["K"], c["A"], c["n"])
    # grad(ln mu) by the chain rule, from second derivatives of V (and grad T)
    exy_x, exy_y = 0.5 * (uxy + vxx), 0.5 * (uyy + vxy)
    de2x = (4.0 / 3.0) * (exx * uxx + eyy * vxy + 2.0 * exy * exy_x)
    de2y = (4.0 / 3.0) * (exx * uxy + eyy * vyy + 2.0 * exy * exy_y)
    lx = 0.5 * (c["n"] - 1.0) * de2x / er2
    ly = 0.5 * (c["n"] - 1.0) * de2y / er2
    if flags.softening:
        T, Tx, Ty = temp[:3]
        lx = lx + c["A"] * Tx / T
        ly = ly + c["A"] * Ty / T
    # div sigma / mu (see the module docstring)
    lam_mu = c["lam"] / mu
    fx = (lam_mu + 1.0) * (uxx + vxy) + (uxx + uyy) + 2.0 * (exx * lx + exy * ly)
    fy = (lam_mu + 1.0) * (uxy + vyy) + (vxx + vyy) + 2.0 * (exy * lx + eyy * ly)
    if flags.incompressible:  # sigma = -p I + 2 mu epsdot (the penalty is 0: scene validation)
        fx = fx - pressure[1] / mu
        fy = fy - pressure[2] / mu
    stiff = 1.0 + c["lam"] / c["mu_ref"]
    if flags.inertia:
        ax = (u - _old_value(st, vel_old_nodal[0])) / dt
        ay = (v - _old_value(st, vel_old_nodal[1])) / dt
        if flags.tracers:
            ax = ax + u * ux + v * uy
            ay = ay + u * vx + v * vy
        fx = fx - c["rho"] / mu * ax
        fy = fy - c["rho"] / mu * ay
        stiff = stiff + c["rho"] * c["dr"] ** 2 / (c["mu_ref"] * dt)
    sm = c["dr"] ** 2 / (c["U"] * stiff)
    xy = p["xy"]
    # the edge velocity: the tool's rigid turn, the plate edge's delta times it (slip)
    turn = jnp.where(kind == PLATE_EDGE, c["delta"], 1.0) * c["omega"] if flags.slip else c["omega"]
    ub, vb = -turn * xy[:, 1], turn * xy[:, 0]
    plate, ring = kind == PLATE, kind == RING
    # the ring moves at (-U_tr, 0) when the tool travels (the plate streaming past it)
    ring_u = u + c["U_tr"] if flags.traverse else u
    rows = [jnp.where(plate, -fx * sm, jnp.where(ring, ring_u, u - ub) / c["U"]),
            jnp.where(plate, -fy * sm, jnp.where(ring, v, v - vb) / c["U"])]
    # grad(mu epsbar^2) = mu (grad epsbar^2 + epsbar^2 grad ln mu): the source's local decay
    grad_mu_e2 = (mu * (de2x + e2 * lx), mu * (de2y + e2 * ly))
    friction = _friction_heat(c, p["normal"], xy, mu, exx, eyy, exy) if flags.slip else None
    continuity = _continuity_rows(p, ux + vy, mu, pressure) if flags.incompressible else None
    return rows, (u, v), (mu * e2, grad_mu_e2, friction), continuity


def _continuity_rows(p, div, mu, pressure):
    """The pressure rows (``incompressible``): ``div V = alpha h^2 / mu_ref Lap p`` at every plate
    point (edge and ring included: one-sided derivatives there), ``p = 0`` in the tool (rigid,
    no pressure needed) and at the one plate point ``p["pin"]`` that fixes the pressure's level
    (only its gradient enters the momentum rows).  Scaled by ``dr / U`` (continuity) and by the
    stress scale ``mu_ref omega`` (``p = 0``).

    ``alpha = c["alpha_p"]`` (``mechanics.pressure_stabilisation``) is Brezzi and Pitkaranta's
    stabilisation, ``h`` the local point spacing, ``mu_ref`` the viscosity scale (the local mu
    would weaken it in the slow, stiff zones where the mode lives, and strengthen it next to
    the tool, where it costs accuracy): without it, equal-order MLS collocation has a
    pressure mode that alternates from ring to ring where the rings are coarse, invisible to the
    momentum rows (a quadratic fit has no gradient at a point whose neighbours on both sides
    carry the opposite value) and to the continuity rows.  Its measurements (the pressure Schur
    complement's smallest singular value, the flux error it adds): docs/notes/traverse_and_slip.md."""
    c, kind = p["c"], p["kind"]
    h = p["spacing"]
    row = (div - c["alpha_p"] * h * h / c["mu_ref"] * pressure[3]) * (c["dr"] / c["U"])
    return jnp.where((kind == TOOL) | (kind == TOOL_EDGE) | p["pin"], pressure[0] / (c["mu_ref"] * c["omega"]), row)


def _friction_heat(c, normal, xy, mu, exx, eyy, exy):
    """Frictional heat flux (W/m^2) released at the tool edge by slip, at every point (used at
    the plate-edge points): ``(1 - delta) omega r`` (the sliding speed) times the shear stress
    the tool exerts on the plate, ``-tau_r_theta = -2 mu e_r_theta`` (the plate's outward normal
    at its edge is -e_r).  Signed: it is the power the interface shear does on the slip, so
    that torque x omega = plastic dissipation + this heat holds exactly in the continuum.
    """
    nx, ny = normal[:, 0], normal[:, 1]
    e_rt = nx * ny * (eyy - exx) + exy * (nx * nx - ny * ny)
    r = nx * xy[:, 0] + ny * xy[:, 1]  # the radius (0 at the centre, whose normal is 0)
    return (1.0 - c["delta"]) * c["omega"] * r * (-2.0 * mu * e_rt)


def _edge_source_width(d, q, dq_dn):
    """Width ``int_0^d exp(-s / lam) ds`` over which the edge half cell collects ``q(R1)``.

    ``1 / lam = -dq_dn / q`` is the source's local decay along the outward normal, from the MLS
    derivatives at the plate-edge point; the width is ``d (1 - exp(-x)) / x`` with
    ``x = d / lam``.  A source that does not decay there (x <= 0, or q = 0 at rest) is counted
    over the whole half cell ``d``, as the one-point quadrature does.
    """
    x = jnp.where(q > 0, -d * dq_dn / jnp.where(q > 0, q, 1.0), 0.0)
    x = jnp.where(x > 0, x, 0.0)
    # (1 - exp(-x)) / x, by its Taylor polynomial where the quotient loses digits (error < x^3 / 24)
    small = x < 1e-3
    x_safe = jnp.where(small, 1.0, x)
    return d * jnp.where(small, 1.0 - x / 2.0 + x * x / 6.0, -jnp.expm1(-x_safe) / x_safe)


def _heat_rows(flags: Effects, edge_rows: str, edge_source: str, st, p, dt, T_old_nodal, temp, vel,
               source):
    """T rows: heat equations, tool-edge interface conditions, the ring's edge condition.

    ``source`` is ``(mu epsbar^2, grad(mu epsbar^2))`` at the points (None without ``viscous``).
    """
    c, kind, partner, normal = p["c"], p["kind"], p["partner"], p["normal"]
    T, Tx, Ty, lapT = temp
    dTdt = (T - _old_value(st, T_old_nodal)) / dt
    if flags.tracers:
        dTdt = dTdt + vel[0] * Tx + vel[1] * Ty
    plate_heat = c["rho"] * c["Cp"] * dTdt - c["k"] * lapT
    if flags.dissipation:
        plate_heat = plate_heat - 3.0 * c["beta"] * source[0]
    if flags.shoulder:  # the shoulder's heat input per area over the plate's thickness, r <= R_sh
        xy = p["xy"]
        under = xy[:, 0] * xy[:, 0] + xy[:, 1] * xy[:, 1] <= c["R_sh"] * c["R_sh"]
        plate_heat = plate_heat - jnp.where(under, c["q_sh"] / c["H"], 0.0)
    s_plate = c["dr"] ** 2 / (c["Ts"] * (c["k"] + c["rho"] * c["Cp"] * c["dr"] ** 2 / dt))
    dTdn = Tx * normal[:, 0] + Ty * normal[:, 1]
    s_flux = c["dr"] / (c["k"] * c["Ts"])
    ring_row = c["k"] * dTdn
    if flags.robin:
        ring_row = ring_row + c["h"] * (T - c["Ta"])
    if flags.traverse:
        # inflow (the ring's velocity (-U_tr, 0) entering, V.N = -U_tr N_x < 0): the plate carries
        # T0 in, -k dT/dN = rho Cp |V.N| (T - T0) added to the edge's own condition (Danckwerts)
        inflow = jnp.maximum(c["U_tr"] * normal[:, 0], 0.0)
        ring_row = ring_row + c["rho"] * c["Cp"] * inflow * (T - c["T0"])
    if flags.tool_conduction:
        tool_heat = c["rho_t"] * c["Cp_t"] * dTdt - c["k_t"] * lapT
        s_tool = c["dr"] ** 2 / (c["Ts"] * (c["k_t"] + c["rho_t"] * c["Cp_t"] * c["dr"] ** 2 / dt))
        tool_row = tool_heat * s_tool
        tool_edge_row = (T - T[partner]) / c["Ts"]
        edge_flux = c["k"] * dTdn - c["k_t"] * dTdn[partner]
    else:
        tool_row = tool_edge_row = (T - c["T0"]) / c["Ts"]
        edge_flux = c["k"] * dTdn
    if edge_rows == "half_cell":
        # heat balance of the edge cell [R1 - d, R1 + d] (module docstring), scaled like a
        # flux row plus the half cell's heat capacity
        d = 0.5 * c["dr"]
        stored = d * plate_heat + (d * tool_heat[partner] if flags.tool_conduction else 0.0)
        if flags.dissipation and edge_source == "exponential":
            # the source over [R1, R1 + d] along its local decay instead of q(R1) d
            q, (qx, qy) = source[:2]
            width = _edge_source_width(d, q, qx * normal[:, 0] + qy * normal[:, 1])
            stored = stored + (d - width) * 3.0 * c["beta"] * q
        s_edge = 1.0 / (c["Ts"] * (c["k"] / c["dr"] + d * c["rho"] * c["Cp"] / dt))
        if flags.slip:  # the interface's frictional heat enters the edge cell
            stored = stored - source[2]
        plate_edge_row = (stored - edge_flux) * s_edge
    else:
        # flux balance at the interface: what the plate and tool conduct away is the friction heat
        plate_edge_row = (edge_flux + source[2] if flags.slip else edge_flux) * s_flux
    return jnp.select(
        [kind == TOOL, kind == TOOL_EDGE, kind == PLATE_EDGE, kind == PLATE, kind == RING],
        [tool_row, tool_edge_row, plate_edge_row, plate_heat * s_plate, ring_row * s_flux])


@functools.lru_cache(maxsize=None)
def residual_for(flags: Effects, edge_rows: str, edge_source: str):
    """The residual function of an effect combination (one function object per combination)."""
    nf = len(flags.fields)
    at = {f: i for i, f in enumerate(flags.fields)}

    def residual(x, x_old, t, dt, p):
        """Implicit-Euler step residual (scaled rows, layout of ``flags.fields``)."""
        st = p["st"]
        N = p["kind"].shape[0]
        X, Xo = x.reshape(nf, N), x_old.reshape(nf, N)
        rows, vel, source, continuity = [], None, None, None
        second = [st.phi, st.dx, st.dy, st.dxx + st.dyy]
        temp = _gather(st, X[at["T"]], second) if flags.conduction else None
        pressure = _gather(st, X[at["p"]], second) if flags.incompressible else None
        if flags.viscous:
            rows, vel, source, continuity = _momentum_rows(flags, st, p, dt, X[:2], Xo[:2], temp, pressure)
        if flags.conduction:
            rows.append(_heat_rows(flags, edge_rows, edge_source, st, p, dt, Xo[at["T"]], temp, vel, source))
        if continuity is not None:
            rows.append(continuity)
        return jnp.concatenate(rows)

    return residual


