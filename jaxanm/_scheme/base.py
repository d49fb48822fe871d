"""The time-scheme interface: :class:`TimeScheme` (a frozen set of options whose
:meth:`~TimeScheme.step` builds a step from stage solves), :class:`SchemeStep` (what a step
gives back), :class:`StageSolve` (what the time loop hands a step to solve one stage with) and
the registry of scheme names (:func:`make_scheme`, :func:`scheme_names`).

A scheme never touches the nonlinear solver.  Every stage equation it poses is
implicit-Euler-shaped, ``R(x, z, t, gamma_h, params) = 0`` with
``R = F(x, (x - z) / gamma_h, t, params)`` for the semi-discrete residual ``F(u, u_dot, t,
params) = 0`` (:class:`~jaxanm.SemiDiscrete`): the scheme chooses ``z`` (what the stage's
derivative is measured from), the stage time ``t`` and ``gamma_h``; the step solver (ANM,
Newton, modified Newton) solves it from ``z`` as it solves an implicit-Euler step from
``x_old``, and one factorised K* serves every stage with the same ``gamma_h``.
"""

from __future__ import annotations

import abc
import math
from typing import Callable, NamedTuple, Protocol

import numpy as np

from ..errors import InputError


class StageSolve(Protocol):
    """What the time loop gives :meth:`TimeScheme.step` to solve one stage: the ``x`` with
    ``R(x, z, t, gamma_h, params) = 0``, solved by the run's step solver from ``start`` (the
    scheme's predictor of the stage; default ``z``).  ``last`` marks the stage whose solution
    ends the step (its residual is checked and recorded as the step's).  A stage that cannot
    be solved raises :class:`~jaxanm.StepFailure`: the whole step is retried as the
    controller says."""

    def __call__(self, z: np.ndarray, t: float, gamma_h: float, last: bool = False,
                 start: np.ndarray | None = None) -> np.ndarray:
        ...


class SchemeStep(NamedTuple):
    """One step of a :class:`TimeScheme`: ``x`` the state at its end, ``history`` the scheme's
    state after it (what the next step needs: past states, a derivative; None when
    nothing), ``embedded`` the embedded solution at its end (the error estimate of a
    Runge-Kutta pair), else None."""

    x: np.ndarray
    history: object
    embedded: np.ndarray | None = None


class Interpolant(NamedTuple):
    """A step's dense output: ``at(theta)``, the state at the fraction ``theta`` in [0, 1] of
    the step (the step's own states at 0 and 1), ``order`` the global order of its values
    between the steps' ends (at most the scheme's)."""

    at: Callable[[float], np.ndarray]
    order: int


class TimeScheme(abc.ABC):
    """Base class of the time schemes :func:`jaxanm.integrate` accepts (its ``scheme``).

    A scheme is a frozen dataclass of options.  What it carries from one step to the next is
    its *history*, a value (None at the start, and after a
    :class:`~jaxanm.Remap`, which restarts it) that :meth:`step` returns anew and the time
    loop keeps in its record and in checkpoints.

    Attributes: ``name`` (the name :func:`make_scheme` and the scenes' ``time.scheme`` know it
    by), ``order`` (of its solution: global error ``O(h^order)``), ``one_step`` (whether it
    serves a one-step residual ``R(x, x_old, t, dt, params)``: only implicit Euler, whose step
    is that residual; the others need the residual in semi-discrete form), ``error_order``
    (q: the local error estimate is ``O(h^(q+1))``, so the step controller's exponent is
    ``1 / (q + 1)``), ``estimate_history`` (the accepted steps before the current one that
    the estimate reads, in the quantities the controller measures) and ``max_growth`` (the
    largest ratio of a step to the one before that keeps the scheme stable; the step
    controller caps its growth there).  Between the steps' ends, :meth:`interpolant` gives
    the state (what :class:`~jaxanm.SaveAt`'s ``fn_ts`` observe).
    """

    name: str
    order: int
    one_step: bool = False
    error_order: int
    estimate_history: int = 0
    max_growth: float = math.inf

    @abc.abstractmethod
    def step(self, history, x: np.ndarray, t: float, h: float, solve: StageSolve) -> SchemeStep:
        """The step from state ``x`` at time ``t`` over ``h``, its stages solved by ``solve``."""

    @abc.abstractmethod
    def local_error(self, y_new, y_embedded, y_now, past: tuple, h: float):
        """The estimate of the step's local error in the measured quantities, or None when the
        step has none (too little history): ``y_new`` and ``y_now`` the measured state at the
        step's end and start, ``y_embedded`` the measured embedded solution (or None),
        ``past`` the ``(y, size)`` of the accepted steps before, newest first (at most
        ``estimate_history``), ``h`` the step's size."""

    def interpolant(self, history, x: np.ndarray, step: SchemeStep, h: float) -> "Interpolant":
        """The dense output of ``step`` (from ``x``, the scheme's ``history`` before it, over
        ``h``): the state at any fraction of the step (:class:`Interpolant`).  By default the
        line through the step's two states, of first order (implicit Euler's own)."""
        return Interpolant(lambda theta: x + theta * (step.x - x), order=1)

    def restart(self, history):
        """The history after the state was remapped (:class:`~jaxanm.Remap`): the past states
        and derivatives are those of another discretisation, so the scheme starts again."""
        return None


_NAMES: dict[str, Callable[[], TimeScheme]] = {}
"""Scheme name -> a factory of the scheme (filled by the scheme modules)."""


def register(name: str, factory: Callable[[], TimeScheme]) -> None:
    """Make :func:`make_scheme` know ``name`` (each scheme module registers its schemes)."""
    _NAMES[name] = factory


def scheme_names() -> tuple[str, ...]:
    """The names of the time schemes, in order of their order (``"euler"``, ``"bdf2"``, ...)."""
    return tuple(sorted(_NAMES, key=lambda n: (_NAMES[n]().order, n)))


def make_scheme(name: str) -> TimeScheme:
    """The time scheme called ``name`` (:func:`scheme_names`), e.g. ``make_scheme("esdirk3")``;
    :class:`~jaxanm.InputError` naming the known ones for another name."""
    factory = _NAMES.get(name)
    if factory is None:
        raise InputError(f"unknown time scheme {name!r}; the known schemes are {', '.join(scheme_names())}")
    return factory()
