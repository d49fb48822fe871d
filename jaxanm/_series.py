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

from ._compile_ahead import compile_ahead, wait
from ._taylor import TaylorProgram, mirrored
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


class AffinePath:
    """Taylor coefficients of ``f(x(a), *args)`` along ``x(a) = x0 + sum_k a^k c_k``, one order at
    a time, with the affine part of ``f`` applied outside the Taylor arithmetic
    (:mod:`jaxanm._affine`).

    The frontier values (stencil sums and the like, affine in x) have coefficients ``A c_k``:
    one linear map (a ``jax.jvp`` of the affine part) per new ``c_k``.  The non-affine rest is
    expanded by incremental Taylor arithmetic (:class:`jaxanm._taylor.TaylorProgram`): the
    coefficients of its intermediates stay on the device, and order k computes only
    coefficient k of each, O(k) work per product instead of a jet's O(k^2), by one program
    compiled for every order.  :meth:`next` appends ``c_k`` and returns ``f_k``.
    ``f0``: the series' start at ``x0`` when already made (the second value of
    :meth:`AffineFunctions.start`).  ``lookahead=True``: :meth:`next` returns ``f_{k+1}`` along
    the path with the provisional ``c_{k+1} = c_k`` instead of ``f_k`` (one more order, not
    kept; the ANM's Newton homotopy, :class:`jaxanm.ANM`).  ``max_terms``: the most path
    coefficients :meth:`next` will be given (p - 1 for an ANM series of order p), so that the
    compiled program has room for them from the start; None: the room doubles when needed.
    """

    def __init__(self, functions: "AffineFunctions", x0, args: tuple, f0=None, lookahead: bool = False,
                 max_terms: int | None = None):
        self._fn, self._lookahead = functions, bool(lookahead)
        self._x0, self._args = x0, args
        size = orders_kept(max_terms, self._lookahead)
        functions.prepare(x0, args, size, self._lookahead)
        first, self._values = functions.start(self._x0, *self._args)[1] if f0 is None else f0
        self._orders = [first] + [functions.zeros] * (size - 1)
        self._known = 0

    def next(self, c) -> np.ndarray:
        """Append the path coefficient ``c_k`` and return the coefficient ``f_k`` (or, with
        ``lookahead``, ``f_{k+1}`` for ``c_{k+1} = c_k``) as a host array."""
        k = self._known + 1
        if k + self._lookahead >= len(self._orders):  # no room: twice as much (a new compilation)
            self._orders += [self._fn.zeros] * len(self._orders)
        fk, self._orders[k] = self._fn.order(self._lookahead, len(self._orders))(
            np.int32(k), self._x0, c, self._orders, mirrored(self._orders, self._fn.zeros, k), self._values,
            *self._args)
        self._known = k
        return np.asarray(fk)


START_ORDERS = 8
"""Orders kept room for when a path does not say how many terms it will take (the room
doubles when they are used up)."""


def orders_kept(max_terms: int | None, lookahead: bool) -> int:
    """The orders a path of at most ``max_terms`` path coefficients keeps room for: 0 ..
    max_terms, one more with ``lookahead`` (:data:`START_ORDERS` when not known)."""
    return START_ORDERS if max_terms is None else max_terms + 1 + int(lookahead)


class AffineFunctions:
    """The compiled pieces of :class:`AffinePath` for one function and one argument layout
    (``x0`` and ``args`` are examples: shapes and pytree structure matter, not values).

    :meth:`start` (``(x0, *args) -> (f(x0), (orders[0], values))``) is compiled once, and
    :meth:`order` (``(k, x0, c_k, orders, mirror, values, *args) -> (f_k, orders[k])``, the
    arguments of :meth:`jaxanm._taylor.TaylorProgram.order`) once per number of orders kept,
    whatever the order k: it is an argument.  :meth:`prepare` compiles both in the background
    as soon as a path's layout is known (:mod:`jaxanm._compile_ahead`).  The split is the one
    the sparse tangent makes (:func:`jaxanm._affine.split_affine` with the scalar factors in the
    rest, cached): the residual is traced once for both.
    """

    def __init__(self, fun: Callable, x0, *args):
        from ._affine import split_affine

        self.split = split = split_affine(fun, x0, *args, scalar_factors_affine=False)
        flat, tree = jax.tree_util.tree_flatten(args)
        frontier = jax.eval_shape(split.linear, x0, *args)
        rest = jax.make_jaxpr(lambda values, *leaves: split.rest(values, *jax.tree_util.tree_unflatten(tree, leaves)))
        self.program = program = TaylorProgram(rest(frontier, *flat), split.n_frontier)
        # the orders not known yet: one device buffer per group, never written (no compilation)
        self.zeros = jax.device_put(program.zeros())

        def start(x0, *args):
            outs, first, values = program.start(split.linear(x0, *args), jax.tree_util.tree_leaves(args))
            return jnp.broadcast_to(outs[0], split.out_shape), (first, values)

        self._start = jax.jit(start)
        self._order = {lookahead: jax.jit(functools.partial(self._coefficient, lookahead))
                       for lookahead in (False, True)}
        self._compiling: dict = {}  # "start" or (orders kept, lookahead) -> its compilation ahead

    def prepare(self, x0, args: tuple, size: int, lookahead: bool) -> None:
        """Start compiling, in the background, the start program for ``(x0, *args)`` and the
        order program for ``size`` orders kept (once each)."""
        if "start" not in self._compiling:
            self._compiling["start"] = compile_ahead(self._start, x0, *args)
        if (size, lookahead) not in self._compiling:
            first = [jax.ShapeDtypeStruct((len(m), *shape), dtype) for (shape, dtype), m in self.program.history_groups]
            values = [jax.ShapeDtypeStruct((len(m), *shape), dtype) for (shape, dtype), m in self.program.value_groups]
            c = jax.ShapeDtypeStruct(np.shape(x0), np.float64)
            self._compiling[(size, lookahead)] = compile_ahead(
                self._order[lookahead], np.int32(1), x0, c, [first] * size, [first] * size, values, *args)

    def _ready(self, key) -> None:
        """Wait for the compilation ahead of ``key``, if one is pending."""
        if self._compiling.get(key) is not None:
            wait(self._compiling[key])
            self._compiling[key] = None

    def start(self, x0, *args):
        """``(f(x0), (orders[0], values))``: the function's value and the state a path starts from."""
        self._ready("start")
        return self._start(x0, *args)

    def _coefficient(self, lookahead, k, x0, c, orders, mirror, values, *args):
        """``(f_k, orders[k])`` (``f_{k+1}`` along ``c_{k+1} = c_k`` with ``lookahead``)."""
        leaves = jax.tree_util.tree_leaves(args)
        new = jax.jvp(lambda y: self.split.linear(y, *args), (x0,), (c,))[1]
        outs, order_k = self.program.order(k, new, orders, mirror, values, leaves)
        if lookahead:  # order k + 1 along c_{k+1} = c_k, its coefficients not kept
            orders = [o if m == 0 else [jnp.where(k == m, a, b) for a, b in zip(order_k, o)]
                      for m, o in enumerate(orders)]
            mirror = [mirror[0], order_k, *mirror[1:-1]]  # item j: orders[k + 1 - j]
            outs, _ = self.program.order(k + 1, new, orders, mirror, values, leaves)
        return jnp.broadcast_to(outs[0], self.split.out_shape), order_k

    def order(self, lookahead: bool, size: int):
        """The jitted ``(k, x0, c_k, orders, mirror, values, *args) -> (f_k, orders[k])``, for
        ``size`` orders kept."""
        self._ready((size, lookahead))
        return self._order[lookahead]
