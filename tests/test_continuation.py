"""Path following (:func:`jaxanm.continuation`, :func:`jaxanm.newton_continuation`) against closed forms.

Two problems with known branches and limit points:

- the 1D Bratu problem ``u'' + lam e^u = 0`` on (0, 1), ``u(0) = u(1) = 0``, by second-order
  central differences on N interior points (h = 1 / (N + 1)).  Its continuum branch is
  ``u(x) = -2 ln(cosh((x - 1/2) theta / 2) / cosh(theta / 4))`` with
  ``theta = sqrt(2 lam) cosh(theta / 4)``, whose fold is at lam_c = 3.51383071912516 (the
  maximum of ``lam = theta^2 / (2 cosh^2(theta / 4))``).  The discrete fold lam_c(N) converges to it
  at second order, the order of the difference scheme;
- the shallow two-bar (von Mises) truss, whose snap-through path is derived in
  :func:`truss_load`.

The series program is compiled once per residual, shape and number of orders kept
(:mod:`jaxanm._series`): the branches are built once per module (fixtures) and the series order
is 8, which keeps the file's compilation to a few seconds; the default order 15 changes
nothing tested here (its agreement is the benchmark's, ``benchmarks/continuation.py``).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
from model_problems import discrete_fold

import jaxanm

LAM_C = 3.51383071912516  # the continuum Bratu fold (module docstring)
ORDER, TOL = 8, 1e-8


@functools.lru_cache(maxsize=None)
def bratu(n: int):
    """The discrete Bratu residual on ``n`` interior points (one object per n, so that its
    compiled jets are found again by every test)."""
    h = 1.0 / (n + 1)

    def residual(u, lam, params):
        up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
        return (up[2:] - 2.0 * u + up[:-2]) / h**2 + lam * jnp.exp(u)

    return residual


def bratu_scale(n: int) -> np.ndarray:
    """u's entries scaled by sqrt(n): the arclength sees the RMS of u, the same on every grid."""
    return np.append(np.full(n, np.sqrt(n)), 1.0)


@functools.lru_cache(maxsize=None)
def bratu_branch(n: int, method: str = "anm", jacobian: str = "dense") -> jaxanm.Branch:
    """From rest through the fold to u(1/2) = 2 (past the fold's u(1/2) of about 1.19 in the
    continuum), ANM (order 8, tol 1e-8) or pseudo-arclength Newton (tol 1e-8, ds_max 0.5)."""
    kwargs = dict(stop_at=(n // 2, 2.0), max_steps=400, tol=TOL, scale=bratu_scale(n), jacobian=jacobian)
    if jacobian == "sparse":
        kwargs["sparsity"] = scipy.sparse.diags([1, 1, 1], [-1, 0, 1], shape=(n, n), dtype=bool)
    if method == "anm":
        return jaxanm.continuation(bratu(n), np.zeros(n), 0.0, order=ORDER, **kwargs)
    return jaxanm.newton_continuation(bratu(n), np.zeros(n), 0.0, ds_max=0.5, **kwargs)


def bratu_fold(n: int) -> float:
    """lam_c(n): the single limit point of the branch, a root of d lam / d a of a step's series."""
    folds = bratu_branch(n).limit_points()
    assert folds.lam.size == 1, f"N = {n}: expected one fold, found lam = {folds.lam}"
    return float(folds.lam[0])


def test_bratu_fold_converges_at_second_order():
    """lam_c(N) for N = 19, 39, 79 (h = 1/20, 1/40, 1/80) against the continuum lam_c.

    The central difference's error expansion is C2 h^2 + C4 h^4 + ..., so the observed order
    log2((lam_c(39) - lam_c(19)) / (lam_c(79) - lam_c(39))) is 2 + O(h^2): the h^4 term moves it
    by 1.04e-3 here (2.6e-4 from N = 39, 79, 159: a quarter, as O(h^2) says; folds computed
    directly, :func:`discrete_fold`), and the folds' own errors (below 1e-9, next test) by less
    than 1e-5.  Tolerance 0.01 on the order, and on the error ratios 4 (+-0.04): ten times the
    h^4 shift.
    """
    folds = {n: bratu_fold(n) for n in (19, 39, 79)}
    order = np.log2((folds[39] - folds[19]) / (folds[79] - folds[39]))
    errors = np.array([LAM_C - folds[n] for n in (19, 39, 79)])
    print(f"\nBratu folds lam_c(N): {folds}; observed order {order:.5f}; errors {errors}; "
          f"ratios {errors[:-1] / errors[1:]}")
    assert abs(order - 2.0) < 0.01
    assert np.all(errors > 0)  # the discrete folds lie below the continuum one (C2 < 0)
    assert np.allclose(errors[:-1] / errors[1:], 4.0, atol=0.04)


def test_bratu_fold_from_the_series_matches_the_direct_fold():
    """The fold found on the ANM's series (a root of d lam / d a) against the fold solved for
    directly: lam at a fold is insensitive to first order to where along the branch the root
    falls, and the branch is followed within tol = 1e-8 (scaled): measured 2e-12 to 3e-11,
    tolerance 1e-9."""
    for n in (19, 39, 79):
        assert abs(bratu_fold(n) - discrete_fold(n)) < 1e-9, n


def test_bratu_branch_points_satisfy_the_residual():
    """Every point (each one corrected at its step's end) satisfies the discrete equations to
    1e-8 relative to their terms (|lam e^u| <= 14 near the fold): the corrections measured
    below tol (Branch.correction, the end points' distance from the branch before it) leave
    a remainder quadratic in them, and the points lie on both sides of the fold."""
    n = 39
    branch = bratu_branch(n)
    size = np.max(np.abs(branch.lam[:, None] * np.exp(branch.u)), axis=1)
    assert branch.stopped == "stop_at" and branch.u[-1, n // 2] == 2.0
    assert np.all(branch.residual_norm <= 1e-8 * size)
    assert np.all(branch.correction <= 10 * TOL * branch.a)  # the end-point check's bound (CHECK_LIMIT)
    fold = bratu_fold(n)
    assert branch.lam.max() < fold and branch.lam[-1] < branch.lam.max()


def test_bratu_series_between_points_stays_on_the_branch():
    """Branch.evaluate on each step's series, mid-step: the series is truncated where its
    last term is tol a (eq. 26), so the residual there is at most about |R_u| tol a ~
    (4 / h^2) 1e-8 * 0.5 = 3e-5: we allow 1e-4 relative to the terms."""
    n = 39
    branch = bratu_branch(n)
    s = 0.5 * (branch.s[1:] + branch.s[:-1])
    lam, u = branch.evaluate(s)
    r = np.array([bratu(n)(jnp.asarray(ui), li, None) for ui, li in zip(u, lam)])
    size = np.max(np.abs(lam[:, None] * np.exp(u)), axis=1)
    assert np.max(np.abs(r), axis=1).max() <= 1e-4 * size.max()


def test_bratu_sparse_bordered_matrix_passes_the_fold_like_the_dense_one():
    """The sparse path (coloured Jacobian, SuperLU of the bordered CSC matrix) follows the same
    branch: same steps, same fold to 1e-10 (the two LUs differ by round-off only)."""
    dense, sparse = bratu_branch(39), bratu_branch(39, jacobian="sparse")
    assert sparse.a.size == dense.a.size
    assert abs(sparse.limit_points().lam[0] - dense.limit_points().lam[0]) < 1e-10
    assert np.max(np.abs(sparse.u - dense.u)) < 1e-8


def test_bratu_direction_and_lam_end():
    """direction=-1 goes to negative lam (the lower branch continues there, u < 0), and
    lam_end stops exactly at the value asked, with the residual of the other points."""
    n = 19
    branch = jaxanm.continuation(bratu(n), np.zeros(n), 0.0, lam_end=-1.0, direction=-1, order=ORDER, tol=TOL,
                                 scale=bratu_scale(n))
    assert branch.stopped == "lam_end" and branch.lam[-1] == -1.0
    assert np.all(np.diff(branch.lam) < 0) and np.all(branch.u[-1] < 0)
    assert branch.residual_norm[-1] < 1e-8


def test_start_is_corrected_by_newton_at_fixed_lam():
    """A starting point off the branch is corrected at fixed lam0 first (counted iterations)."""
    n = 19
    exact = bratu_branch(n)
    lam0 = float(exact.lam[2])
    u0 = exact.u[2] + 1e-3
    branch = jaxanm.continuation(bratu(n), u0, lam0, max_steps=1, order=ORDER, tol=TOL, scale=bratu_scale(n))
    assert branch.lam[0] == lam0 and branch.stats.newton_iterations >= 2
    assert np.max(np.abs(branch.u[0] - exact.u[2])) < 1e-7


L, H, EA = 1.0, 0.1, 1.0  # half-span, rise, axial stiffness of the truss
L0 = np.hypot(L, H)
SUPPORT_X = np.array([-L, L])


def truss_residual(u, lam, params):
    """Nodal equilibrium of the apex, unknowns ``u = (horizontal displacement, deflection w
    downwards)``, load ``lam = P`` downwards: the bar forces summed as vectors (exact bar
    lengths, axial force ``N = EA (l - l0) / l0``), not the closed form."""
    dx = u[0] - SUPPORT_X
    dy = (H - u[1]) * jnp.ones(2)
    length = jnp.sqrt(dx**2 + dy**2)
    n_over_l = EA * (1.0 / L0 - 1.0 / length)
    return jnp.stack([jnp.sum(n_over_l * dx), -jnp.sum(n_over_l * dy) - lam])


def truss_load(w):
    """Closed-form equilibrium path of the two-bar truss (exact bar length, linear elastic in the
    engineering strain ``(l - l0) / l0``).

    Supports at (-L, 0) and (L, 0), apex at (0, H), vertical load P down at the apex, apex
    deflection w (the horizontal displacement stays 0 by symmetry: its stiffness is about
    2 EA / l0 > 0).  Each bar has length ``l(w) = sqrt(L^2 + (H - w)^2)`` and compressive force
    ``N = EA (l0 - l) / l0``; vertical equilibrium ``P = 2 N (H - w) / l`` gives

        P(w) = 2 EA (H - w) (1 / l(w) - 1 / l0).

    dP/dw = 0 where ``l^3 = L^2 l0``: ``y* = sqrt((L^2 l0)^(2/3) - L^2)``, limit points at
    ``w = H -+ y*`` with loads ``+-P* = +-2 EA y* (1 / l* - 1 / l0)``, ``l* = (L^2 l0)^(1/3)``
    (for a shallow truss ``y* ~ H / sqrt(3)``, ``P* ~ 2 EA H^3 / (3 sqrt(3) L^3)``).
    """
    return 2 * EA * (H - w) * (1 / np.sqrt(L**2 + (H - w) ** 2) - 1 / L0)


L_STAR = (L**2 * L0) ** (1 / 3)
Y_STAR = np.sqrt(L_STAR**2 - L**2)
P_STAR = 2 * EA * Y_STAR * (1 / L_STAR - 1 / L0)
TRUSS_SCALE = [H, H, 2 * EA * H**3 / (3 * np.sqrt(3) * L**3)]  # shallow estimates, not the closed form


@functools.lru_cache(maxsize=None)
def truss_branch(method: str = "anm") -> jaxanm.Branch:
    """From the unloaded truss through both limit points to P = 2 P* on the stiffening branch
    (its first crossing: the loads before it stay below P*)."""
    kwargs = dict(lam_end=2 * P_STAR, max_steps=400, tol=TOL, scale=TRUSS_SCALE)
    if method == "anm":
        return jaxanm.continuation(truss_residual, np.zeros(2), 0.0, order=ORDER, **kwargs)
    return jaxanm.newton_continuation(truss_residual, np.zeros(2), 0.0, **kwargs)


def test_truss_snap_through_matches_the_closed_form():
    """Every point against P(w): the points are corrected to a distance below tol (scaled by
    P*'s estimate and H) from the discrete branch, which is the closed form's: 1e-7 P*."""
    branch = truss_branch()
    w = branch.u[:, 1]
    assert branch.stopped == "lam_end" and branch.lam[-1] == 2 * P_STAR
    assert w[-1] > 2 * H  # past the second crossing of P = 0 at w = 2H
    assert np.max(np.abs(branch.lam - truss_load(w))) < 1e-7 * P_STAR
    assert np.max(np.abs(branch.u[:, 0])) < 1e-12  # the symmetric path


def test_truss_without_an_end_condition_ends_well_with_both_limit_points():
    """No lam_end: past both limit points the truss stiffens (P grows with w without bound)
    and the branch ends after max_steps, saying so, its two folds events at +-P* (1e-9 P*)."""
    branch = jaxanm.continuation(truss_residual, np.zeros(2), 0.0, max_steps=120, order=ORDER, tol=TOL,
                                 scale=TRUSS_SCALE)
    assert branch.stopped == "max_steps" and "max_steps" in branch.message
    np.testing.assert_allclose([e.lam for e in branch.events_of("fold")], [P_STAR, -P_STAR], rtol=0,
                               atol=1e-9 * P_STAR)
    assert branch.lam[-1] > 2 * P_STAR and branch.events_of("branch_point") == ()


def test_truss_limit_points_match_the_closed_form_extrema():
    """The two limit points, roots of d lam / d a on the series: their loads are insensitive
    to first order to where on the branch the root falls, so they match +-P* to round-off of
    the series (1e-9 P*); their deflections H -+ y* to 1e-6 H."""
    folds = truss_branch().limit_points()
    assert folds.lam.size == 2
    np.testing.assert_allclose(folds.lam, [P_STAR, -P_STAR], rtol=0, atol=1e-9 * P_STAR)
    np.testing.assert_allclose(folds.u[:, 1], [H - Y_STAR, H + Y_STAR], rtol=0, atol=1e-6 * H)


def test_anm_and_newton_agree_on_the_branch(record_property):
    """The pseudo-arclength Newton points lie on the ANM branch: at each Newton point's monitored
    unknown (w for the truss, u(1/2) for Bratu) the ANM series gives the same point, to the
    two methods' accuracies (tol 1e-8 each, scaled) times ten (measured: 4e-10, 1e-9).  The
    factorisation counts of both are reported (printed and as test properties), not asserted."""
    for name, anm, newton, index in (("truss", truss_branch(), truss_branch("newton"), 1),
                                     ("bratu39", bratu_branch(39), bratu_branch(39, "newton"), 19)):
        scale = anm.scale
        for u, lam in zip(newton.u[1:-1], newton.lam[1:-1]):
            hits = anm.crossings(u[index], index)
            assert hits.lam.size == 1
            gap = np.append(hits.u[0] - u, hits.lam[0] - lam) / scale
            assert np.max(np.abs(gap)) < 10 * 2 * TOL, name
        counts = {m: b.stats.factorizations for m, b in (("anm", anm), ("newton", newton))}
        record_property(f"{name}_factorizations", counts)
        print(f"\n{name}: factorisations ANM {counts['anm']} (steps {anm.a.size}), Newton {counts['newton']} "
              f"(steps {newton.a.size}, iterations {newton.stats.newton_iterations})")


def test_newton_branch_limit_points_polished_on_the_augmented_system():
    """Newton's branch interpolates its points and tangents by chord-length cubics in each step,
    only 0.04-0.6 % accurate at the folds (the steps grow to 0.27, scaled, and the branch turns
    by about 70 degrees within one); a fold event is polished from there by Newton on the
    fold's augmented system: both limit loads to 1e-9 P* (round-off of lam at a stationary
    point), as the ANM's."""
    folds = truss_branch("newton").limit_points()
    np.testing.assert_allclose(folds.lam, [P_STAR, -P_STAR], rtol=0, atol=1e-9 * P_STAR)
    assert all(e.data["located"] == "augmented" for e in truss_branch("newton").events_of("fold"))


def test_a_start_outside_the_residual_s_domain_is_bad_input_not_nan():
    """A residual that is NaN at the start: an InputError naming the start and why."""
    with pytest.raises(jaxanm.InputError, match=r"u0 is not a usable starting point at lam0 = -1.*not finite"):
        jaxanm.continuation(lambda u, lam, p: u - jnp.sqrt(lam), np.zeros(1), -1.0, order=ORDER)


def test_factorize_hook_is_used_for_every_factorisation():
    """The ``factorize`` hook gets every bordered matrix (the door for reusing factors): one
    per point of the branch (three steps, four points), each point's factors serving the
    series of the step from it and the events found at it."""
    seen = []

    def hook(matrix, stats):
        seen.append(matrix.shape)
        return jaxanm.factorize(matrix, stats)

    n = 19
    branch = jaxanm.continuation(bratu(n), np.zeros(n), 0.0, max_steps=3, order=ORDER, tol=TOL,
                                 scale=bratu_scale(n), factorize=hook)
    assert seen == [(n + 1, n + 1)] * 4 == [(n + 1, n + 1)] * branch.stats.factorizations


BAD_INPUTS = [
    (dict(u0=np.zeros((2, 2))), "u0"),
    (dict(u0=np.array([0.0, np.nan])), "u0"),
    (dict(u0=np.zeros(3)), "shape"),  # the residual returns (2,)
    (dict(lam0=np.inf), "lam0"),
    (dict(order=1), "order"),
    (dict(order=2.5), "order"),
    (dict(tol=0.0), "tol"),
    (dict(tol=1.5), "tol"),
    (dict(tol=np.nan), "tol"),
    (dict(max_steps=0), "max_steps"),
    (dict(direction=0), "direction"),
    (dict(lam_end=0.0), "lam_end"),
    (dict(stop_at=(5, 1.0)), "stop_at"),
    (dict(scale=np.ones(5)), "scale"),
    (dict(scale=-1.0), "scale"),
    (dict(jacobian="fancy"), "jacobian"),
    (dict(sparsity=scipy.sparse.eye(3)), "sparsity"),
    (dict(max_step=0.0), "max_step"),
    (dict(residual=lambda u, lam, p: u[:1]), "shape"),
]


@pytest.mark.parametrize("change, word", BAD_INPUTS, ids=[f"{w}-{i}" for i, (_, w) in enumerate(BAD_INPUTS)])
def test_bad_input_raises_input_error_naming_it(change, word):
    """Each bad argument: InputError naming it, before any computation."""
    args = dict(residual=truss_residual, u0=np.zeros(2), lam0=0.0)
    args.update(change)
    with pytest.raises(jaxanm.InputError, match=word):
        jaxanm.continuation(args.pop("residual"), args.pop("u0"), args.pop("lam0"), **args)


@pytest.mark.parametrize("change, word", [(dict(ds=0.0), "ds"), (dict(ds=2.0, ds_max=1.0), "ds_max"),
                                          (dict(max_iter=0), "max_iter")])
def test_bad_newton_input_raises_input_error(change, word):
    with pytest.raises(jaxanm.InputError, match=word):
        jaxanm.newton_continuation(truss_residual, np.zeros(2), 0.0, **change)
