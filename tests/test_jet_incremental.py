"""Incremental Taylor arithmetic (jaxanm._taylor), one order per call through _series.AffinePath.

References nobody tuned: the binomial, exponential and logarithmic series of elementary
functions along ``x(a) = 1 + a`` (closed forms), and ``taylor_coefficients`` (a jet of the
whole function, which tests/test_jet_vs_hand.py checks against hand-coded recursions) for the
operations that fall back to jet and for predicates, gathers and constants mixed in.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import binom

import jaxanm
from jaxanm._series import AffineFunctions, AffinePath, taylor_coefficients
from jaxanm._taylor import TaylorProgram

ORDERS = 9


def elementary(x, two):
    """One output per recurrence of jaxanm._taylor (x > 0; ``two`` is a constant 2.0)."""
    return jnp.concatenate([1.0 / x, jnp.sqrt(x), x**0.3, jnp.log(x), jnp.exp(x), jnp.expm1(x),
                            jnp.log1p(x), two**x, jax.lax.rsqrt(x), x * x, jnp.square(x), x**2,
                            jnp.abs(-x), x / (two * x)])


def closed_forms(k: int) -> np.ndarray:
    """Coefficient k >= 1 of each output of :func:`elementary` along ``x(a) = 1 + a``."""
    ln2 = math.log(2.0)
    quadratic = 2.0 if k == 1 else 1.0 if k == 2 else 0.0
    return np.array([(-1.0) ** k, binom(0.5, k), binom(0.3, k), (-1.0) ** (k + 1) / k,
                     math.e / math.factorial(k), math.e / math.factorial(k),
                     (-1.0) ** (k + 1) / (k * 2.0**k),  # log(2 + a) = log 2 + log(1 + a / 2)
                     2.0 * ln2**k / math.factorial(k), binom(-0.5, k), quadratic, quadratic, quadratic,
                     1.0 if k == 1 else 0.0, 0.0])


def test_recurrences_give_the_series_of_elementary_functions():
    x0, two = np.ones(1), np.float64(2.0)
    terms = [np.ones(1)] + [np.zeros(1)] * (ORDERS - 1)
    with jaxanm.float64():
        path = AffinePath(AffineFunctions(elementary, x0, two), x0, (two,), max_terms=ORDERS)
        got = np.array([path.next(c) for c in terms])
    want = np.array([closed_forms(k) for k in range(1, ORDERS + 1)])
    # each coefficient from its recurrence in a few roundings per order: 1e-13 of the largest
    # coefficient of the function (the recurrences of sqrt and powers divide by k and by x_0 = 1)
    scale = np.abs(want).max(axis=0) + 1.0
    error = np.abs(got - want) / scale
    assert error.max() <= 1e-13, f"largest error {error.max():.3g} in output {np.argmax(error.max(axis=0))}"


def test_every_recurrence_is_used_and_nothing_falls_back_to_jet():
    with jaxanm.float64():
        fns = AffineFunctions(elementary, np.ones(1), np.float64(2.0))
    hows = {plan.how for plan in fns.program.plans}
    assert "jet" not in hows
    assert {"mul", "div", "exp", "expm1", "log", "log1p", "pow", "exp_base", "integer_pow", "square", "sqrt",
            "rsqrt", "abs", "linear"} <= hows


IDX = np.array([2, 0, 1, 1, 3], dtype=np.int32)


def mixed(x, w):
    """Operations by jet (tanh, sin, x^3, max, a product of two expanded matrices), a
    predicate of x, a gather of a nonlinear value, constants concatenated and padded in."""
    y = jnp.tanh(x) * w + jnp.sin(x) ** 3
    big = jnp.where(x > 0.9, jnp.maximum(x * x, y), jnp.exp(-x))
    m = jnp.outer(x, y) @ jnp.outer(y, x)  # dot_general of two expanded operands
    gathered = (x * y)[IDX]
    return jnp.concatenate([big, jnp.sum(m, axis=1), gathered, jnp.pad(x**3, (1, 2), constant_values=4.0), w])


@pytest.mark.parametrize("lookahead", [False, True])
def test_operations_by_jet_and_values_read_as_they_are_match_the_jet_of_the_whole_function(lookahead):
    rng = np.random.default_rng(11)
    x0 = np.array([0.5, 1.2, 0.8, 1.5])
    w = rng.uniform(0.5, 2.0, 4)
    p = 7
    terms = [rng.standard_normal(4) * 0.5**k for k in range(1, p)]
    with jaxanm.float64():
        fns = AffineFunctions(mixed, x0, w)
        assert "jet" in {plan.how for plan in fns.program.plans}
        path = AffinePath(fns, x0, (w,), lookahead=lookahead, max_terms=p - 1)
        got = [path.next(c) for c in terms]
        if lookahead:  # f_{k+1} along the provisional c_{k+1} = c_k
            want = [taylor_coefficients(mixed, x0, terms[:k] + terms[k - 1:k], w)[k + 1] for k in (1, p - 1)]
            got = [got[0], got[-1]]
        else:
            want = taylor_coefficients(mixed, x0, terms, w)[1:]
    for g, r in zip(got, want):
        # the same Taylor coefficients by other recurrences: round-off of the largest term
        np.testing.assert_allclose(g, r, rtol=0, atol=1e-13 * np.abs(r).max())


def test_the_program_keeps_only_what_its_rules_read():
    # the intermediates of sums and products by constants are read neither as histories nor
    # as values: the state holds the operands of the nonlinear recurrences and the predicate
    def f(x):
        s = 2.0 * x + 1.0  # linear: no history
        return jnp.where(x > 0, s * s, jnp.exp(s))

    with jaxanm.float64(), jax.disable_jit():  # jnp.where's inner jit inlined, as the affine split does
        program = TaylorProgram(jax.make_jaxpr(f)(np.ones(3)), 1)
    history = {v for _, members in program.history_groups for v in members}
    values = {v for _, members in program.value_groups for v in members}
    assert len(history) == 2  # s (the product's operands and exp's argument) and exp(s)
    assert len(values) == 1 and all(v.aval.dtype == bool for v in values)  # the predicate
