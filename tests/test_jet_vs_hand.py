"""Jet series against hand-coded orders (the paper's quadratic recast, eq. 12-16 and 22-25).

jaxanm takes the series coefficients of the step residual from ``jax.experimental.jet``
instead of recasting the model into quadratic form by hand as the paper does.  These tests
check that the two give the same coefficients, orders 0..15, on two model problems:

1. a 1D power-law viscous flow with temperature-dependent viscosity
   ``mu = (K/3) T^A epsbar^(n-1)`` and dissipation heating (the FSW analogue);
2. a 2D reaction-diffusion with an Arrhenius source ``c exp(-E/T)`` and a conductivity
   ``k0 / (1 + b T)``.

The residuals are written once, plainly, in ``jax.numpy`` below; the references are the
order-by-order recursions of ``handcoded_series`` (plain numpy, no jax), derived with the
paper's new variables (``alpha = T^A``, ``gamma = epsbar^(n-1)``, ``phi = epsbar^2`` ...).

Error measure: for each order ``k`` and each residual field (velocity / temperature rows,
temperature / reactant rows), ``max|jet_k - hand_k| / max|hand_k|``.  Coefficients of
different orders differ by orders of magnitude, so one global scale would make the high
orders vacuous; single entries can vanish by cancellation, so an entrywise relative error
is ill-posed; the per-order, per-field max-norm is the scale the order-``k`` linear solves
and the validity range (eq. 26) see.  The tolerance is ``1e-10`` for every order.  Each
case also checks that the nonlinear part of the residual carries a sizeable share of every
order (so that the comparison measures the recursions, not the linear terms) and that a
1e-8 change of ``n`` (or ``E``) in the reference is detected (so that the test can fail).

Also covered: the plain (not factorial-scaled) convention against closed forms, float64
results when the global x64 flag is off, and eager ``ValueError`` on mismatched shapes.

Compile time: a jet at order 15 unrolls every nonlinear primitive (and every product by a
constant) into ~K^2/2 operations, and XLA's compile time grows faster than linearly in the
graph size; each model residual below is therefore written with few such products, and
each is compiled once for all of its cases (parameters are traced arguments).
"""

from __future__ import annotations

import math

import handcoded_series as hs
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxanm import taylor_coefficients

ORDER = 15
RTOL = 1e-10
NL_SHARE = 0.1  # minimum share of the nonlinear part in each order's max-norm


def per_order_errors(jet_coeffs: np.ndarray, hand: np.ndarray) -> np.ndarray:
    """``max|jet_k - hand_k| / max|hand_k|`` for each order ``k`` (arrays ``(K+1, ...)``)."""
    axes = tuple(range(1, hand.ndim))
    scale = np.max(np.abs(hand), axis=axes)
    assert np.all(scale > 0.0), "a reference order vanishes identically: the case is degenerate"
    return np.max(np.abs(jet_coeffs - hand), axis=axes) / scale


def nonlinear_share(nonlinear: np.ndarray, total: np.ndarray) -> np.ndarray:
    """Per order, the max-norm of the nonlinear part relative to that of the whole residual."""
    axes = tuple(range(1, total.ndim))
    return np.max(np.abs(nonlinear), axis=axes) / np.max(np.abs(total), axis=axes)


def jet_series(f, x0, terms, *args) -> np.ndarray:
    """``taylor_coefficients`` stacked into one numpy array of shape ``(K+1, *f0.shape)``."""
    coeffs = taylor_coefficients(f, x0, list(terms), *args)
    return np.stack([np.asarray(c) for c in coeffs])


# ---------------------------------------------------------------------------------------------
# Problem 1: 1D power-law viscous flow with mu(T, epsbar) and dissipation heating
# ---------------------------------------------------------------------------------------------

N_NODES = 12


def viscous_residual(x, u_old, T_old, prm):
    """Implicit-Euler step residual of problem 1, ``x = [u, T]`` of shape ``(2, N)``.

    Same discrete problem as :func:`handcoded_series.viscous_flow_series` (see there),
    written the way ``jaxanm.fsw.physics`` writes it: ``epsbar^(n-1)`` as
    ``(d^2 + eps0^2)^((n-1)/2)``, one ``pow`` instead of ``sqrt`` then ``pow`` (jet's
    ``sqrt`` *is* ``x ** 0.5``, the same rule), a route independent of the reference's
    sqrt-then-power.  ``d ** 2`` must stay an integer power: jet expands a float power
    through ``log``, which is NaN for the negative gradients present here.
    """
    u, T = x[0], x[1]
    h = prm["h"]
    d = (u[1:] - u[:-1]) / h
    T_f = 0.5 * (T[1:] + T[:-1])
    mu = prm["K"] / 3.0 * T_f ** prm["A"] * (d**2 + prm["eps0"] ** 2) ** (0.5 * (prm["n"] - 1.0))
    sigma = mu * d
    heat = 0.5 * h * prm["beta"] * (sigma * d)  # h/2 times q = beta mu d^2, on each face
    F = prm["k_cond"] / h * (T[1:] - T[:-1])
    capacity = h / prm["dt"] * jnp.stack([prm["rho"], prm["rho"] * prm["cp"]])
    storage = capacity[:, None] * (x - jnp.stack([u_old, T_old]))
    R_u = storage[0, 1:-1] - (sigma[1:] - sigma[:-1])
    R_T = storage[1, 1:-1] - (F[1:] - F[:-1]) - (heat[:-1] + heat[1:])
    R_u = jnp.concatenate([(u[0] - prm["u_wall"])[None], R_u, u[-1:]])
    R_T = jnp.concatenate(
        [(-F[0] - prm["q_in"])[None], R_T, (F[-1] + prm["h_conv"] * (T[-1] - prm["T_amb"]))[None]]
    )
    return jnp.stack([R_u, R_T])


def viscous_case(seed: int, at_rest_faces: bool):
    """A state and a random path for problem 1: ``(x0, terms, u_old, T_old)``.

    Velocities O(1e-2) with gradients of both signs, temperatures in [300, 600] K; the path
    coefficients decay like ``2^-k``, as those of a converging ANM step do.  With
    ``at_rest_faces`` two faces have exactly zero velocity gradient at ``a = 0``
    (epsbar = eps0 there: the regularisation keeps every order finite).
    """
    rng = np.random.default_rng(seed)
    xg = np.linspace(0.0, 1.0, N_NODES)
    u0 = 0.05 * (1.0 - xg) + 0.02 * rng.standard_normal(N_NODES)
    if at_rest_faces:
        u0[4:7] = u0[4]
    T0 = rng.uniform(300.0, 600.0, N_NODES)
    terms = [
        0.5**k * np.array([[0.01], [20.0]]) * rng.standard_normal((2, N_NODES))
        for k in range(1, ORDER + 1)
    ]
    u_old = u0 - 0.01 * rng.standard_normal(N_NODES)
    T_old = T0 - 5.0 * rng.uniform(size=N_NODES)
    return np.stack([u0, T0]), terms, u_old, T_old


@pytest.mark.parametrize(
    "seed, n, at_rest_faces",
    [(0, 0.1324, False), (1, 0.35, False), (2, 0.1324, True)],
    ids=["AA7075", "n=0.35", "faces-at-rest"],
)
def test_viscous_flow_jet_matches_quadratic_recast(seed, n, at_rest_faces):
    """Problem 1: jet coefficients of the residual = the eq. 12-16 recursion, orders 0..15."""
    prm = dict(hs.VISCOUS_PARAMS, n=n)
    x0, terms, u_old, T_old = viscous_case(seed, at_rest_faces)
    if at_rest_faces:
        assert np.sum(np.diff(x0[0]) == 0.0) == 2

    jet = jet_series(viscous_residual, x0, terms, u_old, T_old, prm)
    U = np.concatenate([x0[None, 0], np.array([t[0] for t in terms])])
    T = np.concatenate([x0[None, 1], np.array([t[1] for t in terms])])
    hand = hs.viscous_flow_series(U, T, u_old, T_old, prm)

    assert jet.shape == (ORDER + 1, 2, N_NODES)
    assert np.all(np.isfinite(jet))
    # The nonlinear terms (viscous stress, dissipation heating) matter at every order.
    assert np.all(nonlinear_share(hand["nl_u"], hand["R_u"]) > NL_SHARE)
    assert np.all(nonlinear_share(hand["nl_T"], hand["R_T"]) > NL_SHARE)

    for field, name in ((0, "R_u"), (1, "R_T")):
        err = per_order_errors(jet[:, field], hand[name])
        assert np.all(err < RTOL), f"{name}: per-order relative errors {err}"

    # The comparison resolves far below the tolerance: a 1e-8 change of n is seen.  It changes
    # the coefficients to first order, (d ln R_k / d ln n) 1e-8 = 6e-9 to 3e-8 in these cases, a
    # property of the model and 1e6 times the round-off of the comparison (err above, ~5e-15).
    wrong = hs.viscous_flow_series(U, T, u_old, T_old, dict(prm, n=n * (1.0 + 1e-8)))
    assert np.max(per_order_errors(jet[:, 0], wrong["R_u"])) > 10 * RTOL


# ---------------------------------------------------------------------------------------------
# Problem 2: 2D Arrhenius reaction-diffusion with a T-dependent conductivity
# ---------------------------------------------------------------------------------------------

GRID = (4, 5)


def _faces(S):
    """Node values on both sides of each interior face (x-faces, then y-faces)."""
    lo = jnp.concatenate([S[:-1, :].ravel(), S[:, :-1].ravel()])
    hi = jnp.concatenate([S[1:, :].ravel(), S[:, 1:].ravel()])
    return lo, hi


def _net_outflow(flux):
    """Per cell, the sum of the face fluxes leaving it (zero flux through the boundary)."""
    nx, ny = GRID
    fx = flux[: (nx - 1) * ny].reshape(nx - 1, ny)
    fy = flux[(nx - 1) * ny :].reshape(nx, ny - 1)
    return (
        jnp.pad(fx, ((0, 1), (0, 0)))
        - jnp.pad(fx, ((1, 0), (0, 0)))
        + jnp.pad(fy, ((0, 0), (0, 1)))
        - jnp.pad(fy, ((0, 0), (1, 0)))
    )


def reaction_residual(x, T_old, c_old, prm):
    """Implicit-Euler step residual of problem 2, ``x = [T, c]`` of shape ``(2, nx, ny)``.

    Same discrete problem as :func:`handcoded_series.arrhenius_series` (see there).
    """
    T, c = x[0], x[1]
    T_lo, T_hi = _faces(T)
    conductivity = prm["k0"] / (1.0 + 0.5 * prm["b"] * (T_lo + T_hi))
    conduction = _net_outflow(conductivity * (T_lo - T_hi))
    c_lo, c_hi = _faces(c)
    diffusion = _net_outflow(prm["D"] * (c_lo - c_hi))
    rate = prm["h"] ** 2 * prm["Z"] * c * jnp.exp(-prm["E"] / T)
    storage = prm["h"] ** 2 / prm["dt"] * (x - jnp.stack([T_old, c_old]))
    return storage + jnp.stack([conduction - prm["Q"] * rate, diffusion + rate])


def reaction_case(seed: int):
    """A state and a random path for problem 2: ``(x0, terms, T_old, c_old)``."""
    rng = np.random.default_rng(seed)
    T0 = rng.uniform(400.0, 600.0, GRID)
    c0 = rng.uniform(0.2, 1.0, GRID)
    terms = [
        0.5**k * np.stack([20.0 * rng.standard_normal(GRID), 0.1 * rng.standard_normal(GRID)])
        for k in range(1, ORDER + 1)
    ]
    T_old = T0 - 5.0 * rng.uniform(size=GRID)
    c_old = c0 + 0.05 * rng.uniform(size=GRID)
    return np.stack([T0, c0]), terms, T_old, c_old


@pytest.mark.parametrize("seed, E", [(3, 3000.0), (4, 6000.0)], ids=["E=3000", "E=6000"])
def test_arrhenius_jet_matches_quadratic_recast(seed, E):
    """Problem 2: jet coefficients of the residual = the hand recursion, orders 0..15."""
    # Z rescaled so that the reaction rate stays O(1) at T = 500 K.
    Z = hs.ARRHENIUS_PARAMS["Z"] * math.exp((E - 3000.0) / 500.0)
    prm = dict(hs.ARRHENIUS_PARAMS, E=E, Z=Z)
    x0, terms, T_old, c_old = reaction_case(seed)

    jet = jet_series(reaction_residual, x0, terms, T_old, c_old, prm)
    T = np.concatenate([x0[None, 0], np.array([t[0] for t in terms])])
    C = np.concatenate([x0[None, 1], np.array([t[1] for t in terms])])
    hand = hs.arrhenius_series(T, C, T_old, c_old, prm)

    assert jet.shape == (ORDER + 1, 2, *GRID)
    assert np.all(np.isfinite(jet))
    assert np.all(nonlinear_share(hand["nl_T"], hand["R_T"]) > NL_SHARE)
    assert np.all(nonlinear_share(hand["nl_c"], hand["R_c"]) > NL_SHARE)

    for field, name in ((0, "R_T"), (1, "R_c")):
        err = per_order_errors(jet[:, field], hand[name])
        assert np.all(err < RTOL), f"{name}: per-order relative errors {err}"

    wrong = hs.arrhenius_series(T, C, T_old, c_old, dict(prm, E=E * (1.0 + 1e-8)))
    assert np.max(per_order_errors(jet[:, 1], wrong["R_c"])) > 10 * RTOL


# ---------------------------------------------------------------------------------------------
# Conventions: plain coefficients, float64, shapes
# ---------------------------------------------------------------------------------------------


def test_exp_along_a_gives_inverse_factorials():
    """``exp(x0 + a)`` has plain coefficients ``e^x0 / k!`` (not ``e^x0``, the derivatives)."""
    x0 = np.array([0.0, 0.5, -1.25])
    terms = [np.ones(3)] + [np.zeros(3)] * (ORDER - 1)
    coeffs = jet_series(jnp.exp, x0, terms)
    expected = np.array([np.exp(x0) / math.factorial(k) for k in range(ORDER + 1)])
    np.testing.assert_allclose(coeffs, expected, rtol=1e-14, atol=0.0)


def test_exp_along_a_plus_a_squared():
    """Higher path terms are plain too: ``exp(a + a^2) = sum_k a^k sum_m 1/(m! (k-2m)!)``."""
    terms = [np.array(1.0), np.array(1.0)] + [np.array(0.0)] * (ORDER - 2)
    coeffs = jet_series(jnp.exp, np.array(0.0), terms)
    expected = [
        sum(1.0 / (math.factorial(m) * math.factorial(k - 2 * m)) for m in range(k // 2 + 1))
        for k in range(ORDER + 1)
    ]
    np.testing.assert_allclose(coeffs, expected, rtol=1e-14, atol=0.0)


def test_cube_along_a_line_gives_binomials():
    """``(x0 + a t)^3``: coefficients ``C(3,k) x0^(3-k) t^k``, exactly zero beyond order 3."""
    x0 = np.array([2.0, -3.0, 0.5])
    t1 = np.array([1.0, 2.0, -4.0])
    coeffs = jet_series(lambda x: x**3, x0, [t1] + [np.zeros(3)] * 5)
    expected = [math.comb(3, k) * x0 ** (3 - k) * t1**k for k in range(4)] + [np.zeros(3)] * 3
    np.testing.assert_array_equal(coeffs, np.array(expected))


def test_cube_along_a_parabola_is_exact():
    """``(x0 + a t1 + a^2 t2)^3`` with integer data: the exact polynomial, zero beyond order 6."""
    x0, t1, t2 = np.array([3.0, -2.0]), np.array([-1.0, 5.0]), np.array([2.0, 1.0])
    coeffs = jet_series(lambda x: x * x * x, x0, [t1, t2] + [np.zeros(2)] * 6)
    expected = np.zeros((9, 2))
    for i in range(2):
        poly = [int(x0[i]), int(t1[i]), int(t2[i])]
        cube = np.convolve(np.convolve(poly, poly), poly)  # exact integer arithmetic
        expected[: cube.size, i] = cube
    np.testing.assert_array_equal(coeffs, expected)


def test_float64_when_global_x64_is_off():
    """Results are float64 and float64-accurate even with x64 disabled; the flag is untouched."""
    with jax.enable_x64(False):
        before = jax.config.jax_enable_x64
        line32 = [np.ones(2, np.float32)] + [np.zeros(2, np.float32)] * 9
        coeffs = taylor_coefficients(jnp.exp, np.full(2, 0.1, np.float32), line32)
        line64 = [np.array(1.0)] + [np.array(0.0)] * 9
        accurate = taylor_coefficients(jnp.exp, np.array(0.1), line64)
        assert jax.config.jax_enable_x64 == before
    assert all(c.dtype == np.float64 for c in coeffs)
    assert all(c.dtype == np.float64 for c in accurate)
    # float32 would give ~1e-7 here.  float64: jet's exp rule divides by k once per order
    # (c_k = c_{k-1} / k on this line), so c_10 carries 10 roundings, plus exp(0.1) to a few
    # ulps in XLA and in libm and the reference's division: ~15 u = 1.7e-15 (u = 2^-53); the
    # 1e-15 used before was below that, 1e-14 as for the exp tests above (orders to 15).
    expected = [math.exp(0.1) / math.factorial(k) for k in range(11)]
    np.testing.assert_allclose([float(c) for c in accurate], expected, rtol=1e-14, atol=0.0)


@pytest.mark.parametrize(
    "x0, terms",
    [
        (np.zeros(4), [np.zeros(3)]),
        (np.zeros((2, 3)), [np.zeros((3, 2))]),
        (np.zeros(4), [np.zeros(4), np.zeros(5)]),
    ],
    ids=["length", "transposed", "ragged"],
)
def test_shape_mismatch_raises(x0, terms):
    """A path term not shaped like ``x0`` is an eager ``ValueError``."""
    with pytest.raises(ValueError, match="shape"):
        taylor_coefficients(jnp.sin, x0, terms)
