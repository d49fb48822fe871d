"""The Asymptotic Numerical Method as a step solver: homotopy, Taylor series by jet, continuation.

The method, its acceptance test and its homotopies are explained in ``docs/method/``
(index, acceptance, homotopies, pade); :class:`ANM` documents the options precisely.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from .. import _pade
from .._acceptance import (
    CHECK_LIMIT,
    CRITERIA,
    evaluate_series,
    next_order_suffices,
    promised_accuracy,
    range_of_norms,
    reference_state,
    validity_range,
)
from .._checks import integer, real
from .._problem import SeriesPath
from ..errors import InputError, NonFiniteError, StepFailure
from .base import Attempt, AttemptSolver, check_count, check_flag, check_tol


class _Start(NamedTuple):
    """Where a series of a step starts: ``d_s``, the residual there when already evaluated (and
    the series path from there, when already started), the first coefficient ``-K*^-1 R(d_s)``
    when already solved with the K* kept (None: to compute); ``refactor``: K* is refactorised
    first (at ``d_s``); ``substep``: a continuation sub-step (counted)."""

    d_s: np.ndarray
    residual: np.ndarray | None = None
    c_1: np.ndarray | None = None
    refactor: bool = False
    substep: bool = False
    path: SeriesPath | None = None


class _ANMStep(Attempt):
    """One time step of the :class:`ANM` (``opts``): series, continuation sub-steps, acceptance.

    ``fact`` is the K* it works with: the state's, replaced (:meth:`drop_factorization`: the
    next series factorises at its start point) when a series from a stale K* falls short and
    does not contract (``max_rate``).
    """

    opts: "ANM"

    def run(self, step: int, x_old, t, dt, params, start=None):
        """The accepted state and the residual there (None when not evaluated): ``(x, R(x))``;
        the homotopy starts at ``start`` (default ``x_old``)."""
        P, st = self.problem, self.report
        args = (x_old, t, dt, params)
        start = _Start(np.array(x_old if start is None else start, dtype=np.float64))
        substeps = 0
        amax = None  # of the previous series in this step (reported if a later one fails)
        while True:
            d_s = start.d_s
            if start.refactor:
                self.drop_factorization()
            if start.substep:
                substeps += 1
                st.substeps += 1
            path = self._path(d_s, args) if start.path is None else start.path
            r0 = path.start_residual() if start.residual is None else start.residual
            r0_norm = float(np.max(np.abs(r0)))
            if not np.isfinite(r0_norm):
                raise NonFiniteError("residual at the start of the series is not finite", step=step, t=t,
                                     amax=amax, residual_norm=r0_norm)
            fresh = self.fact is None
            if fresh:
                self.fact = P.factorize_in_step(step, d_s, *args, amax=amax, residual_norm=r0_norm)
            coeffs, outcome = self._series(path, r0, None if fresh else start.c_1, d_s, args, substeps)
            if isinstance(outcome, _Start):  # a corrected end point missed: on from there
                start = outcome
                continue
            if outcome is not None:
                return outcome
            amax = self._validity_range(coeffs, d_s)
            failure = dict(step=step, t=t, amax=amax, residual_norm=r0_norm)
            if amax >= 1.0:
                start = self._claimed(coeffs, d_s, args, fresh, substeps, failure)
            else:
                start = self._short(coeffs, d_s, args, fresh, substeps, failure)
            if isinstance(start, tuple) and not isinstance(start, _Start):
                return start  # accepted: (x, R(x))

    def _claimed(self, coeffs, d_s, args, fresh: bool, substeps: int, failure: dict):
        """After a series whose a_max reaches 1: ``(x, R(x))`` when its end point passes the
        check, else where the next series starts (a :class:`_Start`)."""
        P, p = self.problem, self.opts.order
        d_end = d_s + coeffs.sum(axis=0)
        check, distance, r_end, correction = self._end_point_check(d_end, d_s, coeffs[0], *args)
        if check <= CHECK_LIMIT:
            return self._accepted(d_end, failure["amax"], p, r_end)
        # the series claimed a = 1 but its end point is not converged (e.g. a last coefficient
        # that vanishes by parity): not an accepted step
        if not fresh:  # stale K*: refactorise at the start point and redo the series
            return _Start(d_s, refactor=True)
        if substeps >= self.opts.max_substeps:
            raise StepFailure(f"series from a fresh K* claims a = 1 (a_max = {failure['amax']:.3g}) but its end "
                              f"point misses the promised accuracy {check:.3g} times, after {substeps} continuation "
                              f"sub-steps (max_substeps = {self.opts.max_substeps})", **failure)
        # continuation sub-step: to the end point when it is closer to the solution than the
        # start (Newton distance by K*), else half-way along the series
        if distance < P.norm(coeffs[0]):
            return _Start(d_end, r_end, -correction, substep=True)
        return _Start(d_s + evaluate_series(coeffs, 0.5), substep=True)

    def _short(self, coeffs, d_s, args, fresh: bool, substeps: int, failure: dict):
        """After a series whose a_max stays below 1: ``(x, R(x))`` when its Padé approximant is
        accepted, else where the next series starts (a :class:`_Start`)."""
        approx, a_pade, pade_end = self._try_pade(coeffs, d_s, args)
        if pade_end is not None and pade_end[1] <= CHECK_LIMIT:
            self.report.pade_accepted += 1
            return self._accepted(pade_end[0], a_pade, self.opts.order, pade_end[3])
        if not fresh:  # stale K*: on from the series' end while it contracts, else refactorise
            return self._stale(coeffs, d_s, args, substeps)
        if not np.all(np.isfinite(coeffs)):
            raise NonFiniteError("series coefficients are not finite with a fresh K*", **failure)
        if substeps >= self.opts.max_substeps or max(failure["amax"], a_pade) < 1e-12:
            raise StepFailure(f"series from a fresh K* cannot reach a = 1 after {substeps} "
                              f"continuation sub-steps (max_substeps = {self.opts.max_substeps})", **failure)
        d, r = self._continuation_point(coeffs, d_s, failure["amax"], approx, a_pade, pade_end)
        return _Start(d, r, substep=True)

    def _series(self, path: SeriesPath, r0, c_1, d_s, args, substeps: int):
        """The series' coefficients ``c_1 .. c_p`` by K* (``c_1`` solved here unless given):
        ``(coeffs, None)``; order-adaptive, ``(None, (x, R(x) or None))`` when a truncated
        series is accepted on the way (:meth:`_accept_early`, :meth:`_corrected`), or ``(None,
        start)`` when a corrected end point missed and the step goes on from there (the norms
        of ``c_1`` and of the state are taken once)."""
        P, p, opts = self.problem, self.opts.order, self.opts
        coeffs = np.zeros((p, d_s.size))
        coeffs[0] = -P.solve(self.factorized(), r0) if c_1 is None else c_1
        n1 = previous = P.norm(coeffs[0])
        state_norm = P.norm(d_s) if opts.criterion == "state" else None
        for j in range(2, p + 1):
            rj = path.next(coeffs[j - 2])
            coeffs[j - 1] = coeffs[j - 2] - P.solve(self.factorized(), rj)
            if opts.adaptive and j < p:
                nj = P.norm(coeffs[j - 1])
                amax = range_of_norms(j, n1, nj, opts.tol, state_norm)
                outcome = None
                if amax >= 1.0:
                    outcome = self._accept_early(coeffs[:j], amax, d_s, *args)
                elif next_order_suffices(j, n1, previous, nj, opts.tol, state_norm, opts.max_rate):
                    outcome = self._corrected(coeffs[:j], d_s, args, substeps)
                if outcome is not None:
                    return None, outcome
                previous = nj
        return coeffs, None

    def _corrected(self, coeffs, d_s, args, substeps: int):
        """The end point of the series truncated at order ``j = len(coeffs)``, corrected by one
        modified-Newton step with K* in place of order j + 1 (whose coefficient the contraction
        of the last two predicts within the tolerance): ``(x, None)`` with ``x = d_end -
        K*^-1 R(d_end)`` when that correction is within the accuracy eq. 26 promises (modified
        Newton's test: the error left is the correction's contraction, at most ``max_rate`` of
        it; the residual at ``x`` is not evaluated).  Else the step goes on from ``d_end`` with
        the correction as its first coefficient (a :class:`_Start`: the residual and the solve
        are not lost) when that point is nearer the solution than the series' start, or the
        series goes on (None)."""
        P, opts = self.problem, self.opts
        d_end = d_s + coeffs.sum(axis=0)
        path = self._path(d_end, args)  # R(d_end) and, on a miss, the next series' start in one evaluation
        r_end = path.start_residual()
        if not np.all(np.isfinite(r_end)):
            return None
        correction = P.solve(self.factorized(), r_end)
        distance = P.norm(correction)
        promised = promised_accuracy(P.norm, opts.tol, coeffs[0], d_end, reference_state(opts.criterion, d_s))
        j = coeffs.shape[0] + 1  # the correction stands for order j
        if distance <= promised:
            state_norm = P.norm(d_s) if opts.criterion == "state" else None
            return self._accepted(d_end - correction, range_of_norms(j, P.norm(coeffs[0]), distance, opts.tol,
                                                                     state_norm), j, None)
        if substeps < opts.max_substeps and distance < P.norm(coeffs[0]):
            return _Start(d_end, r_end, -correction, substep=True, path=path)
        return None

    def _stale(self, coeffs, d_s, args, substeps: int) -> _Start:
        """Where the step goes on after a series from a stale K* falls short of a = 1, as modified
        Newton keeps its Jacobian while its iteration contracts: from the series' end point with
        the same K* when that point is nearer the solution than the start by at least
        ``max_rate`` per order (its Newton distance by K*, ``|K*^-1 R(d_end)|``, at most
        ``max_rate^p |c_1|``); else K* is refactorised at the start (a K* made at the end point
        of a series that fell short served the later steps worse on fsw_paper: 7 factorisations
        in its first 30 steps against 4).  Not beyond ``max_substeps`` sub-steps."""
        if not (self.opts.max_rate > 0 and substeps < self.opts.max_substeps and np.all(np.isfinite(coeffs))):
            return _Start(d_s, refactor=True)
        P = self.problem
        d_end = d_s + coeffs.sum(axis=0)
        path = self._path(d_end, args)  # R(d_end) and the next series' start in one evaluation
        r_end = path.start_residual()
        if not np.all(np.isfinite(r_end)):
            return _Start(d_s, refactor=True)
        correction = P.solve(self.factorized(), r_end)
        if P.norm(correction) <= self.opts.max_rate ** coeffs.shape[0] * P.norm(coeffs[0]):
            return _Start(d_end, r_end, -correction, substep=True, path=path)
        return _Start(d_s, refactor=True)

    def _path(self, d_s, args) -> SeriesPath:
        """The series path from ``d_s``: the residual coefficient that order j needs depends on
        c_1 .. c_{j-1} only (and, for the Newton homotopy, on the provisional c_j = c_{j-1})."""
        return SeriesPath(self.problem, d_s, args, lookahead=self.opts.homotopy == "newton",
                          max_terms=self.opts.order - 1)

    def _try_pade(self, coeffs, d_s, args):
        """With ``pade``, the approximant of a series whose a_max < 1, its range, and when that
        reaches a = 1 its end point checked like a series': ``(approx, a_pade, end)`` with
        ``end = (d_end, check, distance, R(d_end))`` or None; ``(None, 0.0, None)`` untried."""
        if not (self.opts.pade and np.all(np.isfinite(coeffs))):
            return None, 0.0, None
        approx, a_pade = self._pade_range(coeffs, d_s)
        if a_pade < 1.0:
            return approx, a_pade, None
        d_end = d_s + _pade.evaluate(approx, 1.0)
        check, distance, r_end, _ = self._end_point_check(d_end, d_s, coeffs[0], *args)
        return approx, a_pade, (d_end, check, distance, r_end)

    def _continuation_point(self, coeffs, d_s, amax, approx, a_pade, pade_end):
        """Where a continuation sub-step restarts the homotopy (and the residual there, when
        known): the farther trusted point of the series (at a_max) and of its Padé approximant."""
        if approx is None or a_pade <= amax:
            return d_s + evaluate_series(coeffs, amax), None
        if a_pade < 1.0:
            return d_s + _pade.evaluate(approx, a_pade), None
        d_end, _, distance, r_end = pade_end
        if distance < self.problem.norm(coeffs[0]):  # the approximant's end point failed its check but
            return d_end, r_end  # is closer to the solution than the start (as for a series)
        return d_s + evaluate_series(coeffs, amax), None

    def _accept_early(self, coeffs, amax, d_s, x_old, t, dt, params):
        """Order-adaptive acceptance of the series truncated at order ``j = len(coeffs) < p``,
        whose a_max (eq. 26 at order j) reaches 1: ``(x, R(x))`` with the end point ``x = d_s +
        c_1 + ... + c_j`` when it passes the same end-point check as a full series, else None
        (the series goes on to order j + 1; a truncated series that fails is no failure of the
        step)."""
        d_end = d_s + coeffs.sum(axis=0)
        check, _, r_end, _ = self._end_point_check(d_end, d_s, coeffs[0], x_old, t, dt, params)
        if check > CHECK_LIMIT:
            return None
        return self._accepted(d_end, amax, coeffs.shape[0], r_end)

    def _pade_range(self, coeffs, d_s):
        """The Padé approximant of the order-p series and its validity range (searched up to
        a = 1, by this solver's tolerance and criterion): ``(approx, a_pade)``."""
        approx = _pade.approximant(coeffs, self.problem.scale)
        a_pade = _pade.pade_validity_range(approx, self.opts.tol, limit=1.0,
                                           state=reference_state(self.opts.criterion, d_s))
        return approx, a_pade

    def _validity_range(self, coeffs, d_s) -> float:
        """a_max of the series ``coeffs`` from ``d_s`` by this solver's criterion."""
        return validity_range(coeffs, self.problem.scale, self.opts.tol,
                              state=reference_state(self.opts.criterion, d_s))

    def _accepted(self, d_end, amax, order, r_end):
        """Record an accepted series (a_max, its order); return ``(d_end, R(d_end))``."""
        st = self.report
        st.amax.append(amax)
        st.orders.append(order)
        return d_end, r_end

    def _end_point_check(self, d_end, d_s, c_1, x_old, t, dt, params):
        """A-posteriori check of an accepted series: the Newton distance of its end point by the
        factorised K*, ``|K*^-1 R(d_end)|``, over what the acceptance promised (see :class:`ANM`).

        Returns ``(ratio, distance, R(d_end), K*^-1 R(d_end))``.
        One residual evaluation and one triangular solve.  A non-finite residual at the end
        point is not a question of series accuracy: the ratio is then 0 and the state goes to
        the caller, whose accepted-state check names it (:class:`NonFiniteError`).
        """
        P = self.problem
        r_end = P.residual(d_end, x_old, t, dt, params)
        if not np.all(np.isfinite(r_end)):
            return 0.0, np.inf, r_end, None
        correction = P.solve(self.factorized(), r_end)
        distance = P.norm(correction)
        promised = promised_accuracy(P.norm, self.opts.tol, c_1, d_end, reference_state(self.opts.criterion, d_s))
        return distance / promised, distance, r_end, correction


@dataclasses.dataclass(frozen=True)
class ANM(AttemptSolver):
    """Asymptotic Numerical Method: homotopy, Taylor series by jet, continuation (kind ``"anm"``).

    Each time step sums the Taylor series of a homotopy from the previous state to the step's
    solution at a = 1, with one factorised K* reused for every order and, while its series
    stay valid, across steps.  A series is accepted when its validity range a_max (eq. 26,
    :func:`~jaxanm.validity_range`) reaches 1 *and* its end point passes an a-posteriori
    check: its Newton distance ``|K*^-1 R(d_end)|`` must be within
    :data:`~jaxanm._acceptance.CHECK_LIMIT` times what eq. 26 promised (``docs/method/acceptance.md``).
    A series that falls short with a stale K* goes on from its end point with the same K* while
    it contracts (``max_rate``), as modified Newton keeps its Jacobian, else it is redone after
    refactorising; with a fresh K* the step goes on by continuation sub-steps.  The new state
    holds the K* used last and the residual at the accepted state (evaluated by the end-point
    check).

    The defaults are those that hold under a step-size controller as well as at fixed steps
    (``docs/method/defaults.md``): order-adaptive (``adaptive=True``), the Newton homotopy, the
    tolerance relative to the state (``criterion="state"``) and a stale K* kept while its
    series contract at ``max_rate = 0.5``.  The paper's solver is ``ANM(adaptive=False,
    homotopy="convex", criterion="increment", max_rate=0)`` (:meth:`paper`), which the
    defaults were until they were measured against modified Newton under the controller: its
    fixed-order series from a stale K* refactorise where modified Newton iterates on.

    Parameters
    ----------
    order : int
        Truncation order p of the series (>= 2: eq. 26 compares c_1 and c_p).
    tol : float
        eta of eq. 26, in (0, 1): the series is accepted at a = 1 when a_max >= 1 and its end
        point passes the check.
    max_substeps : int
        Continuation sub-steps allowed within one time step (each after a fresh K* still gave
        a_max < 1) before the step is declared failed (then ``integrate`` halves dt); >= 0.
        The sub-steps from a stale K* (``max_rate``) count too: beyond the limit K* is
        refactorised instead.
    criterion : {"increment", "state"}
        What ``tol`` is relative to.  ``"increment"`` is the paper's eq. 26: the last term is
        ``tol`` times the first-order increment ``c_1``.  ``"state"`` also accepts a range where
        the last term is below ``tol`` times the state ``d_s``, the yardstick of Newton's
        ``|dx| / |x| < delta``: eq. 26 is scale-free in the size of the step's residual, so
        quasi-steady steps otherwise refactorise to resolve increments far below the state's
        accuracy (docs/notes/anm_on_fsw_paper.md).
    adaptive : bool
        Order-adaptive series: ``order`` is the maximum, and the series is accepted at the
        first order j whose validity range (eq. 26 with c_j as last term) reaches a = 1 and
        whose end point passes the check; the orders used are in ``stats.orders``.  With
        ``max_rate > 0``, where the contraction of the last two coefficients (at most
        ``max_rate``) predicts that order j + 1 would reach a = 1, one modified-Newton
        correction ``-K*^-1 R(d_end)`` of the order-j end point stands for that order: the
        corrected point is accepted when the correction is within the accuracy eq. 26
        promises (modified Newton's test), else the step goes on from ``d_end`` with the
        correction as its first coefficient (docs/method/defaults.md).  ``False``: fixed order
        p, as in the paper's Table 1.  In both modes order j's jet is truncated to the j - 1
        terms known, so a series costs O(p^2) jet terms.
    homotopy : {"convex", "newton"}
        The artificial problem whose series is summed at a = 1 (docs/method/homotopies.md).
        ``"convex"`` is the paper's eq. 22, ``(1 - a) K* (d - d_s) + a R(d) = 0``: order j reads
        ``K* c_j = K* c_{j-1} - [R]_{j-1}``.  ``"newton"`` is
        ``R(d) = (1 - a) [R(d_s) + (K_T - K*) (d - d_s)]``, whose tangent at a = 0 is K*: order
        j reads ``K* c_j = K* c_{j-1} - [R]_j`` with ``[R]_j`` along the path with the
        provisional ``c_j = c_{j-1}``, and each order gains a power of the increment.
    pade : bool
        Padé approximants extend the order-p series (docs/method/pade.md): a series whose
        a_max < 1 is still accepted when the validity range of its approximant ``P_p`` reaches
        a = 1 and ``P_p(1)`` passes the same end-point check; with a fresh K* a continuation
        sub-step goes to ``P_p`` at its range when that is farther than a_max.  Counted in
        ``stats.pade_accepted`` (their ``stats.amax`` entry is the approximant's range, so 1.0).
        Needs ``order >= 3``; with ``adaptive`` the approximant is tried at order p only.
    max_rate : float
        In [0, 1).  A series from a stale K* that falls short of a = 1 (its series and Padé
        approximant) is continued from its end point ``d_s + c_1 + ... + c_j`` with the same K*
        when that point is nearer the step's solution than the start by at least ``max_rate``
        per order: its Newton distance ``|K*^-1 R(d_end)|`` at most ``max_rate^j |c_1|``, the
        contraction modified Newton's ``max_rate`` allows its iterates.  Otherwise K* is
        refactorised at the series' start.  Counted in ``stats.substeps``.  0: always
        refactorised, as the paper's solver.
    """

    kind = "anm"
    attempt = _ANMStep

    order: int = 7
    tol: float = 1e-6
    max_substeps: int = 50
    criterion: str = "state"
    adaptive: bool = True
    homotopy: str = "newton"
    pade: bool = False
    max_rate: float = 0.5

    @classmethod
    def paper(cls, **options) -> "ANM":
        """The paper's ANM: a series of fixed order (``adaptive=False``) of the convex homotopy
        (eq. 22), accepted by eq. 26 relative to the increment, and K* refactorised whenever a
        series from a stale K* falls short (``max_rate=0``); ``options`` (``order``, ``tol``,
        ...) as for :class:`ANM`, these four included."""
        return cls(**{"adaptive": False, "homotopy": "convex", "criterion": "increment", "max_rate": 0.0, **options})

    def __post_init__(self):
        integer("ANM.order", self.order, 2, hint="the validity range a_max of eq. 26 compares c_1 with c_p and "
                "takes the 1/(p-1)-th root, undefined for p = 1 (an order-1 series is one linearised step: use "
                "jaxanm.ModifiedNewton for that)")
        check_tol("ANM", self.tol)
        check_count("ANM", "max_substeps", self.max_substeps, 0)
        check_flag("ANM", "adaptive", self.adaptive)
        if self.homotopy not in ("convex", "newton"):
            raise InputError(f"ANM.homotopy must be 'convex' (the paper's eq. 22) or 'newton', got {self.homotopy!r}")
        check_flag("ANM", "pade", self.pade)
        if self.pade and self.order < 3:
            raise InputError(f"ANM.pade=True needs order >= 3, got order={self.order}: the Padé range compares "
                             "the approximants of orders p and p - 1, and for p = 2 the lower one is the start "
                             "point (use order >= 3, or pade=False)")
        if self.criterion not in CRITERIA:
            raise InputError(f"ANM.criterion must be 'increment' (eq. 26) or 'state', got {self.criterion!r}")
        real("ANM.max_rate", self.max_rate, 0, 1, open_high=True,
             hint="e.g. max_rate=0.5 (0: a stale K* is refactorised whenever its series falls short)")
