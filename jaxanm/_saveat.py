"""What a run keeps: :class:`SaveAt`, the one description of saving and observing (as diffrax's
``SaveAt``), read by :func:`jaxanm.integrate` and by the FSW recorder alike."""

from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

from ._checks import flag, integer
from .errors import InputError


def fixed_steps(t0: float, t1: float, dt: float) -> int:
    """Number of fixed steps of ``dt`` from ``t0`` to ``t1`` (the last one shortened to end on t1)."""
    return max(1, math.ceil((t1 - t0) / dt - 1e-9))


def step_end(t0: float, t1: float, dt: float, k: int, n_steps: int) -> float:
    """End time of fixed step ``k`` (of ``n_steps``), exactly as the time loop computes it."""
    return t0 + k * dt if k < n_steps else float(t1)


@dataclasses.dataclass(frozen=True)
class SaveAt:
    """What :func:`jaxanm.integrate` keeps of a run.

    Parameters
    ----------
    ts : sequence of float, optional
        Save the state at these times: with fixed steps at the steps ending nearest to them,
        with a :class:`~jaxanm.StepController` the steps end exactly on them.
    steps : int, optional
        Or save every ``steps``-th step.  Neither ``ts`` nor ``steps``: every step.  ``t0`` and
        ``t1`` are always saved.
    fn : callable ``(t, x, params) -> dict of arrays``, optional
        Observed at ``t0`` and after every accepted step (probe histories), returned in
        ``Solution.observed`` as ``{"t": (M,), key: (M, ...)}`` and kept in checkpoints.
    fn_ts : sequence of float, optional
        Observe ``fn`` at these times (and ``t0``) instead of after every step: between the
        steps' ends by the time scheme's dense output (:meth:`jaxanm.TimeScheme.interpolant`),
        so no step is shortened for them, and uniform samples come from steps of any size.
    params : bool
        Also keep ``params`` at the saved times (e.g. moving point clouds).

    Notes
    -----
    A host hook that keeps its own records at the saved steps (the FSW recorder) asks the same
    object: :meth:`times` gives the end times of the saved steps as the loop computes them.
    """

    ts: tuple | None = None
    steps: int | None = None
    fn: Callable | None = None
    fn_ts: tuple | None = None
    params: bool = False

    def __post_init__(self):
        if self.ts is not None and self.steps is not None:
            raise InputError("give SaveAt(ts=...) or SaveAt(steps=...), not both")
        if self.steps is not None:
            integer("SaveAt.steps", self.steps, 1, hint="save every steps-th step")
        flag("SaveAt.params", self.params)
        if self.ts is not None:
            ts = np.atleast_1d(np.asarray(self.ts, dtype=np.float64))
            if ts.ndim != 1 or not np.all(np.isfinite(ts)):
                raise InputError(f"SaveAt ts must be a sequence of finite times, got {self.ts!r}")
            object.__setattr__(self, "ts", tuple(float(t) for t in ts))
        if self.fn_ts is not None:
            fn_ts = np.atleast_1d(np.asarray(self.fn_ts, dtype=np.float64))
            if fn_ts.ndim != 1 or not np.all(np.isfinite(fn_ts)) or np.any(np.diff(fn_ts) <= 0):
                raise InputError(f"SaveAt fn_ts must be increasing finite times, got {self.fn_ts!r}")
            if self.fn is None:
                raise InputError("SaveAt fn_ts are the times fn is observed at: give fn too")
            object.__setattr__(self, "fn_ts", tuple(float(t) for t in fn_ts))
        if self.fn is not None and not callable(self.fn):
            raise InputError(f"SaveAt fn must be a callable (t, x, params) -> dict, got {self.fn!r}")

    def observed_within(self, t_start: float, t_end: float) -> np.ndarray:
        """The ``fn_ts`` in ``(t_start, t_end]``: the times a step over that span observes."""
        ts = np.asarray(self.fn_ts or (), dtype=np.float64)
        return ts[(ts > t_start) & (ts <= t_end)]

    def fixed(self, t0: float, t1: float, dt: float) -> set:
        """The saved step numbers of fixed steps of ``dt`` from t0 to t1 (0 and the last always)."""
        n_steps = fixed_steps(t0, t1, dt)
        if self.ts is None:
            steps = set(range(0, n_steps + 1, self.steps or 1))
        else:
            steps = {int(min(max(round((s - t0) / dt), 0), n_steps)) for s in self.ts}
            steps.add(0)
        steps.add(n_steps)
        return steps

    def times(self, t0: float, t1: float, dt: float, adaptive: bool) -> frozenset:
        """End times of the saved steps after t0 (t1 always), exactly as the time loop computes
        them: of the :meth:`fixed` steps, or with a controller (``adaptive``) the ``ts`` within
        (t0, t1).  Not for ``steps`` with a controller (those are counted, not timed)."""
        if not adaptive:
            n_steps = fixed_steps(t0, t1, dt)
            return frozenset(step_end(t0, t1, dt, k, n_steps) for k in self.fixed(t0, t1, dt) if k > 0)
        if self.ts is None:
            raise InputError("SaveAt.times with a controller needs ts (every k-th step is counted, not timed)")
        return frozenset({float(t1), *(t for t in self.ts if t0 < t < t1)})

    def controlled(self, k: int, t: float, t1: float) -> bool:
        """Whether step ``k`` of a controlled run, ending at ``t``, is saved."""
        if t == t1:
            return True
        if self.ts is not None:
            return t in self.ts
        return k % (self.steps or 1) == 0
