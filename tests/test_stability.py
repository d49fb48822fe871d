"""Stability along a branch: counts of unstable eigenvalues, Hopf points and stability changes
against closed forms and dense eigenvalues."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanm

N, A, D1, D2 = 31, 2.0, 0.05, 0.05
H = 1.0 / (N + 1)
Q2 = (4 / H**2) * np.sin(np.arange(1, N + 1) * np.pi * H / 2) ** 2  # the discrete Laplacian's eigenvalues


def brusselator(w, B, params):
    """u_t = D1 u_xx + A - (B + 1) u + u^2 v, v_t = D2 v_xx + B u - u^2 v on (0, 1), u = A and
    v = B / A at both ends: the homogeneous state (A, B / A) is a steady state for every B."""
    u, v = w[:N], w[N:]
    U = jnp.concatenate([jnp.full(1, A), u, jnp.full(1, A)])
    V = jnp.concatenate([jnp.full(1, B / A), v, jnp.full(1, B / A)])

    def lap(X):
        return (X[2:] - 2 * X[1:-1] + X[:-2]) / H**2

    return jnp.concatenate([D1 * lap(U) + A - (B + 1) * u + u**2 * v, D2 * lap(V) + B * u - u**2 * v])


@pytest.fixture(scope="module")
def brusselator_branch():
    w0 = np.concatenate([np.full(N, A), np.full(N, 4.0 / A)])
    return jaxanm.continuation(brusselator, w0, 4.0, None, lam_end=9.3, max_step=1.0,
                               events=("fold", "branch_point", "stability"))


def test_brusselator_hopf_point_and_frequency_match_the_closed_form(brusselator_branch):
    # Mode k of the homogeneous state has the 2 x 2 Jacobian [[B - 1 - D1 q^2, A^2],
    # [-B, -A^2 - D2 q^2]] (q^2 the discrete Laplacian's eigenvalue): its pair crosses the
    # axis where the trace vanishes, B_H = 1 + A^2 + (D1 + D2) q^2, at the frequency
    # sqrt(det): mode 1 at B_H = 5.99 (mode 2 at 8.94 shares its step with the Turing point,
    # below).  1e-8 relative: what is asked of located events; the location converges to
    # round-off of the eigenvalues.
    branch = brusselator_branch
    hopf = branch.events[0]
    assert hopf.kind == "hopf" and hopf.data["located"]
    B_H = 1 + A**2 + (D1 + D2) * Q2[0]
    det = (B_H - 1 - D1 * Q2[0]) * (-(A**2) - D2 * Q2[0]) + A**2 * B_H
    assert hopf.lam == pytest.approx(B_H, rel=1e-8)
    assert hopf.data["frequency"] == pytest.approx(np.sqrt(det), rel=1e-8)
    assert hopf.data["unstable"] == (0, 2)


def test_unstable_counts_are_those_of_the_dense_jacobian(brusselator_branch):
    # The counts come from the eigenvalues nearest zero by shift-invert through the bordered
    # factors; the reference is every eigenvalue of jax.jacfwd's dense R_u (numpy).
    branch = brusselator_branch
    jac = jax.jit(jax.jacfwd(brusselator))
    with jaxanm.float64():
        dense = [int(np.sum(np.linalg.eigvals(np.asarray(jac(u, lam, None))).real > 0))
                 for u, lam in zip(branch.u, branch.lam)]
    assert list(branch.unstable) == dense
    assert dense[0] == 0 and dense[-1] == 3


def test_turing_point_is_a_branch_point_and_two_crossings_in_a_step_are_not_located(brusselator_branch):
    # A real eigenvalue of mode k crosses zero where det vanishes,
    # B_T = (1 + D1 q^2)(A^2 + D2 q^2) / (D2 q^2), first for mode 2 here (B_T = 9.0005):
    # R_u loses rank on a branch that exists for every B, a branch point.  Mode 2's pair
    # (B_H = 8.935) crosses in the same step (max_step = 1): the count goes 2 -> 3 across
    # it (+2 then -1, the pair turning real), which the detector reports at the step's end
    # without locating it, as it says.
    branch = brusselator_branch
    B_T = np.min((1 + D1 * Q2) * (A**2 + D2 * Q2) / (D2 * Q2))
    (turing,) = branch.events_of("branch_point")
    assert turing.lam == pytest.approx(B_T, rel=1e-8)
    (both,) = branch.events_of("stability")
    assert not both.data["located"] and both.data["unstable"] == (2, 3)
    assert both.lam == branch.lam[both.step + 1]


def test_bratu_stability_changes_exactly_at_its_fold():
    # u_t = u_xx + lam e^u: the lower branch is stable, the upper one has one unstable
    # eigenvalue, and R_u's eigenvalue crosses zero where R_u is singular, at the fold.
    # 1e-10 relative: both are located to about round-off (fold: Newton on its augmented
    # system; the crossing: regula falsi to 1e-10 of its step).
    n = 15
    h = 1.0 / (n + 1)

    def bratu(u, lam, params):
        padded = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
        return (padded[2:] - 2 * padded[1:-1] + padded[:-2]) / h**2 + lam * jnp.exp(u)

    branch = jaxanm.continuation(bratu, np.zeros(n), 0.0, None, stop_at=(n // 2, 3.0), order=10,
                                 events=("fold", "stability"))
    fold, change = branch.events_of("fold")[0], branch.events_of("stability")[0]
    assert change.data["located"] and change.data["unstable"] == (0, 1)
    assert change.lam == pytest.approx(fold.lam, rel=1e-10)
    before = branch.s < fold.s
    assert set(branch.unstable[before]) == {0} and set(branch.unstable[~before]) == {1}
