"""Critical loads as differentiable functions of the parameters.

:func:`critical_load` turns a fold found on a branch into a function ``params -> lam`` that
``jax.grad`` differentiates.  Its value relocates the fold for the given parameters by Newton
on the fold's augmented system (:mod:`jaxanm._augmented`), started from the last fold it
located; its derivative is the implicit function theorem at the fold, not a differentiation
through the walk's steps.  Where ``R(u, lam, p) = 0`` has a quadratic fold, ``R_u`` has a
one-dimensional null space with left null vector ``psi``, and the augmented system's
solution moves with ``p`` as

    d lam / d p = - psi^T R_p / psi^T R_lam,

(``psi^T R_lam != 0`` is what makes the point a fold and not a branch point).  ``R_p`` and
``R_lam`` are forward derivatives of the residual at the fold, so the rule costs one
Jacobian-vector product per direction and holds under ``jax.jit`` (the relocation runs on the
host through :func:`jax.pure_callback`).

A branch point has ``psi^T R_lam = 0``: a generic change of the parameters unfolds it into two
branches that no longer meet, so its lam is not a differentiable function of arbitrary
parameters; :func:`critical_load` refuses one.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._augmented import locate_fold
from .bordered import ContinuationFailure, ExtendedSystem
from .branch import Branch
from .errors import InputError
from .events import Event
from .stats import Stats


def critical_load(branch: Branch, event: Event) -> Callable:
    """The lam of a fold of ``branch`` as a function of the parameters, for ``jax.grad``.

    Parameters
    ----------
    branch : Branch
        The branch the fold was found on (:func:`jaxanm.continuation` or
        :func:`jaxanm.newton_continuation`): its residual, Jacobian options and scale are used.
    event : Event
        One of ``branch.events`` of kind ``"fold"``.

    Returns
    -------
    callable
        ``lam_c(params) -> scalar`` (float64): the fold's lam for ``params`` (a pytree shaped as
        the branch's), located by Newton on its augmented system from the last fold this
        function located (the event's at first); ``jax.grad``, ``jax.jvp`` and ``jax.jit`` apply
        to it.  Run it inside ``jaxanm.float64()`` when differentiating, so that the
        parameters' tangents are float64.  When the fold cannot be located from there (the
        parameters moved it out of Newton's basin, or the fold vanished), it raises
        :class:`~jaxanm.ContinuationFailure` (code ``"corrector"``), wrapped by JAX's runtime
        error when traced: follow the branch again at those parameters.

    Raises
    ------
    InputError
        If ``event`` is not a fold of ``branch`` or the branch does not record its source.
    """
    if not isinstance(event, Event) or event.kind != "fold":
        raise InputError(f"critical_load: event must be a fold, not {getattr(event, 'kind', event)!r}: a branch "
                         "point's lam is not a differentiable function of arbitrary parameters (a generic change "
                         "unfolds it)")
    if not any(event is e for e in branch.events):
        raise InputError("critical_load: event must be one of branch.events (a fold found on this branch)")
    if branch.source is None:
        raise InputError("critical_load: the branch does not record its residual (branch.source is None); "
                         "use a branch returned by jaxanm.continuation or jaxanm.newton_continuation")
    residual, options = branch.source.residual, branch.source.options
    last = {"U": np.append(event.u, event.lam), "phi": np.asarray(event.data["null_vector"])}
    # R_u's pattern, detected (from the residual's jaxpr: it holds for any params) at the first
    # location only, so that a design loop does not detect it again at every call
    pattern = {"sparsity": options["sparsity"]}

    def locate(params):
        """(lam, u, psi) of the fold for ``params``, on the host."""
        for U, phi in ((last["U"], last["phi"]), (np.append(event.u, event.lam), event.data["null_vector"])):
            system = ExtendedSystem(residual, U, params, branch.scale, options["jacobian"], pattern["sparsity"],
                                    Stats(), options["factorize"])
            pattern["sparsity"] = system.sparsity
            found = locate_fold(system, U, phi, step=event.step)
            if found.converged:
                phi = found.null[:-1, 0]
                last.update(U=found.U, phi=phi / np.linalg.norm(phi))
                return np.float64(found.U[-1]), found.U[:-1], found.psi
        raise ContinuationFailure("the fold was not located for these params by Newton on its augmented system "
                                  f"(last step {found.last_step:.3g}, scaled): follow the branch again at these params",
                                  step=event.step, lam=float(found.U[-1]), code="corrector")

    n = event.u.size
    shapes = (jax.ShapeDtypeStruct((), jnp.float64), jax.ShapeDtypeStruct((n,), jnp.float64),
              jax.ShapeDtypeStruct((n,), jnp.float64))

    def fold(params):
        return jax.pure_callback(locate, shapes, params)

    @jax.custom_jvp
    def lam_c(params):
        return fold(params)[0]

    @lam_c.defjvp
    def _tangent(primals, tangents):
        (params,), (dparams,) = primals, tangents
        lam, u, psi = fold(params)
        dR = jax.jvp(lambda p: residual(u, lam, p), (params,), (dparams,))[1]
        R_lam = jax.jvp(lambda s: residual(u, s, params), (lam,), (jnp.ones_like(lam),))[1]
        return lam, -jnp.vdot(psi, dR) / jnp.vdot(psi, R_lam)

    return lam_c
