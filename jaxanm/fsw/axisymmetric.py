"""The axisymmetric solution of the FSW physics: a 1-D reference, independent of the MLS code.

Around a tool turning rigidly at ``omega`` the fields of a scene's physics are axisymmetric:
the plate flows on circles, ``V = v(r) e_theta``, and ``T = T(r)``.  Then (SI units, per unit
thickness, :mod:`jaxanm.fsw.physics` for the 2-D equations):

- momentum: ``d(r^2 tau)/dr = 0`` (quasi-static; inertia is left out, see below), so the
  shear stress is ``tau(r) = C / r^2`` with ``C`` fixed by the kinematics: v = omega R1 at the
  tool edge (sticking), v = 0 at R2.  With ``s = r d(v/r)/dr`` the shear rate,
  ``epsbar = |s| / sqrt 3`` and the regularised law ``mu = K T^A (epsbar^2 + eps0^2)^((n-1)/2) / 3``,
  ``tau = mu s``.  At each radius ``s`` solves ``tau(s, T(r)) = C / r^2`` (monotone in s), and
  ``int_R1^R2 s / r dr = -omega`` fixes ``C``: exact torque balance, the torque on the plate
  ``M = 2 pi |C|``, the mechanical power ``P = M omega``;
- heat: ``rho Cp dT/dt = (1/r) d/dr(r k dT/dr) + q`` in the plate with
  ``q = 3 beta mu epsbar^2 = beta tau s`` (``beta`` times the dissipation ``sigma : epsdot``),
  ``rho_t Cp_t dT/dt = (1/r) d/dr(r k_t dT/dr)`` in the tool, T and heat flux continuous at R1,
  ``-k dT/dr = h (T - Ta)`` at R2;
- slip (effect ``slip``, contact state ``delta = tool.contact_state``): the plate edge turns at
  ``delta omega`` (so ``int s / r dr = -delta omega``), the torque is still ``2 pi |C|`` (the
  interface shear is the plate's ``C / R1^2``), and the interface releases the frictional heat
  ``(1 - delta) omega R1 |C| / R1^2`` W/m^2 at R1, which the tool and the plate conduct away
  (flux jump at R1: ``-k dT/dr|plate + k_t dT/dr|tool`` equals it).  The input power
  ``M omega`` is then ``delta M omega`` of plastic dissipation (``beta`` of it heat) plus
  ``(1 - delta) M omega`` of friction (all of it heat).

The scene's effects select the terms as :mod:`jaxanm.fsw.physics` does: without ``softening``
mu uses T0; without ``dissipation`` q = 0; without ``tool_conduction`` the plate edge R1 is
insulated and the tool stays at T0; without ``robin`` the edge R2 is insulated; without
``conduction`` T = T0 (isothermal Couette flow); without ``viscous`` there is no flow.  The
other effects change nothing here: circular flow carries an axisymmetric T along its own
isotherms (``V . grad T = 0``, so ``lagrangian`` and ``tracers`` agree), it is divergence-free
(the penalty does not act), and ``inertia`` only adds the centripetal ``rho v^2 / r``, balanced
by pressure, and the spin-up of the plate, over ``rho (R2 - R1)^2 / mu ~ 1e-8 s`` for the
paper's data: far below any time step.

Numerics (numpy / scipy only, nothing from :mod:`jaxanm.mls` or the model's residual):

- cell-centred finite volumes on ``[0, R2]``, the tool/plate interface on a face; cells graded
  geometrically towards R1 from both sides (the shear band ``v/r ~ r^(-2/n)`` is about
  ``n R1 / 2`` thick, 0.1 mm for the paper's n), refined by splitting every cell into equal
  parts so that the mesh mapping stays the same (second order in the cell size);
- the shear rate at the cell centres (Newton in ``log |s|``, globally convergent since the
  log-stress is concave and increasing in it), the torque constant by Newton on
  ``log |C|``; the midpoint rule for ``int s / r dr`` and for the cell sources, so that the
  discrete dissipation ``beta 2 pi |C| omega`` equals ``beta P`` exactly;
- conduction by two-point fluxes with the series resistance of the half cells (flux and
  temperature continuous across the interface face), Robin flux through the outer half cell;
- BDF2 in time (the first step implicit Euler), the source implicit and converged by fixed
  point iterations per step (contraction ~ dt |A| q / (rho Cp T) ~ 0.02 at the paper's data),
  or implicit Euler with ``scheme="euler"``.

:func:`solve` returns the solution at given times with an error estimate from a solve on
twice as many cells and one at half the time step.  :func:`couette_exact` (isothermal closed
form) and :func:`radial_finite_volumes` (pure conduction, implicit Euler on uniform cells, an
assembly of its own) are the older references the tests hold this one to.
:mod:`jaxanm.fsw.continuum_error` measures a run against :func:`solve`.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from .scene import Scene

__all__ = ["AxisymmetricSolution", "couette_exact", "couette_shear", "graded_edges",
           "radial_finite_volumes", "solve"]


def couette_exact(r, R1, R2, omega, n):
    """Steady v_theta(r) of a power-law fluid between the turning tool and the fixed ring.

    The shear stress is C / r^2; with mu = K epsbar^(n-1) / 3 and epsbar = |s| / sqrt(3),
    s = r d(v/r)/dr, this gives s ~ -r^(-2/n), so v/r = a r^(-2/n) + b, fixed by
    v(R1) = omega R1 and v(R2) = 0.  n = 1: v = omega R1^2 (R2^2/r - r) / (R2^2 - R1^2).
    (Isothermal, unregularised: eps0 -> 0.)
    """
    a = 2.0 / n
    return omega * r * (r ** -a - R2 ** -a) / (R1 ** -a - R2 ** -a)


def radial_finite_volumes(R1, R2, k_tool, k_plate, c_tool, c_plate, h, Ta, T0, dt, steps, cells=3000):
    """Axisymmetric implicit-Euler finite volumes on [0, R2]: an independent reference.

    Cell-centred, the tool/plate interface on a face (series resistance of the two half cells
    across it: flux and temperature continuous), Robin flux h (T - Ta) through a half cell at
    R2.  Returns cell centres and temperatures after ``steps`` steps from uniform T0.
    Pure conduction (no flow, no source), uniform cells on each side of R1.
    """
    n_tool = round(cells * R1 / R2)
    edges = np.concatenate([np.linspace(0, R1, n_tool + 1), np.linspace(R1, R2, cells - n_tool + 1)[1:]])
    rc, width = 0.5 * (edges[1:] + edges[:-1]), np.diff(edges)
    k = np.where(rc < R1, k_tool, k_plate)
    cap = np.where(rc < R1, c_tool, c_plate) * 0.5 * (edges[1:] ** 2 - edges[:-1] ** 2) / dt
    g = edges[1:-1] / (0.5 * width[:-1] / k[:-1] + 0.5 * width[1:] / k[1:])
    g_out = R2 / (0.5 * width[-1] / k[-1] + 1.0 / h)
    diag = cap.copy()
    diag[:-1] += g
    diag[1:] += g
    diag[-1] += g_out
    lu = scipy.sparse.linalg.splu(scipy.sparse.diags([diag, -g, -g], [0, 1, -1], format="csc"))
    T = np.full(rc.size, T0)
    for _ in range(steps):
        b = cap * T
        b[-1] += g_out * Ta
        T = lu.solve(b)
    return rc, T


def _geometric(length: float, cells: int, ratio: float) -> np.ndarray:
    """Widths (cells,) summing to ``length``, each ``ratio`` times the previous (first smallest)."""
    if abs(ratio - 1.0) < 1e-12:
        return np.full(cells, length / cells)
    w = ratio ** np.arange(cells)
    return length * w / w.sum()


def graded_edges(R1: float, R2: float, tool_cells: int = 40, plate_cells: int = 120,
                 tool_ratio: float = 1.04, plate_ratio: float = 1.04, refine: int = 1,
                 with_tool: bool = True) -> np.ndarray:
    """Cell edges on [0, R2] (or [R1, R2] without the tool) graded geometrically towards R1.

    ``tool_cells`` cells on [0, R1] and ``plate_cells`` on [R1, R2], each ``ratio`` times wider
    than its neighbour nearer R1 (the defaults put the first plate cell at 1.6 um, 1/60 of the
    paper's 0.1 mm shear band, the widest at 0.17 mm); ``refine`` splits every cell into that many equal parts (the same
    mesh mapping: errors fall as ``refine^-2``).  R1 is always an edge.
    """
    plate = R1 + np.concatenate([[0.0], np.cumsum(_geometric(R2 - R1, plate_cells, plate_ratio))])
    plate[-1] = R2
    parts = [plate]
    if with_tool:
        tool = R1 - np.concatenate([[0.0], np.cumsum(_geometric(R1, tool_cells, tool_ratio))])
        tool[-1] = 0.0
        parts = [tool[::-1][:-1], plate]
    edges = np.concatenate(parts)
    if refine > 1:
        a, b = edges[:-1, None], edges[1:, None]
        edges = np.concatenate([(a + (b - a) * np.arange(refine) / refine).ravel(), edges[-1:]])
    return edges


def couette_shear(C, r, stress_coef, n, eps0, guess=None):
    """Shear rate magnitude ``|s| > 0`` with ``stress_coef |s| (s^2/3 + eps0^2)^((n-1)/2) = |C| / r^2``.

    ``stress_coef = K T^A / 3`` (per radius, arrays broadcast).  Newton in ``x = log |s|``: the
    log-stress ``F(x)`` is increasing (``F' = 1 + (n-1) w`` in ``[n, 1]``, ``w = (s^2/3) /
    (s^2/3 + eps0^2)``) and concave for n < 1, so from any start the iterates reach the root's
    left side after one step and then rise monotonically to it (convex for n > 1: the mirror
    argument).  Iterated until the Newton step is below 1e-12 (then x is exact to
    round-off, ~1e-15 |x| / n).  Returns ``(|s|, F')``.
    """
    target = np.log(np.abs(C) / r ** 2) - np.log(stress_coef)
    x = target / n + 0.5 * (n - 1) / n * math.log(3.0) if guess is None else np.log(guess)
    x = np.broadcast_to(x, np.broadcast(target, x).shape).copy()
    for _ in range(200):
        e2 = np.exp(2 * x) / 3.0
        F = x + 0.5 * (n - 1) * np.log(e2 + eps0 ** 2) - target
        dF = 1.0 + (n - 1) * e2 / (e2 + eps0 ** 2)
        step = F / dF
        x = x - step
        if np.max(np.abs(step)) < 1e-12:  # quadratic convergence: x is then exact to round-off
            break
    else:  # pragma: no cover - the iteration is globally convergent (docstring)
        raise RuntimeError("couette_shear: Newton did not converge")
    e2 = np.exp(2 * x) / 3.0
    return np.exp(x), 1.0 + (n - 1) * e2 / (e2 + eps0 ** 2)


@dataclasses.dataclass
class AxisymmetricSolution:
    """The 1-D solution at the requested times.

    Attributes
    ----------
    times : (S,) the times (s).
    edges : (N + 1,) cell edges (m); ``r`` (N,) cell centres.
    T : (S, N) cell temperatures (K); ``T_R1``, ``T_R2`` (S,) the interface and outer-edge
        temperatures; T0 the initial temperature.
    torque : (S,) torque per unit thickness the tool exerts on the plate, ``2 pi |C|`` (N m/m).
    power : (S,) mechanical power ``omega * torque`` (W/m): with ``slip``, ``delta`` of it is
        dissipated plastically (``beta`` times that heats the plate) and ``1 - delta`` is
        frictional heat at the interface.
    v_faces : (S, F) v_theta (m/s) at the plate's cell edges ``plate_edges`` (F,).
    stored : (S,) heat stored, ``int rho Cp (T - T0) dA`` over tool and plate (J/m).
    error_estimate : str, the estimated error (filled by :func:`solve` with ``estimate=True``).
    error_T, error_power : estimated max error of T (K) over the times, relative power error.
    """

    times: np.ndarray
    edges: np.ndarray
    r: np.ndarray
    T: np.ndarray
    T_R1: np.ndarray
    T_R2: np.ndarray
    T0: float
    R1: float
    R2: float
    torque: np.ndarray
    power: np.ndarray
    plate_edges: np.ndarray
    v_faces: np.ndarray
    stored: np.ndarray
    error_estimate: str = "not estimated"
    error_T: float = math.nan
    error_power: float = math.nan
    omega: float = math.nan

    def temperature(self, r, i: int = -1):
        """T (K) at radii ``r`` at the i-th time: piecewise linear through the cell centres, the
        interface value at R1 and the boundary value at R2 (uniform T0 region outside the grid)."""
        r = np.asarray(r, dtype=np.float64)
        nodes = np.concatenate([self.r, [self.R1, self.R2]])
        vals = np.concatenate([self.T[i], [self.T_R1[i], self.T_R2[i]]])
        order = np.argsort(nodes, kind="stable")
        nodes, vals = nodes[order], vals[order]
        if self.edges[0] > 0:  # no tool in the grid: it stays at T0
            return np.where(r < self.R1, self.T0, np.interp(r, nodes, vals))
        return np.interp(r, nodes, vals)

    def velocity(self, r, i: int = -1):
        """v_theta (m/s) at radii ``r`` (tool: rigid; plate: piecewise linear in v/r between edges)."""
        r = np.asarray(r, dtype=np.float64)
        w = np.interp(r, self.plate_edges, self.v_faces[i] / self.plate_edges)
        omega = self.omega if math.isfinite(self.omega) else self.v_faces[i][0] / self.R1
        return np.where(r < self.R1, omega * r, w * r)  # R1 itself: the plate edge (slip)


def _rise_tolerance() -> float:
    """Fixed-point tolerance of a step's temperature change, relative to T0 (round-off level)."""
    return 1e-13


def solve(scene: Scene, times, *, tool_cells: int = 40, plate_cells: int = 120, ratio: float = 1.04,
          refine: int = 2, dt: float = 1e-4, scheme: str = "bdf2", estimate: bool = False) -> AxisymmetricSolution:
    """The axisymmetric solution of ``scene``'s physics at ``times`` (module docstring).

    Parameters
    ----------
    scene : Scene
        Geometry (R1, R2), material, tool, thermal data and effects are used; ``dr``, the
        layout, the penalty, the solver and the scene's time step are not (this is the
        continuum's reference, not the scene's discretisation).
    times : sequence of float
        Output times (s), each a multiple of ``dt`` (to 1e-9 of it).
    tool_cells, plate_cells, ratio, refine
        The mesh: :func:`graded_edges` with ``tool_ratio = plate_ratio = ratio``.  The defaults
        (320 cells) are within 2.3e-3 K on the paper's data to 0.3 s (``estimate``).
    dt : float
        Time step (s).
    scheme : ``"bdf2"`` or ``"euler"`` (implicit Euler, first order).
    estimate : bool
        Also solve on twice the cells and at half the time step, and store the differences
        (times 4/3 for the second-order scheme: the error of this solution, by Richardson's
        argument; times 1 for Euler's time error) in ``error_T`` (max over cells and times,
        K), ``error_power`` (relative) and ``error_estimate`` (a sentence).
    """
    if scheme not in ("bdf2", "euler"):
        raise ValueError(f"scheme must be 'bdf2' or 'euler', got {scheme!r}")
    times = np.atleast_1d(np.asarray(times, dtype=np.float64))
    steps_at = np.rint(times / dt).astype(int)
    if np.any(np.abs(steps_at * dt - times) > 1e-9 * dt) or np.any(steps_at < 0) or np.any(np.diff(steps_at) < 0):
        raise ValueError(f"times {times.tolist()} must be increasing multiples of dt = {dt}")
    sol = _solve(scene, times, steps_at, dt, scheme,
                 graded_edges(scene.geometry.R1, scene.geometry.R2, tool_cells, plate_cells, ratio, ratio, refine,
                              with_tool=scene.has("tool_conduction")))
    if estimate:
        g = scene.geometry
        fine = _solve(scene, times, steps_at, dt, scheme,
                      graded_edges(g.R1, g.R2, tool_cells, plate_cells, ratio, ratio, 2 * refine,
                                   with_tool=scene.has("tool_conduction")))
        half = _solve(scene, times, 2 * steps_at, dt / 2, scheme, sol.edges)
        space = max(float(np.max(np.abs(fine.temperature(sol.r, i) - sol.T[i]))) for i in range(len(times)))
        space_P = float(np.max(np.abs(fine.power - sol.power) / np.maximum(np.abs(sol.power), 1e-300)))
        time_ = float(np.max(np.abs(half.T - sol.T)))
        time_P = float(np.max(np.abs(half.power - sol.power) / np.maximum(np.abs(sol.power), 1e-300)))
        k_time = 4.0 / 3.0 if scheme == "bdf2" else 1.0
        sol.error_T = 4.0 / 3.0 * space + k_time * time_
        sol.error_power = 4.0 / 3.0 * space_P + k_time * time_P
        sol.error_estimate = (f"|T error| <= {sol.error_T:.1e} K ({4 / 3 * space:.1e} cells, {k_time * time_:.1e} "
                              f"time step), power {sol.error_power:.1e} relative")
    return sol


class _Conduction:
    """Radial conduction per radian on the cells of ``edges``: capacities ``rho_cp * vol``, the
    matrix ``L`` of the face conductances (Robin through the outer half cell) and its
    right-hand side ``b_out``, and the interface (R1) and outer-edge (R2) temperatures from the
    two-point fluxes."""

    def __init__(self, scene: Scene, edges: np.ndarray, in_plate: np.ndarray):
        m, tl, th = scene.material, scene.tool, scene.thermal
        R1, R2 = scene.geometry.R1, scene.geometry.R2
        width = np.diff(edges)
        k = np.where(in_plate, m.k, tl.k)
        self.rho_cp = np.where(in_plate, m.rho * m.Cp, tl.rho * tl.Cp)
        self.vol = 0.5 * (edges[1:] ** 2 - edges[:-1] ** 2)
        g_face = edges[1:-1] / (0.5 * width[:-1] / k[:-1] + 0.5 * width[1:] / k[1:])
        g_out = R2 / (0.5 * width[-1] / k[-1] + 1.0 / th.h) if (scene.has("robin") and th.h > 0) else 0.0
        N = width.size
        lap_diag = np.zeros(N)
        lap_diag[:-1] += g_face
        lap_diag[1:] += g_face
        lap_diag[-1] += g_out
        self.L = scipy.sparse.diags([lap_diag, -g_face, -g_face], [0, 1, -1], format="csc")
        self.b_out = np.zeros(N)
        self.b_out[-1] = g_out * th.Ta
        self._k, self._width, self._g_out, self._h, self._Ta = k, width, g_out, th.h, th.Ta
        self._j_int = int(np.searchsorted(edges, R1 * (1 - 1e-12))) if edges[0] < R1 * (1 - 1e-12) else None

    def boundary_values(self, T, q_f: float = 0.0):
        """``(T(R1), T(R2))`` from the cell temperatures ``T`` and the interface source ``q_f``
        (W/m^2; the interface face's balance of the two half-cell fluxes)."""
        k, width, j_int = self._k, self._width, self._j_int
        if j_int is None:  # no tool cells: insulated tool, all of q_f into the first plate cell
            T_R1 = T[0] + q_f * 0.5 * width[0] / k[0]
        else:
            gl, gr = k[j_int - 1] / (0.5 * width[j_int - 1]), k[j_int] / (0.5 * width[j_int])
            T_R1 = (gl * T[j_int - 1] + gr * T[j_int] + q_f) / (gl + gr)
        if self._g_out > 0:
            gi = k[-1] / (0.5 * width[-1])
            T_R2 = (gi * T[-1] + self._h * self._Ta) / (gi + self._h)
        else:
            T_R2 = T[-1]
        return T_R1, T_R2

    def interface_split(self) -> tuple:
        """``(cells, fractions)``: the cells on both sides of R1 and the fractions of a source at
        the interface face that each receives (the face temperature eliminated from the two
        half-cell fluxes: ``g_side / (g_tool + g_plate)``); the first plate cell alone when the
        tool is insulated (no tool cells)."""
        j = self._j_int
        if j is None:
            return np.array([0]), np.array([1.0])
        gl, gr = self._k[j - 1] / self._width[j - 1], self._k[j] / self._width[j]
        return np.array([j - 1, j]), np.array([gl, gr]) / (gl + gr)


class _QuasiStaticFlow:
    """The quasi-static Couette flow of the plate at given temperatures: the torque constant
    ``C`` by Newton on ``log C`` and the shear rates ``|s|`` at the plate cell centres ``r_p``
    (widths ``w_p``), each solve started from the last one's."""

    def __init__(self, scene: Scene, r_p: np.ndarray, w_p: np.ndarray, ip: np.ndarray):
        self.delta = scene.tool.contact_state if scene.has("slip") else 1.0
        self.omega_tool = scene.tool.omega
        # the plate edge's angular speed: the tool's (sticking) or delta times it (slip)
        self.m, self.omega, self.T0 = scene.material, self.delta * scene.tool.omega, scene.thermal.T0
        self.R1, self.R2 = scene.geometry.R1, scene.geometry.R2
        self.soft = scene.has("softening")
        self.eps0 = scene.eps0
        self.r_p, self.w_p, self.ip = r_p, w_p, ip
        self.C = self.s = None

    def __call__(self, T):
        """(|C|, |s| at plate cell centres) of the quasi-static flow at temperatures T."""
        m, omega, R1, R2, r_p, w_p, ip = self.m, self.omega, self.R1, self.R2, self.r_p, self.w_p, self.ip
        if omega == 0.0:  # full sliding: the plate stays at rest, no shear (and no friction heat)
            self.C, self.s = 0.0, np.zeros(r_p.size)
            return self.C, self.s
        coef = m.K / 3.0 * (T[ip] if self.soft else np.full(ip.size, self.T0)) ** m.A
        logC = math.log(self.C) if self.C is not None else None
        if logC is None:  # start: the isothermal power law, C from the unregularised closed form
            a = 2.0 / m.n
            s1 = 2.0 / m.n * omega * R1 ** -a / (R1 ** -a - R2 ** -a)  # |s| at R1 (n law)
            logC = math.log(coef[0] * s1 ** m.n * 3 ** (0.5 * (1 - m.n)) * R1 ** 2)
        s = self.s
        for _ in range(100):
            s, dF = couette_shear(math.exp(logC), r_p, coef, m.n, self.eps0, guess=s)
            G = np.sum(s / r_p * w_p)
            dG = np.sum(s / dF / r_p * w_p)  # d G / d log C
            step = (math.log(G) - math.log(omega)) * G / dG
            logC -= step
            if abs(step) < 1e-13:
                break
        else:  # pragma: no cover - Newton on a convex increasing function of log C
            raise RuntimeError("axisymmetric: the torque constant did not converge")
        s, _ = couette_shear(math.exp(logC), r_p, coef, m.n, self.eps0, guess=s)
        self.C, self.s = math.exp(logC), s
        return self.C, s


class _Record:
    """The solution at the output steps: cell temperatures, T(R1), T(R2), torque constant,
    velocities at the plate edges and stored heat."""

    def __init__(self, cond: _Conduction, flow: _QuasiStaticFlow | None, plate_edges: np.ndarray, T0: float):
        self.cond, self.flow, self.plate_edges, self.T0 = cond, flow, plate_edges, T0
        self.T: list = []
        self.R1: list = []
        self.R2: list = []
        self.M: list = []
        self.v: list = []
        self.E: list = []

    def __call__(self, T):
        """Record the state ``T`` of an output step."""
        q_f = 0.0
        if self.flow is not None:
            f = self.flow
            q_f = (1.0 - f.delta) * f.omega_tool * f(T)[0] / f.R1  # friction heat flux at R1
        T_R1, T_R2 = self.cond.boundary_values(T, q_f)
        self.T.append(T.copy())
        self.R1.append(T_R1)
        self.R2.append(T_R2)
        if self.flow is not None:
            f = self.flow
            C, s = f(T)
            ratio = f.omega - np.concatenate([[0.0], np.cumsum(s / f.r_p * f.w_p)])  # v / r at the plate edges
            self.M.append(2 * math.pi * C)
            self.v.append(ratio * self.plate_edges)
        else:
            self.M.append(0.0)
            self.v.append(np.zeros(self.plate_edges.size))
        self.E.append(2 * math.pi * float(np.sum(self.cond.rho_cp * self.cond.vol * (T - self.T0))))

    def solution(self, scene: Scene, times, steps_at, edges, rc) -> AxisymmetricSolution:
        """The recorded outputs at each of ``times`` (repeated output steps share a record)."""
        g, omega = scene.geometry, scene.tool.omega
        count = [list(steps_at).count(n) for n in sorted({int(n) for n in steps_at})]
        idx = np.repeat(np.arange(len(self.T)), count)
        C = np.asarray(self.M)[idx]
        return AxisymmetricSolution(times=times, edges=edges, r=rc, T=np.asarray(self.T)[idx],
                                    T_R1=np.asarray(self.R1)[idx], T_R2=np.asarray(self.R2)[idx], T0=self.T0,
                                    R1=g.R1, R2=g.R2, torque=C, power=omega * C, plate_edges=self.plate_edges,
                                    v_faces=np.asarray(self.v)[idx], stored=np.asarray(self.E)[idx],
                                    omega=omega)


def _steps(cond: _Conduction, sources, T, n_total: int, dt: float, scheme: str, heat: bool, tol: float):
    """Yield ``(n, T)`` after each of ``n_total`` steps of the heat equation from ``T``: BDF2
    after a first implicit-Euler step (or implicit Euler throughout), the source converged by
    fixed point, one factorisation per step coefficient; without ``heat`` T stays as it is."""
    lu = {}

    def step_matrix(a0: float):
        if a0 not in lu:
            lu[a0] = scipy.sparse.linalg.splu((scipy.sparse.diags(a0 * cond.rho_cp * cond.vol / dt) + cond.L).tocsc())
        return lu[a0]

    T_prev = None
    for n in range(1, n_total + 1):
        if not heat:
            pass
        elif scheme == "euler" or T_prev is None:
            rhs0 = cond.rho_cp * cond.vol / dt * T + cond.b_out
            T_new = _fixed_point(step_matrix(1.0), rhs0, sources, T, tol)
            T_prev, T = T, T_new
        else:
            rhs0 = cond.rho_cp * cond.vol / dt * (2.0 * T - 0.5 * T_prev) + cond.b_out
            guess = 2.0 * T - T_prev
            T_new = _fixed_point(step_matrix(1.5), rhs0, sources, guess, tol)
            T_prev, T = T, T_new
        yield n, T


def _solve(scene: Scene, times, steps_at, dt: float, scheme: str, edges: np.ndarray) -> AxisymmetricSolution:
    """One solve on ``edges`` with step ``dt``; output after ``steps_at`` steps."""
    R1, T0 = scene.geometry.R1, scene.thermal.T0
    rc, width = 0.5 * (edges[1:] + edges[:-1]), np.diff(edges)
    in_plate = rc > R1
    ip = np.flatnonzero(in_plate)
    plate_edges = edges[edges >= R1 - 1e-15 * R1]
    cond = _Conduction(scene, edges, in_plate)
    flow = _QuasiStaticFlow(scene, rc[ip], width[ip], ip) if scene.has("viscous") else None
    beta = scene.material.beta
    cells, fractions = cond.interface_split()
    friction = flow is not None and flow.delta < 1.0

    def sources(T):
        q = np.zeros(rc.size)
        if flow is not None and (scene.has("dissipation") or friction):
            C, s = flow(T)
            if scene.has("dissipation"):
                q[ip] = beta * C * s / flow.r_p * flow.w_p  # beta tau |s| r dr, tau = C / r^2
            if friction:  # (1 - delta) omega R1 tau(R1) R1 per radian at the interface face
                q[cells] += (1.0 - flow.delta) * flow.omega_tool * C * fractions
        return q

    record = _Record(cond, flow, plate_edges, T0)
    save = {int(n) for n in steps_at}
    T_start = np.full(rc.size, T0)
    if 0 in save:
        record(T_start)
    n_total = int(steps_at[-1]) if len(steps_at) else 0
    for n, T in _steps(cond, sources, T_start, n_total, dt, scheme, scene.has("conduction"), _rise_tolerance() * T0):
        if n in save:
            record(T)
    return record.solution(scene, times, steps_at, edges, rc)


def _fixed_point(lu, rhs0, sources, guess, tol: float, max_iter: int = 100):
    """Solve ``(cap/dt + L) T = rhs0 + q(T)`` by fixed-point iteration from ``guess``."""
    T = guess
    for _ in range(max_iter):
        T_new = lu.solve(rhs0 + sources(T))
        if np.max(np.abs(T_new - T)) <= tol:
            return T_new
        T = T_new
    raise RuntimeError("axisymmetric: the source's fixed-point iteration did not converge "
                       f"(last change {np.max(np.abs(T_new - T)):.3g} K); use a smaller dt")
