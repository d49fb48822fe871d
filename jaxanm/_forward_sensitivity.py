"""Forward (tangent-linear) sensitivities of implicit-Euler simulations, step by step: the method.

Each accepted step solves ``R(x_k, x_{k-1}, t_k, dt, p(theta)) = 0``.  Differentiating that
identity gives, for the sensitivity ``S_k = dx_k / dtheta`` (n x P, one column per scalar of
``theta``)::

    J_k S_k = -(dR/dx_old S_{k-1} + dR/dtheta),          J_k = dR/dx_new at x_k

and every observation ``y_k = observe(t_k, x_k, p(theta))`` has ``dy_k/dtheta = dy/dx S_k +
dy/dtheta``.  The gradient of a loss of the observations is then ``sum_k dL/dy_k . dy_k/dtheta
+ dL/dtheta``.  Why this (forward) method rather than an adjoint:

- the calibrated parameters are few (K, A, n: P = 3), so P right-hand sides per step cost less
  than one backward sweep, and nothing of the trajectory is stored (an adjoint needs every
  x_k, or recomputation, on the way back);
- the full Jacobian ``dy/dtheta`` of every observation comes for free: Gauss-Newton matrices,
  Fisher-information conditioning checks and Levenberg-Marquardt steps need it, a gradient
  alone does not give it;
- no extra factorisation: the linear systems are solved by iterative refinement
  ``S <- S + K*^-1 (b - J S)`` preconditioned by the factorised K* the step solver already
  holds (stale for the ANM), with exact products ``J S`` from ``jax.jvp``.  It converges at
  the rate ``rho(I - K*^-1 J)``; an ANM series accepted at a = 1 with tolerance eta and order
  p implies this rate is about ``eta^(1/(p-1))`` or less (0.1 for p = 7, eta = 1e-6), and
  Newton's K* is the Jacobian one iterate back (the rates measured: docs/notes/gradients.md).  Should the
  refinement stall (rate above 1/2) the Jacobian at x_k is factorised once and installed as
  the solver's K* (counted in ``SensitivityStats.extra_factorizations``).

**Polish.**  An ANM step satisfies R = 0 only to the series tolerance and a Newton step to its
increment tolerance, while the sensitivities above are those of the exact root.  Every accepted
step is therefore polished by chord iterations ``x <- x - K*^-1 R(x)`` with the same K* until
the relative correction is below ``polish_tol`` (or stops shrinking at the round-off floor),
*and the trajectory continues from the polished state*.  The simulated map is then the exact
implicit-Euler trajectory (independent of the step solver up to round-off), and the gradients
agree with finite differences of that map.  The price is a few residual evaluations and
triangular solves per step, no factorisation.

Only ``params`` leaves reached through ``bind(params, theta)`` are differentiated.  The initial
state ``x0`` is taken as independent of theta (S_0 = 0), and ``params`` must not be changed
between steps (no Lagrangian re-meshing: geometry changes made on the host are not
differentiable).

The steps are those of :func:`jaxanm.integrate` (the one time loop: step count, dt halving,
sparsity detection); :class:`ForwardSensitivity` is its ``sensitivity`` option, which polishes
each solved step and carries S through it.

The public entry points, :func:`jaxanm.sensitivities` and :func:`jaxanm.value_and_grad`, are in
:mod:`jaxanm.sensitivity`.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ._checks import flag, integer, real
from ._factorization import Factorization
from ._problem import Problem, count, record, work
from ._run_inputs import params_float64
from ._sensitivity_method import Polished, SensitivityMethod
from ._theta import bind_paths, check_paths, theta_float64, theta_names
from .errors import InputError, StepFailure
from .stats import Counters, Stats

_FLOOR = 1e3  # a correction that stops shrinking below _FLOOR * polish_tol is at the round-off floor


@dataclasses.dataclass
class SensitivityStats(Counters):
    """Cost of the polish and of the sensitivity solves (the step solver's cost is in ``Stats``).

    ``polish_iterations`` and ``refine_iterations`` are totals of chord corrections and of
    refinement sweeps (each sweep: one batched ``J S`` product and P triangular solves);
    ``extra_factorizations`` counts the Jacobians factorised because refinement or polish
    stalled with the solver's K*; ``rate`` holds, per step, the measured contraction of the
    refinement (an estimate of ``rho(I - K*^-1 J)``); ``residual_norm`` the max-norm of R after
    polishing; ``wall_time_s`` the run's wall time, which ``wall_time`` splits into ``polish``,
    ``tangent`` (solves), ``observe`` and ``solver`` (the rest: the step solver and the time
    loop).  A :class:`~jaxanm.stats.Counters`, as :class:`jaxanm.Stats`.
    """

    REMAINDER = "solver"

    polish_iterations: int = 0
    refine_iterations: int = 0
    extra_factorizations: int = 0
    rate: list = dataclasses.field(default_factory=list)
    residual_norm: list = dataclasses.field(default_factory=list)
    wall_time_s: float = 0.0
    wall_time: dict = dataclasses.field(
        default_factory=lambda: dict.fromkeys(("solver", "polish", "tangent", "observe"), 0.0))


@dataclasses.dataclass
class Sensitivities:
    """Result of :func:`jaxanm.sensitivities`.

    Attributes
    ----------
    observed : dict
        ``{"t": (M,), key: (M, ...)}``: ``observe`` at t0 and after every step (the same layout
        as :attr:`jaxanm.Solution.observed`; values may be nested pytrees of arrays).
    jacobian : dict or None
        ``d observed / d theta`` with the same keys (no ``"t"``), each leaf ``(M, ..., P)``
        where P is the number of scalars of theta, in the order of :attr:`theta_names`.
        ``None`` when computed with ``tangents=False``.
    theta_names : list of str
        Name of each of the P flattened components (``"key"`` or ``"key[i]"``), in the
        flattening order of ``jax.flatten_util.ravel_pytree`` (dict keys sorted).
    x : (n,) final (polished) state; ``dx_dtheta``: (n, P) its sensitivity (or None).
    stats : jaxanm.Stats of the step solver; ``sensitivity_stats``: :class:`SensitivityStats`.
    wall_time_s : total wall time.
    """

    observed: dict
    jacobian: dict | None
    theta_names: list
    x: np.ndarray
    dx_dtheta: np.ndarray | None
    stats: Stats
    sensitivity_stats: SensitivityStats
    wall_time_s: float
    unravel: Callable | None = dataclasses.field(repr=False, default=None)

    def gradient(self, d_observed) -> dict:
        """Chain rule: ``sum d_observed . d observed/d theta`` as a dict shaped like theta (theta
        is a dict of arrays: :func:`jaxanm._theta.theta_float64` refuses anything else).

        ``d_observed`` has the structure of ``observed`` without ``"t"`` (e.g. from
        ``jax.grad`` of a loss with respect to the observations).
        """
        if self.jacobian is None:
            raise InputError("these sensitivities were computed with tangents=False: no jacobian to contract")
        total = np.zeros(len(self.theta_names))
        for g, jac in zip(jax.tree_util.tree_leaves(d_observed), jax.tree_util.tree_leaves(self.jacobian)):
            g = np.asarray(g, dtype=np.float64)
            total += np.tensordot(g, jac, axes=g.ndim)
        unravel = self.unravel
        if unravel is None:
            raise InputError("Sensitivities.unravel is None: gradient needs theta's layout, which "
                             "jaxanm.sensitivities sets (construct Sensitivities with unravel=...)")
        return unravel(total)


@functools.lru_cache(maxsize=32)
def _kernels(residual, bind, observe):
    """Jitted batched JVPs, compiled once per (residual, bind, observe).

    ``E`` is theta's pytree with a leading axis of P basis directions; ``S_T`` is (P, n).
    """

    def step_rhs(x, x_old, t, dt, params, theta, S_T, E):
        """``dR/dx_old S + dR/dtheta``, one row per column of S (P, n)."""
        def f(xo, th):
            return residual(x, xo, t, dt, bind(params, th))

        return jax.vmap(lambda s, e: jax.jvp(f, (x_old, theta), (s, e))[1])(S_T, E)

    def jac_x(x, x_old, t, dt, params, theta, V_T):
        """``J V`` for each row of V_T (P, n)."""
        bound = bind(params, theta)
        def f(xx):
            return residual(xx, x_old, t, dt, bound)

        return jax.vmap(lambda v: jax.jvp(f, (x,), (v,))[1])(V_T)

    def obs(t, x, params, theta):
        return observe(t, x, bind(params, theta))

    def obs_tangent(t, x, params, theta, S_T, E):
        def f(xx, th):
            return observe(t, xx, bind(params, th))

        value = f(x, theta)
        tangent = jax.vmap(lambda s, e: jax.jvp(f, (x, theta), (s, e))[1])(S_T, E)
        return value, tangent

    return jax.jit(step_rhs), jax.jit(jac_x), jax.jit(obs), jax.jit(obs_tangent)


class ForwardSensitivity(SensitivityMethod):
    """Forward sensitivities ``S = dx/dtheta`` along the steps of :func:`jaxanm.integrate` (its
    ``sensitivity`` option), every solved step polished first (module docstring): what
    :func:`jaxanm.sensitivities` runs.  Pass :attr:`bound_params` as the run's ``params``; after the
    run, :meth:`result` gives the :class:`Sensitivities`.

    Parameters are those of :func:`jaxanm.sensitivities` (``residual``, ``params``, ``theta``,
    ``observe``, ``bind``, ``tangents``, ``polish_tol``, ``max_polish``, ``max_refine``),
    checked here (:class:`InputError`).
    """

    def __init__(self, residual: Callable, params, theta: dict, observe: Callable, *, bind: Callable | None = None,
                 tangents: bool = True, polish_tol: float = 1e-13, max_polish: int = 30, max_refine: int = 60):
        if not callable(observe):
            raise InputError("observe must be a callable (t, x, params) -> dict of arrays (jax.numpy)")
        real("polish_tol", polish_tol, 0.0, 1e-3, open_low=True, open_high=True, hint="e.g. 1e-13")
        integer("max_polish", max_polish, 1)
        integer("max_refine", max_refine, 1)
        flag("tangents", tangents)
        self.theta = theta_float64(theta)
        self.params = params_float64(params)
        if bind is None:
            check_paths(self.params, self.theta)
            bind = bind_paths
        theta_vec, self.unravel = ravel_pytree({k: jnp.asarray(v) for k, v in self.theta.items()})
        self.size = theta_vec.size  # P, the number of scalars of theta
        self.basis = jax.vmap(self.unravel)(jnp.eye(self.size))
        self.theta_j = self.unravel(theta_vec)
        self.bound_params = bind(self.params, self.theta_j)  # the residual's params at theta: the run's params
        self.step_rhs, self.jac_x, self.obs, self.obs_tangent = _kernels(residual, bind, observe)
        self.tangents, self.polish_tol, self.max_polish, self.max_refine = tangents, polish_tol, max_polish, max_refine
        self.stats = SensitivityStats()
        self.values: list = []
        self.tangent_values: list = []
        self.times: list[float] = []
        self.problem: Problem | None = None
        self.S_T: np.ndarray | None = None
        self.x: np.ndarray | None = None
        # during after_solve: the K* in use, and the one made here (if any)
        self._fact: Factorization | None = None
        self._made: Factorization | None = None

    def start(self, problem, t0, x0, params) -> None:
        """The run's problem; S_0 = 0 (x0 independent of theta) and the observation at t0."""
        self.problem = problem
        self.S_T = np.zeros((self.size, x0.size)) if self.tangents else None
        self.record(t0, x0, params)

    def after_solve(self, factorization, x_old, x, t, dt, step) -> Polished:
        """Polish the solved (sub-)step and carry S through it, with the solver's K*
        ``factorization``: the polished state, ``|R(x)|_inf``, and the Jacobian factorised here
        if polish or refinement stalled with that K* (the loop makes it the solver's K*)."""
        self._fact, self._made = factorization, None
        with work(self.stats, "polish"):
            x, r_norm = self._polish(x, x_old, t, dt, step)
        with work(self.stats, "tangent"):
            if self.tangents:
                self.S_T = self._tangent(x, x_old, t, dt, self.S_T, step)
        made, self._fact, self._made = self._made, None, None
        return Polished(x, r_norm, made)

    def record(self, t, x, params) -> None:
        """The observation at an accepted step (and its tangent), by this sensitivity's own
        ``params`` and theta (those of the run are ``bound_params``)."""
        with work(self.stats, "observe"):
            t_j = jnp.float64(t)
            if self.S_T is None:
                self.values.append(jax.tree_util.tree_map(np.asarray, self.obs(t_j, x, self.params, self.theta_j)))
            else:
                v, tan = self.obs_tangent(t_j, x, self.params, self.theta_j, self.S_T, self.basis)
                self.values.append(jax.tree_util.tree_map(np.asarray, v))
                self.tangent_values.append(jax.tree_util.tree_map(lambda a: np.moveaxis(np.asarray(a), 0, -1),
                                                                  tan))
            self.times.append(float(t))
            self.x = x

    def result(self, stats: Stats, wall: float) -> Sensitivities:
        """The :class:`Sensitivities` of the run, whose step solver's statistics are ``stats``
        and wall time ``wall`` (the part not spent polishing, refining or observing is
        ``sensitivity_stats.wall_time["solver"]``)."""
        if not isinstance(self.values[0], dict):
            raise InputError(f"observe must return a dict of arrays, got {type(self.values[0]).__name__}")
        sst = self.stats
        sst.close(wall)
        stack = lambda *leaves: np.stack(leaves)  # noqa: E731
        observed = {"t": np.asarray(self.times), **jax.tree_util.tree_map(stack, *self.values)}
        jac = jax.tree_util.tree_map(stack, *self.tangent_values) if self.tangents else None
        to_np = lambda v: jax.tree_util.tree_map(lambda a: np.asarray(a, dtype=np.float64), self.unravel(v))  # noqa: E731
        return Sensitivities(observed=observed, jacobian=jac, theta_names=theta_names(self.theta), x=np.asarray(self.x),
                             dx_dtheta=None if self.S_T is None else self.S_T.T.copy(), stats=stats,
                             sensitivity_stats=sst, wall_time_s=wall, unravel=to_np)

    def _scaled_norms(self, v) -> np.ndarray:
        """Scaled 2-norm per row of a (P, n) block (or of one vector)."""
        return np.linalg.norm(np.atleast_2d(v) / self._run_problem().scale, axis=1)

    def _run_problem(self) -> Problem:
        """The run's problem, which :meth:`start` sets before any step."""
        if self.problem is None:
            raise RuntimeError("ForwardSensitivity steps before start(): pass it to integrate(sensitivity=...)")
        return self.problem

    def _kstar(self):
        """The K* in use: the step solver's, or the one :meth:`_refresh` made in this step."""
        return self._fact

    def _refresh(self, x, x_old, t, dt) -> None:
        """The Jacobian at ``x`` factorised, used from here on and handed to the loop as the
        solver's next K* (counted)."""
        fact = self._run_problem().factorize_at(x, x_old, t, dt, self.bound_params)
        self._fact = self._made = fact
        count(self.stats, "extra_factorizations")

    def _polish(self, x, x_old, t, dt, k):
        """Chord iterations with the solver's K* until R(x) = 0 to round-off: ``(x, |R(x)|_inf)``."""
        P, sst, tol = self.problem, self.stats, self.polish_tol
        previous, refreshed = np.inf, False
        for _ in range(self.max_polish):
            r = P.residual(x, x_old, t, dt, self.bound_params)
            dx = -self.problem.solve(self._kstar(), r)
            size, ref = self._scaled_norms(dx)[0], max(self._scaled_norms(x)[0], np.finfo(float).tiny)
            if not np.isfinite(size):
                raise StepFailure("polish correction is not finite", step=k, t=float(t))
            stalled = size > 0.5 * previous
            if stalled and size > _FLOOR * tol * ref:  # slow with this K*: exact Jacobian once
                if refreshed:
                    raise StepFailure(f"polish does not converge even with a fresh Jacobian "
                                      f"(relative correction {size / ref:.3g})", step=k, t=float(t))
                self._refresh(x, x_old, t, dt)
                refreshed, previous = True, np.inf
                continue
            x = x + dx
            count(sst, "polish_iterations")
            if size <= tol * ref or stalled:  # converged, or stalled at the round-off floor
                break
            previous = size
        else:
            raise StepFailure(f"polish did not converge in {self.max_polish} iterations", step=k, t=float(t))
        r_norm = float(np.max(np.abs(P.residual(x, x_old, t, dt, self.bound_params))))
        record(sst, "residual_norm", r_norm)
        return x, r_norm

    def _tangent(self, x, x_old, t, dt, S_old_T, k):
        """Refinement ``S <- S + K*^-1 (b - J S)`` for the P columns at once."""
        args = (x, x_old, t, dt, self.params, self.theta_j)
        b = -np.asarray(self.step_rhs(*args, S_old_T, self.basis))
        S_T = self.problem.solve(self._kstar(), b.T).T
        rels, refreshed = [], False
        for _ in range(self.max_refine):
            res = b - np.asarray(self.jac_x(*args, S_T))
            dS_T = self.problem.solve(self._kstar(), res.T).T
            count(self.stats, "refine_iterations")
            rel = float(np.max(self._scaled_norms(dS_T) / np.maximum(self._scaled_norms(S_T), np.finfo(float).tiny)))
            if not np.isfinite(rel):
                raise StepFailure("sensitivity refinement is not finite", step=k, t=float(t))
            S_T = S_T + dS_T
            rels.append(rel)
            stalled = len(rels) > 1 and rel > 0.5 * rels[-2]
            if rel <= self.polish_tol or (stalled and rel <= _FLOOR * self.polish_tol):
                rate = float((rels[-1] / rels[0]) ** (1 / (len(rels) - 1))) if len(rels) > 1 else 0.0
                record(self.stats, "rate", rate)
                return S_T
            if stalled:  # slow with this K*: exact Jacobian once
                if refreshed:
                    raise StepFailure(f"sensitivity refinement stalls at {rel:.3g} even with a fresh Jacobian",
                                      step=k, t=float(t))
                self._refresh(x, x_old, t, dt)
                refreshed, rels = True, []
                S_T = self.problem.solve(self._kstar(), b.T).T
        raise StepFailure(f"sensitivity refinement did not converge in {self.max_refine} sweeps (last {rel:.3g})",
                          step=k, t=float(t))

