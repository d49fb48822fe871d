"""The discrete Bratu fold solved directly, the reference the path followers' folds are held to:
Newton on the extended system R(u, lam) = 0, R_u(u, lam) phi = 0, |phi| = 1 (dense numpy),
independent of jaxanm."""

import functools

import numpy as np


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
