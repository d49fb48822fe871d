"""The step-solver interface: :class:`StepSolver` (options as fields, ``init`` / ``step``),
:class:`SolverState` (what a solver carries between time steps), and the registry of solver
kinds (:func:`solver_kinds`, :func:`make_solver`)."""

from __future__ import annotations

import abc
import dataclasses
import weakref
from typing import ClassVar

import numpy as np

from .._checks import flag, integer, real
from .._factorization import Factorization
from .._problem import Problem
from ..errors import InputError, StepFailure

_KINDS: dict[str, type] = {}
"""Solver kind name -> concrete :class:`StepSolver` subclass (filled on subclass definition)."""

_RETAINED: weakref.WeakSet = weakref.WeakSet()
"""The K*s of states a caller keeps (:meth:`StepSolver.retain`): no step frees them.  Weak: a
K* leaves the set when its last reference goes."""


@dataclasses.dataclass
class StepReport:
    """What one :meth:`StepSolver.step` did besides the problem's work (which the
    :class:`~jaxanm._problem.Problem` counts): its fields are named as the
    :class:`~jaxanm.Stats` counters the time loop adds them to (the loop is their one writer).

    ``newton_iterations`` the Newton corrections made, ``substeps`` the ANM's continuation
    sub-steps, ``pade_accepted`` the series accepted through their Padé approximant, and, per
    accepted series, ``amax`` its validity range and ``orders`` its order.  A failed step's
    report (on the state attached to the failure) holds the work done before it failed.
    """

    newton_iterations: int = 0
    substeps: int = 0
    pade_accepted: int = 0
    amax: list = dataclasses.field(default_factory=list)
    orders: list = dataclasses.field(default_factory=list)


@dataclasses.dataclass(frozen=True)
class SolverState:
    """What a step solver carries from one time step to the next, as a value.

    ``problem`` is the step problem the solver was made for (:meth:`StepSolver.init`),
    ``factorization`` the factorised K* it holds (or None), ``accepted_residual`` the residual
    at the state the last :meth:`StepSolver.step` returned when the solver evaluated it there
    (the time loop then records it instead of evaluating it again), else None; ``report`` the
    :class:`StepReport` of the step that returned it (or of the failed step it is attached to),
    which the time loop records in the run's statistics.  A state is
    never changed in place: :meth:`StepSolver.step` returns a new one; who may free the factors
    of its K* is the rule of :class:`StepSolver`.  A solver that carries more subclasses this
    (frozen) dataclass.
    """

    problem: Problem
    factorization: Factorization | None = None
    accepted_residual: np.ndarray | None = None
    report: StepReport | None = None


class StepSolver(abc.ABC):
    """Base class of the nonlinear step solvers that :func:`jaxanm.integrate` accepts.

    A solver is a set of options: a frozen dataclass whose fields are the options, each
    validated in ``__post_init__`` (:class:`~jaxanm.InputError` naming the option and its
    allowed values).  What it carries across time steps is a :class:`SolverState` made by
    :meth:`init` and returned anew by every :meth:`step`; nothing outside the solver changes it
    except through the methods below.

    **Writing a solver.**  Subclass this class in a new module of ``jaxanm/_solver/`` (every
    module there is imported with the package), give it a class attribute ``kind`` (the name
    :func:`make_solver` and the scenes know it by; registered when the class is defined) and
    implement :meth:`step` (and :meth:`init` if the state carries more than a factorisation).
    The :class:`~jaxanm._problem.Problem` in the state gives residuals, tangents, counted
    factorisations and solves; what else a step did (Newton iterations, sub-steps, ...) goes in
    the new state's ``report`` (a :class:`StepReport`), which the time loop adds to the run's
    statistics (a solver never writes them itself).  ``reuses_factorization`` says whether the K* a state holds is
    carried to the next step (and so stored in checkpoints).

    **The arguments of a step** (the same for every solver): ``state`` the solver's state,
    ``step`` the index of the time step (for messages), ``x_old`` the state at the start of the
    step (or the ``z`` of a time scheme's stage), ``t`` the time at its end, ``dt`` its size
    (a stage's ``gamma h``) and ``params`` the residual's parameters; the step solves
    ``R(x, x_old, t, dt, params) = 0`` for ``x``.  ``start``, when given, is where the
    iteration starts instead of ``x_old`` (a time scheme's predictor of the stage); the time
    loop gives it only with a scheme other than implicit Euler, so a solver written without
    it serves implicit Euler.

    **Who frees a K\\*.**  LU factors are large (on fine clouds one takes most of a run's
    memory), so a step frees the factors of a K* it replaces before it factorises the next
    (:meth:`~jaxanm.Factorization.release`): two are never alive at once.  The rule that keeps
    this safe: *passing a state to* :meth:`step` *hands its K\\* over to that step*.  The time
    loop does so: it keeps only the state a step returned, or the one attached to its failure
    (:meth:`state_after_failure`).  A caller that will step from the same state again (a retry
    from the state before a step, two experiments from one state) says so first with
    :meth:`retain`: a step never frees a retained K*, whose factors go with the last reference
    to it.  A K* given to :meth:`with_factorization` is handed over likewise.  A freed K* is
    never wrong, only slow: its matrix is kept, and a solve with it factorises it again
    (counted in ``stats.factorizations``).
    """

    kind: ClassVar[str | None] = None
    reuses_factorization: ClassVar[bool] = True

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        kind = cls.__dict__.get("kind")
        if kind is None:
            return
        if not (isinstance(kind, str) and kind):
            raise TypeError(f"{cls.__qualname__}.kind must be a non-empty string, got {kind!r}")
        known = _KINDS.get(kind)
        if known is not None and (known.__module__, known.__qualname__) != (cls.__module__, cls.__qualname__):
            raise TypeError(f"solver kind {kind!r} of {cls.__module__}.{cls.__qualname__} is already "
                            f"{known.__module__}.{known.__qualname__}'s: give the new solver another kind")
        _KINDS[kind] = cls

    def init(self, problem: Problem) -> SolverState:
        """The state at the start of a run: the problem, no factorisation yet."""
        return SolverState(problem)

    @abc.abstractmethod
    def step(self, state: SolverState, step: int, x_old, t, dt, params,
             start=None) -> tuple[np.ndarray, SolverState]:
        """Solve the time step ``R(x, x_old, t, dt, params) = 0`` from ``x_old`` (or ``start``):
        ``(x, new state)``.

        The arguments are those of every solver (see the class).  ``state``'s K* is handed
        over to the step (freed if the step replaces it) unless it was retained
        (:meth:`retain`).  A step
        that cannot be solved raises :class:`~jaxanm.StepFailure` (or
        :class:`~jaxanm.NonFiniteError`), with the state to retry from attached
        (:meth:`state_after_failure`) when it differs from ``state``.
        """

    def accepted_residual(self, state: SolverState) -> np.ndarray | None:
        """The residual at the state the last :meth:`step` returned, if it evaluated it, else None."""
        return state.accepted_residual

    def factorization(self, state: SolverState) -> Factorization | None:
        """The factorised K* the state holds (or None)."""
        return state.factorization

    def with_factorization(self, state: SolverState, factorization: Factorization | None) -> SolverState:
        """``state`` with ``factorization`` as its K* (e.g. a Jacobian factorised by the caller,
        handed over like any state's K*), or with none (``None``: the next step factorises, as
        at the start of a run; the time loop drops a K* made at a step size far from the next
        step's this way)."""
        return dataclasses.replace(state, factorization=factorization)

    def retain(self, state: SolverState) -> SolverState:
        """``state``, its K* kept alive for a caller that will step from it again: no step
        frees a retained K* (see the class).  Returns ``state`` itself."""
        if state.factorization is not None:
            _RETAINED.add(state.factorization)
        return state

    def state_after_failure(self, state: SolverState, failure: StepFailure) -> SolverState:
        """The state to retry from after :meth:`step` from ``state`` raised ``failure``: the one
        the failed step attached (e.g. holding the K* it factorised before failing, which a
        retry then reuses), else ``state``."""
        attached = failure.solver_state
        return attached if isinstance(attached, SolverState) else state

    def to_checkpoint(self, state: SolverState):
        """What a checkpoint stores of ``state``: the matrix of the K* carried to the next step,
        or None (nothing carried)."""
        if not self.reuses_factorization or state.factorization is None:
            return None
        return state.factorization.matrix

    def from_checkpoint(self, state: SolverState, stored) -> SolverState:
        """``state`` with what :meth:`to_checkpoint` stored: K* factorised again from its matrix
        (the same factors, so a resumed run is bit-identical; not counted in
        ``stats.factorizations``: the time loop counts it in ``stats.resumes``)."""
        return self.with_factorization(state, Factorization(stored))


def solver_kinds() -> tuple[str, ...]:
    """The kind names of the registered step solvers, sorted (``"anm"``, ``"mnewton"``,
    ``"newton"``, and any :class:`StepSolver` subclass that declares a ``kind``)."""
    return tuple(sorted(_KINDS))


def make_solver(kind: str, **options) -> StepSolver:
    """The step solver of kind ``kind`` with ``options`` as its fields, e.g.
    ``make_solver("anm", order=9, tol=1e-8)``; the solver validates them.

    Raises :class:`~jaxanm.InputError` for an unknown kind (naming the known ones) or an option
    the kind does not take (naming those it takes).
    """
    cls = _KINDS.get(kind)
    if cls is None:
        raise InputError(f"unknown solver kind {kind!r}; the known kinds are {', '.join(solver_kinds())}")
    if dataclasses.is_dataclass(cls):
        fields = [f.name for f in dataclasses.fields(cls) if f.init]
        unknown = sorted(set(options) - set(fields))
        if unknown:
            raise InputError(f"solver kind {kind!r} has no option {unknown[0]!r}; it takes "
                             f"{', '.join(fields) if fields else 'no options'}")
    return cls(**options)


def failed(failure: StepFailure, state: SolverState) -> StepFailure:
    """``failure`` carrying the state to retry from (:meth:`StepSolver.state_after_failure`): a
    new exception, to raise in its place."""
    return failure.carrying(solver_state=state)


class Attempt(abc.ABC):
    """One time step of a built-in solver (``opts``) on ``problem``; ``fact`` is the K* it
    works with: the state's, replaced as the solver's algorithm says; ``report`` the
    :class:`StepReport` it fills."""

    def __init__(self, opts: StepSolver, problem: Problem, fact: Factorization | None):
        self.opts = opts
        self.problem = problem
        self.fact = fact
        self.report = StepReport()

    @abc.abstractmethod
    def run(self, step: int, x_old, t, dt, params, start=None) -> tuple[np.ndarray, np.ndarray | None]:
        """The accepted state and the residual there, or None when not evaluated: ``(x, R(x))``;
        the iteration starts from ``start`` (default ``x_old``)."""

    def factorized(self) -> Factorization:
        """``fact`` at a solve, which the algorithm has factorised (or kept) before solving."""
        if self.fact is None:
            raise RuntimeError(f"{type(self).__name__} solves with K* before factorising it")
        return self.fact

    def drop_factorization(self) -> None:
        """Give up the K* (the next factorisation is made where it is needed), its factors
        freed unless retained: one LU alive (the rule of :class:`StepSolver`)."""
        if self.fact is not None and self.fact not in _RETAINED:
            self.fact.release()
        self.fact = None


class AttemptSolver(StepSolver):
    """A solver whose step is one :class:`Attempt` of class ``attempt``: the new state holds
    the K* the attempt used last and the residual it evaluated at the accepted state, and a
    failure carries the state with that K* (for the retry)."""

    attempt: ClassVar[type[Attempt]]

    def step(self, state: SolverState, step: int, x_old, t, dt, params,
             start=None) -> tuple[np.ndarray, SolverState]:
        """One time step by the solver's :class:`Attempt` (see :meth:`StepSolver.step`)."""
        attempt = self.attempt(self, state.problem, state.factorization)
        try:
            x, residual = attempt.run(step, x_old, t, dt, params, start)
        except StepFailure as failure:
            # the same failure, carrying the state to retry from (with the failed step's report)
            raise failed(failure, dataclasses.replace(state, factorization=attempt.fact, accepted_residual=None,
                                                      report=attempt.report)) from failure.__cause__
        return x, dataclasses.replace(state, factorization=attempt.fact, accepted_residual=residual,
                                      report=attempt.report)


def check_tol(solver: str, tol) -> None:
    """``<solver>.tol`` is a float in (0, 1), else :class:`~jaxanm.InputError`."""
    real(f"{solver}.tol", tol, 0.0, 1.0, open_low=True, open_high=True, hint="e.g. tol=1e-6")


def check_count(solver: str, field: str, value, minimum: int) -> None:
    """``<solver>.<field>`` is an integer >= ``minimum``, else :class:`~jaxanm.InputError`."""
    integer(f"{solver}.{field}", value, minimum)


def check_flag(solver: str, field: str, value) -> None:
    """``<solver>.<field>`` is True or False, else :class:`~jaxanm.InputError`."""
    flag(f"{solver}.{field}", value)

