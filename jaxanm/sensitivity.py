"""Gradients of implicit-Euler simulations: forward (tangent-linear) sensitivities, step by step.

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
  p implies this rate is about ``eta^(1/(p-1))`` or less (0.1 for p = 7, eta = 1e-6; a few
  per cent measured), Newton's K* is the Jacobian one iterate back (rate ~ 1e-8).  Should the
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

Public entry points: :func:`sensitivities` (observations and their Jacobian) and
:func:`value_and_grad` (a scalar loss and its gradient, shaped like theta, for optax).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jax.flatten_util import ravel_pytree

from ._x64 import entry_point
from .errors import InputError, StepFailure
from .integrate import check_run_inputs, jacobian_kind, params_float64
from .jacobian import detect_sparsity
from .solvers import Problem
from .stats import Stats

_FLOOR = 1e3  # a correction that stops shrinking below _FLOOR * polish_tol is at the round-off floor

__all__ = ["SensitivityStats", "Sensitivities", "bind_paths", "loss_value_and_grad", "sensitivities", "value_and_grad"]


def bind_paths(params, theta):
    """Default ``bind``: each key of ``theta`` is a dotted path to a leaf of nested dicts in params.

    ``bind_paths({"c": {"K": 1.0, "n": 0.3}}, {"c.n": 0.2})`` returns a copy of params with
    ``["c"]["n"] = 0.2``.  Traceable (used inside ``jax.jit``); only the dicts on the path are
    copied.
    """
    for key, value in theta.items():
        params = _set_path(params, key.split("."), value)
    return params


def _set_path(tree, path, value):
    head, rest = path[0], path[1:]
    new = dict(tree)
    new[head] = value if not rest else _set_path(tree[head], rest, value)
    return new


def _check_paths(params, theta) -> None:
    """Every theta key names an existing floating leaf of nested dicts in ``params``."""
    for key in theta:
        node = params
        for part in key.split("."):
            if not (isinstance(node, dict) and part in node):
                known = sorted(_leaf_paths(params))
                raise InputError(
                    f"theta key {key!r} names no leaf of params (dotted path into nested dicts); known "
                    f"leaves: {known[:30]}{' ...' if len(known) > 30 else ''}; or pass bind=(params, theta) -> params")
            node = node[part]


def _leaf_paths(tree, prefix=""):
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _leaf_paths(v, f"{prefix}{k}.")
    else:
        yield prefix[:-1]


@dataclasses.dataclass
class SensitivityStats:
    """Cost of the polish and of the sensitivity solves (the step solver's cost is in ``Stats``).

    ``polish_iterations`` and ``refine_iterations`` are totals of chord corrections and of
    refinement sweeps (each sweep: one batched ``J S`` product and P triangular solves);
    ``extra_factorizations`` counts the Jacobians factorised because refinement or polish
    stalled with the solver's K*; ``rate`` holds, per step, the measured contraction of the
    refinement (an estimate of ``rho(I - K*^-1 J)``); ``residual_norm`` the max-norm of R after
    polishing; ``wall_time`` splits the time into ``solver``, ``polish``, ``tangent`` (solves)
    and ``observe``.
    """

    polish_iterations: int = 0
    refine_iterations: int = 0
    extra_factorizations: int = 0
    rate: list = dataclasses.field(default_factory=list)
    residual_norm: list = dataclasses.field(default_factory=list)
    wall_time: dict = dataclasses.field(default_factory=lambda: dict.fromkeys(("solver", "polish", "tangent", "observe"), 0.0))


@dataclasses.dataclass
class Sensitivities:
    """Result of :func:`sensitivities`.

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
    unravel: Callable = dataclasses.field(repr=False, default=None)

    def gradient(self, d_observed) -> object:
        """Chain rule: ``sum d_observed . d observed/d theta`` as a pytree shaped like theta.

        ``d_observed`` has the structure of ``observed`` without ``"t"`` (e.g. from
        ``jax.grad`` of a loss with respect to the observations).
        """
        if self.jacobian is None:
            raise InputError("these sensitivities were computed with tangents=False: no jacobian to contract")
        total = np.zeros(len(self.theta_names))
        for g, jac in zip(jax.tree_util.tree_leaves(d_observed), jax.tree_util.tree_leaves(self.jacobian)):
            g = np.asarray(g, dtype=np.float64)
            total += np.tensordot(g, jac, axes=g.ndim)
        return self.unravel(total)


@functools.lru_cache(maxsize=32)
def _kernels(residual, bind, observe):
    """Jitted batched JVPs, compiled once per (residual, bind, observe).

    ``E`` is theta's pytree with a leading axis of P basis directions; ``S_T`` is (P, n).
    """

    def step_rhs(x, x_old, t, dt, params, theta, S_T, E):
        """``dR/dx_old S + dR/dtheta``, one row per column of S (P, n)."""
        f = lambda xo, th: residual(x, xo, t, dt, bind(params, th))
        return jax.vmap(lambda s, e: jax.jvp(f, (x_old, theta), (s, e))[1])(S_T, E)

    def jac_x(x, x_old, t, dt, params, theta, V_T):
        """``J V`` for each row of V_T (P, n)."""
        bound = bind(params, theta)
        f = lambda xx: residual(xx, x_old, t, dt, bound)
        return jax.vmap(lambda v: jax.jvp(f, (x,), (v,))[1])(V_T)

    def obs(t, x, params, theta):
        return observe(t, x, bind(params, theta))

    def obs_tangent(t, x, params, theta, S_T, E):
        f = lambda xx, th: observe(t, xx, bind(params, th))
        value = f(x, theta)
        tangent = jax.vmap(lambda s, e: jax.jvp(f, (x, theta), (s, e))[1])(S_T, E)
        return value, tangent

    return jax.jit(step_rhs), jax.jit(jac_x), jax.jit(obs), jax.jit(obs_tangent)


def _theta_float64(theta):
    if not isinstance(theta, dict) or not theta:
        raise InputError(f"theta must be a non-empty dict name -> value of the differentiable parameters, got {theta!r}")
    out = {}
    for key, value in theta.items():
        arr = np.asarray(value)
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise InputError(f"theta[{key!r}] must be a real number or array, got {value!r}")
        arr = arr.astype(np.float64)
        if not np.all(np.isfinite(arr)):
            raise InputError(f"theta[{key!r}] = {value!r} is not finite")
        out[key] = arr
    return out


def _names(theta) -> list:
    """Names of the flattened components, in the order of ``ravel_pytree`` (sorted keys)."""
    names = []
    for path, value in jax.tree_util.tree_flatten_with_path(theta)[0]:
        key = path[0].key
        names += [key] if value.ndim == 0 else [f"{key}[{', '.join(map(str, i))}]" for i in np.ndindex(value.shape)]
    return names


@entry_point
def sensitivities(residual: Callable, x0, params, theta: dict, *, observe: Callable, t0: float, t1: float,
                  dt: float, solver, bind: Callable | None = None, scale=None, jacobian: str = "auto",
                  sparsity=None, tangents: bool = True, polish_tol: float = 1e-13, max_polish: int = 30,
                  max_refine: int = 60, max_dt_halvings: int = 4) -> Sensitivities:
    """Simulate by implicit Euler steps and return observations and their Jacobian d/dtheta.

    Parameters
    ----------
    residual, x0, t0, t1, dt, solver, scale, jacobian, sparsity, max_dt_halvings :
        As in :func:`jaxanm.integrate` (the residual contract is the same).
    params : pytree
        The residual's parameters; the differentiated leaves are replaced by ``bind``.
    theta : dict name -> float or array
        The differentiable parameters (float64).
    observe : callable ``(t, x, params) -> dict of arrays``
        Traceable (``jax.numpy``) observation, recorded at t0 and after every step.
    bind : callable ``(params, theta) -> params``, optional
        Traceable map from theta to the residual's params (e.g. ``K = exp(logK)``); default
        :func:`bind_paths` (theta keys are dotted paths of params leaves, ``"c.K"``).
    tangents : bool
        False: observations only (the polished forward map, e.g. for finite differences).
    polish_tol : float
        Relative (scaled) size of the last chord correction below which a step is polished.
    max_polish, max_refine : int
        Iteration caps of the polish and of the sensitivity refinement per step.

    Returns
    -------
    :class:`Sensitivities`.

    Raises
    ------
    InputError
        Bad arguments (unknown theta path, non-finite values, ...), before any computation.
    StepFailure
        A step failed (see :func:`jaxanm.integrate`), or polish or refinement diverged even
        with a fresh Jacobian.
    """
    start = time.perf_counter()
    x0, scale = check_run_inputs(x0, t0, t1, dt, solver, scale, jacobian, None, None)
    if not callable(observe):
        raise InputError("observe must be a callable (t, x, params) -> dict of arrays (jax.numpy)")
    if not (isinstance(polish_tol, float) and 0 < polish_tol < 1e-3):
        raise InputError(f"polish_tol must be a float in (0, 1e-3), got {polish_tol!r}")
    theta = _theta_float64(theta)
    params = params_float64(params)
    if bind is None:
        _check_paths(params, theta)
        bind = bind_paths
    theta_vec, unravel = ravel_pytree({k: jnp.asarray(v) for k, v in theta.items()})
    P = theta_vec.size
    basis = jax.vmap(unravel)(jnp.eye(P))
    theta_j = unravel(theta_vec)
    bound = bind(params, theta_j)
    step_rhs, jac_x, obs, obs_tangent = _kernels(residual, bind, observe)

    n = x0.size
    jacobian = jacobian_kind(jacobian, sparsity, n)
    if jacobian == "sparse" and sparsity is None:
        sparsity = detect_sparsity(residual, x0, x0, t0 + dt, dt, bound)
    stats, sst = Stats(), SensitivityStats()
    prob = Problem(residual, scale, stats, jacobian, sparsity)
    state = solver.init(prob)

    def snorm(v):  # scaled 2-norm per column of a (P, n) block
        return np.linalg.norm(np.atleast_2d(v) / scale, axis=1)

    def refresh(x, x_old, t, h):
        """The Jacobian at ``x`` factorised and installed as the solver's K* (counted)."""
        nonlocal state
        state = solver.with_factorization(state, prob.factorize_at(x, x_old, t, h, bound))
        sst.extra_factorizations += 1

    def kstar():
        """The solver's factorised K*."""
        return solver.factorization(state)

    def polish(x, x_old, t, h, k):
        """Chord iterations with the solver's K* until R(x) = 0 to round-off."""
        previous, refreshed = np.inf, False
        for _ in range(max_polish):
            r = prob.residual(x, x_old, t, h, bound)
            dx = -kstar().solve(r)
            size, ref = snorm(dx)[0], max(snorm(x)[0], np.finfo(float).tiny)
            if not np.isfinite(size):
                raise StepFailure("polish correction is not finite", step=k, t=float(t))
            stalled = size > 0.5 * previous
            if stalled and size > _FLOOR * polish_tol * ref:  # slow with this K*: exact Jacobian once
                if refreshed:
                    raise StepFailure(f"polish does not converge even with a fresh Jacobian "
                                      f"(relative correction {size / ref:.3g})", step=k, t=float(t))
                refresh(x, x_old, t, h)
                refreshed, previous = True, np.inf
                continue
            x = x + dx
            sst.polish_iterations += 1
            if size <= polish_tol * ref or stalled:  # converged, or stalled at the round-off floor
                break
            previous = size
        else:
            raise StepFailure(f"polish did not converge in {max_polish} iterations", step=k, t=float(t))
        sst.residual_norm.append(float(np.max(np.abs(prob.residual(x, x_old, t, h, bound)))))
        return x

    def tangent(x, x_old, t, h, S_old_T, k):
        """Refinement ``S <- S + K*^-1 (b - J S)`` for the P columns at once."""
        b = -np.asarray(step_rhs(x, x_old, t, h, params, theta_j, S_old_T, basis))
        S_T = kstar().solve(b.T).T
        rels, refreshed = [], False
        for _ in range(max_refine):
            res = b - np.asarray(jac_x(x, x_old, t, h, params, theta_j, S_T))
            dS_T = kstar().solve(res.T).T
            sst.refine_iterations += 1
            rel = float(np.max(snorm(dS_T) / np.maximum(snorm(S_T), np.finfo(float).tiny)))
            if not np.isfinite(rel):
                raise StepFailure("sensitivity refinement is not finite", step=k, t=float(t))
            S_T = S_T + dS_T
            rels.append(rel)
            stalled = len(rels) > 1 and rel > 0.5 * rels[-2]
            if rel <= polish_tol or (stalled and rel <= _FLOOR * polish_tol):
                sst.rate.append(float((rels[-1] / rels[0]) ** (1 / (len(rels) - 1))) if len(rels) > 1 else 0.0)
                return S_T
            if stalled:  # slow with this K*: exact Jacobian once
                if refreshed:
                    raise StepFailure(f"sensitivity refinement stalls at {rel:.3g} even with a fresh Jacobian",
                                      step=k, t=float(t))
                refresh(x, x_old, t, h)
                refreshed, rels = True, []
                S_T = kstar().solve(b.T).T
        raise StepFailure(f"sensitivity refinement did not converge in {max_refine} sweeps (last {rel:.3g})",
                          step=k, t=float(t))

    def one_step(x_old, S_old_T, t_old, h, k, depth):
        """A step of size h (halved on solver failure), polished, with its sensitivities."""
        nonlocal state
        t_new = jnp.float64(t_old + h)
        tic = time.perf_counter()
        try:
            x, state = solver.step(state, k, x_old, t_new, jnp.float64(h), bound)
        except StepFailure as failure:
            state = solver.state_after_failure(state, failure)
            if depth >= max_dt_halvings:
                raise
            stats.dt_halvings += 1
            xm, Sm = one_step(x_old, S_old_T, t_old, h / 2, k, depth + 1)
            return one_step(xm, Sm, t_old + h / 2, h / 2, k, depth + 1)
        tac = time.perf_counter()
        sst.wall_time["solver"] += tac - tic
        x = polish(x, x_old, t_new, jnp.float64(h), k)
        toc = time.perf_counter()
        sst.wall_time["polish"] += toc - tac
        S_T = tangent(x, x_old, t_new, jnp.float64(h), S_old_T, k) if tangents else None
        sst.wall_time["tangent"] += time.perf_counter() - toc
        return x, S_T

    def record(t, x, S_T):
        tic = time.perf_counter()
        if S_T is None:
            values.append(jax.tree_util.tree_map(np.asarray, obs(jnp.float64(t), x, params, theta_j)))
        else:
            v, tan = obs_tangent(jnp.float64(t), x, params, theta_j, S_T, basis)
            values.append(jax.tree_util.tree_map(np.asarray, v))
            tans.append(jax.tree_util.tree_map(lambda a: np.moveaxis(np.asarray(a), 0, -1), tan))
        times.append(float(t))
        sst.wall_time["observe"] += time.perf_counter() - tic

    values, tans, times = [], [], []
    x = x0
    S_T = np.zeros((P, n)) if tangents else None
    record(t0, x, S_T)
    n_steps = max(1, math.ceil((t1 - t0) / dt - 1e-9))
    t = float(t0)
    for k in range(1, n_steps + 1):
        t_new = t0 + k * dt if k < n_steps else float(t1)
        x_new, S_T = one_step(x, S_T, t, t_new - t, k, 0)
        r = prob.residual(x_new, x, jnp.float64(t_new), jnp.float64(t_new - t), bound)
        stats.residual_norm.append(float(np.max(np.abs(r))))
        stats.time_steps += 1
        x, t = x_new, t_new
        record(t, x, S_T)
    if not isinstance(values[0], dict):
        raise InputError(f"observe must return a dict of arrays, got {type(values[0]).__name__}")
    stack = lambda *leaves: np.stack(leaves)  # noqa: E731
    observed = {"t": np.asarray(times), **jax.tree_util.tree_map(stack, *values)}
    jac = jax.tree_util.tree_map(stack, *tans) if tangents else None
    wall = time.perf_counter() - start
    stats.close(wall)
    to_np = lambda v: jax.tree_util.tree_map(lambda a: np.asarray(a, dtype=np.float64), unravel(v))  # noqa: E731
    return Sensitivities(observed=observed, jacobian=jac, theta_names=_names(theta), x=np.asarray(x),
                         dx_dtheta=None if S_T is None else S_T.T.copy(), stats=stats,
                         sensitivity_stats=sst, wall_time_s=wall, unravel=to_np)


@entry_point
def loss_value_and_grad(loss: Callable, sens: Sensitivities, theta: dict):
    """``loss(observed, theta)`` and its total gradient from computed sensitivities.

    ``dL/dtheta = sum dL/dy . dy/dtheta + (partial dL/dtheta)`` with the partials of the loss
    by ``jax.vjp``.  Returns ``(float64 value, gradient shaped like theta)``.
    """
    theta = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in _theta_float64(theta).items()}
    t = sens.observed["t"]
    data = {k: v for k, v in sens.observed.items() if k != "t"}
    value, vjp = jax.vjp(lambda d, th: loss({"t": t, **d}, th), data, theta)
    if jnp.ndim(value) != 0:
        raise InputError(f"loss must return a scalar, got shape {jnp.shape(value)}")
    g_data, g_theta = vjp(jnp.ones_like(value))
    chain = sens.gradient(g_data)
    grad = {k: np.asarray(chain[k] + np.asarray(g_theta[k]), dtype=np.float64) for k in theta}
    return np.float64(value), grad


@entry_point
def value_and_grad(loss: Callable, residual: Callable, x0, params, theta: dict, *, observe: Callable,
                   **kwargs):
    """Value and gradient of ``loss(observed, theta)`` over an implicit-Euler simulation.

    ``observed = {"t": (M,), key: (M, ...)}`` are the values of ``observe(t, x, params)`` at
    t0 and after every step (see :func:`sensitivities`, which takes the same keyword
    arguments: ``t0``, ``t1``, ``dt``, ``solver``, ``bind``, ``scale``, ...).  ``loss`` is
    written in ``jax.numpy`` and returns a scalar.

    Returns ``(value, grad)``: a float64 scalar and a dict shaped like ``theta`` of float64
    arrays, ready for optax (run the optax update inside ``jaxanm.float64()`` so that it
    stays in float64)::

        with jaxanm.float64():
            value, grad = jaxanm.value_and_grad(loss, residual, x0, params, theta, observe=obs, ...)
            updates, state = opt.update(grad, state, theta)
    """
    sens = sensitivities(residual, x0, params, theta, observe=observe, **kwargs)
    return loss_value_and_grad(loss, sens, theta)
