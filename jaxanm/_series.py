"""Taylor coefficients of a function along a polynomial path, by ``jax.experimental.jet``.

This is the only place where jaxanm calls ``jet``.  Everything is in *plain*
Taylor coefficients (``f(x(a)) = sum_k a^k f_k``), never in derivatives
(``k! f_k``): jet is called with ``factorial_scaled=False``.
"""

from __future__ import annotations

import functools
from typing import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
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
    stacked = jnp.stack([jnp.asarray(t, dtype=jnp.float64) for t in terms])
    f0, fs = jax.jit(path_coefficients, static_argnums=0)(f, x0, stacked, *args)
    return [f0, *list(fs)]


# Jets of up to this many terms are compiled for their exact length; longer ones are padded with
# zero terms to the next size of a geometric ladder, so that a series of order p compiles
# O(log p) jets beyond it instead of p (docstring of AffineFunctions).
EXACT_TERMS = 8
LADDER_GROWTH = 1.5


def jet_length(terms: int, max_terms: int | None = None) -> int:
    """Number of terms the compiled jet for ``terms`` known terms has: ``terms`` itself up to
    :data:`EXACT_TERMS`, else the next rung of the ladder 8, 12, 18, 27, ... (capped at
    ``max_terms``, the longest jet the series will need, so the top rung wastes nothing)."""
    if terms <= EXACT_TERMS:
        return terms
    length = EXACT_TERMS
    while length < terms:
        length = int(np.ceil(length * LADDER_GROWTH))
    return max(terms, min(length, max_terms)) if max_terms is not None else length


class AffinePath:
    """Taylor coefficients of ``f(x(a), *args)`` along ``x(a) = x0 + sum_k a^k c_k``, one order at
    a time, with the affine part of ``f`` applied outside ``jet`` (:mod:`jaxanm._affine`).

    The frontier values (stencil sums and the like, affine in x) have coefficients ``A c_k``:
    one linear map (a ``jax.jvp`` of the affine part) per new ``c_k``, computed once and kept
    on the device, stacked per frontier value.  Only the non-affine rest is expanded by
    ``jet``, from the kept frontier coefficients, truncated at the k terms known: O(k^2) work
    at order k, so a series of order p costs O(p^2) jet terms.  (Padding every order to
    p - 1 terms with zeros would cost O(p^3) per series; the two are measured in
    benchmarks/results/series_cost.md.)  Beyond :data:`EXACT_TERMS` terms the jet is padded to
    the next rung of a geometric ladder (:func:`jet_length`): a few compiled jets instead of
    one per order, for at most ``LADDER_GROWTH^2`` times the work of an exact one.
    :meth:`next` appends ``c_k`` and returns ``f_k``.
    ``f0``: the frontier values at ``x0`` when already known (from
    :attr:`AffineFunctions.residual_and_frontier`).  ``lookahead=True``: :meth:`next` returns
    ``f_{k+1}`` along the path with the provisional ``c_{k+1} = c_k`` instead of ``f_k`` (one
    more term of the same jet; the ANM's Newton homotopy, :class:`jaxanm.ANM`).
    ``max_terms``: the most path coefficients :meth:`next` will be given (p - 1 for an ANM
    series of order p), so that the top rung of the ladder is no longer than needed; None: no
    cap.
    """

    def __init__(self, functions: "AffineFunctions", x0, args: tuple, f0=None, lookahead: bool = False,
                 max_terms: int | None = None):
        self._fn, self._x0, self._args = functions, x0, args
        self._lookahead = bool(lookahead)
        self._max_length = None if max_terms is None else max_terms + self._lookahead
        self._f0 = functions.frontier(x0, *args) if f0 is None else f0
        self._stack = None  # frontier coefficients, one (length, *shape) array per frontier value
        self._known = 0

    def next(self, c) -> np.ndarray:
        """Append the path coefficient ``c_k`` and return the coefficient ``f_k`` (or, with
        ``lookahead``, ``f_{k+1}`` for ``c_{k+1} = c_k``) as a host array."""
        length = jet_length(self._known + 1 + self._lookahead, self._max_length)
        if self._stack is None or self._stack[0].shape[0] < length:
            # room for the whole series when its length is known, else for twice this jet
            capacity = max(length, self._max_length or 2 * length)
            self._stack = self._fn.grown(self._f0, self._stack, capacity)
        fk, self._stack = self._fn.truncated[self._lookahead](
            length, self._x0, c, self._f0, self._stack, np.int32(self._known), *self._args)
        self._known += 1
        return np.asarray(fk)


class AffineFunctions:
    """The compiled pieces of :class:`AffinePath` for one function and one argument layout
    (``x0`` and ``args`` are examples: shapes and pytree structure matter, not values).

    ``truncated[lookahead]`` is compiled once per jet length (:func:`jet_length`, a static
    argument): the known frontier coefficients come stacked in arrays allocated once per
    series, the new one is written at a traced position, the jet reads the first ``length``
    of them, and the coefficient wanted is read at a traced index, so every order that falls
    on one rung of the ladder reuses one compilation.  A coefficient of order m
    depends on the terms up to m only, so the zero (or stale) terms above it change nothing.
    """

    def __init__(self, fun: Callable, x0, *args):
        from ._affine import split_affine

        self.split = split = split_affine(fun, x0, *args)

        def rest_coefficients(length, f0, stack, *args):
            """``[rest]_1..[rest]_length`` (stacked) from the frontier's ``f0`` and its stacked
            coefficients (one ``(capacity, *shape)`` array per frontier value)."""
            _, fs = jet.jet(lambda *F: split.rest(list(F), *args), tuple(f0),
                            tuple([s[m] for m in range(length)] for s in stack), factorial_scaled=False)
            return jnp.stack([jnp.broadcast_to(f, split.out_shape) for f in fs])

        def new_term(x0, c, args):
            return jax.jvp(lambda y: split.linear(y, *args), (x0,), (c,))[1]

        def truncated(lookahead, length, x0, c, f0, stack, known, *args):
            new = new_term(x0, c, args)
            stack = [s.at[known].set(n) for s, n in zip(stack, new)]
            terms = [s.at[known + 1].set(n) for s, n in zip(stack, new)] if lookahead else stack
            return rest_coefficients(length, f0, terms, *args)[known + lookahead], stack

        def grown(f0, stack, length):
            zeros = [jnp.zeros((length,) + jnp.shape(f), jnp.result_type(f)) for f in f0]
            if stack is None:
                return zeros
            return [z.at[:s.shape[0]].set(s) for z, s in zip(zeros, stack)]

        def residual_and_frontier(x, *args):
            frontier = split.linear(x, *args)
            return jnp.broadcast_to(split.rest(frontier, *args), split.out_shape), frontier

        self.frontier = jax.jit(split.linear)
        # f(x0) and the frontier at x0 in one call: a series start needs both
        self.residual_and_frontier = jax.jit(residual_and_frontier)
        # indexed by ``lookahead`` (AffinePath)
        self.truncated = {flag: jax.jit(functools.partial(truncated, flag), static_argnums=0)
                          for flag in (False, True)}
        self.grown = jax.jit(grown, static_argnums=2)
