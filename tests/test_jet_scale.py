"""jaxanm._jet_scale: a product by a constant that jet propagates as linear.

Reference: jet's own bilinear and quotient rules on the same operations (which add only exact
zeros to the same products), and ``lax.mul``/``lax.div`` for values and derivatives.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental import jet

import jaxanm
from jaxanm._jet_scale import scale

RNG = np.random.default_rng(3)
X0 = RNG.uniform(0.5, 1.5, 7)
C = RNG.uniform(0.5, 2.0, 7)
TERMS = [RNG.standard_normal(7) * 0.5**k for k in range(9)]


@pytest.mark.parametrize("op", ["mul", "div"])
@pytest.mark.parametrize("c", [C, np.float64(2.7)], ids=["vector", "scalar"])
def test_jet_of_a_scaled_nonlinear_term_equals_jets_own_rules(op, c):
    ref_op = jnp.multiply if op == "mul" else jnp.divide

    def with_scale(x):
        return scale(x * x + jnp.exp(x), c, op) / (1.0 + x)

    def with_lax(x):
        return ref_op(x * x + jnp.exp(x), c) / (1.0 + x)

    with jaxanm.float64():
        got = jax.jit(lambda x, t: jet.jet(with_scale, (x,), (t,), factorial_scaled=False))(X0, TERMS)
        want = jax.jit(lambda x, t: jet.jet(with_lax, (x,), (t,), factorial_scaled=False))(X0, TERMS)
    # the same products (jet's rules add exact zeros to them); the two compiled programs may
    # contract a multiply-add into one FMA in different places: a few roundings per term
    for g, w in zip([got[0], *got[1]], [want[0], *want[1]]):
        np.testing.assert_allclose(g, w, rtol=0, atol=8 * np.finfo(float).eps * np.abs(w).max())


@pytest.mark.parametrize("op", ["mul", "div"])
def test_scale_has_the_derivatives_of_the_product(op):
    ref_op = jnp.multiply if op == "mul" else jnp.divide
    with jaxanm.float64():
        for argnums in (0, 1, (0, 1)):
            got = jax.jacfwd(lambda x, c: scale(jnp.sin(x), c, op), argnums)(X0, C)
            want = jax.jacfwd(lambda x, c: ref_op(jnp.sin(x), c), argnums)(X0, C)
            # the same formula evaluated in another order: round-off of the entries
            np.testing.assert_allclose(got, want, rtol=1e-14, atol=0)


def test_an_unknown_operation_is_named():
    with pytest.raises(ValueError, match="op must be one of"):
        scale(X0, C, "add")
