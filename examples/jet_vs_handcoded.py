"""Jet series against the paper's hand-coded quadratic recast, order by order.

The paper (eq. 12-16) gets the Taylor series of its FSW residual by introducing new variables
(``alpha = T^A``, ``gamma = epsbar^(n-1)``, ``phi = epsbar^2`` ...) that turn every
nonlinearity into a quadratic relation, then equating powers of the path parameter ``a``.
jaxanm writes the residual once in ``jax.numpy`` and asks ``jax.experimental.jet`` for the
same coefficients (:func:`jaxanm.taylor_coefficients`).  This script compares the two on a
1D power-law viscous flow with temperature-dependent viscosity ``mu = (K/3) T^A epsbar^(n-1)``
and dissipation heating (one implicit Euler step, finite volumes on 12 nodes), along a random
path whose coefficients decay like ``2^-k`` (as those of a converging ANM step do), and prints,
for every order ``k``, ``max|jet_k - hand_k| / max|hand_k|`` per residual field.

The hand-coded reference is ``tests/handcoded_series.py`` (plain numpy, no jax).  This is the
script version of ``notebooks/02_jet_vs_handcoded.ipynb``.

    python examples/jet_vs_handcoded.py [--order 10] [--n 0.1324] [--seed 0] [--at-rest]
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import jax.numpy as jnp
import numpy as np

import jaxanm

_TESTS = pathlib.Path(__file__).resolve().parents[1] / "tests"
if str(_TESTS) not in sys.path:
    sys.path.insert(0, str(_TESTS))
import handcoded_series as hs  # noqa: E402  (the paper's recursions, plain numpy)

N_NODES = 12
PARAMS = hs.VISCOUS_PARAMS
"""Problem parameters (nondimensional apart from T in kelvin; AA7075's A and n)."""


def viscous_residual(x, u_old, T_old, prm):
    """Implicit-Euler step residual, ``x = [u, T]`` of shape ``(2, N)``, written once in jnp.

    ``epsbar^(n-1)`` is written ``(d^2 + eps0^2)^((n-1)/2)``: regularised, so that it stays
    finite where the velocity gradient ``d`` vanishes, and ``d**2`` is an *integer* power
    (a float power such as ``d**2.0`` goes through ``log`` in jet: NaN for negative ``d``).
    """
    u, T = x[0], x[1]
    h = prm["h"]
    d = (u[1:] - u[:-1]) / h  # velocity gradient on the faces
    T_f = 0.5 * (T[1:] + T[:-1])
    mu = prm["K"] / 3.0 * T_f ** prm["A"] * (d**2 + prm["eps0"] ** 2) ** (0.5 * (prm["n"] - 1.0))
    sigma = mu * d
    heat = 0.5 * h * prm["beta"] * (sigma * d)  # dissipation beta mu d^2, half to each node
    F = prm["k_cond"] / h * (T[1:] - T[:-1])  # conductive flux
    capacity = h / prm["dt"] * jnp.stack([prm["rho"], prm["rho"] * prm["cp"]])
    storage = capacity[:, None] * (x - jnp.stack([u_old, T_old]))
    R_u = storage[0, 1:-1] - (sigma[1:] - sigma[:-1])
    R_T = storage[1, 1:-1] - (F[1:] - F[:-1]) - (heat[:-1] + heat[1:])
    R_u = jnp.concatenate([(u[0] - prm["u_wall"])[None], R_u, u[-1:]])  # tool wall, fixed wall
    R_T = jnp.concatenate(
        [(-F[0] - prm["q_in"])[None], R_T, (F[-1] + prm["h_conv"] * (T[-1] - prm["T_amb"]))[None]]
    )
    return jnp.stack([R_u, R_T])


def make_case(order: int = 10, seed: int = 0, at_rest: bool = False):
    """A state and a random path: ``(x0 (2, N), terms [order x (2, N)], u_old, T_old)``.

    Velocities O(1e-2) with gradients of both signs, temperatures in [300, 600] K.  With
    ``at_rest`` two faces have exactly zero velocity gradient at ``a = 0`` (there
    ``epsbar = eps0``: only the regularisation keeps the series finite).
    """
    rng = np.random.default_rng(seed)
    xg = np.linspace(0.0, 1.0, N_NODES)
    u0 = 0.05 * (1.0 - xg) + 0.02 * rng.standard_normal(N_NODES)
    if at_rest:
        u0[4:7] = u0[4]
    T0 = rng.uniform(300.0, 600.0, N_NODES)
    terms = [0.5**k * np.array([[0.01], [20.0]]) * rng.standard_normal((2, N_NODES)) for k in range(1, order + 1)]
    u_old = u0 - 0.01 * rng.standard_normal(N_NODES)
    T_old = T0 - 5.0 * rng.uniform(size=N_NODES)
    return np.stack([u0, T0]), terms, u_old, T_old


def per_order_errors(jet_k: np.ndarray, hand_k: np.ndarray) -> np.ndarray:
    """``max|jet_k - hand_k| / max|hand_k|`` for each order ``k`` (arrays ``(K+1, N)``)."""
    return np.max(np.abs(jet_k - hand_k), axis=1) / np.max(np.abs(hand_k), axis=1)


def compare(order: int = 10, n: float = 0.1324, seed: int = 0, at_rest: bool = False) -> dict:
    """Coefficients of the residual by jet and by the quadratic recast, and their differences.

    Returns a dict with ``jet`` (K+1, 2, N), ``hand`` (the dict of
    :func:`handcoded_series.viscous_flow_series`: ``R_u``, ``R_T`` (K+1, N) and the recast
    variables), ``err_u``, ``err_T`` (K+1,) per-order relative differences, and ``params``.
    """
    prm = dict(PARAMS, n=n)
    x0, terms, u_old, T_old = make_case(order, seed, at_rest)
    jet = np.stack([np.asarray(c) for c in jaxanm.taylor_coefficients(viscous_residual, x0, terms, u_old, T_old, prm)])
    U = np.concatenate([x0[None, 0], np.array([t[0] for t in terms])])
    T = np.concatenate([x0[None, 1], np.array([t[1] for t in terms])])
    hand = hs.viscous_flow_series(U, T, u_old, T_old, prm)
    return dict(
        jet=jet, hand=hand, params=prm,
        err_u=per_order_errors(jet[:, 0], hand["R_u"]), err_T=per_order_errors(jet[:, 1], hand["R_T"]),
    )


def print_table(result: dict) -> None:
    """Per order: coefficient sizes and the relative jet-vs-hand differences of both fields."""
    hand = result["hand"]
    print(f"{'order':>5s} {'max|R_u,k|':>12s} {'max|R_T,k|':>12s} {'rel. diff u':>12s} {'rel. diff T':>12s}")
    for k in range(hand["R_u"].shape[0]):
        print(
            f"{k:5d} {np.abs(hand['R_u'][k]).max():12.3e} {np.abs(hand['R_T'][k]).max():12.3e} "
            f"{result['err_u'][k]:12.2e} {result['err_T'][k]:12.2e}"
        )
    worst = max(result["err_u"].max(), result["err_T"].max())
    print(f"largest per-order relative difference: {worst:.2e}")


def main(argv=None) -> None:
    """Command-line entry: compare and print the per-order table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--order", type=int, default=10, help="highest series order (compile time grows fast)")
    parser.add_argument("--n", type=float, default=0.1324, help="strain-rate sensitivity (AA7075: 0.1324)")
    parser.add_argument("--seed", type=int, default=0, help="random state and path")
    parser.add_argument("--at-rest", action="store_true", help="two faces with zero velocity gradient")
    args = parser.parse_args(argv)
    print_table(compare(args.order, args.n, args.seed, args.at_rest))


if __name__ == "__main__":
    main()
