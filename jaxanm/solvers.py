"""Nonlinear step solvers on one step residual: ANM (homotopy + jet series) and Newton.

A solver is a small frozen options object, a :class:`StepSolver` (``ANM``, ``Newton``,
``ModifiedNewton``, or a user's subclass).  What it carries across time steps (the factorised
K*) is a :class:`SolverState` value: ``init(problem)`` makes the first, and
``step(state, ...)`` returns the solved state with a new one.  Every solver sees the problem
only through :class:`Problem`: residual evaluations, series evaluations, tangent matrices and
factorisations, all counted in the same :class:`~jaxanm.stats.Stats`.
"""

from __future__ import annotations

import abc
import dataclasses
import functools
import warnings

import jax
import numpy as np
import scipy.sparse

from .errors import InputError, NonFiniteError, SingularMatrixError, StepFailure
from .jacobian import SparseJacobian, dense_jacobian_function
from .linalg import Factorization, factorize
from . import pade as _pade
from .series import AffineFunctions, AffinePath, path_coefficients
from .stats import Stats


@functools.lru_cache(maxsize=64)
def _residual_function(residual):
    return jax.jit(residual)


@functools.lru_cache(maxsize=64)
def _series_function(residual):
    """Jitted ``(d_s, terms, x_old, t, dt, params) -> [R]_1..[R]_K`` along ``d_s + sum a^k terms[k-1]``.

    Compiled once per number of terms K, the terms known at an order (as
    :class:`~jaxanm.series.AffinePath` truncates its jets), so nothing recompiles per step.
    """
    return jax.jit(lambda d_s, terms, *args: path_coefficients(residual, d_s, terms, *args)[1])


_AFFINE_CACHE: dict = {}
"""Compiled affine-split series functions per (residual, argument layout), shared by runs."""


def _affine_functions(residual, d_s, args):
    """The :class:`~jaxanm.series.AffineFunctions` of ``residual`` for this argument layout, or
    None (with a warning, once per layout) when the split cannot be made; the series then comes
    from a jet of the whole residual."""
    leaves, tree = jax.tree_util.tree_flatten((d_s, args))
    key = (residual, tree, tuple((np.shape(v), str(getattr(v, "dtype", type(v).__name__))) for v in leaves))
    if key not in _AFFINE_CACHE:
        if len(_AFFINE_CACHE) >= 16:
            _AFFINE_CACHE.pop(next(iter(_AFFINE_CACHE)))
        try:
            _AFFINE_CACHE[key] = AffineFunctions(residual, d_s, *args)
        except Exception as exc:  # noqa: BLE001 - any tracing failure: fall back, and say why
            warnings.warn(f"the residual could not be split into its affine part and the rest ({exc!r}); "
                          "the ANM series uses a jet of the whole residual (correct, slower)", stacklevel=4)
            _AFFINE_CACHE[key] = None
    return _AFFINE_CACHE[key]


class SeriesPath:
    """The residual's Taylor coefficients along the ANM path from ``d_s``, one order per
    :meth:`next` (counted in ``stats.series_orders`` and timed as ``series``).

    The affine part of the residual is applied outside jet (:class:`~jaxanm.series.AffinePath`),
    and each order's jet is truncated at the terms known.
    :meth:`start_residual` evaluates ``R(d_s)`` together with the frontier values the series
    starts from, in one call.
    """

    def __init__(self, problem: "Problem", d_s, args: tuple, lookahead: bool = False,
                 max_terms: int | None = None):
        self._problem, self._d_s, self._args = problem, d_s, args
        self._lookahead, self._max_terms = lookahead, max_terms
        self._terms = []
        with problem.stats.timer("series"):
            self._fns = problem.affine_functions(d_s, args)
        self._path = None

    def _affine_path(self, f0=None) -> AffinePath:
        """The series along this path (``f0``: the frontier at ``d_s`` when already known)."""
        return AffinePath(self._fns, self._d_s, self._args, f0=f0, lookahead=self._lookahead,
                          max_terms=self._max_terms)

    def start_residual(self) -> np.ndarray:
        """``R(d_s)`` on the host (counted as a residual evaluation)."""
        P = self._problem
        if self._fns is None:
            return P.residual(self._d_s, *self._args)
        with P.stats.timer("series"):
            r, f0 = self._fns.residual_and_frontier(self._d_s, *self._args)
            self._path = self._affine_path(f0)
            r = np.asarray(r)
        P.stats.residual_evaluations += 1
        return r

    def next(self, c) -> np.ndarray:
        """Append the path coefficient ``c_k``; return the residual's coefficient ``[R]_k``
        (with ``lookahead``: ``[R]_{k+1}`` for the provisional ``c_{k+1} = c_k``)."""
        P = self._problem
        if self._fns is None:  # jet of the whole residual
            self._terms.append(np.asarray(c))
            terms = np.stack(self._terms + self._terms[-1:] * self._lookahead)
            return P.series(self._d_s, terms, *self._args)[-1]
        with P.stats.timer("series"):
            if self._path is None:
                self._path = self._affine_path()
            r = self._path.next(c)
        P.stats.series_orders += 1
        return r


_NOT_LOOKED_UP = object()


class Problem:
    """The discrete step problem as the solvers see it (residual, series, tangent, scale)."""

    def __init__(self, residual, scale, stats: Stats, jacobian: str, sparsity):
        self.stats = stats
        self.scale = scale
        self._raw_residual = residual
        self._residual = _residual_function(residual)
        self._series = _series_function(residual)
        self._mode = jacobian
        self._sparsity = sparsity
        self._sparse = None
        self._pattern_key = None
        self._dense = dense_jacobian_function(residual) if jacobian == "dense" else None
        self._affine = _NOT_LOOKED_UP  # AffineFunctions or None once looked up: a run keeps its layout

    def affine_functions(self, d_s, args):
        """The residual's affine-split series functions for this run's argument layout (looked
        up once: a run keeps its shapes and dtypes), or None when it cannot be split."""
        if self._affine is _NOT_LOOKED_UP:
            self._affine = _affine_functions(self._raw_residual, d_s, args)
        return self._affine

    def residual(self, x, x_old, t, dt, params) -> np.ndarray:
        """Step residual on the host."""
        with self.stats.timer("series"):
            r = np.asarray(self._residual(x, x_old, t, dt, params))
        self.stats.residual_evaluations += 1
        return r

    def series(self, d_s, terms, x_old, t, dt, params) -> np.ndarray:
        """Taylor coefficients ``[R]_1..[R]_K`` of the residual along the series path."""
        with self.stats.timer("series"):
            fs = np.asarray(self._series(d_s, terms, x_old, t, dt, params))
        self.stats.series_orders += 1
        return fs

    def tangent(self, x, x_old, t, dt, params):
        """``dR/dx_new`` at ``x``: dense ndarray or scipy CSC, by forward-mode autodiff."""
        with self.stats.timer("jacobian"):
            if self._dense is not None:
                jac = np.asarray(self._dense(x, x_old, t, dt, params))
            else:
                pattern = self._sparsity(params) if callable(self._sparsity) else self._sparsity
                if self._sparse is None:
                    self._sparse = SparseJacobian(self._raw_residual, pattern)
                    self._pattern_key = _pattern_key(pattern)
                elif callable(self._sparsity):
                    key = _pattern_key(pattern)
                    if key != self._pattern_key:
                        self._sparse.set_pattern(pattern)
                        self._pattern_key = key
                jac = self._sparse(x, x_old, t, dt, params)
        self.stats.jacobian_evaluations += 1
        return jac

    def factorize_at(self, x, x_old, t, dt, params) -> Factorization:
        """Tangent at ``x`` factorised on the host (counted)."""
        return factorize(self.tangent(x, x_old, t, dt, params), self.stats)

    def factorize_in_step(self, step, x, x_old, t, dt, params, *, amax=None, residual_norm=None) -> Factorization:
        """:meth:`factorize_at` inside time step ``step``: a tangent that cannot be factorised
        raises :class:`NonFiniteError` (NaN/inf entries) or :class:`StepFailure` (singular),
        located by step and time and carrying a_max and the residual norm."""
        try:
            return self.factorize_at(x, x_old, t, dt, params)
        except SingularMatrixError as exc:
            kind = NonFiniteError if "non-finite" in str(exc) else StepFailure
            raise kind(f"tangent matrix K* cannot be factorised ({exc})", step=step, t=t, amax=amax,
                       residual_norm=residual_norm) from exc

    def norm(self, v) -> float:
        """2-norm of ``v / scale`` (non-dimensional unknowns)."""
        return float(np.linalg.norm(v / self.scale))


def _pattern_key(pattern):
    csr = scipy.sparse.csr_matrix(pattern)
    csr.sort_indices()
    return (csr.shape, csr.nnz, hash(csr.indptr.tobytes()), hash(csr.indices.tobytes()))


CHECK_LIMIT = 10.0
"""An accepted series' end point may miss the accuracy eq. 26 promised (``tol |c_1|``, or
``tol |d_s|`` for ``criterion="state"``) by at most this factor in its Newton distance
``|K*^-1 R(d_end)|`` (a series whose a_max is just above 1 has a tail beyond order p of a few
times ``|c_p|``; ``benchmarks/hard_cases.py`` uses the same limit for its independent check)."""

CHECK_ROUND_OFF = 1e-12
"""Floor of the promised accuracy, relative to the end point: once the increment ``c_1`` of a
(quasi-)steady step is below round-off, ``tol |c_1|`` is below what double precision resolves."""


def validity_range(coeffs: np.ndarray, scale, tol: float, state=None) -> float:
    """a_max of eq. 26: ``(tol ||c_1|| / ||c_p||)^(1/(p-1))`` on the scaled unknowns.

    With ``state`` (the series' starting point d_s), the larger of eq. 26 and the range where
    the last term stays below ``tol`` relative to the state, ``(tol ||d_s|| / ||c_p||)^(1/p)``
    (the criterion of :class:`ANM` with ``criterion="state"``).
    ``inf`` when the last coefficient vanishes (the series is exact); ``0`` when the first does
    not but a coefficient is non-finite.
    """
    p = coeffs.shape[0]
    n1 = np.linalg.norm(coeffs[0] / scale)
    npp = np.linalg.norm(coeffs[-1] / scale)
    if not (np.isfinite(n1) and np.isfinite(npp)):
        return 0.0
    if npp == 0.0:
        return np.inf
    amax = float((tol * n1 / npp) ** (1.0 / (p - 1)))
    if state is not None:
        amax = max(amax, float((tol * np.linalg.norm(state / scale) / npp) ** (1.0 / p)))
    return amax


def evaluate_series(coeffs: np.ndarray, a: float) -> np.ndarray:
    """``sum_j a^j c_j`` by Horner's rule (``coeffs[j-1] = c_j``)."""
    acc = np.zeros_like(coeffs[0])
    for c in coeffs[::-1]:
        acc = (acc + c) * a
    return acc


def _check_tol(name, tol):
    if not (isinstance(tol, (int, float)) and np.isfinite(tol) and 0 < tol < 1):
        raise InputError(f"{name}.tol must be a float in (0, 1), got {tol!r}; e.g. tol=1e-6")


def _check_count(name, field, value, minimum):
    if not (isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= minimum):
        raise InputError(f"{name}.{field} must be an integer >= {minimum}, got {value!r}")


@dataclasses.dataclass(frozen=True)
class SolverState:
    """What a step solver carries from one time step to the next, as a value.

    ``problem`` is the step problem the solver was made for (:meth:`StepSolver.init`),
    ``factorization`` the factorised K* it holds (or None), ``accepted_residual`` the residual
    at the state the last :meth:`StepSolver.step` returned when the solver evaluated it there
    (the time loop then records it instead of evaluating it again), else None.  A state is
    never changed in place: :meth:`StepSolver.step` returns a new one.  A solver that carries
    more subclasses this (frozen) dataclass.
    """

    problem: Problem
    factorization: Factorization | None = None
    accepted_residual: np.ndarray | None = None


class StepSolver(abc.ABC):
    """Base class of the nonlinear step solvers that :func:`jaxanm.integrate` accepts.

    A solver is a set of options; what it carries across time steps is a :class:`SolverState`
    made by :meth:`init` and returned anew by every :meth:`step`, and nothing outside the
    solver changes it except through the methods below.  To write a solver, subclass this
    class and implement :meth:`step` (and :meth:`init` if the state carries more than a
    factorisation); the :class:`Problem` in the state gives residuals, tangents and counted
    factorisations.  ``reuses_factorization`` says whether the K* a state holds is carried to
    the next step (and so stored in checkpoints).
    """

    reuses_factorization: bool = True

    def init(self, problem: Problem) -> SolverState:
        """The state at the start of a run: the problem, no factorisation yet."""
        return SolverState(problem)

    @abc.abstractmethod
    def step(self, state: SolverState, step: int, x_old, t, dt, params) -> tuple[np.ndarray, SolverState]:
        """Solve the time step ``R(x, x_old, t, dt, params) = 0`` from ``x_old``: ``(x, new state)``.

        ``step`` is the time step's index (for messages).  A step that cannot be solved raises
        :class:`StepFailure` (or :class:`NonFiniteError`), with the state to retry from
        attached (:meth:`state_after_failure`) when it differs from ``state``.
        """

    def accepted_residual(self, state: SolverState) -> np.ndarray | None:
        """The residual at the state the last :meth:`step` returned, if it evaluated it, else None."""
        return state.accepted_residual

    def factorization(self, state: SolverState) -> Factorization | None:
        """The factorised K* the state holds (or None)."""
        return state.factorization

    def with_factorization(self, state: SolverState, factorization: Factorization | None) -> SolverState:
        """``state`` with ``factorization`` as its K* (e.g. a Jacobian factorised by the caller),
        or with none (``None``: the next step factorises, as at the start of a run; the time
        loop drops a K* made at a step size far from the next step's this way)."""
        return dataclasses.replace(state, factorization=factorization)

    def state_after_failure(self, state: SolverState, failure: StepFailure) -> SolverState:
        """The state to retry from after :meth:`step` from ``state`` raised ``failure``: the one
        the failed step attached (e.g. holding the K* it factorised before failing, which a
        retry then reuses), else ``state``."""
        attached = getattr(failure, "solver_state", None)
        return state if attached is None else attached

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
        return self.with_factorization(state, Factorization(stored, state.problem.stats))


def _failed(failure: StepFailure, state: SolverState) -> StepFailure:
    """``failure`` with the state to retry from attached (:meth:`StepSolver.state_after_failure`)."""
    failure.solver_state = state
    return failure


@dataclasses.dataclass(frozen=True)
class ANM(StepSolver):
    """Asymptotic Numerical Method: homotopy, Taylor series by jet, continuation.

    Parameters
    ----------
    order : int
        Truncation order p of the series (>= 2: eq. 26 compares c_1 and c_p).
    tol : float
        eta of eq. 26: the series is accepted at a = 1 when a_max >= 1 *and* its end point
        passes the a-posteriori check below.
    max_substeps : int
        Continuation sub-steps allowed within one time step (each after a fresh K*
        still gave a_max < 1) before the step is declared failed (then ``integrate`` halves dt).
    criterion : {"increment", "state"}
        What ``tol`` is relative to.  ``"increment"`` is the paper's eq. 26: the last term is
        ``tol`` times the first-order increment ``c_1``.  ``"state"`` also accepts a range where
        the last term is below ``tol`` times the state ``d_s`` (:func:`validity_range`), the
        same yardstick as Newton's ``|dx| / |x| < delta``.  Eq. 26 is scale-free in the size
        of the step's residual: once ``R(d_s)`` is tiny, a stale K* still gives the same
        a_max, so quasi-steady steps refactorise to resolve increments far below the state's
        accuracy (docs/notes/anm_on_fsw_paper.md).
    adaptive : bool
        Order-adaptive series: ``order`` is the maximum, and the series is accepted at the
        first order j whose validity range (eq. 26 with c_j as last term) reaches a = 1 and
        whose end point passes the check below; at order p everything is as in the fixed-order
        mode.  The orders used are in ``stats.orders``.  ``False``: fixed order p, as in the
        paper's Table 1.  In both modes the coefficients are computed one order at a time, the
        jet at order j truncated to the j - 1 terms known, so a series costs O(p^2) jet terms,
        not O(p^3).
    homotopy : {"convex", "newton"}
        The artificial problem whose series is summed at a = 1 (both reach ``R(d) = 0`` there
        and share the validity range, the end-point check and the continuation).
        ``"convex"`` is the paper's eq. 22: ``(1 - a) K* (d - d_s) + a R(d) = 0``; order j reads
        ``K* c_j = K* c_{j-1} - [R]_{j-1}``, so the nonlinear terms of order j - 1 enter at order
        j: with a fresh K* (the tangent K_T at d_s) c_2 = 0, and the series gains about one power
        of the increment every two orders.  ``"newton"`` is
        ``R(d) = (1 - a) [R(d_s) + (K_T - K*) (d - d_s)]``: its tangent at a = 0 is K* itself,
        with a fresh K* it is the Newton homotopy ``R(d) = (1 - a) R(d_s)`` of the ANM
        literature, and order j reads ``K* c_j = K* c_{j-1} - [R]_j`` with ``[R]_j`` taken along
        the path with the provisional ``c_j = c_{j-1}`` (``K_T c_{j-1}`` plus the nonlinear terms
        of order j: one more term of the same jet).  Each order then gains a power of the
        increment, as a modified-Newton iteration with the same K* does
        (docs/notes/anm_homotopy.md).
    pade : bool
        Padé approximants extend the order-p series (:mod:`jaxanm.pade`: one common
        denominator, Elhage-Hussein, Potier-Ferry and Damil 2000).  A series whose a_max < 1 is
        still accepted when the validity range of its approximant ``P_p`` (where it agrees with
        ``P_{p-1}`` within ``tol`` relative to the increment, or for ``"state"`` to the larger
        of increment and state; never past a real pole) reaches a = 1: the end point is then
        ``P_p(1)``, not the truncated sum, and it must pass the same end-point check as any
        accepted series (Notes).  With a fresh K* a continuation sub-step goes to ``P_p`` at its
        range when that is farther than a_max.  Nothing else changes (a stale K* whose series
        and approximant both fall short is refactorised as before).  Costs one QR of the
        ``(n, p)`` scaled coefficients per series with a_max < 1 (counted in the ``other``
        wall time).  ``stats.pade_accepted`` counts the series accepted this way; their
        ``stats.amax`` entry is the approximant's range, searched up to a = 1 (so 1.0).
        Needs ``order >= 3`` (for p = 2 the companion ``P_1`` is the start point and vouches
        for nothing).  With ``adaptive`` the approximant is tried at order p only: below p the
        next order costs one jet order and no factorisation, and is what adaptivity weighs;
        the approximant replaces what order p alone would refuse.

    Notes
    -----
    Eq. 26 judges the series by its last coefficient alone, and that coefficient can vanish
    while the series is far from converged: with K* factorised at the series' start, c_2 = 0
    identically, and a residual with a vanishing second derivative there (a cubic reaction from
    u = 0) zeroes every coefficient but c_1, c_4, c_7, ....  Every series with a_max >= 1 is
    therefore checked at its end point, for one residual evaluation and one triangular solve
    with the K* already factorised: its Newton distance ``|K*^-1 R(d_end)|`` (scaled norm) must
    be at most :data:`CHECK_LIMIT` times what the criterion promised, ``tol |c_1|`` (for
    ``"state"`` the larger ``tol |d_s|``), with a round-off floor :data:`CHECK_ROUND_OFF`
    ``|d_end|``.  A series that fails is treated like a_max < 1: with a stale K*, K* is
    refactorised and the series redone; with a fresh one, a continuation sub-step restarts the
    homotopy at the end point when it is closer to the solution than the start (its residual is
    reused), else half-way along the series (docs/notes/anm_acceptance.md).  Where eq. 26 tells
    the truth this changes no factorisation and no state.
    """

    order: int = 7
    tol: float = 1e-6
    max_substeps: int = 50
    criterion: str = "increment"
    adaptive: bool = False
    homotopy: str = "convex"
    pade: bool = False

    def __post_init__(self):
        if not (isinstance(self.order, (int, np.integer)) and not isinstance(self.order, bool) and self.order >= 2):
            raise InputError(f"ANM.order must be an integer >= 2, got {self.order!r}: the validity range a_max "
                             "of eq. 26 compares c_1 with c_p and takes the 1/(p-1)-th root, undefined for p = 1 "
                             "(an order-1 series is one linearised step: use jaxanm.ModifiedNewton for that)")
        _check_tol("ANM", self.tol)
        _check_count("ANM", "max_substeps", self.max_substeps, 0)
        if not isinstance(self.adaptive, (bool, np.bool_)):
            raise InputError(f"ANM.adaptive must be True or False, got {self.adaptive!r}")
        if self.homotopy not in ("convex", "newton"):
            raise InputError(f"ANM.homotopy must be 'convex' (the paper's eq. 22) or 'newton', got {self.homotopy!r}")
        if not isinstance(self.pade, (bool, np.bool_)):
            raise InputError(f"ANM.pade must be True or False, got {self.pade!r}")
        if self.pade and self.order < 3:
            raise InputError(f"ANM.pade=True needs order >= 3, got order={self.order}: the Padé range compares "
                             "the approximants of orders p and p - 1, and for p = 2 the lower one is the start "
                             "point (use order >= 3, or pade=False)")
        if self.criterion not in ("increment", "state"):
            raise InputError(f"ANM.criterion must be 'increment' (eq. 26) or 'state', got {self.criterion!r}")


    def step(self, state: SolverState, step: int, x_old, t, dt, params) -> tuple[np.ndarray, SolverState]:
        """One time step by series and continuation from ``x_old``, with the state's K* (refactorised
        when its series falls short); the new state holds the K* used last and the residual
        at the accepted state (evaluated by the end-point check)."""
        attempt = _ANMStep(self, state.problem, state.factorization)
        try:
            x, residual = attempt.run(step, x_old, t, dt, params)
        except StepFailure as failure:
            raise _failed(failure, dataclasses.replace(state, factorization=attempt.fact, accepted_residual=None))
        return x, dataclasses.replace(state, factorization=attempt.fact, accepted_residual=residual)


def _release(fact: Factorization | None) -> None:
    """Free the factors of a K* the step replaces, before the next one is made: at most one LU
    alive (the state the step started from keeps the matrix, and a solve with it factorises
    again; see :meth:`Factorization.release`)."""
    if fact is not None:
        fact.release()


class _ANMStep:
    """One time step of the :class:`ANM` (``opts``): series, continuation sub-steps, acceptance.

    ``fact`` is the K* it works with: the state's, replaced when a series from a stale K*
    falls short; :meth:`ANM.step` hands the last one on in the new state.
    """

    def __init__(self, opts: ANM, problem: Problem, fact: Factorization | None):
        self.opts = opts
        self.problem = problem
        self.fact = fact

    def _drop_factorization(self) -> None:
        """Give up the stale K* (its factors freed, see :func:`_release`); the next series
        factorises at its start point."""
        _release(self.fact)
        self.fact = None

    def run(self, step: int, x_old, t, dt, params):
        """The accepted state and the residual there (None when not evaluated): ``(x, R(x))``."""
        P, p, st = self.problem, self.opts.order, self.problem.stats
        args = (x_old, t, dt, params)
        d_s = np.array(x_old, dtype=np.float64)
        fresh = False
        substeps = 0
        amax = None  # of the previous series in this step (reported if a later one fails)
        r_next = None  # R at the next series' start when already known (a sub-step to a checked end point)
        while True:
            # the residual coefficient that order j needs depends on c_1 .. c_{j-1} only (and, for
            # the Newton homotopy, on the provisional c_j = c_{j-1}): each jet is truncated there
            path = SeriesPath(P, d_s, args, lookahead=self.opts.homotopy == "newton", max_terms=p - 1)
            r0 = path.start_residual() if r_next is None else r_next
            r_next = None
            r0_norm = float(np.max(np.abs(r0)))
            if not np.isfinite(r0_norm):
                raise NonFiniteError("residual at the start of the series is not finite", step=step, t=t,
                                     amax=amax, residual_norm=r0_norm)
            if self.fact is None:
                self.fact = P.factorize_in_step(step, d_s, *args, amax=amax, residual_norm=r0_norm)
                fresh = True
            coeffs, accepted = self._series(path, r0, d_s, args)
            if accepted is not None:
                return accepted
            amax = self._validity_range(coeffs, d_s)
            if amax >= 1.0:
                d_end = d_s + coeffs.sum(axis=0)
                check, distance, r_end = self._end_point_check(d_end, d_s, coeffs[0], *args)
                if check <= CHECK_LIMIT:
                    return self._accepted(d_end, amax, p, r_end)
                # the series claimed a = 1 but its end point is not converged (e.g. a last
                # coefficient that vanishes by parity): not an accepted step
                if not fresh:  # stale K*: refactorise at the start point and redo the series
                    self._drop_factorization()
                    continue
                if substeps >= self.opts.max_substeps:
                    raise StepFailure(f"series from a fresh K* claims a = 1 (a_max = {amax:.3g}) but its end point "
                                      f"misses the promised accuracy {check:.3g} times, after {substeps} "
                                      f"continuation sub-steps (max_substeps = {self.opts.max_substeps})",
                                      step=step, t=t, amax=amax, residual_norm=r0_norm)
                substeps += 1
                st.substeps += 1
                # continuation sub-step: to the end point when it is closer to the solution than
                # the start (Newton distance by K*), else half-way along the series
                if distance < P.norm(coeffs[0]):
                    d_s, r_next = d_end, r_end
                else:
                    d_s = d_s + evaluate_series(coeffs, 0.5)
                fresh = False
                continue
            approx, a_pade, pade_end = self._try_pade(coeffs, d_s, args)
            if pade_end is not None and pade_end[1] <= CHECK_LIMIT:
                st.pade_accepted += 1
                return self._accepted(pade_end[0], a_pade, p, pade_end[3])
            if not fresh:  # stale K*: refactorise at the current point and redo the series
                self._drop_factorization()
                continue
            if not np.all(np.isfinite(coeffs)):
                raise NonFiniteError("series coefficients are not finite with a fresh K*", step=step, t=t,
                                     amax=amax, residual_norm=r0_norm)
            if substeps >= self.opts.max_substeps or max(amax, a_pade) < 1e-12:
                raise StepFailure(f"series from a fresh K* cannot reach a = 1 after {substeps} "
                                  f"continuation sub-steps (max_substeps = {self.opts.max_substeps})",
                                  step=step, t=t, amax=amax, residual_norm=r0_norm)
            substeps += 1
            st.substeps += 1  # counted when taken (a refused sub-step is a failure, not a sub-step)
            d_s, r_next = self._continuation_point(coeffs, d_s, amax, approx, a_pade, pade_end)
            fresh = False

    def _series(self, path: SeriesPath, r0, d_s, args):
        """The series' coefficients ``c_1 .. c_p`` by K*: ``(coeffs, None)``, or, order-adaptive,
        ``(None, (x, R(x)))`` when a truncated series is accepted on the way."""
        p = self.opts.order
        coeffs = np.zeros((p, d_s.size))
        coeffs[0] = -self.fact.solve(r0)
        for j in range(2, p + 1):
            rj = path.next(coeffs[j - 2])
            coeffs[j - 1] = coeffs[j - 2] - self.fact.solve(rj)
            if self.opts.adaptive and j < p:
                accepted = self._accept_early(coeffs[:j], d_s, *args)
                if accepted is not None:
                    return None, accepted
        return coeffs, None

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
        check, distance, r_end = self._end_point_check(d_end, d_s, coeffs[0], *args)
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

    def _accept_early(self, coeffs, d_s, x_old, t, dt, params):
        """Order-adaptive acceptance of the series truncated at order ``j = len(coeffs) < p``:
        ``(x, R(x))`` with the end point ``x = d_s + c_1 + ... + c_j`` when its a_max (eq. 26 at
        order j) reaches 1 and it passes the same end-point check as a full series, else None
        (the series goes on to order j + 1; a truncated series that fails is no failure of the
        step)."""
        amax = self._validity_range(coeffs, d_s)
        if not amax >= 1.0:
            return None
        d_end = d_s + coeffs.sum(axis=0)
        check, _, r_end = self._end_point_check(d_end, d_s, coeffs[0], x_old, t, dt, params)
        if check > CHECK_LIMIT:
            return None
        return self._accepted(d_end, amax, coeffs.shape[0], r_end)

    def _pade_range(self, coeffs, d_s):
        """The Padé approximant of the order-p series and its validity range (searched up to
        a = 1, by this solver's tolerance and criterion): ``(approx, a_pade)``."""
        approx = _pade.approximant(coeffs, self.problem.scale)
        a_pade = _pade.validity_range(approx, self.opts.tol, limit=1.0,
                                      state=d_s if self.opts.criterion == "state" else None)
        return approx, a_pade

    def _validity_range(self, coeffs, d_s) -> float:
        """a_max of the series ``coeffs`` from ``d_s`` by this solver's criterion."""
        return validity_range(coeffs, self.problem.scale, self.opts.tol,
                              state=d_s if self.opts.criterion == "state" else None)

    def _accepted(self, d_end, amax, order, r_end):
        """Record an accepted series (a_max, its order); return ``(d_end, R(d_end))``."""
        st = self.problem.stats
        st.amax.append(amax)
        st.orders.append(order)
        return d_end, r_end

    def _end_point_check(self, d_end, d_s, c_1, x_old, t, dt, params):
        """A-posteriori check of an accepted series: the Newton distance of its end point by the
        factorised K*, ``|K*^-1 R(d_end)|``, over what the acceptance promised (see :class:`ANM`).

        Returns ``(ratio, distance, R(d_end))``.
        One residual evaluation and one triangular solve.  A non-finite residual at the end
        point is not a question of series accuracy: the ratio is then 0 and the state goes to
        the caller, whose accepted-state check names it (:class:`NonFiniteError`).
        """
        P = self.problem
        r_end = P.residual(d_end, x_old, t, dt, params)
        if not np.all(np.isfinite(r_end)):
            return 0.0, np.inf, r_end
        distance = P.norm(self.fact.solve(r_end))
        promised = self.opts.tol * P.norm(c_1)
        if self.opts.criterion == "state":
            promised = max(promised, self.opts.tol * P.norm(d_s))
        promised = max(promised, CHECK_ROUND_OFF * P.norm(d_end), np.finfo(float).tiny)
        return distance / promised, distance, r_end


def _relative_change(P: Problem, dx, x) -> float:
    return P.norm(dx) / max(P.norm(x), np.finfo(float).tiny)


class _NewtonIteration(StepSolver):
    """The Newton iteration shared by :class:`Newton` (a Jacobian per iteration) and
    :class:`ModifiedNewton` (the factorised Jacobian reused while it contracts): subclasses set
    ``tol``, ``max_iter``, ``reuses_factorization`` and, when reusing, ``max_rate``."""

    def step(self, state: SolverState, step: int, x_old, t, dt, params) -> tuple[np.ndarray, SolverState]:
        """Newton iterations from ``x_old`` until ``|dx| / |x| <= tol``; the new state holds the
        last factorised Jacobian (carried to the next step when ``reuses_factorization``)."""
        attempt = _NewtonStep(self, state.problem, state.factorization)
        try:
            x = attempt.run(step, x_old, t, dt, params)
        except StepFailure as failure:
            raise _failed(failure, dataclasses.replace(state, factorization=attempt.fact, accepted_residual=None))
        return x, dataclasses.replace(state, factorization=attempt.fact, accepted_residual=None)


class _NewtonStep:
    """One time step of a :class:`_NewtonIteration` (``opts``); ``fact`` is the factorised
    Jacobian it works with (the state's, rebuilt as the options say)."""

    def __init__(self, opts: _NewtonIteration, problem: Problem, fact: Factorization | None):
        self.opts = opts
        self.problem = problem
        self.fact = fact

    def run(self, step: int, x_old, t, dt, params) -> np.ndarray:
        """The converged iterate."""
        P, st = self.problem, self.problem.stats
        x = np.array(x_old, dtype=np.float64)
        previous = None
        change = np.inf
        for _ in range(self.opts.max_iter):
            r = P.residual(x, x_old, t, dt, params)
            r_norm = float(np.max(np.abs(r)))
            if not np.isfinite(r_norm):
                raise NonFiniteError("Newton residual is not finite", step=step, t=t, residual_norm=r_norm)
            just_factored = self.fact is None or not self.opts.reuses_factorization
            if just_factored:
                _release(self.fact)
                self.fact = P.factorize_in_step(step, x, x_old, t, dt, params, residual_norm=r_norm)
            dx = -self.fact.solve(r)
            size = P.norm(dx)
            if (not just_factored and previous is not None and size > self.opts.max_rate * previous) or not np.isfinite(size):
                if just_factored:
                    raise NonFiniteError("Newton correction is not finite", step=step, t=t, residual_norm=r_norm)
                _release(self.fact)  # slow or diverging with an old Jacobian: rebuild it here
                self.fact = None
                previous = None
                continue
            x = x + dx
            st.newton_iterations += 1
            previous = size
            change = _relative_change(P, dx, x)
            if change <= self.opts.tol:
                return x
        raise StepFailure(f"{type(self.opts).__name__} did not converge in {self.opts.max_iter} iterations "
                          f"(last relative change {change:.3g} > tol {self.opts.tol:g})",
                          step=step, t=t, residual_norm=r_norm)


@dataclasses.dataclass(frozen=True)
class Newton(_NewtonIteration):
    """Newton–Raphson: a Jacobian and a factorisation at every iteration.

    Converged when the relative change of the (scaled) iterates ``|dx| / |x|`` is below ``tol``
    (the paper's delta).
    """

    tol: float = 1e-6
    max_iter: int = 30
    reuses_factorization = False  # nothing is reused across iterations or steps

    def __post_init__(self):
        _check_tol("Newton", self.tol)
        _check_count("Newton", "max_iter", self.max_iter, 1)


@dataclasses.dataclass(frozen=True)
class ModifiedNewton(_NewtonIteration):
    """Modified Newton: the factorised Jacobian is reused across iterations and time steps.

    It is rebuilt at the current iterate when the contraction ``|dx_k| / |dx_{k-1}|`` exceeds
    ``max_rate`` (or the iteration diverges).  Same convergence test as :class:`Newton`.
    """

    tol: float = 1e-6
    max_iter: int = 50
    max_rate: float = 0.5
    reuses_factorization = True

    def __post_init__(self):
        _check_tol("ModifiedNewton", self.tol)
        _check_count("ModifiedNewton", "max_iter", self.max_iter, 1)
        if not (0 < self.max_rate < 1):
            raise InputError(f"ModifiedNewton.max_rate must be in (0, 1), got {self.max_rate!r}")
