"""Design a parameter so that a limit load reaches a target, by gradient (optax).

The Bratu problem u'' + lam e^u = 0 on (0, L), u(0) = u(L) = 0, has a fold (the largest load
lam for which a solution exists).  Its lam is a differentiable function of L
(:func:`jaxanm.critical_load`: relocation on the fold's augmented system, gradient by the
implicit function theorem); L-BFGS finds the length whose fold lies at ``TARGET``.  With
N fixed the discrete fold obeys lam_c(L) = lam_c(1) / L^2, so the answer is known:
L = sqrt(lam_c(1) / TARGET).

Run: ``python examples/fold_design.py``.
"""

import jax
import jax.numpy as jnp
import numpy as np
import optax

import jaxanm

N, TARGET = 63, 1.0


def bratu(u, lam, p):
    """Second-order differences on N interior points of (0, L)."""
    h = p["L"] / (N + 1)
    padded = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
    return (padded[2:] - 2 * padded[1:-1] + padded[:-2]) / h**2 + lam * jnp.exp(u)


def main() -> None:
    """Follow the branch once at L = 1, then descend on (lam_c(L) - TARGET)^2."""
    with jaxanm.float64():
        params = {"L": jnp.float64(1.0)}
        branch = jaxanm.continuation(bratu, np.zeros(N), 0.0, params, stop_at=(N // 2, 2.0))
        fold = branch.events_of("fold")[0]
        lam_c = jaxanm.critical_load(branch, fold)

        def loss(p):
            return (lam_c(p) - TARGET) ** 2

        optimiser = optax.lbfgs()

        @jax.jit
        def descend(p, state):
            value, grad = jax.value_and_grad(loss)(p)
            updates, state = optimiser.update(grad, state, p, value=value, grad=grad, value_fn=loss)
            return optax.apply_updates(p, updates), state, value

        state = optimiser.init(params)
        for iteration in range(30):
            params, state, value = descend(params, state)
            print(f"iteration {iteration}: L = {float(params['L']):.12f}, loss = {float(value):.3e}")
            if value < 1e-20:
                break
    print(f"fold at L = 1: lam = {fold.lam:.12f}; designed L = {float(params['L']):.12f}, "
          f"closed form sqrt(lam_c(1) / target) = {np.sqrt(fold.lam / TARGET):.12f}")


if __name__ == "__main__":
    main()
