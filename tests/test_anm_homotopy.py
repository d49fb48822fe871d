"""The ANM's two homotopies (``ANM(homotopy="convex" | "newton")``), against closed forms.

Scalar ``R(d) = d^2 - b`` from ``d_s = s``: the tangent there is ``K_T = 2 s``, and the path of
each homotopy is the root of a quadratic in ``d`` for every ``a``, so its Taylor coefficients
and values are known without the solver:

- Newton homotopy, fresh K* (``K* = K_T``): ``R(d) = (1 - a) R(s)``, ``d(a) = s sqrt(1 - a z)``
  with ``z = 1 - b / s^2``, whose Taylor coefficients are ``s binom(1/2, j) (-z)^j``;
- Newton homotopy, stale K* = k: ``R(d) = (1 - a) [R(s) + (K_T - k)(d - s)]``.

The series are built by the stepper's own recursion (``c_j = c_{j-1} - K*^-1 [R]_j``) from
:class:`jaxanm._problem.SeriesPath`, so these tests check the lookahead coefficients that jet
returns, the recursion and the homotopy together.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import binom
from test_anm_acceptance import CHECK_LIMIT, cubic_reaction_diffusion, newton_distance_ratio

import jaxanm
from jaxanm import evaluate_series
from jaxanm._problem import Problem, SeriesPath

B, S = 0.6, 1.0


def _residual(d, d_old, t, dt, params):
    return d**2 - B


def _series(k, p):
    """ANM coefficients c_1..c_p of the Newton homotopy from d_s = S with K* = k."""
    problem = Problem(_residual, np.ones(1), jaxanm.Stats(), "dense", None)
    with jaxanm.float64():
        d_s = np.full(1, S)
        args = (d_s, np.float64(1.0), np.float64(1.0), None)
        fact = jaxanm.factorize(np.array([[k]]), problem.stats)
        path = SeriesPath(problem, d_s, args, lookahead=True)
        coeffs = np.zeros((p, 1))
        coeffs[0] = -fact.solve(path.start_residual())
        for j in range(2, p + 1):
            coeffs[j - 1] = coeffs[j - 2] - fact.solve(path.next(coeffs[j - 2]))
    return coeffs[:, 0]


def test_newton_homotopy_with_fresh_kstar_is_the_taylor_series_of_the_newton_path():
    """K* = K_T: every coefficient is the closed form's, to round-off.

    Each c_j is a few dozen roundings of terms no larger than |c_1| (the recursion subtracts
    K*^-1 [R]_j from c_{j-1}), so 1e-13 |c_1| bounds the error with room for the order-15
    accumulation and any re-association XLA chooses.
    """
    p = 15
    coeffs = _series(2 * S, p)
    z = 1 - B / S**2
    exact = np.array([S * binom(0.5, j) * (-z) ** j for j in range(1, p + 1)])
    np.testing.assert_allclose(coeffs, exact, rtol=0, atol=1e-13 * abs(exact[0]))


def _stale_path(k, a):
    """Root of d^2 - b = (1 - a) [(s^2 - b) + (2 s - k)(d - s)] through d(0) = s (k > 0)."""
    lin = (1 - a) * (2 * S - k)
    const = B + (1 - a) * (S**2 - B - (2 * S - k) * S)
    return (lin + np.sqrt(lin * lin + 4 * const)) / 2


def test_newton_homotopy_with_stale_kstar_follows_its_exact_path_within_amax():
    """K* = 1.5 (the tangent of d = 0.75, not of d_s = 1): the series is the Taylor series of the
    closed-form path, so within a_max it is within the truncation error eq. 26 promises,
    ``tol |c_1|`` at a_max (10x: the tail beyond order p, as CHECK_LIMIT allows)."""
    k, p, tol = 1.5, 12, 1e-8
    coeffs = _series(k, p)
    amax = jaxanm.validity_range(coeffs[:, None], np.ones(1), tol)
    assert 0.2 < amax < np.inf  # (tol |c_1| / |c_12|)^(1/11) of the closed-form path: 0.83
    for a in (0.25 * min(amax, 1.0), 0.5 * min(amax, 1.0), min(amax, 1.0)):
        exact = _stale_path(k, a)
        assert abs(S + evaluate_series(coeffs[:, None], a)[0] - exact) <= 10 * tol * abs(coeffs[0])


def test_newton_homotopy_gains_an_order_of_the_increment_per_order():
    """The convex homotopy's order j takes the nonlinear terms of order j - 1, so with a fresh
    K* c_2 vanishes and the series needs about twice the orders of the Newton homotopy for the
    same decay.  Both ratios are closed forms, computed to round-off (the test above), so the
    margins below are exact, not measured: with z = 1 - b/s^2 = 0.4 the Newton path's
    |c_7 / c_1| = |binom(1/2, 7) / binom(1/2, 1)| z^6 = 1.32e-4; the convex series from K* = 2 s
    obeys c_j = -(1/2) sum_{i+k=j-1} c_i c_k (c_1 = -0.2, c_3 = -0.02, c_5 = -0.004,
    c_7 = -0.001), so |c_7 / c_1| = 5e-3, 38 times the Newton path's."""
    newton = _series(2 * S, 7)
    assert abs(newton[6] / newton[0]) < 1e-3
    problem = Problem(_residual, np.ones(1), jaxanm.Stats(), "dense", None)
    with jaxanm.float64():
        d_s = np.full(1, S)
        args = (d_s, np.float64(1.0), np.float64(1.0), None)
        fact = jaxanm.factorize(np.array([[2 * S]]), problem.stats)
        path = SeriesPath(problem, d_s, args)
        convex = np.zeros(7)
        convex[0] = -fact.solve(path.start_residual())[0]
        for j in range(2, 8):
            convex[j - 1] = convex[j - 2] - fact.solve(path.next(convex[j - 2:j - 1]))[0]
    assert convex[1] == 0.0  # c_2 = 0 identically with a fresh K* (tests/test_anm_acceptance.py)
    assert abs(convex[6] / convex[0]) > 10 * abs(newton[6] / newton[0])


@pytest.mark.parametrize("adaptive", [False, True])
def test_newton_homotopy_solves_each_step_to_the_promised_accuracy(adaptive):
    """Cubic reaction-diffusion from u = 0 (c_2 = 0 along the first step's path: the end-point
    check guards it): every accepted state is within CHECK_LIMIT of the promised Newton distance
    by an independent dense Jacobian, and the run agrees with the convex homotopy's within the
    two runs' tolerances compounded over the steps (as tests/test_anm_adaptive.py)."""
    residual, x0, params = cubic_reaction_diffusion()
    tol, p = 1e-6, 8
    kw = dict(t0=0.0, t1=0.5, dt=0.02)
    newton = jaxanm.integrate(residual, x0, params, solver=jaxanm.ANM.paper(order=p, tol=tol, adaptive=adaptive,
                                                                           homotopy="newton"), **kw)
    convex = jaxanm.integrate(residual, x0, params, solver=jaxanm.ANM.paper(order=p, tol=tol, adaptive=adaptive), **kw)
    assert newton_distance_ratio(residual, params, newton, tol) <= CHECK_LIMIT
    scale = np.abs(convex.xs).max()
    assert np.abs(newton.xs - convex.xs).max() <= 2 * CHECK_LIMIT * tol * scale * len(convex.ts)
    if adaptive:
        assert newton.stats.series_orders < convex.stats.series_orders


def test_homotopy_is_validated():
    with pytest.raises(jaxanm.InputError, match="homotopy"):
        jaxanm.ANM(homotopy="linear")
