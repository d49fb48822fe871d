"""Small residuals used by the core tests and the examples' tests: time steps, branches, and
the discrete Bratu fold solved directly (the reference the path followers' folds are held to)."""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np


def heat_1d(n: int = 40):
    """Nonlinear 1D reaction-diffusion: u_t = (D(u) u_x)_x + s(x, t) - r u^3, D = 1 + c u^2.

    Homogeneous Dirichlet ends, flux-form finite differences; the source varies smoothly in
    time, so the solution evolves smoothly (the regime where K* can be reused).
    Returns ``(residual, x0, params)``.
    """
    h = 1.0 / (n + 1)
    xg = np.linspace(h, 1.0 - h, n)

    def residual(u, u_old, t, dt, p):
        up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
        d = 1.0 + p["c"] * up**2
        flux = 0.5 * (d[1:] + d[:-1]) * (up[1:] - up[:-1]) / h
        source = 5.0 * jnp.sin(jnp.pi * xg) * (1.0 + 0.5 * jnp.sin(4.0 * t))
        return (u - u_old) / dt - (flux[1:] - flux[:-1]) / h - source + p["r"] * u**3

    return residual, np.zeros(n), {"c": np.float64(1.0), "r": np.float64(1.0)}


def impulsive_cubic(n: int = 5):
    """Stiff, impulsively forced cubic relaxation: eps u_t = F - u^3 - u, per component.

    With dt >> eps the first step jumps from u = 0 to u ~ F^(1/3): a series from the initial
    tangent cannot reach a = 1 and in-step continuation is needed.
    """
    forcing = np.linspace(50.0, 200.0, n)

    def residual(u, u_old, t, dt, p):
        return p["eps"] * (u - u_old) / dt - (forcing - u**3 - u)

    return residual, np.zeros(n), {"eps": np.float64(1e-6)}


def bratu_1d(n: int = 30, lam: float = 2.0):
    """Transient Bratu problem: u_t = u_xx + lam (1 + sin(4 t) / 2) e^u on (0, 1), u = 0 at the ends.

    From rest.  The steady 1D Bratu problem has its fold at lam ~ 3.51; with lam (1 + sin/2) up
    to 3 it stays below, but large steps (dt ~ 0.5) bring the step's homotopy path near that
    singularity, which all unknowns share through the one critical mode: series whose radius is
    limited by it, the regime of Padé approximants.  Returns ``(residual, x0, params)``.
    """
    h = 1.0 / (n + 1)

    def residual(u, u_old, t, dt, p):
        up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
        lap = (up[2:] - 2 * u + up[:-2]) / h**2
        return (u - u_old) / dt - lap - p["lam"] * (1.0 + 0.5 * jnp.sin(4.0 * t)) * jnp.exp(u)

    return residual, np.zeros(n), {"lam": np.float64(lam)}


@functools.lru_cache(maxsize=None)
def bratu_2d(m: int):
    """``Delta u + lam e^u`` by the 5-point Laplacian on m x m interior points of the unit square,
    as ``residual(u, lam, params)`` (one object per m, so that what one test compiled for it the
    next finds again)."""
    h = 1.0 / (m + 1)

    def residual(u, lam, params):
        grid = jnp.pad(u.reshape(m, m), 1)
        lap = (grid[2:, 1:-1] + grid[:-2, 1:-1] + grid[1:-1, 2:] + grid[1:-1, :-2] - 4.0 * grid[1:-1, 1:-1]) / h**2
        return (lap + lam * jnp.exp(grid[1:-1, 1:-1])).ravel()

    return residual


@functools.lru_cache(maxsize=None)
def discrete_fold(n: int) -> float:
    """The discrete Bratu fold lam_c(N), solved directly: Newton on R(u, lam) = 0,
    R_u(u, lam) phi = 0, phi . phi = 1 (dense numpy; the unscaled form, whose fold is the
    scaled form's), from the continuum fold's neighbourhood, until its step is below 1e-12 of
    the state (quadratic convergence: the step after it is at round-off)."""
    h = 1.0 / (n + 1)
    lap = (np.diag(np.full(n, -2.0)) + np.diag(np.ones(n - 1), 1) + np.diag(np.ones(n - 1), -1)) / h**2
    x = np.linspace(h, 1.0 - h, n)
    u, phi, lam = 1.2 * np.sin(np.pi * x), np.sin(np.pi * x) / np.sqrt(n / 2), 3.5
    for _ in range(40):
        e = np.exp(u)
        jac = lap + np.diag(lam * e)
        rows = np.block([[jac, np.zeros((n, n)), e[:, None]],
                         [np.diag(lam * e * phi), jac, (e * phi)[:, None]],
                         [np.zeros((1, n)), 2.0 * phi[None, :], np.zeros((1, 1))]])
        step = np.linalg.solve(rows, -np.concatenate([lap @ u + lam * e, jac @ phi, [phi @ phi - 1.0]]))
        u, phi, lam = u + step[:n], phi + step[n:2 * n], lam + step[-1]
        if np.max(np.abs(step)) < 1e-12 * np.max(np.abs(u)):
            return float(lam)
    raise AssertionError(f"the direct fold solve did not converge for N = {n}")
