"""What a path follower records along its walk, why the walk ended, and the events found on
the way: the one owner of the walk's counters in :class:`~jaxanm.Stats` and of the
:class:`~jaxanm.Branch` it becomes.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from .bordered import ContinuationFailure, ExtendedSystem, Linearisation
from .branch import STOP_REASONS, Branch
from .events import StepEnd, StepSeries
from .stability import StabilityDetector
from .stats import Stats


@dataclasses.dataclass
class Walk:
    """A walk's record, point by point, turned into a :class:`~jaxanm.Branch` by
    :meth:`branch`.  ``detectors``: callables ``StepEnd -> events`` (:mod:`jaxanm.events`)
    told of every point with its factorisation."""

    system: ExtendedSystem
    detectors: list
    points: list = dataclasses.field(default_factory=list)
    tangents: list = dataclasses.field(default_factory=list)
    residual_norms: list = dataclasses.field(default_factory=list)
    a: list = dataclasses.field(default_factory=list)
    amax: list = dataclasses.field(default_factory=list)
    corrections: list = dataclasses.field(default_factory=list)
    distances: list = dataclasses.field(default_factory=list)
    series: list = dataclasses.field(default_factory=list)
    orders: list = dataclasses.field(default_factory=list)
    halvings: int = 0
    newton_iterations: int = 0
    events: list = dataclasses.field(default_factory=list)
    stopped: str = ""
    message: str = ""

    def start(self, point, tangent, residual_norm: float, lin: Linearisation | None, iterations: int = 0,
              distance: float = 0.0) -> None:
        """Record the first point, with its unit ``tangent``, its linearisation (None where the
        bordered matrix is singular: a branch point) and its distance from the branch."""
        self.newton_iterations += iterations
        self.distances.append(float(distance))
        self._record(point, tangent, residual_norm)
        self.notify(lin, None)

    def _record(self, point, tangent, residual_norm) -> None:
        self.points.append(np.array(point, dtype=np.float64))
        self.tangents.append(np.array(tangent, dtype=np.float64))
        self.residual_norms.append(residual_norm)

    def add(self, lin: Linearisation, tangent, a: float, series, *, correction: float, distance: float,
            amax=np.nan, halvings: int = 0, iterations: int = 0, residual_norm=None, point=None) -> None:
        """Record a step: its end point (``point``, default ``lin.point``; factorised there, or
        within tol of it) and unit tangent, its length ``a`` (scaled pseudo-arclength), its
        ``series`` ((q, n+1) from the step's start), the size of its end correction (its end's
        distance from the branch before it) and the end point's distance after it, its validity
        range, the halvings of its length and the Newton iterations it took; then tell the
        detectors."""
        self.a.append(float(a))
        self.distances.append(float(distance))
        self.amax.append(float(amax))
        self.corrections.append(float(correction))
        self.series.append(np.asarray(series))
        self.orders.append(int(np.asarray(series).shape[0]))
        self.halvings += halvings
        self.newton_iterations += iterations
        norm = float(np.max(np.abs(lin.residual))) if residual_norm is None else residual_norm
        self._record(lin.point if point is None else point, tangent, norm)
        self.notify(lin, np.asarray(series))

    def notify(self, lin: Linearisation | None, series) -> None:
        """Tell every detector of the last point, and keep the events they return."""
        if not self.detectors:
            return
        index, s = len(self.points) - 1, float(np.sum(self.a))
        step = None if series is None else StepSeries(self.points[-2], s - self.a[-1], self.a[-1], series,
                                                      self.corrections[-1], self.distances[-2])
        end = StepEnd(index=index, point=self.points[-1], tangent=self.tangents[-1], s=s, linearisation=lin,
                      system=self.system, step=step)
        for detector in self.detectors:
            self.events.extend(detector(end) or ())

    def stop(self, code: str, detail: str = "") -> None:
        """End the walk with the reason ``code`` (:data:`STOP_REASONS`) and a one-line message."""
        self.stopped = code
        where = f"after {len(self.a)} steps at lam = {self.points[-1][-1]:.8g}"
        self.message = f"stopped {where}: " + (f"{detail}; " if detail else "") + STOP_REASONS[code]

    def fail(self, failure: ContinuationFailure) -> None:
        """End the walk on a step that could not be completed (the steps before it kept)."""
        self.stop(failure.code, f"step {failure.step} at lam = {failure.lam:.8g}: {failure.reason}")

    def branch(self, stats: Stats, method: str, keep_series: bool, began: float, source=None):
        """The :class:`~jaxanm.Branch` of this walk (its counters written into ``stats``)."""
        stats.time_steps = len(self.a)
        stats.rejected_steps = self.halvings
        stats.newton_iterations = self.newton_iterations
        stats.step_sizes = list(self.a)
        if method == "anm":
            stats.amax, stats.orders = list(self.amax), list(self.orders)
        stats.close(time.perf_counter() - began)
        points, n = np.array(self.points), self.system.n
        rows = self.orders[0] if self.orders else 1
        series = np.array(self.series).reshape(len(self.a), rows, n + 1) if keep_series else None
        events = tuple(sorted(self.events, key=lambda e: e.s))
        counts = next((d.counts for d in self.detectors if isinstance(d, StabilityDetector)), None)
        return Branch(lam=points[:, -1].copy(), u=points[:, :-1].copy(), a=np.array(self.a),
                      amax=np.array(self.amax) if method == "anm" else None,
                      residual_norm=np.array(self.residual_norms), correction=np.array(self.corrections),
                      tangent=np.array(self.tangents), series=series, scale=self.system.scale, stats=stats,
                      method=method, stopped=self.stopped, message=self.message, events=events, source=source,
                      unstable=None if counts is None else np.array(counts, dtype=int))


def orient(system: ExtendedSystem, lin: Linearisation) -> np.ndarray:
    """The unit tangent (scaled norm) at ``lin.point``, oriented by its border (``lin.z``)."""
    return lin.z / system.norm(lin.z)

