"""The time loop's record: what a run carries from one accepted step to the next, as a value.

:class:`LoopState` is an immutable record; the loop (:mod:`jaxanm._loop`) replaces it
(``_replace``) at every change and nothing else holds it.  What the run keeps for its
:class:`~jaxanm.Solution` is a :class:`Kept` of :class:`Log` values: append-only sequences
whose every version stays what it was, so a record (or a checkpoint of it) never changes
under whoever holds it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Callable, NamedTuple

import numpy as np

from .checkpoint import to_host

if TYPE_CHECKING:
    from ._solver import SolverState


class Log(NamedTuple):
    """An append-only sequence as a value: the first ``size`` entries of ``items``.

    :meth:`append` returns a new log; the old one still reads its own ``size`` entries.
    Appending to the newest version (the loop's case) extends the shared list in place, in
    constant time; appending to an older one copies its entries first.
    """

    items: list
    size: int

    @classmethod
    def of(cls, items) -> Log:
        """A log of ``items`` (copied into a new list)."""
        items = list(items)
        return cls(items, len(items))

    def append(self, item) -> Log:
        """The log with ``item`` after its entries."""
        items = self.items if len(self.items) == self.size else self.items[:self.size]
        items.append(item)
        return Log(items, self.size + 1)

    def tolist(self) -> list:
        """The entries, as a new list."""
        return self.items[:self.size]


class Kept(NamedTuple):
    """What a run keeps (:class:`~jaxanm.SaveAt`): ``ts`` and ``xs`` the saved times and
    states, ``ps`` the host params at them (``SaveAt(params=True)``, else None), ``observed``
    the values of ``SaveAt.fn`` at t0 and after every step (or at its ``fn_ts``),
    ``{"t": Log, key: Log}`` (None without ``fn``)."""

    ts: Log
    xs: Log
    ps: Log | None
    observed: dict | None

    @classmethod
    def start(cls, t0, x0: np.ndarray, params, keep_params: bool, observe: Callable | None) -> Kept:
        """What is kept at t0: the initial state always, and its observation."""
        ps = Log.of([to_host(params)]) if keep_params else None
        return cls(Log.of([float(t0)]), Log.of([x0.copy()]), ps, _observed(observe, t0, x0, params, None))

    def after(self, t: float, x: np.ndarray, params, *, saved: bool, observe: Callable | None) -> Kept:
        """What is kept after an accepted step ending at ``t`` in ``x`` (saved or not)."""
        kept = self
        if saved:
            kept = kept._replace(ts=kept.ts.append(t), xs=kept.xs.append(x.copy()))
            if kept.ps is not None:
                kept = kept._replace(ps=kept.ps.append(to_host(params)))  # numpy, as the user gave them
        return kept._replace(observed=_observed(observe, t, x, params, kept.observed))

    def observing(self, observations, params, observe: Callable) -> Kept:
        """``observe`` at each ``(time, state)`` of ``observations`` appended to what is kept
        (a step's dense output at ``SaveAt.fn_ts``, with the params the step was solved with)."""
        observed = self.observed
        for t, x in observations:
            observed = _observed(observe, t, x, params, observed)
        return self._replace(observed=observed)


def _observed(observe, t, x, params, observed):
    """``observed`` with ``observe(t, x, params)`` appended (created at the first call);
    unchanged without ``observe``."""
    if observe is None:
        return observed
    values = observe(t, x, params)
    if observed is None:
        observed = {"t": Log([], 0), **{key: Log([], 0) for key in values}}
    observed = dict(observed, t=observed["t"].append(float(t)))
    for key, value in values.items():
        observed[key] = observed[key].append(np.asarray(value))
    return observed


class LoopState(NamedTuple):
    """The loop's record between steps (and what a checkpoint stores of a run).

    Attributes
    ----------
    k : int
        Accepted steps so far (the index of the last one; 0 at t0).
    t : float
        The time reached.
    x : ndarray (n,)
        The state at ``t`` (after any ``Remap``).
    params : pytree
        The residual's parameters from ``t`` on, on the device.
    solver_state : SolverState
        What the step solver carries to the next solve (its K*).  Within a step the loop
        replaces it after every solve, so a checkpoint written then (interruption, failure)
        holds the newest K*.
    controller_state :
        The step-size controller's state (:meth:`jaxanm.StepController.init`).
    scheme_state :
        The time scheme's history after the last accepted step (:class:`jaxanm.TimeScheme`:
        BDF2's previous state, an ESDIRK's derivative; None for implicit Euler and at the start).
    kstar_dt : float or None
        The stage size (``gamma h``; h for implicit Euler) the solver's K* was factorised at
        (the controller's ``refactor_ratio`` compares the next stage's with it); None before
        the first factorisation.
    kept : Kept
        The saved times, states, params and observations so far.
    """

    k: int
    t: float
    x: np.ndarray
    params: object
    solver_state: SolverState
    controller_state: object
    scheme_state: object
    kstar_dt: float | None
    kept: Kept
