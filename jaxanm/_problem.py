"""The discrete step problem as the step solvers see it, and its compiled functions.

:class:`Problem` gives residuals, series, tangents and factorisations of one run, each timed
and counted in the run's :class:`~jaxanm.stats.Stats`.  This module is the one writer of those
work counters (:func:`work`, :func:`count`, :func:`record`, :func:`factorize`,
:func:`counted_solve`): every other caller (the path follower's system, IDA, the
sensitivities) records through them.  :class:`SeriesPath` gives the
residual's Taylor coefficients along one ANM path, one order at a time.  The compiled
functions of a residual are shared by every run with that residual: they live in
:func:`compiled`, a bounded cache of :class:`CompiledResidual` objects, each of which owns
its affine-split series functions per argument layout.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import warnings

import jax
import numpy as np
import scipy.sparse

from ._factorization import Factorization
from ._series import AffineFunctions, AffinePath, orders_kept, path_coefficients
from .errors import NonFiniteError, SingularMatrixError, StepFailure
from .jacobian import SparseJacobian, dense_jacobian_function
from .stats import Counters, Stats

MAX_LAYOUTS = 16
"""Argument layouts (shapes and dtypes) whose affine-split functions a residual keeps: a
rezoned run changes its layout at every rezone and never goes back to an old one, while a
sweep or a calibration reuses one; the oldest layout is dropped first."""


def count(stats: Counters, counter: str, n: int = 1) -> None:
    """Add ``n`` to the work counter ``stats.<counter>``."""
    setattr(stats, counter, getattr(stats, counter) + n)


def record(stats: Counters, field: str, value) -> None:
    """Append ``value`` to the per-step list ``stats.<field>`` (e.g. a sensitivity's refinement
    rate)."""
    getattr(stats, field).append(value)


@contextlib.contextmanager
def work(stats: Counters, timer: str, counter: str | None = None, n: int = 1):
    """Time the ``with`` block under ``stats.wall_time[timer]`` and, when it completes, count it
    (``n`` added to ``stats.<counter>``; nothing counted for a block that raised)."""
    with stats.timer(timer):
        yield
    if counter is not None:
        count(stats, counter, n)


def factorize(matrix, stats: Stats) -> Factorization:
    """Factorise ``matrix`` on the host, timed as ``factorize`` and counted in
    ``stats.factorizations``."""
    with work(stats, "factorize", "factorizations"):
        made = Factorization(matrix)
    return made


def counted_solve(fact, rhs, stats: Stats) -> np.ndarray:
    """``fact.solve(rhs)`` timed as ``solve`` and counted in ``stats.solves`` (1 per column of
    ``rhs``); a released :class:`~jaxanm.Factorization` is factorised again first, timed and
    counted as a factorisation.  ``fact``: any object with ``solve(rhs)`` (a factorisation hook's)."""
    rhs = np.asarray(rhs, dtype=np.float64)
    if getattr(fact, "released", False):
        with work(stats, "factorize", "factorizations"):
            fact.refactor()
    with work(stats, "solve", "solves", 1 if rhs.ndim == 1 else rhs.shape[1]):
        x = fact.solve(rhs)
    return x


class CompiledResidual:
    """The compiled functions of one residual ``(x, x_old, t, dt, params) -> R``: ``residual``
    (jitted), ``series`` (jitted ``(d_s, terms, x_old, t, dt, params) -> [R]_1..[R]_K`` along
    ``d_s + sum a^k terms[k-1]``, compiled once per number of terms K, the terms known at an
    order, so nothing recompiles per step) and :meth:`affine_functions` per argument layout."""

    def __init__(self, residual):
        self.raw = residual
        self.residual = jax.jit(residual)
        self.series = jax.jit(lambda d_s, terms, *args: path_coefficients(residual, d_s, terms, *args)[1])
        self._affine = collections.OrderedDict()  # layout -> AffineFunctions or None, oldest first

    def affine_functions(self, d_s, args):
        """The :class:`~jaxanm._series.AffineFunctions` of the residual for the layout of
        ``(d_s, args)``, or None (with a warning, once per layout) when the split cannot be
        made; the series then comes from a jet of the whole residual."""
        leaves, tree = jax.tree_util.tree_flatten((d_s, args))
        key = (tree, tuple((np.shape(v), str(getattr(v, "dtype", type(v).__name__))) for v in leaves))
        if key not in self._affine:
            if len(self._affine) >= MAX_LAYOUTS:
                self._affine.popitem(last=False)
            try:
                self._affine[key] = AffineFunctions(self.raw, d_s, *args)
            except Exception as exc:  # noqa: BLE001 - any tracing failure: fall back, and say why
                warnings.warn(f"the residual could not be split into its affine part and the rest ({exc!r}); "
                              "the ANM series uses a jet of the whole residual (correct, slower)", stacklevel=4)
                self._affine[key] = None
        return self._affine[key]


@functools.lru_cache(maxsize=64)
def compiled(residual) -> CompiledResidual:
    """The :class:`CompiledResidual` of ``residual`` (by identity), shared by every run with it;
    the 64 most recently used residuals are kept (a bounded ``functools.lru_cache``)."""
    return CompiledResidual(residual)


class SeriesPath:
    """The residual's Taylor coefficients along the ANM path from ``d_s``, one order per
    :meth:`next` (counted in ``stats.series_orders`` and timed as ``series``).

    The affine part of the residual is applied outside jet (:class:`~jaxanm._series.AffinePath`),
    and each order's jet is truncated at the terms known.
    :meth:`start_residual` evaluates ``R(d_s)`` together with the frontier values the series
    starts from, in one call.
    """

    def __init__(self, problem: "Problem", d_s, args: tuple, lookahead: bool = False,
                 max_terms: int | None = None):
        self._problem, self._d_s, self._args = problem, d_s, args
        self._lookahead, self._max_terms = lookahead, max_terms
        self._terms: list[np.ndarray] = []
        with work(problem.stats, "series"):
            self._fns = problem.affine_functions(d_s, args)
            if self._fns is not None:
                self._fns.prepare(d_s, args, orders_kept(max_terms, lookahead), lookahead)
        self._path: AffinePath | None = None

    def _affine_path(self, f0=None) -> AffinePath:
        """The series along this path (``f0``: its state at ``d_s`` when already made)."""
        return AffinePath(self._fns, self._d_s, self._args, f0=f0, lookahead=self._lookahead,
                          max_terms=self._max_terms)

    def start_residual(self) -> np.ndarray:
        """``R(d_s)`` on the host (counted as a residual evaluation)."""
        P = self._problem
        if self._fns is None:
            return P.residual(self._d_s, *self._args)
        with work(P.stats, "series", "residual_evaluations"):
            r, f0 = self._fns.start(self._d_s, *self._args)
            self._path = self._affine_path(f0)
            r = np.asarray(r)
        return r

    def next(self, c) -> np.ndarray:
        """Append the path coefficient ``c_k``; return the residual's coefficient ``[R]_k``
        (with ``lookahead``: ``[R]_{k+1}`` for the provisional ``c_{k+1} = c_k``)."""
        P = self._problem
        if self._fns is None:  # jet of the whole residual
            self._terms.append(np.asarray(c))
            terms = np.stack(self._terms + self._terms[-1:] * self._lookahead)
            return P.series(self._d_s, terms, *self._args)[-1]
        with work(P.stats, "series", "series_orders"):
            if self._path is None:
                self._path = self._affine_path()
            r = self._path.next(c)
        return r


_NOT_LOOKED_UP = object()


class Problem:
    """The discrete step problem as the solvers see it: residual, series, tangent, factorisations
    and solves, each timed and counted in ``stats``; ``scale`` makes the unknowns
    non-dimensional for :meth:`norm`.

    ``jacobian`` is ``"dense"`` or ``"sparse"``; ``sparsity`` the sparse tangent's pattern, or a
    function of the parameters giving it (a pattern that changes is re-coloured).
    """

    def __init__(self, residual, scale, stats: Stats, jacobian: str, sparsity):
        self.stats = stats
        self.scale = scale
        self._compiled = compiled(residual)
        self._mode = jacobian
        self._sparsity = sparsity
        self._sparse: SparseJacobian | None = None
        self._pattern_key = None
        self._dense = dense_jacobian_function(residual) if jacobian == "dense" else None
        self._affine = _NOT_LOOKED_UP  # AffineFunctions or None once looked up: a run keeps its layout

    def affine_functions(self, d_s, args):
        """The residual's affine-split series functions for this run's argument layout (looked
        up once: a run keeps its shapes and dtypes), or None when it cannot be split."""
        if self._affine is _NOT_LOOKED_UP:
            self._affine = self._compiled.affine_functions(d_s, args)
        return self._affine

    def residual(self, x, x_old, t, dt, params) -> np.ndarray:
        """Step residual on the host: by the series' start program when this run has made one
        (one compiled program of the residual per run, not two), else the jitted residual."""
        with work(self.stats, "series", "residual_evaluations"):
            fns = self._affine if isinstance(self._affine, AffineFunctions) else None
            r = np.asarray(fns.start(x, x_old, t, dt, params)[0] if fns is not None
                           else self._compiled.residual(x, x_old, t, dt, params))
        return r

    def series(self, d_s, terms, x_old, t, dt, params) -> np.ndarray:
        """Taylor coefficients ``[R]_1..[R]_K`` of the residual along the series path."""
        with work(self.stats, "series", "series_orders"):
            fs = np.asarray(self._compiled.series(d_s, terms, x_old, t, dt, params))
        return fs

    def tangent(self, x, x_old, t, dt, params):
        """``dR/dx_new`` at ``x``: dense ndarray or scipy CSC, by forward-mode autodiff."""
        with work(self.stats, "jacobian", "jacobian_evaluations"):
            if self._dense is not None:
                jac = np.asarray(self._dense(x, x_old, t, dt, params))
            else:
                jac = self._sparse_jacobian(params)(x, x_old, t, dt, params)
        return jac

    def _sparse_jacobian(self, params) -> SparseJacobian:
        """The coloured sparse Jacobian, its pattern brought up to date with ``params``."""
        pattern = self._sparsity(params) if callable(self._sparsity) else self._sparsity
        if self._sparse is None:
            self._sparse = SparseJacobian(self._compiled.raw, pattern)
            self._pattern_key = _pattern_key(pattern)
        elif callable(self._sparsity):
            key = _pattern_key(pattern)
            if key != self._pattern_key:
                self._sparse.set_pattern(pattern)
                self._pattern_key = key
        return self._sparse

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

    def solve(self, fact: Factorization, rhs) -> np.ndarray:
        """``K*^-1 rhs`` with ``fact`` (timed and counted, see
        :func:`counted_solve`)."""
        return counted_solve(fact, rhs, self.stats)

    def norm(self, v) -> float:
        """2-norm of ``v / scale`` (non-dimensional unknowns)."""
        return float(np.linalg.norm(v / self.scale))


def _pattern_key(pattern):
    csr = scipy.sparse.csr_matrix(pattern)
    csr.sort_indices()
    return (csr.shape, csr.nnz, hash(csr.indptr.tobytes()), hash(csr.indices.tobytes()))


def relative_change(P: Problem, dx, x) -> float:
    """``|dx| / |x|`` in the scaled norm (the Newton solvers' convergence test)."""
    return P.norm(dx) / max(P.norm(x), np.finfo(float).tiny)
