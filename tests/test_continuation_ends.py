"""A branch that cannot go on returns what it found (:attr:`jaxanm.Branch.stopped`,
:attr:`jaxanm.Branch.message`), and the default step control goes as far as the problem's
conditioning allows.

The family: the 1D Bratu problem ``u'' + lam e^u = 0`` on (0, 1), ``u(0) = u(1) = 0``, central
differences on N interior points, its residual written with the 1/h^2 factor ("unscaled") and
without it (multiplied through by h^2, "scaled"), followed from u = 0 at lam = 0 with no end
condition and ``max_steps=200``.  Past the fold the upper branch climbs without bound as lam
falls towards 0 (u(1/2) ~ 2 ln(1 / lam) ...): the state grows, lam shrinks, and the branch
must end with a reason, its fold reported, never an exception.  The fold is checked against
the discrete fold solved directly (Newton on the extended system R = 0, R_u phi = 0,
|phi| = 1, dense, numpy: :func:`discrete_fold`).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
from model_problems import bratu_2d, discrete_fold

import jaxanm


@functools.lru_cache(maxsize=None)
def bratu(n: int):
    """The discrete Bratu residual on ``n`` interior points, its rows multiplied by
    ``params["rows"]``: 1 keeps the 1/h^2 factor (rows of size 4 |u| / h^2), h^2 writes it
    without (rows of size 4 |u|); its unknowns are ``v = c u``, ``c = params["c"]``.  One
    object per n, the factors traced parameters, so every variant shares one compilation."""
    h = 1.0 / (n + 1)

    def residual(v, lam, params):
        u = v / params["c"]
        up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
        return params["rows"] * ((up[2:] - 2.0 * u + up[:-2]) / h**2 + lam * jnp.exp(u))

    return residual


def rows(n: int, form: str, c: float = 1.0) -> dict:
    """The params of :func:`bratu` for the residual written with (``"unscaled"``) or without
    (``"scaled"``) the 1/h^2 factor, unknowns ``c u``."""
    return {"rows": 1.0 if form == "unscaled" else 1.0 / (n + 1) ** 2, "c": c}


def check_ends_well(branch: jaxanm.Branch, n: int):
    """Past the fold, ended with a reason and a one-line message, the fold an event at the
    discrete fold's lam to 1e-8 relative."""
    assert branch.stopped in jaxanm.Branch.STOP_REASONS, branch.stopped
    assert branch.message and "\n" not in branch.message
    assert np.all(np.isfinite(branch.u)) and np.all(np.isfinite(branch.lam))
    folds = [e for e in branch.events if e.kind == "fold"]
    assert len(folds) == 1, [(e.kind, e.lam) for e in branch.events]
    assert branch.lam[-1] < folds[0].lam and branch.u[-1, n // 2] > folds[0].u[n // 2]  # past the fold
    # the series locates the fold to round-off of lam along it (lam is stationary there):
    # 1e-8 relative is the accuracy asked of a located event
    assert abs(folds[0].lam - discrete_fold(n)) <= 1e-8 * discrete_fold(n), (folds[0].lam, discrete_fold(n))


@pytest.mark.parametrize("form", ["unscaled", "scaled"])
@pytest.mark.parametrize("n", [15, 63])
def test_bratu_from_rest_without_an_end_passes_the_fold_and_ends_well(n, form):
    """The recipe a new user tries first: ``continuation(residual, zeros(N), 0.0, params,
    max_steps=200)``, no end condition, default order and tol (it raised at step 11 on the
    unscaled N = 63: its end points' distance from the branch, left by one chord correction
    after long steps, was taken for a round-off floor)."""
    branch = jaxanm.continuation(bratu(n), np.zeros(n), 0.0, rows(n, form), max_steps=200)
    print(f"\nN = {n} {form}: {branch.a.size} steps, stopped {branch.stopped!r}: {branch.message}")
    check_ends_well(branch, n)


@pytest.mark.slow
@pytest.mark.parametrize("form", ["unscaled", "scaled"])
@pytest.mark.parametrize("n", [255, 1023])
def test_bratu_on_fine_grids_passes_the_fold_and_ends_well(n, form):
    """As above on fine grids, where the unscaled rows reach 4 |u| / h^2 ~ 1e8."""
    branch = jaxanm.continuation(bratu(n), np.zeros(n), 0.0, rows(n, form), max_steps=200)
    print(f"\nN = {n} {form}: {branch.a.size} steps, stopped {branch.stopped!r}: {branch.message}")
    check_ends_well(branch, n)


@functools.lru_cache(maxsize=None)
def upper_branch(n: int) -> jaxanm.Branch:
    """N = n, unscaled, 40 steps from rest (past the fold, u(1/2) ~ 60): points on the upper
    branch where its state is large."""
    return jaxanm.continuation(bratu(n), np.zeros(n), 0.0, rows(n, "unscaled"), max_steps=40, events=())


def test_round_off_bound_bounds_what_newton_stalls_at():
    """At points of the upper branch (u(1/2) from 2 to 60), Newton iterated to its stall
    measures the round-off floor: its corrections, once they stop halving, are below the
    bound made from eps times the sizes of R's terms through the bordered solve
    (``ExtendedSystem.round_off``, what the walk classifies stalls with).  Measured ratios
    0.002 to 0.1 (the stencil's differences of nearby values are exact); asserted <= 1."""
    from jaxanm.bordered import ExtendedSystem
    from jaxanm.stats import Stats

    n = 63
    branch = upper_branch(n)
    with jaxanm.float64():
        system = ExtendedSystem(bratu(n), np.append(branch.u[0], 0.0), rows(n, "unscaled"), np.ones(n + 1),
                                "dense", None, Stats())
        for i in (5, 15, 25, 40):
            U, row = np.append(branch.u[i], branch.lam[i]), system.tangent_row(branch.tangent[i])
            sizes = []
            for _ in range(6):
                lin = system.linearise(U, row, step=0)
                dU = lin.constrained(-lin.residual, row)
                sizes.append(system.norm(dU))
                U = U + dU
            stall, bound = max(sizes[3:]), system.round_off(lin, row)
            print(f"u(1/2) = {branch.u[i, n // 2]:.3g}: Newton stalls at {stall:.2g}, bound {bound:.2g}")
            assert 0 < stall <= bound


def test_a_tol_below_round_off_ends_the_branch_with_round_off_past_the_fold():
    """tol = 1e-15 asks the points to lie within 1e-15 a of the branch: near the fold the steps
    keep it, on the upper branch Newton's corrections stall higher (round-off, 1e-14 and
    more): the branch ends there, says so, and keeps its fold, located to 1e-12 of the
    direct solve (the fold's lam is round-off-limited by the direct solve as well)."""
    n = 63
    branch = jaxanm.continuation(bratu(n), np.zeros(n), 0.0, rows(n, "unscaled"), max_steps=200, tol=1e-15)
    print(f"\n{branch.a.size} steps: {branch.message}")
    assert branch.stopped == "round_off" and "round-off" in branch.message and "larger tol" in branch.message
    (fold,) = branch.events_of("fold")
    assert abs(fold.lam - discrete_fold(n)) < 1e-12 * discrete_fold(n)
    assert branch.lam[-1] < fold.lam and branch.u[-1, n // 2] > fold.u[n // 2]


@pytest.mark.parametrize("c", [2.0**-40, 2.0**40])
def test_tiny_and_huge_states_follow_the_same_branch_when_scaled(c):
    """The unknowns multiplied by c = 2^-40 or 2^40 (exact in binary) with ``scale=c``: the
    scaled problem is the same, so the walk must be the same, step for step (no absolute
    threshold in the step control, the round-off judgement or the fold detection)."""
    n = 15
    reference = jaxanm.continuation(bratu(n), np.zeros(n), 0.0, rows(n, "unscaled"), max_steps=40)
    branch = jaxanm.continuation(bratu(n), np.zeros(n), 0.0, rows(n, "unscaled", c), max_steps=40, scale=c)
    assert branch.a.size == reference.a.size and branch.stopped == reference.stopped
    np.testing.assert_allclose(branch.u / c, reference.u, rtol=1e-12, atol=1e-12)
    assert [e.lam for e in branch.events] == pytest.approx([e.lam for e in reference.events], rel=1e-12)


M2 = 8  # the 2D grid: M2 x M2 interior points
H2 = 1.0 / (M2 + 1)


def laplacian_2d() -> np.ndarray:
    """The 5-point Laplacian of ``bratu_2d(M2)``, dense."""
    line = np.diag(np.full(M2, -2.0)) + np.diag(np.ones(M2 - 1), 1) + np.diag(np.ones(M2 - 1), -1)
    return (np.kron(line, np.eye(M2)) + np.kron(np.eye(M2), line)) / H2**2


def test_bratu_2d_from_rest_passes_its_fold_and_ends_well():
    """The 2D Bratu problem on an 8 x 8 grid with its sparsity pattern (SuperLU, whose
    determinant's sign is read off its factors), from rest, no end condition, 60 steps: it
    passes the fold (the discrete fold solved directly, dense, to 1e-8 relative) and ends
    with a reason.  The one branch point it reports, on the upper branch, is one: R_U (n x
    (n+1)) there has a singular value below 1e-10 of its largest (numpy's SVD): rank n - 1, a
    two-dimensional null space (round-off of a point located to ~1e-14 leaves ~1e-14)."""
    n = M2 * M2
    line = scipy.sparse.diags([1, 1, 1], [-1, 0, 1], shape=(M2, M2), dtype=bool)
    pattern = (scipy.sparse.kron(line, scipy.sparse.eye(M2)) + scipy.sparse.kron(scipy.sparse.eye(M2), line)) != 0
    branch = jaxanm.continuation(bratu_2d(M2), np.zeros(n), 0.0, sparsity=pattern, max_steps=60)
    print(f"\n{branch.a.size} steps, {branch.stats.factorizations} factorisations: {branch.message}; {branch.events}")
    assert branch.stopped == "max_steps" and np.all(np.isfinite(branch.u))
    (fold,) = branch.events_of("fold")
    assert len(branch.events_of("branch_point")) == 1
    lap = laplacian_2d()
    u, phi, lam = 1.2 * np.ones(n), np.ones(n) / np.sqrt(n), 6.8  # Newton on R = 0, R_u phi = 0, |phi| = 1
    for _ in range(40):
        e = np.exp(u)
        jac = lap + np.diag(lam * e)
        rows = np.block([[jac, np.zeros((n, n)), e[:, None]], [np.diag(lam * e * phi), jac, (e * phi)[:, None]],
                         [np.zeros((1, n)), 2.0 * phi[None, :], np.zeros((1, 1))]])
        step = np.linalg.solve(rows, -np.concatenate([lap @ u + lam * e, jac @ phi, [phi @ phi - 1.0]]))
        u, phi, lam = u + step[:n], phi + step[n:2 * n], lam + step[-1]
    assert abs(fold.lam - lam) < 1e-8 * lam and branch.lam[-1] < fold.lam
    for event in branch.events_of("branch_point"):
        R_U = np.column_stack([lap + np.diag(event.lam * np.exp(event.u)), np.exp(event.u)])
        singular = np.linalg.svd(R_U, compute_uv=False)
        assert singular[-1] < 1e-10 * singular[0], singular[-3:] / singular[0]


def test_a_residual_that_leaves_its_domain_ends_the_branch_there():
    """``u - sqrt(lam)`` from (1, 1) towards smaller lam: the branch steepens as lam -> 0 (the
    series' steps shrink with the distance to sqrt's singularity) and the first point with
    lam < 0 has a NaN residual: the branch ends with "non_finite", its points kept, all with
    lam >= 0 and within tol = 1e-8 of the curve lam = u^2 (their distance from it,
    |lam - u^2| / sqrt(1 + 4 u^2), in the unit scales)."""
    branch = jaxanm.continuation(lambda u, lam, p: u - jnp.sqrt(lam), np.ones(1), 1.0, direction=-1, max_steps=100,
                                 order=8)
    assert branch.stopped == "non_finite" and "not finite" in branch.message
    assert np.all(branch.lam >= 0) and branch.lam[-1] < 1e-6
    u = branch.u[:, 0]
    assert np.all(np.abs(branch.lam - u**2) / np.sqrt(1 + 4 * u**2) <= 1e-8)
