"""The inputs of a run of :func:`jaxanm.integrate`, checked and prepared before any step: the
shapes and values of ``x0``, ``t0``, ``t1``, ``dt`` and ``scale``, the options that go
together, float64 parameters placed on the device, and the tangent's kind and pattern."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

from ._checks import real
from ._constant_step import ConstantStepSize
from ._saveat import SaveAt
from ._scheme import ImplicitEuler, SemiDiscrete, TimeScheme, stage_residual
from ._sensitivity_method import SensitivityMethod
from ._solver import StepSolver
from ._step_size import StepSizeController
from .errors import InputError
from .jacobian import dense_jacobian_fits, detect_sparsity

AUTO_SPARSE_SIZE = 400
"""Above this many unknowns ``jacobian="auto"`` picks the sparse Jacobian."""


def check_run_inputs(x0, t0, t1, dt, solver, scale, jacobian, saveat=None, controller=None):
    """Check a run's inputs before any computation (:class:`InputError` naming the fix);
    return ``x0`` and ``scale`` as float64 arrays.  Shared with :mod:`jaxanm.sensitivity`."""
    x0 = np.asarray(x0, dtype=np.float64)
    if x0.ndim != 1 or x0.size == 0:
        raise InputError(f"x0 must be a non-empty 1-D array of unknowns, got shape {x0.shape}; flatten your state")
    if not np.all(np.isfinite(x0)):
        raise InputError(f"x0 has {int(np.sum(~np.isfinite(x0)))} non-finite entries; give a finite initial state")
    for name, v in (("t0", t0), ("t1", t1), ("dt", dt)):
        real(name, v)
    if not dt > 0:
        raise InputError(f"dt must be > 0, got {dt!r}")
    if not t1 > t0:
        raise InputError(f"t1 must be > t0, got t0={t0!r}, t1={t1!r}")
    if not isinstance(solver, StepSolver):
        raise InputError(f"solver must be jaxanm.ANM(...), jaxanm.Newton(...), jaxanm.ModifiedNewton(...) or another "
                         f"jaxanm.StepSolver, got {solver!r}")
    scale = np.broadcast_to(np.asarray(1.0 if scale is None else scale, dtype=np.float64), x0.shape).copy()
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise InputError("scale must be positive and finite (a characteristic magnitude per unknown)")
    if jacobian not in ("auto", "dense", "sparse"):
        raise InputError(f"jacobian must be 'auto', 'dense' or 'sparse', got {jacobian!r}")
    if saveat is not None and not isinstance(saveat, SaveAt):
        raise InputError(f"saveat must be jaxanm.SaveAt(ts=..., steps=..., fn=..., params=...), got {saveat!r}")
    if controller is not None and not isinstance(controller, StepSizeController):
        raise InputError(f"controller must be jaxanm.StepController(...), jaxanm.ConstantStepSize() or None, "
                         f"got {controller!r}")
    return x0, scale


def check_run_options(checkpoint, checkpoint_every, resume, host_state, after_step, controller, sensitivity):
    """Check the options of :func:`jaxanm.integrate` that go together (:class:`InputError`)."""
    if checkpoint_every and checkpoint is None:
        raise InputError("checkpoint_every needs a checkpoint path: pass checkpoint='run.ckpt'")
    if resume and checkpoint is None:
        raise InputError("resume=True needs the checkpoint path to resume from")
    if host_state is not None and not (isinstance(host_state, tuple) and len(host_state) == 2
                                       and all(callable(f) for f in host_state)):
        raise InputError("host_state must be a (get, set) pair of callables")
    if sensitivity is None:
        return
    if not isinstance(sensitivity, SensitivityMethod):
        raise InputError(f"sensitivity must be a jaxanm.SensitivityMethod (e.g. "
                         f"jaxanm.ForwardSensitivity), got {sensitivity!r}")
    if after_step is not None or not _fixed(controller) or checkpoint is not None:
        raise InputError("sensitivity cannot be combined with after_step (params changed on the host are not "
                         "differentiable), a StepController or checkpoints (the sensitivities are not stored)")


def check_scheme(residual, scheme, sensitivity):
    """Check that ``scheme`` can serve ``residual`` (:class:`InputError` naming the argument and
    the fix); return the step-shaped residual the solvers work on and the scheme (None:
    implicit Euler)."""
    scheme = ImplicitEuler() if scheme is None else scheme
    if not isinstance(scheme, TimeScheme):
        raise InputError(f"scheme must be jaxanm.ImplicitEuler(), jaxanm.BDF2(), jaxanm.ESDIRK(order=3 or 4) or "
                         f"another jaxanm.TimeScheme, got {scheme!r}")
    if not (isinstance(residual, SemiDiscrete) or callable(residual)):
        raise InputError("residual must be a one-step residual R(x_new, x_old, t_new, dt, params) or a "
                         f"jaxanm.SemiDiscrete(F), got {residual!r}")
    if not (scheme.one_step or isinstance(residual, SemiDiscrete)):
        raise InputError(f"scheme={scheme!r} cannot use a one-step residual R(x_new, x_old, t_new, dt, params): "
                         "it is the residual of an implicit-Euler step, which says nothing of the time derivative "
                         "the scheme's stages need.  Pass the residual in semi-discrete form, "
                         "jaxanm.SemiDiscrete(F) with F(u, u_dot, t, params), or "
                         "jaxanm.SemiDiscrete(step_residual=R) when R depends on x_old only through "
                         "(x_new - x_old) / dt (see jaxanm.SemiDiscrete); or use scheme=jaxanm.ImplicitEuler()")
    if sensitivity is not None and not isinstance(scheme, ImplicitEuler):
        raise InputError(f"sensitivity supports only scheme=jaxanm.ImplicitEuler(), got scheme={scheme!r}: the "
                         "forward sensitivities are propagated through implicit-Euler steps")
    return stage_residual(residual), scheme


def _fixed(controller) -> bool:
    """Whether ``controller`` is that of fixed steps (None or :class:`~jaxanm.ConstantStepSize`)."""
    return controller is None or isinstance(controller, ConstantStepSize)


def jacobian_kind(jacobian: str, sparsity, n: int) -> str:
    """``"dense"`` or ``"sparse"``: ``jacobian`` itself, or for ``"auto"`` sparse when a pattern
    is given or there are more than :data:`AUTO_SPARSE_SIZE` unknowns.  A dense Jacobian that
    would not fit in memory is refused (:class:`InputError`) before anything is computed."""
    if jacobian == "auto":
        jacobian = "sparse" if (sparsity is not None or n > AUTO_SPARSE_SIZE) else "dense"
    if jacobian == "dense":
        dense_jacobian_fits(n, "jacobian='dense'", "use jacobian='sparse' (its pattern is found from the residual "
                            "when no sparsity= is given) or 'auto'")
    return jacobian


def tangent_pattern(residual, x0, t0, dt, params, jacobian: str, sparsity):
    """The tangent's kind (``"dense"`` or ``"sparse"``) and its sparsity pattern: the one given,
    or for a sparse tangent without one, found from the residual's jaxpr
    (:func:`~jaxanm.detect_sparsity`: it holds for every state, old state, time and step)."""
    jacobian = jacobian_kind(jacobian, sparsity, x0.size)
    if jacobian == "sparse" and sparsity is None:
        sparsity = detect_sparsity(residual, x0, x0, t0 + dt, dt, params)
    if sparsity is not None and not (callable(sparsity) or scipy.sparse.issparse(sparsity)):
        raise InputError("sparsity must be a scipy sparse matrix or a callable params -> matrix")
    return jacobian, sparsity


def params_float64(params):
    """Floating leaves of ``params`` as float64; warn when a lower precision was given."""
    lowered = []

    def cast(leaf):
        dtype = np.asarray(leaf).dtype if not hasattr(leaf, "dtype") else leaf.dtype
        if np.issubdtype(dtype, np.floating) and dtype != np.float64:
            lowered.append(str(dtype))
            return jnp.asarray(leaf, dtype=jnp.float64)
        return leaf

    params = jax.tree_util.tree_map(cast, params)
    if lowered:
        warnings.warn(
            f"{len(lowered)} params leaves were {sorted(set(lowered))}, converted to float64; their values "
            "may already have lost precision: build them as numpy float64 or inside jaxanm.float64()",
            stacklevel=3,
        )
    return params


def on_device(params, previous=None):
    """``params`` with every array leaf placed on the device once (``jax.device_put``).

    A jitted call converts each numpy leaf it is given (a copy to the device per leaf and per
    call); a step makes several calls with the same params (residuals, series orders,
    tangents), so the run hands them over as device arrays, converted once per change.

    ``previous``: the device params they replace.  A numpy leaf equal to the device array at
    the same place there (same shape, dtype and values) keeps that array instead of a new
    copy: an ``after_step`` hook that rebuilds its params every step then pays a transfer only
    for what changed (a Lagrangian hook: its moved points and normals, not its scalar
    constants).  The device values are the same either way.
    """
    if previous is not None:
        leaves, tree = jax.tree.flatten(params)
        old, old_tree = jax.tree.flatten(previous)
        if tree == old_tree:
            kept = [_unchanged(leaf, o) for leaf, o in zip(leaves, old)]
            moved = iter(jax.device_put([leaf for leaf, k in zip(leaves, kept) if k is None]))
            return jax.tree.unflatten(tree, [next(moved) if k is None else k for k in kept])
    return jax.device_put(params)


def _unchanged(leaf, old):
    """The device array to keep for ``leaf``: ``leaf`` itself if on the device already, ``old``
    if ``leaf`` is a numpy array or scalar of its shape, dtype and values; else None."""
    if isinstance(leaf, jax.Array):
        return leaf
    if (isinstance(leaf, (np.ndarray, np.generic)) and isinstance(old, jax.Array) and not old.weak_type
            and old.shape == leaf.shape and old.dtype == leaf.dtype and np.array_equal(np.asarray(old), leaf)):
        return old
    return None


def remapped_state(x, like):
    """The state an ``after_step`` hook returned in :class:`~jaxanm.Remap`, checked like ``x0``."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape != like.shape or not np.all(np.isfinite(x)):
        raise InputError(f"after_step returned a Remap state of shape {x.shape} with "
                         f"{int(np.sum(~np.isfinite(x)))} non-finite entries; "
                         f"it must be finite with shape {like.shape}")
    return x
