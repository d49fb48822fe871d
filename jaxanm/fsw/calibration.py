"""Calibration of the flow law of an FSW scene: gradients of simulated observations w.r.t. K, A, n.

The plate's viscosity is ``mu = K T^A epsbar^(n-1) / 3``.  :func:`simulate` runs a scene with
forward sensitivities (:mod:`jaxanm.sensitivity`) and returns the observations — MLS values
of u, v, T at the scene's registration points (probes) and along its registration sections,
at t = 0 and after every step — together with their Jacobian with respect to ``theta``;
:func:`scene_value_and_grad` turns a loss of those observations into a float64 value and gradient
for optax.

``theta`` is a dict of material / thermal constants of the model (:data:`PARAMETERS`), usually
``{"logK": log(K), "A": A, "n": n}``; ``logK`` (natural log of K in SI units) is the natural
variable for K, which spans many orders of magnitude and enters mu as a factor.

What is (not) differentiated:

- Fixed-point scenes only.  A ``lagrangian`` scene moves its points with the flow and rebuilds
  the MLS stencils on the host after every step; the stencils (hence the residual) then depend
  on theta through the point positions, which this forward-sensitivity pass does not follow.
  Such scenes raise :class:`jaxanm.InputError` instead of returning a silently incomplete
  gradient: use the same physics on fixed points (effect ``tracers`` instead of
  ``lagrangian``, or neither).
- The viscosity scale ``mu_ref = K T0^A omega^(n-1) / 3`` only scales the momentum rows
  (:mod:`jaxanm.fsw.physics`); it stays at the scene's value, so theta changes the physics, not
  the row scaling.  Row scaling does not change the discrete solution, hence not its
  derivatives.
- ``T0`` and ``omega`` set the initial state and are not in :data:`PARAMETERS`; calibrate
  against several scenes (experiments) instead, see :func:`scene_value_and_grad`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from typing import Callable, Sequence

import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

from .. import sensitivity
from ..errors import InputError, StepFailure
from ..internal import entry_point, positive, real
from .discretisation import discretise
from .geometry import evaluate_stencils
from .physics import complete_fields
from .record import ProbeSites
from .scene import Scene

__all__ = ["PARAMETERS", "FitResult", "fit", "gauss_newton", "material_theta", "simulate", "theta_to_material",
           "scene_value_and_grad", "weighted_residuals"]

PARAMETERS = ("logK", "K", "A", "n", "eps0", "rho", "Cp", "k", "beta", "rho_t", "Cp_t", "k_t", "h", "Ta", "lam",
              "delta")
"""Names ``theta`` may hold: ``logK`` (= ln K) or ``K``, and constants of ``params["c"]``
(:data:`jaxanm.fsw.physics.CONSTANTS`) other than the initial-state data (``T0``, ``omega``),
the discretisation (``dr``) and the scales (``U``, ``Ts``, ``mu_ref``); ``delta`` is the
contact state of a scene with the ``slip`` effect (the initial state keeps the scene's)."""


def _bind(params, theta):
    """``params`` with ``params["c"]`` constants replaced by theta (``logK`` -> ``K = exp(logK)``)."""
    c = dict(params["c"])
    for name, value in theta.items():
        if name == "logK":
            c["K"] = jnp.exp(value)
        else:
            c[name] = value
    return {**params, "c": c}


@functools.lru_cache(maxsize=None)
def _observer(fields: tuple):
    """``observe(t, x, params)`` for a field layout: u, v, T at probes and sections (one per layout)."""

    def observe(t, x, p):
        """MLS values of u, v, T at the probe points and section samples (absent fields: 0, T0)."""
        X = x.reshape(len(fields), -1)
        out = {}
        for group, targets in p["obs"].items():
            out[group] = {}
            for name, st in targets.items():
                vals = {f: jnp.sum(st["phi"] * X[i][st["index"]], axis=1) for i, f in enumerate(fields)}
                full = complete_fields(vals, st["index"].shape[0], p["c"]["T0"], jnp)
                out[group][name] = {k: v[0] for k, v in full.items()} if group == "probes" else full
        return out

    return observe


_THETA_RANGES = {"n": (0.0, 2.0, True, "the power-law index"),
                 "A": (-20.0, 20.0, False, "the range jaxanm.fsw.Material accepts"),
                 "delta": (0.0, 1.0, False, "the contact state"),
                 "K": (0.0, None, True, "or calibrate logK")}
"""Allowed range of each calibrated parameter that has one: ``(low, high, low open, why)``."""


def _check_theta(theta) -> dict:
    """``theta`` as float64 scalars, each a known parameter within its range (:class:`InputError`)."""
    if not isinstance(theta, dict) or not theta:
        raise InputError(f"theta must be a non-empty dict such as {{'logK': 37.83, 'A': -3.3155, 'n': 0.1324}}, "
                         f"got {theta!r}")
    unknown = [k for k in theta if k not in PARAMETERS]
    if unknown:
        raise InputError(f"unknown calibration parameter(s) {unknown}: theta keys must be among {PARAMETERS} "
                         f"(T0 and omega set the initial state: vary them across scenes instead)")
    if "logK" in theta and "K" in theta:
        raise InputError("theta has both 'logK' and 'K': give one of them")
    out = {}
    for k, v in theta.items():
        arr = np.asarray(v)
        if arr.ndim != 0 or not np.issubdtype(arr.dtype, np.number) or not np.isfinite(arr):
            raise InputError(f"theta[{k!r}] must be a finite real scalar, got {v!r}")
        out[k] = np.float64(arr)
    for k, (low, high, open_low, hint) in _THETA_RANGES.items():
        if k in out:
            real(f"theta[{k!r}]", float(out[k]), low, high, open_low=open_low, hint=hint)
    return out


def _check_scene(scene) -> None:
    if not isinstance(scene, Scene):
        raise InputError(f"expected a jaxanm.fsw.Scene, got {type(scene).__name__}")
    if scene.has("lagrangian"):
        fixed = tuple("tracers" if e == "lagrangian" else e for e in scene.effects)
        raise InputError(
            f"scene {scene.name!r} moves its points (effect 'lagrangian'): the stencils rebuilt on the host "
            f"after every step depend on K, A, n through the point motion, which the gradient does not "
            f"follow. Calibrate on fixed points: scene.with_overrides({{'effects': {list(fixed)!r}}}) "
            f"(tracers), or drop 'lagrangian'")
    if scene.time.scheme != "euler":
        raise InputError(f"scene {scene.name!r} has time.scheme = {scene.time.scheme!r}: the sensitivities are "
                         "propagated through implicit-Euler steps; calibrate with time.scheme = 'euler'")
    if not scene.probes and not scene.sections:
        raise InputError(f"scene {scene.name!r} has no probes and no sections: nothing to observe; add "
                         f"[[probes]] or [[sections]] to the scene")


def material_theta(scene: Scene) -> dict:
    """``{"logK", "A", "n"}`` of a scene's material (float64)."""
    m = scene.material
    return {"logK": np.float64(math.log(m.K)), "A": np.float64(m.A), "n": np.float64(m.n)}


def theta_to_material(theta: dict) -> dict:
    """``{"K", "A", "n"}`` (K in Pa s^n K^-A) from a theta holding ``logK`` or ``K``, ``A``, ``n``."""
    K = math.exp(float(theta["logK"])) if "logK" in theta else float(theta["K"])
    return {"K": K, "A": float(theta["A"]), "n": float(theta["n"])}


def _setup(scene: Scene):
    """Model, params (with the observation stencils under ``"obs"``), initial state."""
    g = scene.geometry
    cloud, _, model, params, x0 = discretise(scene)
    obs: dict[str, dict] = {"probes": {}, "sections": {}}
    sites = ProbeSites.of(scene, cloud)  # at the probe positions, as in a run
    if sites.stencils is not None:  # None without probes
        for j, name in enumerate(sites.names):
            obs["probes"][name] = {"index": sites.stencils.index[j:j + 1], "phi": sites.stencils.phi[j:j + 1]}
    for s in scene.sections:
        st = evaluate_stencils(cloud.points, cloud.n_tool, g, np.linspace(s.start, s.end, s.samples))
        obs["sections"][s.name] = {"index": np.asarray(st.index), "phi": np.asarray(st.phi)}
    params["obs"] = obs
    return model, params, x0


@entry_point
def simulate(scene: Scene, theta: dict, *, solver=None, tangents: bool = True) -> sensitivity.Sensitivities:
    """Run ``scene`` with the material constants of ``theta``; observations and d/dtheta.

    Parameters
    ----------
    scene : Scene
        A fixed-point scene (no ``lagrangian`` effect) with probes and/or sections.
    theta : dict
        Calibration parameters (:data:`PARAMETERS`), e.g. ``{"logK": ..., "A": ..., "n": ...}``;
        they replace the scene's values.
    solver : jaxanm.ANM | jaxanm.Newton | jaxanm.ModifiedNewton, optional
        Default ``scene.solver.make()``.
    tangents : bool
        False: observations only (the polished forward map).

    Returns
    -------
    :class:`jaxanm.sensitivity.Sensitivities` whose ``observed`` is ``{"t": (M,), "probes":
    {name: {"u", "v", "T": (M,)}}, "sections": {name: {"u", "v", "T": (M, samples)}}}`` (MLS
    values at t = 0 and after every step; each probe at its position)
    and ``jacobian`` the same without ``"t"``, each leaf with a trailing axis over theta's keys
    (``theta_names``).
    """
    theta = _check_theta(theta)
    _check_scene(scene)
    model, params, x0 = _setup(scene)
    tm = scene.time
    return sensitivity.sensitivities(
        model.residual, x0, params, theta, observe=_observer(model.fields), bind=_bind, t0=0.0,
        t1=tm.t_end, dt=tm.dt, solver=scene.solver.make() if solver is None else solver,
        scale=model.scale(), jacobian="sparse", sparsity=model.sparsity(params), tangents=tangents)


@entry_point
def scene_value_and_grad(loss: Callable, scenes, theta: dict, *, solver=None):
    """Value and gradient of ``loss(observed, theta)`` over one scene or several (experiments).

    Parameters
    ----------
    loss : callable
        ``loss(observed, theta) -> scalar`` in ``jax.numpy``; ``observed`` is the ``observed``
        of :func:`simulate` for one scene, or the list of them (in order) when ``scenes`` is a
        sequence, e.g. experiments at several initial temperatures and tool speeds.
    scenes : Scene or sequence of Scene
    theta : dict
        Calibration parameters (:data:`PARAMETERS`), e.g. ``{"logK", "A", "n"}``.
    solver : optional step solver for every scene (default: each scene's own).

    Returns
    -------
    ``(value, grad)``: float64 scalar and a dict of float64 scalars keyed like ``theta``.  For
    optax, run the update inside ``jaxanm.float64()``.

    Raises
    ------
    jaxanm.InputError
        Unknown parameter name, Lagrangian scene, scene without observations — before any
        simulation.
    """
    single = isinstance(scenes, Scene)
    scene_list = [scenes] if single else list(scenes)
    if not scene_list:
        raise InputError("scenes is empty: give a Scene or a non-empty sequence of scenes")
    theta = _check_theta(theta)
    for s in scene_list:
        _check_scene(s)
    runs = [simulate(s, theta, solver=solver) for s in scene_list]
    return _contract(loss, runs, theta, single)


def _contract(loss, runs: Sequence[sensitivity.Sensitivities], theta: dict, single: bool):
    """Loss value and the chain rule through the observations' Jacobians."""
    data = [r.observed for r in runs]
    th = {k: jnp.asarray(v) for k, v in theta.items()}
    value, vjp = jax.vjp(lambda d, t: loss(d[0] if single else d, t), data, th)
    if jnp.ndim(value) != 0:
        raise InputError(f"loss must return a scalar, got shape {jnp.shape(value)}")
    g_data, g_theta = vjp(jnp.ones_like(value))
    grad = {k: np.float64(g_theta[k]) for k in theta}
    for run, g in zip(runs, g_data):
        chain = run.gradient({k: v for k, v in g.items() if k != "t"})
        for k in theta:
            grad[k] += np.float64(chain[k])
    return np.float64(value), grad


def gauss_newton(step: float = 1.0):
    """An optax transformation: the Gauss-Newton step ``-alpha F^-1 grad`` of a least-squares loss.

    ``update(grad, state, params, *, gn_matrix)`` returns ``-alpha F^-1 grad`` (shaped like
    ``grad``), ``F = J^T J`` the Gauss-Newton matrix of ``0.5 |r|^2`` (``J = dr/dtheta``, which
    forward sensitivities give for free) and ``alpha = state["step"]`` the step length (1: the
    full Gauss-Newton step), which the fit loop shortens after a rejected step and lengthens
    after accepted ones (:func:`fit`).  The direction is affine invariant: the near-degenerate
    K-A direction (condition numbers ~1e4-1e6, docs/notes/gradients.md) costs nothing extra.
    Why not Adam or ``optax.lbfgs``: Adam's per-coordinate scaling cannot undo an ill-conditioned
    direction that mixes log K and A (many hundreds of steps expected; not measured), and optax's
    L-BFGS line search evaluates the objective inside ``jax.lax`` loops, into which a host-side
    simulation cannot be traced.

    Returns an ``optax.GradientTransformationExtraArgs`` (state: ``{"step": alpha}``).
    """
    import optax

    def init(params):
        return {"step": jnp.asarray(step, dtype=jnp.float64)}

    def update(grad, state, params=None, *, gn_matrix, **extra):
        g, unravel = jax.flatten_util.ravel_pytree(grad)
        direction = -jnp.linalg.solve(jnp.asarray(gn_matrix), g)
        return unravel(state["step"] * direction), state

    return optax.GradientTransformationExtraArgs(init, update)


def weighted_residuals(observed, data, sigma, jacobian=None):
    """Weighted residuals ``r = (model - data) / sigma`` over every u, v, T leaf named in ``sigma``.

    ``observed`` and ``data`` have the layout of :func:`simulate`'s ``observed`` (``"t"`` is
    skipped); ``sigma`` maps ``"u"``, ``"v"``, ``"T"`` to noise levels (fields not named are
    left out).  Returns ``r`` (flat), or ``(r, J)`` with ``J = dr/dtheta`` (one row per
    residual, one column per ``theta_names`` entry) when ``jacobian`` is given;
    ``J^T J`` is the Gauss-Newton (Fisher) matrix.
    """
    res, jac = [], []
    flat_obs = jax.tree_util.tree_flatten_with_path({k: v for k, v in observed.items() if k != "t"})[0]
    flat_data = jax.tree_util.tree_leaves({k: v for k, v in data.items() if k != "t"})
    flat_jac = jax.tree_util.tree_leaves(jacobian) if jacobian is not None else [None] * len(flat_obs)
    if len(flat_data) != len(flat_obs):
        raise InputError("data must have the structure of the simulated observations (probes, sections)")
    for (path, model), measured, dmodel in zip(flat_obs, flat_data, flat_jac):
        field = path[-1].key
        if field not in sigma:
            continue
        res.append(((np.asarray(model) - np.asarray(measured)) / sigma[field]).reshape(-1))
        if dmodel is not None:
            jac.append(np.asarray(dmodel).reshape(-1, dmodel.shape[-1]) / sigma[field])
    r = np.concatenate(res)
    return (r, np.concatenate(jac)) if jacobian is not None else r


@dataclasses.dataclass
class FitResult:
    """Result of :func:`fit`: fitted ``theta``, per-iteration ``loss_history`` (accepted steps,
    starting with the start point), ``theta_history``, number of simulations (``evaluations``,
    each with sensitivities), the Gauss-Newton matrix ``gn_matrix`` at the fitted point
    (its inverse is the parameters' covariance for the given sigmas), and ``converged``: False
    when ``max_iter`` simulations ran out before a stopping test held (the fitted values and
    their covariance are then not those of the minimum; raise ``max_iter``).
    """

    theta: dict
    loss_history: list
    theta_history: list
    evaluations: int
    gn_matrix: np.ndarray
    theta_names: list
    converged: bool


def _check_fit_inputs(scenes, data, start: dict, sigma: dict):
    """Check :func:`fit`'s experiments, measurements, start and noise levels
    (:class:`InputError`); return the scenes and data as lists and the start as theta."""
    scenes, data = list(scenes), list(data)
    if len(scenes) != len(data) or not scenes:
        raise InputError(f"give one data set per scene: {len(scenes)} scenes, {len(data)} data sets")
    if not (isinstance(sigma, dict) and sigma and all(k in ("u", "v", "T") for k in sigma)):
        raise InputError(f"sigma must map some of 'u', 'v', 'T' to positive noise levels, got {sigma!r}")
    for k, v in sigma.items():
        positive(f"sigma[{k!r}]", v, hint="the noise level of the measured field")
    theta = _check_theta(start)
    for s in scenes:
        _check_scene(s)
    return scenes, data, theta


def _gauss_newton_terms(scenes, data, theta: dict, sigma: dict, solver):
    """Simulate every experiment at ``theta``: the loss ``0.5 r^T r``, its gradient ``J^T r``
    and the Gauss-Newton matrix ``J^T J`` of the weighted residuals of all of them."""
    rs, js = [], []
    for s, d in zip(scenes, data):
        run = simulate(s, theta, solver=solver)
        r, J = weighted_residuals(run.observed, d, sigma, run.jacobian)
        rs.append(r)
        js.append(J)
    r, J = np.concatenate(rs), np.concatenate(js)
    return 0.5 * float(r @ r), J.T @ r, J.T @ J


def _stopped(updates: dict, theta: dict, names: list, loss: float, grad, F, xtol: float, ftol: float) -> bool:
    """:func:`fit`'s stopping test after an accepted step ``updates`` to ``theta``: every
    component below ``xtol * max(1, |theta|)``, or the decrease a full Gauss-Newton step
    predicts, ``0.5 g^T F^-1 g``, below ``ftol * max(1, loss)``."""
    step = np.array([float(updates[k]) for k in names])
    decrement = 0.5 * float(grad @ np.linalg.solve(F, grad))  # predicted decrease of a full step
    return bool(np.all(np.abs(step) <= xtol * np.maximum(1.0, np.abs([theta[k] for k in names])))
                or decrement <= ftol * max(1.0, loss))


@entry_point
def fit(scenes: Sequence[Scene], data: Sequence[dict], start: dict, *, sigma: dict, solver=None,
        max_iter: int = 20, xtol: float = 1e-9, ftol: float = 1e-6, callback: Callable | None = None) -> FitResult:
    """Weighted least-squares calibration of ``theta`` against measured observations.

    Minimises ``0.5 sum ((y_model - y_data) / sigma_field)^2`` over the probe and section
    values of every scene (experiment) by Gauss-Newton steps (the optax transformation
    :func:`gauss_newton`) with step-length control: a step that does not lower the loss (or
    whose run fails) is rejected and the step length divided by 8; after an accepted step it
    is multiplied by 4, up to the full Gauss-Newton step.

    Parameters
    ----------
    scenes : sequence of Scene
        The experiments (fixed-point scenes).
    data : sequence of dict
        Per scene, measurements with the structure of :func:`simulate`'s ``observed``.
    start : dict
        Initial theta (:data:`PARAMETERS`).
    sigma : dict
        Noise standard deviation per field, e.g. ``{"T": 0.02, "u": 1e-5, "v": 1e-5}``;
        fields not named are not fitted.
    max_iter : int
        Maximum number of simulations.
    xtol, ftol : float
        Stop when every component of an accepted step is below ``xtol * max(1, |theta|)``, or
        when the decrease a full Gauss-Newton step predicts, ``0.5 g^T F^-1 g``, is below
        ``ftol * max(1, loss)`` (the loss is in units of the noise variance: nothing left to gain).
    callback : callable ``(iteration, theta, loss)``, optional
        Called after every simulation.
    """
    import optax

    scenes, data, theta = _check_fit_inputs(scenes, data, start, sigma)
    names = sorted(theta)  # the flattening order of theta (and of the Jacobians' last axis)

    opt = gauss_newton(1.0)
    params = {k: jnp.asarray(v) for k, v in theta.items()}
    state = opt.init(params)
    loss, grad, F = _gauss_newton_terms(scenes, data, theta, sigma, solver)
    evaluations = 1
    history, thetas = [loss], [dict(theta)]
    if callback is not None:
        callback(0, dict(theta), loss)
    converged = False
    while evaluations < max_iter:
        g = {k: jnp.asarray(grad[i]) for i, k in enumerate(names)}
        updates, _ = opt.update(g, state, params, gn_matrix=F)
        trial = optax.apply_updates(params, updates)
        trial_theta = {k: np.float64(v) for k, v in trial.items()}
        try:
            _check_theta(trial_theta)
            new = _gauss_newton_terms(scenes, data, trial_theta, sigma, solver)
        except (InputError, StepFailure):  # outside the admissible range, or the run failed: shorter step
            new = None
        evaluations += 1
        if callback is not None:
            callback(evaluations - 1, trial_theta, np.nan if new is None else new[0])
        if new is not None and new[0] < loss:
            params, theta = trial, trial_theta
            loss, grad, F = new
            history.append(loss)
            thetas.append(dict(theta))
            state = {"step": jnp.minimum(1.0, 4.0 * state["step"])}
            if _stopped(updates, theta, names, loss, grad, F, xtol, ftol):
                converged = True
                break
        else:
            state = {"step": state["step"] / 8.0}
            if state["step"] < 1e-6:  # no decrease even along a tiny Gauss-Newton step: at the minimum
                converged = True
                break
    if not converged:
        warnings.warn(f"calibration.fit: max_iter = {max_iter} simulations ran out before the fit converged "
                      f"(loss {loss:.6g}); the fitted values are not the minimum: raise max_iter", stacklevel=2)
    return FitResult(theta=theta, loss_history=history, theta_history=thetas, evaluations=evaluations,
                     gn_matrix=F, theta_names=names, converged=converged)
