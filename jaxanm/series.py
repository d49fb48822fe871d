"""Taylor coefficients of a function along a polynomial path, by ``jax.experimental.jet``.

This is the only place where jaxanm calls ``jet``.  Everything is in *plain*
Taylor coefficients (``f(x(a)) = sum_k a^k f_k``), never in derivatives
(``k! f_k``): jet is called with ``factorial_scaled=False``.
"""

from __future__ import annotations

from typing import Callable, Sequence

import jax
import jax.numpy as jnp
from jax.experimental import jet

from ._x64 import entry_point


def path_coefficients(f: Callable, x0, terms, *args):
    """Traceable core of :func:`taylor_coefficients`.

    ``terms`` is an array of shape ``(K, *x0.shape)`` (or a sequence of K arrays).
    Returns ``(f0, fs)`` with ``fs`` of shape ``(K, *f0.shape)``.  Safe inside
    ``jax.jit``; ``args`` are constants of the expansion.
    """
    terms = list(terms)
    f0, fs = jet.jet(lambda x: f(x, *args), (x0,), (terms,), factorial_scaled=False)
    return f0, jnp.stack([jnp.broadcast_to(c, jnp.shape(f0)) for c in fs])


@entry_point
def taylor_coefficients(f: Callable, x0, terms: Sequence, *args) -> list:
    """Plain Taylor coefficients of ``f(x(a), *args)`` along ``x(a) = x0 + sum_k a^k terms[k-1]``.

    Parameters
    ----------
    f : callable
        ``f(x, *args)`` written in ``jax.numpy`` (jet-compatible: no
        ``custom_jvp`` functions, no ``scan``/``while``, no linear solves).
    x0 : array
        Point of expansion.
    terms : sequence of arrays
        ``terms[k-1]`` is the coefficient of ``a^k`` of the path, each shaped like ``x0``.
    *args
        Extra arguments of ``f``, held constant.

    Returns
    -------
    list of arrays ``[f_0, f_1, ..., f_K]`` (float64), with ``K = len(terms)`` and
    ``f(x(a)) = sum_k a^k f_k + O(a^(K+1))``; these are *not* multiplied by ``k!``.
    """
    x0 = jnp.asarray(x0, dtype=jnp.float64)
    if len(terms) == 0:
        return [jnp.asarray(f(x0, *args))]
    shapes = [jnp.shape(t) for t in terms]
    if any(shape != x0.shape for shape in shapes):
        raise ValueError(
            f"taylor_coefficients: every term must have the shape of x0 {x0.shape}, "
            f"got {shapes}; pass one array per order shaped like x0."
        )
    terms = jnp.stack([jnp.asarray(t, dtype=jnp.float64) for t in terms])
    f0, fs = jax.jit(path_coefficients, static_argnums=0)(f, x0, terms, *args)
    return [f0, *list(fs)]
