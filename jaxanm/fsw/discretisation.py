"""The discretisation of an FSW scene: the unknowns' layout (MLS nodal parameters of the fields
the effects need, stacked field by field in a flat vector ``[u (N), v (N), T (N)]``), the
residual's parameters, the initial state, scales, the Jacobian's sparsity, field values from
the unknowns and the refit of the unknowns to given values (:class:`Refit`).

The residual itself and the laws it holds are :mod:`jaxanm.fsw.physics`; the cloud and its
stencils :mod:`jaxanm.fsw.geometry`.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
import scipy.sparse

from .. import Factorization, mls
from ..checkpoint import stored_type
from ..internal import sparse_lu
from .effects import CONSTANTS, REGISTRY, Effects, scene_value
from .geometry import PLATE_EDGE, RING, TOOL_EDGE, Cloud, build_cloud, cloud_stencils, rigid, spacing
from .physics import complete_fields, mu_reference, residual_for
from .scene import Scene

__all__ = ["Discretisation", "Model", "Refit", "discretise", "make_model"]


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
        return residual_for(self.effects, th.edge_rows, th.edge_source)

    @property
    def size(self) -> int:
        """Number of unknowns ``len(fields) * N``."""
        return len(self.fields) * self.cloud.size

    def constants(self) -> dict:
        """``params["c"]``: the scalars of :data:`jaxanm.fsw.effects.CONSTANTS` as float64 numpy scalars.

        Scales: velocity ``U = omega R1``; temperature ``Ts = T0`` (see :meth:`scale`);
        viscosity ``mu_ref`` (:func:`mu_reference`).
        """
        s = self.scene
        m, tl, th, g = s.material, s.tool, s.thermal, s.geometry
        values = dict(K=m.K, A=m.A, n=m.n, eps0=s.eps0, rho=m.rho, Cp=m.Cp, k=m.k, beta=m.beta,
                      rho_t=tl.rho, Cp_t=tl.Cp, k_t=tl.k, omega=tl.omega, h=th.h, Ta=th.Ta,
                      T0=th.T0, lam=s.mechanics.penalty, dr=g.dr, U=tl.omega * g.R1, Ts=th.T0,
                      mu_ref=mu_reference(s))
        # each effect's parameters, from its record (their defaults when the effect is absent)
        values.update({p.constant: scene_value(s, p.key) for e in REGISTRY.values() for p in e.parameters})
        return {k: np.float64(values[k]) for k in CONSTANTS}

    def params(self, points: np.ndarray, stencils: mls.Stencils) -> dict:
        """The residual's parameter pytree for the cloud at ``points`` with ``stencils``."""
        points = np.asarray(points, dtype=np.float64)
        r = np.hypot(points[:, 0], points[:, 1])
        normal = np.where(r[:, None] > 0, points / np.where(r > 0, r, 1.0)[:, None], 0.0)
        p = {"st": stencils, "c": self.constants(), "xy": points, "kind": self.cloud.kind,
             "partner": self.cloud.partner, "normal": normal}
        if self.effects.incompressible:
            p.update(self._pressure_params(points))
        return p

    def _pressure_params(self, points: np.ndarray) -> dict:
        """The continuity rows' point spacing (the stabilisation's h) and the point that fixes the
        pressure's level: the leading point of the ring (largest x)."""
        g, kind = self.scene.geometry, self.cloud.kind
        h = spacing(g, np.hypot(points[:, 0], points[:, 1]), kind <= TOOL_EDGE)
        ring = np.flatnonzero(kind == RING)
        pin = np.zeros(kind.size, dtype=bool)
        pin[ring[np.argmax(points[ring, 0])]] = True
        return {"spacing": np.broadcast_to(np.asarray(h, dtype=np.float64), kind.shape).copy(), "pin": pin}

    def initial_values(self, points: np.ndarray) -> np.ndarray:
        """Initial field values (N, len(fields)): the tool (and its edge) turning, plate at rest, T0.

        With ``slip`` the plate edge turns at ``delta omega``; with ``traverse`` the plate at
        rest is seen from the travelling tool: it moves at (-U, 0).
        """
        sc, kind = self.scene, self.cloud.kind
        sticking = rigid(kind)
        omega = np.full(len(kind), sc.tool.omega)
        if self.effects.slip:
            omega = np.where(kind == PLATE_EDGE, sc.tool.contact_state, 1.0) * omega
        rest_u = -sc.tool.traverse_speed if self.effects.traverse else 0.0
        cols = {"u": np.where(sticking, -omega * points[:, 1], rest_u),
                "v": np.where(sticking, omega * points[:, 0], 0.0),
                "T": np.full(len(kind), sc.thermal.T0), "p": np.zeros(len(kind))}
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
        """Characteristic magnitude of each unknown: ``omega R1`` for u, v, ``T0`` for T and the
        stress ``mu_ref omega`` for p.

        The ANM validity range (eq. 26) and Newton's convergence test use ``x / scale``.
        T is measured by T0 because the viscosity depends on it through ``(T/T0)^A``: a relative
        change of T/T0 changes mu, hence V/(omega R1), by the same relative order, so the two
        non-dimensional fields weigh alike in the series norms.  (The temperature *rise* is of
        the same order as T0 here, hundreds of kelvin.)
        """
        sc, N = self.scene, self.cloud.size
        per = {"u": sc.tool.omega * sc.geometry.R1, "v": sc.tool.omega * sc.geometry.R1,
               "T": sc.thermal.T0, "p": mu_reference(sc) * sc.tool.omega}
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

    As one sparse product (:func:`_value_csr`), faster than numpy gathers per field (measured
    in benchmarks/results/profile_host_step.md); the sums run in stencil order, so the values
    change from the gathers' pairwise sums by round-off only."""
    return _value_csr(index, phi, nodal.shape[0]) @ nodal


@stored_type("fsw.Refit")
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
    one solve more).  ``refresh`` = 7 balances the two costs, solves a step against
    factorisations, each result within round-off of the direct solve's; the replayed runs that
    chose it, and the factorisation every step it replaced, are in
    benchmarks/results/profile_host_step.md.

    Stored in checkpoints with the factorised matrix (:meth:`to_plain`; the factors are remade
    from it on load, bit-identically, so a resumed run refits exactly as an uninterrupted one).

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
        self._lu: Factorization | None = None
        self.iterations: list[int] = []
        self.factorizations = 0

    STATE = ("tol", "max_iter", "refresh", "matrix", "iterations", "factorizations")
    """What :meth:`to_plain` stores: every attribute but the factors, remade from ``matrix``."""

    def to_plain(self) -> dict:
        """The refit's state, ``{name: value}`` for each name of :data:`STATE`."""
        return {name: getattr(self, name) for name in self.STATE}

    @classmethod
    def from_plain(cls, state: dict) -> Refit:
        """The refit :meth:`to_plain` stored, its factors remade from the stored matrix."""
        new = cls(state["tol"], state["max_iter"], state["refresh"])
        new.matrix, new.iterations, new.factorizations = state["matrix"], state["iterations"], state["factorizations"]
        new._lu = None if new.matrix is None else sparse_lu(new.matrix)
        return new

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
        assert self._lu is not None  # just factorised
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
    stencils = cloud_stencils(cloud.points, cloud.n_tool, scene.geometry)
    model = make_model(scene, cloud)
    return Discretisation(cloud, stencils, model, model.params(cloud.points, stencils),
                          model.initial_state(cloud.points))
