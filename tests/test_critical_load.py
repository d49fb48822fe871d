"""Gradients of critical loads: jax.grad of a fold's lam by the implicit function theorem at
the fold, checked against a closed form and central differences, and used to design a
parameter with optax."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import jaxanm
from jaxanm.critical import critical_load

N = 15


def bratu_on(u, lam, p):
    """u'' + lam e^u = 0 on (0, L), u(0) = u(L) = 0, N interior points (h = L / (N + 1))."""
    h = p["L"] / (N + 1)
    padded = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
    return (padded[2:] - 2 * padded[1:-1] + padded[:-2]) / h**2 + lam * jnp.exp(u)


@pytest.fixture(scope="module")
def bratu_fold():
    with jaxanm.float64():
        branch = jaxanm.continuation(bratu_on, np.zeros(N), 0.0, {"L": jnp.float64(1.0)}, stop_at=(N // 2, 2.0),
                                     order=10)
    (fold,) = [e for e in branch.events if e.kind == "fold"]
    return branch, fold


def test_fold_load_and_its_gradient_follow_the_length_scaling(bratu_fold):
    # With N fixed, the discrete problem on (0, L) is the one on (0, 1) with lam L^2 for lam:
    # lam_c(L) = lam_c(1) / L^2 exactly, d lam_c / dL = -2 lam_c(1) / L^3.  Both are
    # independent of how the fold is found; 1e-10 relative leaves room for the located
    # folds' round-off (Newton stops within sqrt(eps) of the point, its error the square).
    branch, fold = bratu_fold
    lam_c = critical_load(branch, fold)
    with jaxanm.float64():
        for L in (0.6, 1.0, 1.7):
            p = {"L": jnp.float64(L)}
            assert float(lam_c(p)) == pytest.approx(fold.lam / L**2, rel=1e-10)
            assert float(jax.grad(lam_c)(p)["L"]) == pytest.approx(-2 * fold.lam / L**3, rel=1e-10)
        jitted = jax.jit(jax.grad(lam_c))({"L": jnp.float64(1.3)})["L"]
    assert float(jitted) == pytest.approx(-2 * fold.lam / 1.3**3, rel=1e-10)


def test_fold_gradient_matches_central_differences(bratu_fold):
    # Central differences of the relocated fold with step d: truncation ~ d^2 lam''' / 6
    # ~ 1e-8 relative at d = 1e-4, round-off ~ 1e-15 / d ~ 1e-11: the 1e-6 holds
    # with margin.  A second parameter (a source term s, R + s) checks a gradient without
    # a closed form.
    def forced(u, lam, p):
        return bratu_on(u, lam, p) + p["s"]

    with jaxanm.float64():
        params = {"L": jnp.float64(1.0), "s": jnp.float64(0.5)}
        branch = jaxanm.continuation(forced, np.zeros(N), 0.0, params, stop_at=(N // 2, 2.0), order=10)
        lam_c = critical_load(branch, next(e for e in branch.events if e.kind == "fold"))
        grad = jax.grad(lam_c)(params)
        d = 1e-4
        for key in params:
            up, down = dict(params), dict(params)
            up[key], down[key] = params[key] + d, params[key] - d
            central = (float(lam_c(up)) - float(lam_c(down))) / (2 * d)
            assert float(grad[key]) == pytest.approx(central, rel=1e-6)


def test_optax_designs_the_length_for_a_target_fold_load(bratu_fold):
    # The length whose fold is at lam = 1 is sqrt(lam_c(1)) (the scaling above); gradient
    # descent on (lam_c(L) - 1)^2 from L = 1 reaches it.  1e-6 relative: the loss's own
    # stopping level (loss < 1e-14 means |lam_c - 1| < 1e-7).
    branch, fold = bratu_fold
    lam_c = critical_load(branch, fold)
    with jaxanm.float64():
        params = {"L": jnp.float64(1.0)}
        def loss(p):
            return (lam_c(p) - 1.0) ** 2

        optimiser = optax.lbfgs()

        @jax.jit
        def descend(p, state):
            value, grad = jax.value_and_grad(loss)(p)
            updates, state = optimiser.update(grad, state, p, value=value, grad=grad, value_fn=loss)
            return optax.apply_updates(p, updates), state, value

        state = optimiser.init(params)
        for _ in range(30):
            params, state, value = descend(params, state)
            if value < 1e-14:
                break
    assert float(params["L"]) == pytest.approx(np.sqrt(fold.lam), rel=1e-6)


def test_only_folds_of_the_branch_are_accepted(bratu_fold):
    branch, fold = bratu_fold
    with pytest.raises(jaxanm.InputError, match="branch point"):
        critical_load(branch, jaxanm.Event("branch_point", fold.lam, fold.u, 0, 0.0, fold.tangent))
    other = jaxanm.Event("fold", fold.lam, fold.u, fold.step, fold.s, fold.tangent, fold.data)
    with pytest.raises(jaxanm.InputError, match="one of branch.events"):
        critical_load(branch, other)
