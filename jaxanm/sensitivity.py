"""Gradients of implicit-Euler simulations: :func:`sensitivities` (observations and their
Jacobian d/dtheta) and :func:`value_and_grad` (a scalar loss and its gradient, shaped like
theta, for optax), by forward sensitivities along the steps of :func:`jaxanm.integrate`.

How (polished steps, refinement with the step solver's own K*) and why forward rather than
adjoint: :mod:`jaxanm._forward_sensitivity`, whose :class:`ForwardSensitivity` is the
``sensitivity`` option these entry points pass to :func:`jaxanm.integrate`; the parameters
``theta`` and their binding into ``params``: :mod:`jaxanm._theta`.
"""

from __future__ import annotations

import time
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._forward_sensitivity import ForwardSensitivity, Sensitivities, SensitivityStats
from ._integrate import integrate
from ._run_inputs import check_run_inputs
from ._saveat import SaveAt
from ._scheme import stage_residual
from ._theta import bind_paths, theta_float64
from ._x64 import entry_point
from .errors import InputError

__all__ = ["ForwardSensitivity", "SensitivityStats", "Sensitivities", "bind_paths", "loss_value_and_grad",
           "sensitivities", "value_and_grad"]


@entry_point
def sensitivities(residual: Callable, x0, params, theta: dict, *, observe: Callable, t0: float, t1: float,
                  dt: float, solver, bind: Callable | None = None, scale=None, jacobian: str = "auto",
                  sparsity=None, tangents: bool = True, polish_tol: float = 1e-13, max_polish: int = 30,
                  max_refine: int = 60, max_dt_halvings: int = 4) -> Sensitivities:
    """Simulate by implicit Euler steps and return observations and their Jacobian d/dtheta.

    The steps are those of :func:`jaxanm.integrate`, with a :class:`ForwardSensitivity` as its
    ``sensitivity``.

    Parameters
    ----------
    residual, x0, t0, t1, dt, solver, scale, jacobian, sparsity, max_dt_halvings :
        As in :func:`jaxanm.integrate` (the residual contract is the same: a one-step residual
        or a :class:`~jaxanm.SemiDiscrete` one, stepped by implicit Euler).
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
    check_run_inputs(x0, t0, t1, dt, solver, scale, jacobian)
    residual = stage_residual(residual)  # the implicit-Euler step of a semi-discrete residual
    forward = ForwardSensitivity(residual, params, theta, observe, bind=bind, tangents=tangents,
                                 polish_tol=polish_tol, max_polish=max_polish, max_refine=max_refine)
    solution = integrate(residual, x0, forward.bound_params, t0=t0, t1=t1, dt=dt, solver=solver, scale=scale,
                         jacobian=jacobian, sparsity=sparsity, saveat=SaveAt(ts=(t1,)), max_dt_halvings=max_dt_halvings,
                         sensitivity=forward)
    return forward.result(solution.stats, time.perf_counter() - start)



@entry_point
def loss_value_and_grad(loss: Callable, sens: Sensitivities, theta: dict):
    """``loss(observed, theta)`` and its total gradient from computed sensitivities.

    ``dL/dtheta = sum dL/dy . dy/dtheta + (partial dL/dtheta)`` with the partials of the loss
    by ``jax.vjp``.  Returns ``(float64 value, gradient shaped like theta)``.
    """
    theta = {k: jnp.asarray(v, dtype=jnp.float64) for k, v in theta_float64(theta).items()}
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

