"""The two forms a residual is given in, and the stage residual each makes.

- A **one-step residual** ``R(x_new, x_old, t_new, dt, params)``: a plain callable, the
  residual of one implicit-Euler step (jaxanm's original contract).  Only implicit Euler can
  use it: nothing says what the step's time derivative is.
- A **semi-discrete residual** ``F(u, u_dot, t, params) = 0`` (:class:`SemiDiscrete`), the form
  of an ODE or DAE that IDA and every time scheme start from.  A scheme's stage equation is
  then ``R(x, z, t, gamma_h, params) = F(x, (x - z) / gamma_h, t, params)``.

A one-step residual that depends on ``x_old`` only through the difference quotient
``(L x_new - L x_old) / dt`` of a linear map ``L``, up to row scalings that depend on ``dt``
alone (the FSW residual on fixed points; :mod:`jaxanm.ida` explains it), *is* that stage
residual: ``R(x, z, t, gamma_h) = D(gamma_h) F(x, (x - z) / gamma_h, t)`` exactly.
``SemiDiscrete(step_residual=R)`` declares it so, and every scheme then uses ``R`` itself.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Callable

from ..errors import InputError


@dataclasses.dataclass(frozen=True, eq=False)
class SemiDiscrete:
    """A residual in semi-discrete form, for :func:`jaxanm.integrate` with any time scheme
    (and :func:`jaxanm.ida.integrate_ida`).

    Give exactly one of:

    Parameters
    ----------
    fn : callable ``(u, u_dot, t, params) -> (n,)``
        ``F(u, u_dot, t, params) = 0``, in ``jax.numpy`` and jet-compatible as a step
        residual is (:func:`jaxanm.integrate`).  An ODE ``u' = f(u, t)`` is
        ``F = u_dot - f(u, t)``; a DAE leaves ``u_dot`` out of its algebraic rows.
    step_residual : callable ``(x_new, x_old, t_new, dt, params) -> (n,)``
        A one-step residual of the difference-quotient form of the module docstring (the FSW
        model's on fixed points): ``F(u, u_dot, t) = R(u, u - dt u_dot, t, dt)`` for every
        ``dt``, up to a row scaling by ``dt`` alone.  Each stage is then solved on ``R``
        itself, with the stage's ``gamma h`` as its ``dt``.
    """

    fn: Callable | None = None
    step_residual: Callable | None = None

    def __post_init__(self):
        given = [name for name in ("fn", "step_residual") if getattr(self, name) is not None]
        if len(given) != 1:
            raise InputError("SemiDiscrete takes exactly one of fn (F(u, u_dot, t, params)) and step_residual "
                             f"(a one-step residual of difference-quotient form), got {given or 'neither'}")
        if not callable(getattr(self, given[0])):
            raise InputError(f"SemiDiscrete.{given[0]} must be a callable, got {getattr(self, given[0])!r}")

    @property
    def stage_residual(self) -> Callable:
        """``R(x, z, t, gamma_h, params)`` of every stage (module docstring): the same function
        object for the same ``fn``, so runs share their compiled code."""
        if self.step_residual is not None:
            return self.step_residual
        return quotient_residual(self.fn)


@functools.lru_cache(maxsize=64)
def quotient_residual(fn: Callable) -> Callable:
    """``(x, z, t, gamma_h, params) -> fn(x, (x - z) / gamma_h, t, params)``: the stage
    residual of a semi-discrete ``fn`` (one function object per ``fn``)."""

    def stage(x, z, t, gamma_h, params):
        return fn(x, (x - z) / gamma_h, t, params)

    return stage


def stage_residual(residual) -> Callable:
    """The step-shaped residual the step solvers work on: a one-step residual itself, or the
    stage residual of a :class:`SemiDiscrete`."""
    return residual.stage_residual if isinstance(residual, SemiDiscrete) else residual
