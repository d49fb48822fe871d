"""The buckling of a discrete elastica, against its eigenvalues and the elliptic-integral
solution of the continuous one.

A cantilever of length L = 1 and bending stiffness EI = 1 as a chain of N rigid links of
length 1/N (a Hencky chain): link i at angle theta_i to the axis, rotational springs of
stiffness EI / (L / N) at the clamp (theta_0 = 0) and between links, an axial compressive load
P at the free end.  Equilibrium (the energy's gradient, times N):

    R_i = N^2 (2 theta_i - theta_(i-1) - theta_(i+1)) - lam sin theta_i = 0,    lam = P L^2 / EI,

with theta_(N+1) = theta_N (no spring beyond the last link).  theta = 0 is a solution for every
lam; R_theta = N^2 T - lam I there, T tridiagonal (2 on the diagonal but its last entry 1, -1
beside it), so the critical loads are N^2 times T's eigenvalues (computed here by scipy), each
a simple branch point.  Past the first, the chain bends: the continuous elastica with tip
rotation alpha has ``sqrt(lam) = K(m)``, ``m = sin^2(alpha / 2)`` (K the complete elliptic
integral of the first kind), its tip at ``x = 2 E(m) / K(m) - 1``, ``y = 2 sqrt(m) / K(m)``.
The chain approaches it at first order in 1/N, as its critical load does,
``4 N^2 sin^2(pi / (2 (2N + 1))) = (pi^2 / 4) (1 - 1/N + O(N^-2))``: its springs make it a
rod of length (N + 1/2) / N.
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
import scipy.special

import jaxanm


@functools.lru_cache(maxsize=None)
def elastica(n: int):
    """The chain's residual for ``n`` links (one object per n: compiled once)."""

    def residual(theta, lam, params):
        padded = jnp.concatenate([jnp.zeros(1), theta, theta[-1:]])
        return n**2 * (2.0 * theta - padded[:-2] - padded[2:]) - lam * jnp.sin(theta)

    return residual


def critical_loads(n: int) -> np.ndarray:
    """The four lowest critical loads, N^2 times the eigenvalues of T (scipy, tridiagonal)."""
    diagonal = np.full(n, 2.0)
    diagonal[-1] = 1.0
    return n**2 * scipy.linalg.eigh_tridiagonal(diagonal, -np.ones(n - 1), eigvals_only=True)[:4]


@functools.lru_cache(maxsize=None)
def straight(n: int) -> jaxanm.Branch:
    """The straight chain from lam = 0 to midway between the third and fourth critical loads,
    in steps of at most 5 (its series is exact; the critical loads are 19 or more apart)."""
    loads = critical_loads(n)
    return jaxanm.continuation(elastica(n), np.zeros(n), 0.0, {}, lam_end=0.5 * (loads[2] + loads[3]),
                               max_step=5.0, max_steps=100, order=8)  # order 8: fewer jets to compile than 15


def bent(n: int, alpha: float) -> jaxanm.Branch:
    """The post-buckling branch from the first branch point to tip rotation ``alpha``."""
    return straight(n).switch(straight(n).events_of("branch_point")[0], stop_at=(n - 1, alpha))


def independent_bent(n: int, alpha: float) -> float:
    """lam on the chain's first post-buckling branch at tip rotation ``alpha``, solved
    independently: Newton (dense numpy, Jacobian by hand) on R = 0, theta_N = alpha, from the
    first buckling mode's shape scaled to that tip rotation and the continuum's lam."""
    T = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    T[-1, -1] = 1.0
    mode = scipy.linalg.eigh(T)[1][:, 0]
    z = np.append(alpha * mode / mode[-1], scipy.special.ellipk(np.sin(alpha / 2) ** 2) ** 2)
    for _ in range(50):
        theta, lam = z[:-1], z[-1]
        equations = np.append(n**2 * T @ theta - lam * np.sin(theta), theta[-1] - alpha)
        jacobian = np.vstack([np.column_stack([n**2 * T - lam * np.diag(np.cos(theta)), -np.sin(theta)]),
                              np.eye(1, n + 1, n - 1)])
        step = np.linalg.solve(jacobian, -equations)
        z = z + step
        if np.max(np.abs(step)) < 1e-13 * np.max(np.abs(z)):
            return float(z[-1])
    raise AssertionError("the independent solve of the bent chain did not converge")


def test_critical_loads_are_the_tridiagonal_eigenvalues():
    """The straight chain's branch points, N = 20: the three lowest critical loads to 1e-8
    relative (measured 1e-14), each a pitchfork whose second tangent is the buckling mode."""
    n = 20
    branch = straight(n)
    points = branch.events_of("branch_point")
    np.testing.assert_allclose([e.lam for e in points], critical_loads(n)[:3], rtol=1e-8)
    T = 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    T[-1, -1] = 1.0
    modes = scipy.linalg.eigh(T)[1]
    for j, event in enumerate(points):
        t2 = event.data["tangents"][1]
        assert abs(t2[-1]) < 1e-8
        assert abs(abs(t2[:-1] @ modes[:, j]) / np.linalg.norm(t2[:-1]) - 1.0) < 1e-10


def test_post_buckling_branch_matches_an_independent_solve():
    """Switched onto the first branch point and followed to a tip rotation of 1 rad (N = 20):
    lam there is the independent solve's to 1e-8 relative, and the chain bends one way
    (every link's angle of one sign, rising from the clamp)."""
    n, alpha = 20, 1.0
    branch = bent(n, alpha)
    print(f"\n{branch.a.size} steps, {branch.stats.factorizations} factorisations, lam = {branch.lam[-1]:.12g}")
    assert branch.stopped == "stop_at" and branch.u[-1, -1] == alpha
    assert abs(branch.lam[-1] - independent_bent(n, alpha)) < 1e-8 * branch.lam[-1]
    assert np.all(np.diff(np.concatenate([[0.0], branch.u[-1]])) > 0)


@pytest.mark.slow
def test_chain_approaches_the_continuous_elastica_at_first_order():
    """lam and the tip's position at tip rotations 1 and 2 rad for N = 10, 20, 40, 80 against
    the elliptic-integral solution: each error halves with N doubled (observed orders within
    0.1 of 1 from N = 20, 40, 80; the O(N^-2) term shifts them by about 1/N)."""
    for alpha in (1.0, 2.0):
        m = np.sin(alpha / 2) ** 2
        k, e = scipy.special.ellipk(m), scipy.special.ellipe(m)
        exact = np.array([k**2, 2 * e / k - 1, 2 * np.sqrt(m) / k])
        errors = []
        for n in (10, 20, 40, 80):
            theta, lam = bent(n, alpha).u[-1], bent(n, alpha).lam[-1]
            errors.append(np.array([lam, np.mean(np.cos(theta)), np.mean(np.sin(theta))]) - exact)
        orders = np.log2(np.abs(np.array(errors[:-1]) / np.array(errors[1:])))
        print(f"alpha = {alpha}: errors {np.array(errors)}, observed orders {orders}")
        assert np.all(np.abs(orders[1:] - 1.0) < 0.1)
