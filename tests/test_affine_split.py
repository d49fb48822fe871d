"""The affine split of a residual (jaxanm._affine) and the series built on it (_series.AffinePath).

References: the function itself (the split must reproduce it exactly, up to the order of the
same floating-point operations) and ``taylor_coefficients``, a jet of the whole function,
which tests/test_jet_vs_hand.py checks against hand-coded recursions.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import jaxanm
from jaxanm._affine import split_affine
from jaxanm._series import START_ORDERS, AffineFunctions, AffinePath, taylor_coefficients

N, M = 30, 5
RNG = np.random.default_rng(7)
INDEX = RNG.integers(0, N, (N, M)).astype(np.int32)
W = RNG.standard_normal((N, M))


def stencil_residual(x, x_old, t, dt, p):
    """Gathers times constant weights (affine) feeding pointwise nonlinear terms, like the FSW rows."""
    g = x[p["index"]]
    lap = jnp.sum(p["w"] * g, axis=1)
    grad = jnp.sum(p["w"] ** 2 * g, axis=1) / 3.0
    mu = (grad * grad + 0.1) ** (-0.4)
    return jnp.where(p["w"][:, 0] > 0, (x - x_old) / dt - mu * lap + x**3 / (1 + x * x), x - jnp.sin(t))


ARGS = (np.full(N, 0.2), np.float64(0.3), np.float64(0.1), {"index": INDEX, "w": W})


def test_split_reproduces_the_function():
    x = RNG.uniform(0.5, 1.5, N)
    with jaxanm.float64():
        split = split_affine(stencil_residual, x, *ARGS)
        full = np.asarray(stencil_residual(x, *ARGS))
        parts = np.asarray(split.rest(split.linear(x, *ARGS), *ARGS))
    # the same operations on the same values, regrouped: equal to round-off of the largest term
    np.testing.assert_allclose(parts, full, rtol=0, atol=1e-14 * np.abs(full).max())
    assert split.n_affine_eqns > 0 and split.n_rest_eqns > 0


def test_an_affine_function_has_no_rest():
    with jaxanm.float64():
        split = split_affine(lambda x, w: jnp.sum(w * x[INDEX], axis=1) - 2.0 * x + 1.0, np.ones(N), W)
    assert split.n_rest_eqns == 0 and split.n_frontier == 1


def test_affine_path_coefficients_equal_the_jet_of_the_whole_residual():
    x = RNG.uniform(0.5, 1.5, N)
    terms = [RNG.standard_normal(N) * 0.3 for _ in range(6)]
    with jaxanm.float64():
        reference = taylor_coefficients(stencil_residual, x, terms, *ARGS)
        path = AffinePath(AffineFunctions(stencil_residual, x, *ARGS), x, ARGS)
        for k in range(1, 7):
            got = path.next(terms[k - 1])
            # the same Taylor arithmetic, with the affine maps applied to c_k before rather than
            # inside the products: a few roundings of the largest term of the coefficient
            scale = np.abs(reference[k]).max()
            np.testing.assert_allclose(got, reference[k], rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("lookahead", [False, True])
def test_long_paths_grow_and_keep_the_coefficients_of_the_whole_residual(lookahead):
    # no max_terms: the kept orders start at START_ORDERS and double when used up (a new
    # compilation at the same arguments); every coefficient, across the growth, must be the
    # whole-residual jet's (with the provisional c_{k+1} = c_k for the lookahead)
    x = RNG.uniform(0.5, 1.5, N)
    p = START_ORDERS + 2
    terms = [RNG.standard_normal(N) * 0.5**k for k in range(1, p)]
    with jaxanm.float64():
        path = AffinePath(AffineFunctions(stencil_residual, x, *ARGS), x, ARGS, lookahead=lookahead)
        got = [path.next(c) for c in terms]
        if lookahead:  # f_{k+1} with the provisional c_{k+1} = c_k: one reference jet per k
            checked = {k: taylor_coefficients(stencil_residual, x, terms[:k] + terms[k - 1:k], *ARGS)[k + 1]
                       for k in (START_ORDERS - 2, p - 1)}  # before the growth (at k = 7) and after
        else:
            reference = taylor_coefficients(stencil_residual, x, terms, *ARGS)
            checked = {k: reference[k] for k in range(1, p)}
    for k, want in checked.items():
        # as above: the same arithmetic regrouped, a few roundings of the coefficient's largest
        # term
        np.testing.assert_allclose(got[k - 1], want, rtol=0, atol=1e-12 * np.abs(want).max())
