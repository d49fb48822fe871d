"""What the time loop hands a method that carries derivatives along the steps (the
``sensitivity`` option of :func:`jaxanm.integrate`, as diffrax's ``adjoint``), and the
do-nothing method the loop runs without one."""

from __future__ import annotations

import abc
from typing import NamedTuple

import numpy as np

from ._factorization import Factorization
from ._problem import Problem


class Polished(NamedTuple):
    """What :meth:`SensitivityMethod.after_solve` returns for a solved (sub-)step.

    ``x``: the state the trajectory goes on from (e.g. the solver's state polished to
    round-off); ``residual_norm``: ``|R(x)|_inf``, recorded in ``stats.residual_norm``;
    ``factorization``: a K* the method factorised for this step (e.g. the Jacobian at ``x``
    when its own iterations stalled with the solver's K*), which the loop installs as the
    solver's K* for the next step (:meth:`jaxanm.StepSolver.with_factorization`), or None.  The loop
    alone changes its solver state: a method reads the K* it is given and hands a new one back
    through this value.
    """

    x: np.ndarray
    residual_norm: float
    factorization: Factorization | None = None


class SensitivityMethod(abc.ABC):
    """Derivatives carried along the steps of :func:`jaxanm.integrate` (its ``sensitivity``
    option, as diffrax's ``adjoint``): the loop hands it every solved (sub-)step and every
    accepted step; :class:`jaxanm.sensitivity.ForwardSensitivity` is the one in jaxanm.

    ``polishes``: whether :meth:`after_solve` gives the state the run goes on from with its
    residual norm (the loop then leaves the check of the solved state's residual to it).
    """

    polishes: bool = True

    @abc.abstractmethod
    def start(self, problem: Problem, t0: float, x0: np.ndarray, params) -> None:
        """Before the first step: the run's problem and initial state."""

    @abc.abstractmethod
    def after_solve(self, factorization: Factorization | None, x_old, x, t, dt, step: int) -> Polished | None:
        """After the solver solved the (sub-)step from ``x_old`` to ``x`` at time ``t`` over
        ``dt``, with ``factorization`` the K* the solver's state holds (to read, not to change): a :class:`Polished`
        state the run goes on from, or None to go on from ``x`` as solved (the loop then checks
        its residual).  Failures raised here are not retried by dt halving."""

    @abc.abstractmethod
    def record(self, t: float, x: np.ndarray, params) -> None:
        """After every accepted step, with the state the run goes on from."""


class NoSensitivity(SensitivityMethod):
    """The loop's default: no derivatives; every solved state is taken as solved."""

    polishes = False

    def start(self, problem, t0, x0, params) -> None:
        """Nothing to start."""

    def after_solve(self, factorization, x_old, x, t, dt, step) -> None:
        """The state as solved."""
        return None

    def record(self, t, x, params) -> None:
        """Nothing to record."""
