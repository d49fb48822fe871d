"""Small step residuals used by the core tests and the examples' tests."""

from __future__ import annotations

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
