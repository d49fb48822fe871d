"""The FSW step residual: strong-form MLS collocation of the effects a scene lists.

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

(alternatives in brackets when ``tool_conduction`` / ``robin`` are absent).  The coincident
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

import dataclasses
import functools
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
import scipy.sparse

from .. import mls
from ..linalg import sparse_lu
from .geometry import PLATE, PLATE_EDGE, RING, TOOL, TOOL_EDGE, Cloud, build_cloud, build_stencils
from .scene import Scene

__all__ = ["Discretisation", "Effects", "Model", "Refit", "complete_fields", "discretise", "make_model",
           "mu_reference", "rigid", "viscosity"]

CONSTANTS = ("K", "A", "n", "eps0", "rho", "Cp", "k", "beta", "rho_t", "Cp_t", "k_t", "omega",
             "h", "Ta", "T0", "lam", "dr", "U", "Ts", "mu_ref")
"""Scalars of ``params["c"]``: material, tool, thermal data, penalty and the scales."""


class Effects(NamedTuple):
    """Which terms the residual assembles (static: a new combination compiles a new residual)."""

    viscous: bool
    inertia: bool
    softening: bool
    conduction: bool
    tool_conduction: bool
    dissipation: bool
    robin: bool
    lagrangian: bool
    tracers: bool

    @classmethod
    def of(cls, scene: Scene) -> "Effects":
        """The effect flags of a scene."""
        return cls(*(scene.has(name) for name in cls._fields))

    @property
    def fields(self) -> tuple:
        """Unknown fields, in layout order."""
        return (("u", "v") if self.viscous else ()) + (("T",) if self.conduction else ())


def mu_reference(scene: Scene) -> float:
    """Viscosity scale ``K T0^A omega^(n-1) / 3`` (Pa s): mu at T0 and strain rate omega."""
    m, th, tl = scene.material, scene.thermal, scene.tool
    return m.K * th.T0 ** m.A * tl.omega ** (m.n - 1) / 3


def viscosity(T, er2, K, A, n):
    """The viscosity law ``mu = K T^A epsbar_reg^(n-1) / 3`` (Pa s) at temperature ``T`` and
    ``er2 = epsbar_reg^2 = epsbar^2 + eps0^2``; numpy or jax arrays (the residual's own law)."""
    return K / 3.0 * T ** A * er2 ** (0.5 * (n - 1.0))


def rigid(kind: np.ndarray) -> np.ndarray:
    """Points that turn with the tool: the tool and both sides of its edge (sticking)."""
    return (kind == TOOL) | (kind == TOOL_EDGE) | (kind == PLATE_EDGE)


def complete_fields(values: dict, n: int, T0, xp=np) -> dict:
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


def _momentum_rows(flags: Effects, st, p, dt, vel_nodal, vel_old_nodal, temp):
    """u and v rows, velocity, and ``mu epsbar^2`` and its gradient at the points (the dissipation)."""
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
    ub, vb = -c["omega"] * xy[:, 1], c["omega"] * xy[:, 0]
    plate, ring = kind == PLATE, kind == RING
    rows = [jnp.where(plate, -fx * sm, jnp.where(ring, u, u - ub) / c["U"]),
            jnp.where(plate, -fy * sm, jnp.where(ring, v, v - vb) / c["U"])]
    # grad(mu epsbar^2) = mu (grad epsbar^2 + epsbar^2 grad ln mu): the source's local decay
    grad_mu_e2 = (mu * (de2x + e2 * lx), mu * (de2y + e2 * ly))
    return rows, (u, v), (mu * e2, grad_mu_e2)


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
    s_plate = c["dr"] ** 2 / (c["Ts"] * (c["k"] + c["rho"] * c["Cp"] * c["dr"] ** 2 / dt))
    dTdn = Tx * normal[:, 0] + Ty * normal[:, 1]
    s_flux = c["dr"] / (c["k"] * c["Ts"])
    ring_row = c["k"] * dTdn
    if flags.robin:
        ring_row = ring_row + c["h"] * (T - c["Ta"])
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
            q, (qx, qy) = source
            width = _edge_source_width(d, q, qx * normal[:, 0] + qy * normal[:, 1])
            stored = stored + (d - width) * 3.0 * c["beta"] * q
        s_edge = 1.0 / (c["Ts"] * (c["k"] / c["dr"] + d * c["rho"] * c["Cp"] / dt))
        plate_edge_row = (stored - edge_flux) * s_edge
    else:
        plate_edge_row = edge_flux * s_flux
    return jnp.select(
        [kind == TOOL, kind == TOOL_EDGE, kind == PLATE_EDGE, kind == PLATE, kind == RING],
        [tool_row, tool_edge_row, plate_edge_row, plate_heat * s_plate, ring_row * s_flux])


@functools.lru_cache(maxsize=None)
def _residual_for(flags: Effects, edge_rows: str, edge_source: str):
    """The residual function of an effect combination (one function object per combination)."""
    nf = len(flags.fields)

    def residual(x, x_old, t, dt, p):
        """Implicit-Euler step residual (scaled rows, layout of ``flags.fields``)."""
        st = p["st"]
        N = p["kind"].shape[0]
        X, Xo = x.reshape(nf, N), x_old.reshape(nf, N)
        rows, vel, source = [], None, None
        temp = _gather(st, X[-1], [st.phi, st.dx, st.dy, st.dxx + st.dyy]) if flags.conduction else None
        if flags.viscous:
            rows, vel, source = _momentum_rows(flags, st, p, dt, X[:2], Xo[:2], temp)
        if flags.conduction:
            rows.append(_heat_rows(flags, edge_rows, edge_source, st, p, dt, Xo[-1], temp, vel, source))
        return jnp.concatenate(rows)

    return residual


@dataclasses.dataclass(frozen=True)
class Model:
    """The discrete FSW model of a scene on a cloud: residual, layout, scales, sparsity.

    ``residual(x_new, x_old, t_new, dt, params)`` is the implicit-Euler step residual in the
    contract of :func:`jaxanm.integrate`; ``params`` comes from :meth:`params`.
    """

    scene: Scene
    effects: Effects
    cloud: Cloud

    @property
    def fields(self) -> tuple:
        """Unknown fields in layout order, e.g. ``("u", "v", "T")``."""
        return self.effects.fields

    @property
    def residual(self):
        """The step residual (one function object per effect combination: no recompiles)."""
        th = self.scene.thermal
        return _residual_for(self.effects, th.edge_rows, th.edge_source)

    @property
    def size(self) -> int:
        """Number of unknowns ``len(fields) * N``."""
        return len(self.fields) * self.cloud.size

    def constants(self) -> dict:
        """``params["c"]``: the scalars of :data:`CONSTANTS` as float64 numpy scalars.

        Scales: velocity ``U = omega R1``; temperature ``Ts = T0`` (see :meth:`scale`);
        viscosity ``mu_ref`` (:func:`mu_reference`).
        """
        s = self.scene
        m, tl, th, g = s.material, s.tool, s.thermal, s.geometry
        values = dict(K=m.K, A=m.A, n=m.n, eps0=m.eps0, rho=m.rho, Cp=m.Cp, k=m.k, beta=m.beta,
                      rho_t=tl.rho, Cp_t=tl.Cp, k_t=tl.k, omega=tl.omega, h=th.h, Ta=th.Ta,
                      T0=th.T0, lam=s.mechanics.penalty, dr=g.dr, U=tl.omega * g.R1, Ts=th.T0,
                      mu_ref=mu_reference(s))
        return {k: np.float64(values[k]) for k in CONSTANTS}

    def params(self, points: np.ndarray, stencils: mls.Stencils) -> dict:
        """The residual's parameter pytree for the cloud at ``points`` with ``stencils``."""
        points = np.asarray(points, dtype=np.float64)
        r = np.hypot(points[:, 0], points[:, 1])
        normal = np.where(r[:, None] > 0, points / np.where(r > 0, r, 1.0)[:, None], 0.0)
        p = {"st": stencils, "c": self.constants(), "xy": points, "kind": self.cloud.kind,
             "partner": self.cloud.partner, "normal": normal}
        return p

    def initial_values(self, points: np.ndarray) -> np.ndarray:
        """Initial field values (N, len(fields)): the tool (and its edge) turning, plate at rest, T0."""
        sc, kind = self.scene, self.cloud.kind
        sticking = rigid(kind)
        omega = sc.tool.omega
        cols = {"u": np.where(sticking, -omega * points[:, 1], 0.0),
                "v": np.where(sticking, omega * points[:, 0], 0.0),
                "T": np.full(len(kind), sc.thermal.T0)}
        return np.stack([cols[f] for f in self.fields], axis=1)

    def fit_state(self, values: np.ndarray, stencils: mls.Stencils, refit: "Refit | None" = None,
                  guess: np.ndarray | None = None) -> np.ndarray:
        """Unknowns whose MLS values at the stencils' points are ``values`` (N, len(fields)).

        MLS is not interpolating: the value matrix ``Phi[i, index[i, k]] = phi[i, k]`` is not the
        identity.  After a Lagrangian move the rebuilt stencils change ``Phi``; solving
        ``Phi x_f = values_f`` (one sparse LU of ``Phi``, shared by the fields) gives the state
        that carries the points' values onto the new stencils, so the next step's residual holds
        only the physical change.  With ``refit`` (a :class:`Refit` kept across the steps of a
        run) the solve iterates on an earlier factorisation instead of a new one, to round-off,
        from ``guess`` (flat unknowns, e.g. the state these values came from) if given.
        Flattened in the layout of :attr:`fields`.
        """
        values = np.asarray(values, dtype=np.float64)
        if refit is None:
            fitted = sparse_lu(mls.value_matrix(stencils)).solve(values)
        else:
            start = None if guess is None else np.asarray(guess, dtype=np.float64).reshape(values.shape[::-1]).T
            fitted = refit.solve(values, stencils, start)
        return fitted.T.reshape(-1).copy()

    def initial_state(self, points: np.ndarray) -> np.ndarray:
        """Initial unknowns: nodal parameters equal to :meth:`initial_values`, flattened."""
        return self.initial_values(points).T.reshape(-1).copy()

    def scale(self) -> np.ndarray:
        """Characteristic magnitude of each unknown: ``omega R1`` for u, v and ``T0`` for T.

        The ANM validity range (eq. 26) and Newton's convergence test use ``x / scale``.
        T is measured by T0 because the viscosity depends on it through ``(T/T0)^A``: a relative
        change of T/T0 changes mu, hence V/(omega R1), by the same relative order, so the two
        non-dimensional fields weigh alike in the series norms.  (The temperature *rise* is of
        the same order as T0 here, hundreds of kelvin.)
        """
        sc, N = self.scene, self.cloud.size
        per = {"u": sc.tool.omega * sc.geometry.R1, "v": sc.tool.omega * sc.geometry.R1,
               "T": sc.thermal.T0}
        return np.concatenate([np.full(N, per[f]) for f in self.fields])

    def sparsity(self, params: dict) -> scipy.sparse.csr_matrix:
        """Jacobian pattern: row i couples to the stencil of i (and of its edge partner), all fields."""
        index = np.asarray(params["st"].index)
        partner = np.asarray(params["partner"])
        N, m = index.shape
        cols = np.concatenate([index, index[partner]], axis=1)
        rows = np.repeat(np.arange(N), 2 * m)
        point = scipy.sparse.csr_matrix((np.ones(rows.size, dtype=bool), (rows, cols.reshape(-1))),
                                        shape=(N, N))
        nf = len(self.fields)
        return scipy.sparse.kron(np.ones((nf, nf), dtype=bool), point, format="csr")

    def split(self, x) -> dict:
        """Nodal parameters per field: ``{"u": (N,), ...}`` from the flat unknowns ``x``."""
        X = np.asarray(x).reshape(len(self.fields), self.cloud.size)
        return dict(zip(self.fields, X))

    def full_values(self, values: np.ndarray) -> dict:
        """``{"u", "v", "T"}`` from field values (..., len(fields)), e.g. (M,) at M points or
        (S, M) at S saved steps, the fields the scene lacks filled (:func:`complete_fields`)."""
        return complete_fields(dict(zip(self.fields, np.moveaxis(values, -1, 0))), values.shape[:-1],
                               self.scene.thermal.T0)

    def values(self, x, stencils: mls.Stencils) -> np.ndarray:
        """Field values at the stencils' points, (M, len(fields)), from the unknowns ``x``.

        On the host in numpy (the gathers of :func:`jaxanm.mls.value`, without a device
        dispatch per field: this runs after every step).
        """
        X = np.asarray(x, dtype=np.float64).reshape(len(self.fields), self.cloud.size)
        return _stencil_values(np.asarray(stencils.index), np.asarray(stencils.phi), X.T)


def _value_csr(index: np.ndarray, phi: np.ndarray, n_nodes: int) -> scipy.sparse.csr_matrix:
    """The stencils' value operator ``Phi[i, index[i, k]] = phi[i, k]`` as CSR, straight from the
    (M, m) arrays (m entries a row; padding entries add zeros)."""
    M, m = index.shape
    return scipy.sparse.csr_matrix((phi.reshape(-1), index.reshape(-1), np.arange(0, M * m + 1, m)),
                                   shape=(M, n_nodes))


def _stencil_values(index: np.ndarray, phi: np.ndarray, nodal: np.ndarray) -> np.ndarray:
    """``sum_k phi[i, k] nodal[index[i, k], f]``: values (M, F) of nodal parameters (N, F).

    As one sparse product (:func:`_value_csr`), 2x faster than numpy gathers per field (on
    fsw_paper: 0.08 against 0.17 ms); the sums run in stencil order, so the values change
    from the gathers' pairwise sums by round-off only."""
    return _value_csr(index, phi, nodal.shape[0]) @ nodal


class Refit:
    """Refits of a Lagrangian run's state, preconditioned by an earlier factorisation.

    The value matrix ``Phi`` of the stencils changes little from one step to the next (the
    points move by ``dt V``), so :meth:`solve` runs preconditioned Richardson iterations
    ``x <- x + LU0^{-1} (values - Phi x)`` with the SuperLU factors ``LU0`` of an earlier
    ``Phi`` instead of factorising each step's matrix.  Each iteration shrinks the error by
    the spectral radius of ``I - LU0^{-1} Phi`` (fsw_paper: 0.0044 with the previous step's
    factors, growing with their age), so the error left after a correction ``dx`` is about
    ``rate / (1 - rate) |dx|`` with ``rate`` the ratio of the last two corrections.  The
    iterations stop when that is below ``tol`` times ``max |x|`` (per field; 1e-15, five ulps:
    the direct solve's own error is ``cond(Phi) eps``, cond ~ 3), so the result is the direct
    solve's to round-off.  The current ``Phi`` is factorised when the iterations did not
    converge within ``max_iter`` (then it is solved directly), or needed more than
    ``refresh`` (for the next steps: the factors have aged).  The first solve factorises.

    The iterations start from a given ``start`` (a Lagrangian run passes the state it just
    solved, whose values on the previous stencils are ``values``: it is off by one step's
    change of ``Phi``) or else from ``LU0^{-1} values`` (off by the change since ``LU0``, and
    one solve more).  ``refresh`` = 7 balances the two costs: on 60 steps of fsw_paper
    (replayed, with rezonings) 6.2 solves a step and a factorisation every 7.5 steps, against
    6.9 and one every 4 steps with the previous start and ``refresh`` = 6 (0.22 ms a solve,
    2.5-5 ms a factorisation), each result within 3e-15 of the direct solve's (per field,
    relative to max |x|).  Before: a SuperLU factorisation every step
    (docs/profile_host_step.md).

    Pickles as the factorised matrix (the factors are remade from it on load, bit-identically,
    so a resumed run refits exactly as an uninterrupted one).

    Attributes
    ----------
    iterations : list of int
        Iterations of each solve (0: factorised and solved directly).
    factorizations : int
        SuperLU factorisations of ``Phi`` made.
    """

    def __init__(self, tol: float = 1e-15, max_iter: int = 20, refresh: int = 7):
        self.tol, self.max_iter, self.refresh = tol, max_iter, refresh
        self.matrix = None
        self._lu = None
        self.iterations = []
        self.factorizations = 0

    def __getstate__(self):
        return {k: v for k, v in vars(self).items() if k != "_lu"}

    def __setstate__(self, state):
        vars(self).update(state)
        self._lu = None if self.matrix is None else sparse_lu(self.matrix)

    def _factorise(self, stencils: mls.Stencils) -> None:
        self.matrix = mls.value_matrix(stencils)
        self._lu = sparse_lu(self.matrix)
        self.factorizations += 1

    def solve(self, values: np.ndarray, stencils: mls.Stencils, start: np.ndarray | None = None) -> np.ndarray:
        """Nodal parameters (N, F) whose MLS values at the stencils' points are ``values`` (N, F),
        iterated from ``start`` (N, F) if given."""
        if self._lu is not None:
            matrix = _value_csr(np.asarray(stencils.index), np.asarray(stencils.phi), values.shape[0])
            x = self._lu.solve(values) if start is None else np.array(start)
            last = None
            for it in range(1, self.max_iter + 1):
                dx = self._lu.solve(values - matrix @ x)
                x += dx
                size = np.abs(dx).max(axis=0)
                if last is not None:
                    # the error left after this correction is about rate / (1 - rate) of it
                    rate = np.minimum(size / np.maximum(last, np.finfo(float).tiny), 0.5)
                    if np.all(rate / (1 - rate) * size <= self.tol * np.abs(x).max(axis=0)):
                        self.iterations.append(it)
                        if it > self.refresh:
                            self._factorise(stencils)
                        return x
                last = size
        self._factorise(stencils)
        self.iterations.append(0)
        return self._lu.solve(values)


def make_model(scene: Scene, cloud: Cloud) -> Model:
    """The :class:`Model` of ``scene`` on ``cloud``."""
    return Model(scene=scene, effects=Effects.of(scene), cloud=cloud)


class Discretisation(NamedTuple):
    """A scene discretised at t = 0: what :func:`jaxanm.integrate` needs, and what built it."""

    cloud: Cloud
    stencils: mls.Stencils
    model: Model
    params: dict
    x0: np.ndarray


def discretise(scene: Scene) -> Discretisation:
    """Point cloud, MLS stencils, :class:`Model`, residual params and initial state of ``scene``."""
    cloud = build_cloud(scene.geometry)
    stencils = build_stencils(cloud.points, cloud.n_tool, scene.geometry)
    model = make_model(scene, cloud)
    return Discretisation(cloud, stencils, model, model.params(cloud.points, stencils),
                          model.initial_state(cloud.points))
