"""The sparse tangent through the affine frontier (jaxanm.jacobian): the chain rule
``J S = J_rest(F(x)) (A S)`` with ``A S`` kept while the linear map's arguments stay the same
objects, checked against the dense ``jax.jacfwd`` of the same residual."""

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse

import jaxanm
from jaxanm import jacobian

N = 50


def _stencil_problem(old_weighted: bool = False, seed: int = 3):
    """Stencil sums feeding a pointwise nonlinearity, with a time step that scales both the
    linear and the nonlinear part (the FSW residual's shape); ``old_weighted``: the stencil sum
    is also weighted by the old state, so the linear map reads ``x_old``."""
    rng = np.random.default_rng(seed)
    index = np.stack([np.arange(N), *(rng.integers(0, N, N) for _ in range(5))], axis=1)
    params = {"idx": index, "w": rng.standard_normal(index.shape)}

    def residual(x, x_old, t, dt, p):
        g = (p["w"] * x[p["idx"]]).sum(axis=1)
        if old_weighted:
            g = g * x_old
        return (x - x_old) / dt + g**3 + jnp.exp(0.1 * g) * x

    rows = np.repeat(np.arange(N), index.shape[1])
    pattern = scipy.sparse.csc_matrix((np.ones(rows.size), (rows, index.ravel())), shape=(N, N))
    return residual, params, pattern + scipy.sparse.identity(N)


def _dense(residual, x, x_old, dt, params):
    return np.asarray(jax.jacfwd(lambda y: residual(y, x_old, 0.0, dt, params))(jnp.asarray(x)))


def test_frontier_tangent_is_the_jacobian_and_keeps_A_S_across_time_steps(monkeypatch):
    residual, params, pattern = _stencil_problem()
    rng = np.random.default_rng(0)
    calls = []
    with jaxanm.float64():
        params = jax.device_put(params)  # the same device arrays at every call, as integrate passes them
        sj = jaxanm.SparseJacobian(residual, pattern)
        for dt in (0.1, 0.1, 0.03):
            x, x_old = rng.standard_normal(N), rng.standard_normal(N)
            jac = sj(x, x_old, 0.0, dt, params).toarray()
            assert sj._chain, "the residual splits at its stencil sums: the tangent goes through the frontier"
            if not calls:
                original = sj._chain._seeded_frontier
                monkeypatch.setattr(sj._chain, "_seeded_frontier",
                                    lambda *a, original=original: calls.append(1) or original(*a))
            dense = _dense(residual, x, x_old, dt, params)
            # the same chain rule in another order of operations: round-off of the largest entry
            np.testing.assert_allclose(jac, dense, rtol=0, atol=1e-13 * np.abs(dense).max())
    assert calls == [], "new states and a new dt (a scalar factor of the rest) reuse the kept A S"


def test_new_stencil_weights_give_the_new_jacobian():
    # a moving cloud: new stencil weights between two tangents; A S is made anew for them
    residual, params, pattern = _stencil_problem()
    x = np.random.default_rng(1).standard_normal(N)
    with jaxanm.float64():
        sj = jaxanm.SparseJacobian(residual, pattern)
        for scale in (1.0, 2.0, 3.0):
            moved = jax.device_put({"idx": params["idx"], "w": scale * params["w"]})
            jac = sj(x, x, 0.0, 0.1, moved).toarray()
            dense = _dense(residual, x, x, 0.1, moved)
            np.testing.assert_allclose(jac, dense, rtol=0, atol=1e-13 * np.abs(dense).max())
    assert sj._chain


def test_a_linear_map_that_reads_the_old_state_is_remade_with_it():
    residual, params, pattern = _stencil_problem(old_weighted=True)
    rng = np.random.default_rng(2)
    with jaxanm.float64():
        params = jax.device_put(params)
        sj = jaxanm.SparseJacobian(residual, pattern)
        for _ in range(3):
            x, x_old = rng.standard_normal(N), rng.standard_normal(N)
            jac = sj(x, x_old, 0.0, 0.1, params).toarray()
            dense = _dense(residual, x, x_old, 0.1, params)
            np.testing.assert_allclose(jac, dense, rtol=0, atol=1e-13 * np.abs(dense).max())


def test_a_frontier_above_the_memory_budget_uses_the_plain_seeded_jvp(monkeypatch):
    residual, params, pattern = _stencil_problem()
    monkeypatch.setattr(jacobian, "JACOBIAN_MEMORY_BYTES", 1000)
    x = np.random.default_rng(4).standard_normal(N)
    with jaxanm.float64():
        sj = jaxanm.SparseJacobian(residual, pattern)
        jac = sj(x, x, 0.0, 0.1, params).toarray()
        dense = _dense(residual, x, x, 0.1, params)
    assert sj._chain is False
    np.testing.assert_allclose(jac, dense, rtol=0, atol=1e-13 * np.abs(dense).max())


def test_A_S_seeded_in_batches_when_a_columns_intermediates_exceed_the_budget(monkeypatch):
    # the budget holds A S (the frontier for every colour) but not every colour's gathered
    # stencil values at once: A S is made a few colours at a time, to the same matrix
    residual, params, pattern = _stencil_problem()
    monkeypatch.setattr(jacobian, "JACOBIAN_MEMORY_BYTES", 20_000)
    x = np.random.default_rng(5).standard_normal(N)
    with jaxanm.float64():
        sj = jaxanm.SparseJacobian(residual, pattern)
        jac = sj(x, x, 0.0, 0.1, params).toarray()
        dense = _dense(residual, x, x, 0.1, params)
    assert sj._chain and 1 <= sj._chain._batch < sj._seeds.shape[0]
    np.testing.assert_allclose(jac, dense, rtol=0, atol=1e-13 * np.abs(dense).max())
