"""Linear stability of the steady states ``R(u, lam) = 0`` of ``u' = R(u, lam, params)`` along a
branch, and the points where it changes.

At every point the eigenvalues of ``R_u`` nearest zero are found by shift-invert (ARPACK's
Arnoldi on ``R_u^-1``) through the bordered factorisation the point already has, with no
factorisation of its own: ``B [x; mu] = [b; 0]`` and ``B z = [0; 1]`` give
``R_u^-1 b = x - (mu / z_lam) z_u``.  The number of them with a positive real part is the
point's count of unstable eigenvalues (:attr:`jaxanm.Branch.unstable`).  Where the count changes
across a step, the crossing eigenvalue's real part is followed on the step's series (each point
brought back onto the branch by one Newton correction, then factorised) and its zero located by
the Illinois variant of regula falsi:

- a complex pair crossing is a **Hopf point** (event kind ``"hopf"``: a periodic orbit is born
  there, of angular frequency ``|Im|`` of the pair);
- a real eigenvalue crossing is a **stability change** (kind ``"stability"``), which lies at a
  fold or a branch point (reported by their own detectors as well).

The count sees only the :data:`NEV` eigenvalues nearest zero: an unstable eigenvalue farther
from zero than those (a fast oscillatory mode) is not counted; where every one of them is
unstable the count is a lower bound.  Requested by ``events=(..., "stability")`` of
:func:`jaxanm.continuation`; it costs one Arnoldi run (a few dozen solves) per point.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg

from .bordered import ContinuationFailure, ExtendedSystem, Linearisation, release
from .events import DETECTORS, Event, StepEnd, StepSeries

NEV = 8
"""Eigenvalues of R_u nearest zero computed at each point."""

LOCATE_TO = 1e-10
"""The crossing is located to this fraction of its step's length (then lam to about this times
the step's change of lam, below the 1e-8 relative of the other events)."""

MAX_EVALUATIONS = 30
"""Points on a step's series at which the eigenvalues may be computed to locate one crossing."""


def eigenvalues_near_zero(lin: Linearisation, nev: int = NEV) -> np.ndarray:
    """The ``nev`` eigenvalues of R_u nearest zero at ``lin.point`` (all of them when ``n`` is
    too small for Arnoldi), by shift-invert through the bordered factorisation; sorted by
    decreasing real part.  :class:`ContinuationFailure` (code ``"singular"``) where R_u itself
    is singular (``z_lam = 0``: exactly at a fold)."""
    n, z = lin.point.size - 1, lin.z
    if z[-1] == 0.0:
        raise ContinuationFailure("R_u is singular here: its eigenvalues nearest zero include 0", step=-1,
                                  lam=lin.point[-1], code="singular")
    if nev >= n - 1:  # ARPACK needs k < n - 1: a system this small is dense anyway
        jac = lin.jacobian.toarray() if hasattr(lin.jacobian, "toarray") else np.asarray(lin.jacobian)
        values = np.linalg.eigvals(jac)
    else:
        def inverse(b):
            y = lin.solve(np.ravel(b))
            return y[:-1] - (y[-1] / z[-1]) * z[:-1]

        op = scipy.sparse.linalg.LinearOperator((n, n), matvec=inverse, dtype=np.float64)
        start = np.random.default_rng(n).standard_normal(n)  # ARPACK's own start is random: runs would differ
        values = 1.0 / scipy.sparse.linalg.eigs(op, k=nev, which="LM", v0=start, return_eigenvectors=False)
    return values[np.argsort(-values.real, kind="stable")]


def unstable_count(values: np.ndarray) -> int:
    """How many of ``values`` have a positive real part."""
    return int(np.sum(values.real > 0.0))


def _crosses(before: np.ndarray, after: np.ndarray, complex_pair: bool) -> bool:
    """Whether the eigenvalue of the kind nearest the imaginary axis changes side."""
    return bool(np.sign(_nearest_axis(before, complex_pair).real) != np.sign(_nearest_axis(after, complex_pair).real))


def _nearest_axis(values: np.ndarray, complex_pair: bool) -> complex:
    """The eigenvalue of the crossing's kind nearest the imaginary axis (upper member of a pair)."""
    pick = values[values.imag > 0] if complex_pair else values[values.imag == 0]
    pick = values if pick.size == 0 else pick
    return complex(pick[np.argmin(np.abs(pick.real))])


class StabilityDetector:
    """The stability detector (module docstring): the count of unstable eigenvalues at every
    point (:attr:`counts`, -1 where none was computed) and an event where it changes."""

    def __init__(self, system: ExtendedSystem, nev: int = NEV):
        self.system, self.nev = system, nev
        self.counts: list[int] = []
        self.previous: np.ndarray | None = None

    def __call__(self, end: StepEnd) -> list:
        lin = end.linearisation
        try:
            values = None if lin is None else eigenvalues_near_zero(lin, self.nev)
        except ContinuationFailure:
            values = None
        self.counts.append(-1 if values is None else unstable_count(values))
        previous, self.previous = self.previous, values
        if values is None or previous is None or end.step is None:
            return []
        before, after = unstable_count(previous), unstable_count(values)
        if before == after:
            return []
        # One real eigenvalue or one complex pair crossed; any other change is several crossings
        # within the step, which are reported at its end unlocated (bound the steps there).
        pair = abs(after - before) == 2 and _crosses(previous, values, True)
        single = abs(after - before) == 1 or pair
        try:
            return [self._located(end, pair, (previous, values), (before, after), single)]
        except ContinuationFailure:
            return []  # a point of the bracket where R cannot be evaluated or B factorised

    def _at(self, index: int, step: StepSeries, a: float):
        """``(U, eigenvalues)`` at ``a`` on the step, the point corrected onto the branch."""
        system = self.system
        t = step.derivative(a)
        row = system.tangent_row(t / system.norm(t))
        lin = system.linearise(step.at(a), row, step=index, aside=True)
        U = lin.point + lin.solve(-lin.residual)
        release(lin.fact)
        lin = system.linearise(U, row, step=index, aside=True)
        try:
            return U, eigenvalues_near_zero(lin, self.nev)
        finally:
            release(lin.fact)

    def _located(self, end: StepEnd, pair: bool, ends: tuple, counts: tuple, single: bool) -> Event:
        """The crossing in the step that ended at ``end``, by Illinois regula falsi on the real
        part of the eigenvalue nearest the axis (``ends``: the eigenvalues at the step's ends);
        at the step's end, unlocated, unless one eigenvalue or pair crossed (``single``)."""
        index, step = end.index, end.step
        assert step is not None  # called for a step's end only
        a0, f0 = 0.0, _nearest_axis(ends[0], pair).real
        a1, crossing = step.a, _nearest_axis(ends[1], pair)
        f1, U, a, replaced = crossing.real, end.point, step.a, -1
        located = single and np.sign(f0) != np.sign(f1)
        for _ in range(MAX_EVALUATIONS if located else 0):
            if a1 - a0 <= LOCATE_TO * step.a:
                break
            a = (a0 * f1 - a1 * f0) / (f1 - f0)
            U, values = self._at(index, step, a)
            crossing = _nearest_axis(values, pair)
            if crossing.real == 0.0:
                break
            if np.sign(crossing.real) == np.sign(f1):
                a1, f1 = a, crossing.real
                f0 *= 0.5 if replaced == 1 else 1.0  # a0 kept twice: halve its value (Illinois)
                replaced = 1
            else:
                a0, f0 = a, crossing.real
                f1 *= 0.5 if replaced == 0 else 1.0
                replaced = 0
        t = step.derivative(a)
        data = {"eigenvalue": crossing, "unstable": counts, "located": bool(located)}
        if pair:
            data["frequency"] = abs(crossing.imag)
        return Event("hopf" if pair else "stability", float(U[-1]), U[:-1], index - 1, step.s + a,
                     t / self.system.norm(t), data)


DETECTORS["stability"] = lambda system, tol, method: StabilityDetector(system)
