"""Events on a branch: what path following finds between its points (folds, branch points, and
later kinds), and the hook through which it finds them.

Every point of a walk is factorised (the bordered matrix ``B`` of :mod:`jaxanm.bordered`).
After each point the walk calls its **detectors** with a :class:`StepEnd`: the point, the
step that ended there (its series), and the factorised linearisation.  A detector returns
the :class:`Event` values it found in that step (usually none); they are kept on the branch
in branch order (:attr:`jaxanm.Branch.events`).  The built-in detectors, chosen by
``events=`` of :func:`jaxanm.continuation`, are in :data:`DETECTORS`; ``on_step=`` adds one
of the user's.  A detector keeps its own state between calls (it sees the points in order).

- ``"fold"`` (:class:`FoldDetector`): a root of ``d lam / d a`` of a step's series where lam
  turns by more than the branch's accuracy (:func:`fold_roots`; on a Newton branch, whose
  interpolant is only cubic, the tangent's turn between the points decides); lam is
  stationary at a fold, so the ANM's series gives it to its own accuracy, and where that is
  not enough (:data:`POLISH_BELOW`; always on a Newton branch) it is polished by Newton on
  the fold's augmented system (:mod:`jaxanm._augmented`), which also gives the left null
  vector.
- ``"branch_point"`` (:class:`BranchPointDetector`): ``det B`` changes sign across a step that
  passes a simple branch point, and only there (its sign is read off the LU already made);
  the point is then located by Newton on its augmented system (:mod:`jaxanm._augmented`) and
  its two tangents come from the algebraic bifurcation equation (:mod:`jaxanm.switching`).
"""

from __future__ import annotations

import dataclasses
import types
from typing import Any, Callable, Mapping, NamedTuple

import numpy as np

from ._augmented import locate_branch_point, locate_fold
from ._real_roots import real_roots, sign_changes
from .bordered import ContinuationFailure, ExtendedSystem, Linearisation, release
from .switching import branch_tangents


@dataclasses.dataclass(frozen=True, eq=False)
class Event:
    """Something found on a branch between two of its points.

    Attributes
    ----------
    kind : str
        ``"fold"`` (a limit point in lam) or ``"branch_point"`` (a simple bifurcation); other
        detectors add their own kinds.
    lam : float
        The parameter at the event.
    u : ndarray (n,)
        The unknowns at the event.
    step : int
        Index of the branch step it lies on (step i goes from point i to point i + 1).
    s : float
        Its arclength along the branch (:attr:`jaxanm.Branch.s`).
    tangent : ndarray (n+1,)
        The branch's unit tangent there (scaled norm, oriented along the branch).
    data : mapping
        What is particular to the kind (read-only; arrays are the event's own):

        - fold: ``"null_vector"`` (n,), the unit null vector of R_u (the tangent's u part);
          ``"left_null_vector"`` (n,) ``psi``, ``psi^T R_u = 0`` (when polished);
          ``"located"``: ``"augmented"`` (polished by Newton on the augmented system) or
          ``"series"`` (the root on the ANM's series, accurate enough not to need it,
          :data:`POLISH_BELOW`, or where the polish did not converge).
        - branch_point: ``"tangents"`` (2, n+1), the unit tangents of the branch followed and
          of the bifurcated branch (the second one's first entry of largest magnitude, scaled,
          positive: ``direction=+1`` of a switch follows it); ``"null_vectors"`` (n+1, 2), an orthonormal basis (scaled)
          of R_U's null space; ``"left_null_vector"`` (n,), R_u's left null vector ``psi``;
          ``"abe"`` (2, 2), the algebraic bifurcation equation's coefficients
          ``psi^T R_UU[e_j, e_k]`` in that basis.
    """

    kind: str
    lam: float
    u: np.ndarray
    step: int
    s: float
    tangent: np.ndarray
    data: Mapping[str, Any] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "data", types.MappingProxyType(dict(self.data)))

    def __reduce__(self):
        """Pickled with its data as a plain dict (a read-only view is not picklable)."""
        return Event, (self.kind, self.lam, self.u, self.step, self.s, self.tangent, dict(self.data))

    def __repr__(self) -> str:
        return f"Event({self.kind!r}, lam={self.lam:.10g}, step={self.step}, s={self.s:.6g})"


class StepSeries(NamedTuple):
    """The step that ended at a point: where it started (``start`` (n+1,), at arclength
    ``s``), its length ``a`` (scaled pseudo-arclength) and its ``series`` (q, n+1):
    ``U(a') = start + sum_k a'^k series[k-1]`` for ``a'`` in ``[0, a]`` (the ANM's own series;
    Newton's cubic Hermite interpolant of the step); how far from the branch its end was before
    the end correction (``end_error``) and its start is (``start_error``), scaled: the series'
    accuracy."""

    start: np.ndarray
    s: float
    a: float
    series: np.ndarray
    end_error: float = 0.0
    start_error: float = 0.0

    def at(self, a: float) -> np.ndarray:
        """``U`` on the step's series at ``a``."""
        return self.start + (a ** np.arange(1, self.series.shape[0] + 1)) @ self.series

    def derivative(self, a: float) -> np.ndarray:
        """``dU/da`` of the step's series at ``a``."""
        k = np.arange(1, self.series.shape[0] + 1)
        return (k * a ** (k - 1)) @ self.series


@dataclasses.dataclass(frozen=True, eq=False)
class StepEnd:
    """What a detector is told at each point of a walk (the hook ``on_step`` of
    :func:`jaxanm.continuation` gets the same).

    Attributes
    ----------
    index : int
        The point's index on the branch (0: the start; the step that ended here is
        ``index - 1``).
    point : ndarray (n+1,)
        ``U = (u, lam)`` at the point.
    tangent : ndarray (n+1,)
        The unit tangent there (scaled norm), oriented along the branch.
    s : float
        The point's arclength.
    linearisation : Linearisation or None
        The bordered matrix ``[[R_u, R_lam], [w^T]]`` factorised at the point (or at Newton's
        last iterate, within tol of it): ``solve``, ``constrained``, ``z`` (its kernel
        vector), ``jacobian`` (R_u, dense or scipy sparse), ``dlam``, ``residual``,
        ``slogdet()``.  Solving with it costs no factorisation (until another one is
        made: the walk keeps one LU alive, so a detector that factorises must expect its
        solves to refactorise, counted).  None at a point where the matrix is singular (the
        branch point a switched branch starts from).
    system : ExtendedSystem
        The problem: ``residual(U)``, ``linearise``, ``norm``, ``scale``, ``params``, ``stats``.
    step : StepSeries or None
        The step that ended here (None at the start).
    """

    index: int
    point: np.ndarray
    tangent: np.ndarray
    s: float
    linearisation: Linearisation | None
    system: ExtendedSystem
    step: StepSeries | None


def fold_roots(series, a: float, noise: float, ends_lam: tuple | None = None) -> np.ndarray:
    """Where a step holds folds: the roots in ``[0, a)`` of ``d lam / d a`` of its ``series``
    across which it changes sign and where lam turns by more than ``noise`` (the branch's
    accuracy in lam): neighbouring roots whose lams differ by less are a wiggle, a root whose
    lam is within ``noise`` of both step ends is a flat stretch, not a fold.

    ``ends_lam``: the lam components of the exact unit tangents at the step's ends, for a
    "series" that is only an interpolant (Newton's, whose wiggles over a long step can be
    deeper than any noise level): a fold turns the tangent, so the sign change between them
    decides, one fold (the root of the most extreme lam, if it turns by more than ``noise``)
    or none; two folds within one such step are not seen."""
    lam_series = np.append(0.0, series[:, -1])
    slope = np.arange(1, series.shape[0] + 1) * series[:, -1]
    roots = list(sign_changes(slope, real_roots(slope, a, closed=False), a))
    lam = [float(np.polynomial.polynomial.polyval(r, lam_series)) for r in roots]
    ends = (0.0, float(np.polynomial.polynomial.polyval(a, lam_series)))
    if ends_lam is not None:
        if (ends_lam[0] > 0) == (ends_lam[1] > 0) or not roots:
            return np.zeros(0)
        k = int(np.argmax(lam) if ends_lam[0] > 0 else np.argmin(lam))
        roots, lam = roots[k:k + 1], lam[k:k + 1]
    j = 0
    while j + 1 < len(roots):
        if abs(lam[j] - lam[j + 1]) < noise:
            del roots[j:j + 2], lam[j:j + 2]
            j = max(j - 1, 0)
        else:
            j += 1
    return np.array([r for r, value in zip(roots, lam) if max(abs(value - ends[0]), abs(value - ends[1])) >= noise])


POLISH_BELOW = 1e-10
"""A fold on the ANM's series is polished on its augmented system unless the series' error
in lam there is below this fraction of lam: the step's measured end error scaled down to the
root by the truncation's ``(a / a_end)^(p+1)``, plus its start's distance (measured: 2e-12
to 3e-11 from the series alone on the Bratu problem, lam about 3.5; 7e-9 relative on
``u - lam e^u``, whose fold lies near its step's end)."""


class FoldDetector:
    """Folds in lam (module docstring); ``series``: whether the steps' series are the branch's
    own (the ANM's: a fold is polished by Newton on its augmented system, three factorisations
    per iteration, only where the series is not accurate enough, :data:`POLISH_BELOW`) or
    interpolants (Newton's: the tangent's turn between the points decides, every fold is
    polished)."""

    def __init__(self, system: ExtendedSystem, tol: float, series: bool):
        self.system, self.tol, self.series = system, tol, series
        self.previous: np.ndarray | None = None

    def __call__(self, end: StepEnd) -> list:
        previous, self.previous, step = self.previous, end.tangent, end.step
        if previous is None or step is None:
            return []
        # the branch's accuracy in lam: the ANM's series to tol a, Newton's points to tol (CHECK_LIMIT's leeway)
        noise = 10 * self.tol * (step.a if self.series else 1.0) * self.system.scale[-1]
        ends = None if self.series else (previous[-1], end.tangent[-1])
        return [self._event(end.index, step, root) for root in fold_roots(step.series, step.a, noise, ends)]

    def _event(self, index: int, step: StepSeries, root: float) -> Event:
        system = self.system
        U, t = step.at(root), step.derivative(root)
        t = t / system.norm(t)
        data: dict = {"null_vector": t[:-1] / np.linalg.norm(t[:-1]), "located": "series"}
        truncation = max(step.end_error - step.start_error, 0.0) * (root / step.a) ** (step.series.shape[0] + 1)
        if self.series and (truncation + step.start_error) * system.scale[-1] <= POLISH_BELOW * abs(U[-1]):
            return Event("fold", float(U[-1]), U[:-1], index - 1, step.s + root, t, data)
        try:
            found = locate_fold(system, U, t[:-1], step=index)
        except ContinuationFailure:
            found = None
        first = step.series[0] / system.norm(step.series[0])  # the step's parameter is <U - U_s, U_1>
        inside = found is not None and -0.01 * step.a <= system.dot(found.U - step.start, first) <= 1.01 * step.a
        if found is not None and found.converged and inside:
            U = found.U
            phi = found.null[:-1, 0]
            data.update(null_vector=phi / np.linalg.norm(phi), left_null_vector=found.psi, located="augmented")
        return Event("fold", float(U[-1]), U[:-1], index - 1, step.s + root, t, data)


BRACKET_WIDTH = 1e-3
"""A branch point is bracketed to this fraction of its step (by the sign of ``det B`` on the
step's series) before Newton on its augmented system starts: close enough that Newton, whose
basin is the distance to the next singularity, converges (a guess 5 units of lam off on a
step of 17 was measured to diverge)."""


DIP = 0.1
"""A sign change of ``det B`` is a branch point's only if ``|det B|`` falls inside the step to
this fraction of its larger value at the step's ends (where it vanishes linearly, narrowing
the bracket to :data:`BRACKET_WIDTH` takes it to about that fraction of it): a flip of its sign
by round-off, where B is too badly scaled for the sign to mean anything (R_lam = e^u above
1e20 on the 2D Bratu's upper branch, lam below 1e-20), does not dip."""


class BranchPointDetector:
    """Simple branch points (module docstring): the sign of ``det B`` at every point; a step
    across which it changes is narrowed down on its series (``det B`` at a point inside, by a
    factorisation there) to :data:`BRACKET_WIDTH` of its length, each point chosen by the
    secant of ``det B`` (smooth, with a simple zero at the branch point), or halfway when the
    secant did not halve the bracket; if ``|det B|`` dipped there (:data:`DIP`), Newton on the
    augmented system locates it.  A sign change that does not dip, or whose Newton does not
    converge inside the step, is no simple branch point that can be located: it is not
    reported (a point where R_U loses more than one rank, or round-off in a matrix too badly
    scaled for its determinant's sign to mean anything)."""

    def __init__(self, system: ExtendedSystem):
        self.system = system
        self.b = np.random.default_rng(system.n + 1).standard_normal(system.n)
        self.previous: tuple | None = None

    def __call__(self, end: StepEnd) -> list:
        lin = end.linearisation
        det = None if lin is None else lin.slogdet()
        if lin is None or det is None:
            self.previous = None
            return []
        previous, self.previous, step = self.previous, det, end.step
        if previous is None or previous[0] == det[0] or step is None:
            return []
        try:
            a, inside, smallest = self._narrowed(end.index, step, (0.0, *previous), (step.a, *det), lin)
            try:
                if smallest > max(previous[1], det[1]) + np.log(DIP):
                    return []  # det B does not vanish inside: its sign flipped with round-off
                event = self._event(end.index, step, a, inside)
                return [] if event is None else [event]
            finally:
                if inside is not lin:
                    release(inside.fact)
        except ContinuationFailure:
            return []  # a point of the bracket or of Newton where R_U cannot be evaluated or factorised

    def _narrowed(self, index: int, step: StepSeries, lo: tuple, hi: tuple, lin: Linearisation):
        """The bracket ``(a, sign, log|det B|)`` at both ends narrowed to :data:`BRACKET_WIDTH`
        of the step, or until the secant's guesses agree to that: ``(a inside, linearisation
        there, the smallest log|det B| met inside)``."""
        system, held, bisect, guess, smallest = self.system, lin, False, np.inf, np.inf
        while hi[0] - lo[0] > BRACKET_WIDTH * step.a:
            width, top = hi[0] - lo[0], max(lo[2], hi[2])
            d_lo, d_hi = lo[1] * np.exp(lo[2] - top), hi[1] * np.exp(hi[2] - top)
            secant = lo[0] - d_lo * width / (d_hi - d_lo)
            if abs(secant - guess) <= BRACKET_WIDTH * step.a:
                return secant, lin, smallest
            a, guess = (lo[0] + 0.5 * width, np.inf) if bisect else (secant, secant)
            t = step.derivative(a)
            if lin is not held:
                release(lin.fact)
            lin = system.linearise(step.at(a), system.tangent_row(t / system.norm(t)), step=index, aside=True)
            sign, logdet = lin.slogdet() or (np.nan, np.nan)  # the walk's factors tell it: so do these
            middle, smallest = (a, sign, logdet), min(smallest, logdet)
            lo, hi = (middle, hi) if middle[1] == lo[1] else (lo, middle)
            bisect = hi[0] - lo[0] > 0.5 * width  # the secant did not halve the bracket: halve it next
        return 0.5 * (lo[0] + hi[0]), lin, smallest

    def _event(self, index: int, step: StepSeries, a: float, lin: Linearisation) -> Event | None:
        """The branch point located from ``a`` on the step (None: Newton did not converge in it)."""
        system = self.system
        U, t = step.at(a), step.derivative(a)
        t = t / system.norm(t)
        phi = lin.constrained(self.b, system.tangent_row(t))  # inverse iteration: B's near-null direction
        found = locate_branch_point(system, U, t, phi / system.norm(phi), step=index)
        first = step.series[0] / system.norm(step.series[0])  # the step's parameter is <U - U_s, U_1>
        along = system.dot(found.U - step.start, first)
        if not (found.converged and -0.01 * step.a <= along <= 1.01 * step.a):  # Newton left the step
            return None
        tangents, abe = branch_tangents(system, found, t)
        return Event("branch_point", float(found.U[-1]), found.U[:-1], index - 1,
                     step.s + float(np.clip(along, 0.0, step.a)), tangents[0],
                     {"tangents": tangents, "null_vectors": found.null, "left_null_vector": found.psi, "abe": abe})


DETECTORS: dict[str, Callable[..., Callable[[StepEnd], list]]] = {
    "fold": lambda system, tol, method: FoldDetector(system, tol, series=(method == "anm")),
    "branch_point": lambda system, tol, method: BranchPointDetector(system),
}
"""The built-in detectors by event kind: ``make(system, tol, method) -> detector``, a callable
``StepEnd -> list of Event``.  A new kind of event registers its detector here."""


def detectors(kinds, system: ExtendedSystem, tol: float, method: str, on_step=None) -> list:
    """The detectors of ``kinds`` (keys of :data:`DETECTORS`), then the user's ``on_step``."""
    made = [DETECTORS[kind](system, tol, method) for kind in kinds]
    return made + ([on_step] if on_step is not None else [])
