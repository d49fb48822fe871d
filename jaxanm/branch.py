"""A branch of solutions of ``R(u, lam) = 0``, the value both path followers return: its points,
a series per step between them, the events found on it, and why it ends."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, NamedTuple

import numpy as np

from ._real_roots import real_roots
from .errors import InputError
from .events import Event, fold_roots
from .stats import Stats

STOP_REASONS = {
    "lam_end": "reached lam_end",
    "stop_at": "reached the stop_at value",
    "max_steps": "took max_steps steps: raise max_steps to go on, or give lam_end / stop_at",
    "non_finite": "the residual, its derivatives or the series are not finite beyond here (overflow, or outside "
                  "the residual's domain): end the branch before it with lam_end / stop_at",
    "singular": "the bordered matrix cannot be factorised here (a singular point the branch cannot pass)",
    "round_off": "round-off in R, through the conditioning of the bordered matrix, leaves the points farther from "
                 "the branch than the steps promise: a larger tol, or scale= giving the unknowns their sizes",
    "min_step": "the step fell below what can advance the branch (the series' validity range, halvings of a "
                "step whose end misses its accuracy, or Newton's corrector failing down to ds_min): a larger tol, "
                "a lower order or max_step (ANM); if none helps, R is too ill-conditioned here (entries near "
                "overflow, a singular point)",
    "corrector": "Newton's corrections do not converge onto the branch: shorter steps (max_step, ds_max)",
}
"""The reasons a :class:`Branch` ends (:attr:`Branch.stopped`) with what each means or
suggests (the end of :attr:`Branch.message`)."""


class BranchPoints(NamedTuple):
    """Points of a branch found on its series: ``lam (k,)``, ``u (k, n)``, and their arclength
    ``s (k,)`` along the branch (:attr:`Branch.s`)."""

    lam: np.ndarray
    u: np.ndarray
    s: np.ndarray


class Source(NamedTuple):
    """How a branch was made, to follow another from one of its events: the path follower
    (``follow(residual, params=..., start=event, **options)``), the residual, its params and
    the options that carry over (not the start, direction or end conditions)."""

    follow: Callable
    residual: Callable
    params: Any
    options: dict


@dataclasses.dataclass(frozen=True)
class Branch:
    """A branch of solutions of ``R(u, lam) = 0`` from :func:`jaxanm.continuation` or
    :func:`jaxanm.newton_continuation`: its points at the step ends, the start first, a series
    per step to evaluate it between them, the events found on it, and why it ends.

    Attributes
    ----------
    lam : ndarray (S,)
        The parameter at the points.
    u : ndarray (S, n)
        The unknowns at the points.
    a : ndarray (S-1,)
        Length of each step in the scaled pseudo-arclength, ``<U_(i+1) - U_i, t_i>`` (:attr:`s`
        is their running sum).
    amax : ndarray (S-1,) or None
        The ANM's validity range of each step (eq. 26); ``a`` is shorter where the branch
        stopped at ``lam_end`` / ``stop_at`` or the end-point check halved it.  None for Newton.
    residual_norm : ndarray (S,)
        ``|R|_inf`` at the points.
    correction : ndarray (S-1,)
        Scaled norm of each step's end correction: for the ANM, the end point's distance from
        the branch before it was corrected; for Newton, the last Newton correction.
    tangent : ndarray (S, n+1)
        Unit tangent (scaled norm) at the points, oriented along the branch.
    series : ndarray (S-1, q, n+1) or None
        ``U(a) = U_i + sum_k a^k series[i, k-1]`` on step i, ``a`` in ``[0, a[i]]``: the ANM's own
        series (q = order; the next point is its corrected end), Newton's chord-length cubic
        Hermite interpolant of the points and tangents (q = 3).  None with ``keep_series=False``.
    scale : ndarray (n+1,)
        The scale of the unknowns (u's, then lam's).
    stats : Stats
        Factorisations, series orders, solves, Newton iterations, ``amax``, ``orders``,
        ``step_sizes``, ``rejected_steps`` (halvings of a step), the wall-time split.
    method : str
        ``"anm"`` or ``"newton"``.
    stopped : str
        Why the branch ends, a key of :data:`STOP_REASONS`: ``"lam_end"``, ``"stop_at"``,
        ``"max_steps"``, or a step that could not be completed (``"non_finite"``,
        ``"singular"``, ``"round_off"``, ``"min_step"``, ``"corrector"``).
    message : str
        One line: where the branch stopped, why, and what to try.
    events : tuple of Event
        Folds, branch points (and what other detectors found), in branch order.
    source : Source or None
        How the branch was made (for :meth:`switch`).
    unstable : ndarray (S,) of int or None
        With ``"stability"`` among the events: at each point, how many eigenvalues of R_u have
        a positive real part, among the :data:`jaxanm.stability.NEV` nearest zero (-1 where
        none were computed); the steady state is stable where it is 0
        (:mod:`jaxanm.stability`).  None otherwise.
    """

    STOP_REASONS = STOP_REASONS

    lam: np.ndarray
    u: np.ndarray
    a: np.ndarray
    amax: np.ndarray | None
    residual_norm: np.ndarray
    correction: np.ndarray
    tangent: np.ndarray
    series: np.ndarray | None
    scale: np.ndarray
    stats: Stats
    method: str
    stopped: str
    message: str = ""
    events: tuple = ()
    source: Source | None = dataclasses.field(default=None, repr=False, compare=False)
    unstable: np.ndarray | None = None

    @property
    def s(self) -> np.ndarray:
        """Arclength at the points (S,): the running sum of ``a``, from 0."""
        return np.concatenate([[0.0], np.cumsum(self.a)])

    def events_of(self, kind: str) -> tuple:
        """The events of one ``kind`` (``"fold"``, ``"branch_point"``, ...), in branch order."""
        return tuple(e for e in self.events if e.kind == kind)

    def switch(self, event: Event, **options) -> "Branch":
        """Follow the branch that bifurcates at the branch-point ``event`` (one of this branch's,
        or of another branch of the same problem), by the same method and with the same
        options except those given (e.g. ``direction=-1`` for the other half, ``lam_end``,
        ``max_steps``): ``follow(residual, params=..., start=event, **options)``."""
        if self.source is None:
            raise InputError("this branch does not know its problem; call jaxanm.continuation(residual, "
                             "params=..., start=event) instead")
        follow, residual, params, carried = self.source
        return follow(residual, params=params, start=event, **{**carried, **options})

    def _points(self) -> np.ndarray:
        return np.column_stack([self.u, self.lam])

    def _kept_series(self) -> np.ndarray:
        """:attr:`series`, or an error saying how to keep it."""
        if self.series is None:
            raise InputError("this branch kept no series (keep_series=False): run it with keep_series=True")
        return self.series

    def evaluate(self, s) -> tuple[np.ndarray, np.ndarray]:
        """``(lam (m,), u (m, n))`` on the branch at arclengths ``s`` (m,) in ``[0, s[-1]]``,
        from each step's series."""
        series = self._kept_series()
        s = np.atleast_1d(np.asarray(s, dtype=np.float64))
        starts = self.s
        steps = np.clip(np.searchsorted(starts, s, side="right") - 1, 0, self.a.size - 1)
        local = s - starts[steps]
        values = self._points()[steps].copy()
        power = np.ones_like(local)
        for k in range(series.shape[1]):
            power = power * local
            values += power[:, None] * series[steps, k]
        return values[:, -1], values[:, :-1]

    def crossings(self, value: float, index: int | None = None) -> BranchPoints:
        """The points where ``lam`` (``index`` None) or ``u[index]`` equals ``value``, found as
        real roots of each step's series (every crossing, in branch order)."""
        series = self._kept_series()
        j = self.u.shape[1] if index is None else int(index)
        points = self._points()
        found = []
        last = self.a.size - 1
        for i, a in enumerate(self.a):
            found += [self.s[i] + r for r in real_roots(np.concatenate([[points[i, j] - value], series[i, :, j]]), a,
                                                         closed=(i == last))]
        return self._at(np.array(found))

    def limit_points(self) -> BranchPoints:
        """The folds in ``lam``: the fold events (:attr:`events`), or, on a branch followed
        without fold detection (``events`` without ``"fold"``), the same test on its series
        (:func:`jaxanm.events.fold_roots`, unpolished: only turns of lam by more than the
        steps' end distances, not wiggles of an interpolant where lam is flat)."""
        folds = self.events_of("fold")
        detected = self.source is None or "fold" in self.source.options.get("events", ())
        if detected or self.series is None:
            u = np.array([e.u for e in folds]).reshape(len(folds), self.u.shape[1])
            return BranchPoints(np.array([e.lam for e in folds]), u, np.array([e.s for e in folds]))
        # the branch's accuracy in lam: Newton's last corrections, the ANM's end points' distances
        newton = self.method == "newton"
        found = []
        for i, a in enumerate(self.a):
            noise = 10 * max(self.correction[i], np.finfo(float).tiny) * self.scale[-1]
            ends = (self.tangent[i, -1], self.tangent[i + 1, -1]) if newton else None
            found += [self.s[i] + r for r in fold_roots(self.series[i], a, noise, ends)]
        return self._at(np.array(found))

    def _at(self, s) -> BranchPoints:
        lam, u = self.evaluate(s) if s.size else (np.zeros(0), np.zeros((0, self.u.shape[1])))
        return BranchPoints(lam, u, s)
