"""Incremental Taylor arithmetic on a jaxpr: one new order of every intermediate per call.

``jax.experimental.jet`` expands a function from scratch: asked for K terms it computes every
term of every intermediate, O(K^2) products per multiplication, and it is compiled anew for
each K.  An ANM series asks for one order at a time, from the path's coefficients known so
far, so the lower terms of every intermediate are known from the calls before.
:class:`TaylorProgram` keeps them on the device: every intermediate that a recurrence reads
has a *history*, its coefficients ``0 .. P-1``, and :meth:`TaylorProgram.order` computes
coefficient k of each intermediate from the histories and the inputs' coefficient k, by the
recurrences of automatic differentiation's Taylor mode (Griewank and Walther, *Evaluating
Derivatives*, 2nd ed., SIAM 2008, ch. 13), with k an argument:

- linear operations (sums, reshapes, gathers at constant indices, products by constants) map
  the operands' coefficient k: O(1) per order;
- a product ``w = a b`` is the Cauchy product ``w_k = sum_j a_j b_(k-j)``; a quotient, ``exp``,
  ``log``, powers and square roots follow from their differential equations (``b w = a``,
  ``u w' = c w u'``, ...): O(k) per order, O(P) as compiled (the orders not known are zeros);
- piecewise constant operations (comparisons, ``sign``, ``floor``) have no coefficients above
  their value, and predicates and indices are read at their values;
- any other operation jet knows is expanded by jet from its operands' histories: O(P^2), exact.

So one compiled program serves every order, an order costs O(P) instead of O(k^2), and the
coefficients stay on the device between orders.  Coefficient k of anything depends on the
inputs' coefficients up to k only.
"""

from __future__ import annotations

from typing import Any, Callable, NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import lax
from jax.experimental import jet
from jax.extend import core as jex_core

_LINEAR = {lax.neg_p, lax.add_p, lax.sub_p, lax.convert_element_type_p, lax.broadcast_in_dim_p,
           lax.concatenate_p, lax.pad_p, lax.reshape_p, lax.squeeze_p, lax.rev_p, lax.transpose_p,
           lax.slice_p, lax.reduce_sum_p, lax.copy_p, lax.cumsum_p, lax.split_p, lax.reduce_precision_p}
"""Linear in all operands jointly: coefficient k >= 1 is the operation on the operands'
coefficients k, a constant operand's being zero."""

_STRUCTURAL = {lax.gather_p: (1,), lax.scatter_add_p: (1,), lax.select_n_p: (0,)}
"""Linear in some operands; the operands listed (indices, a predicate) are read at their values."""

_BILINEAR = {lax.mul_p, lax.dot_general_p}
"""Linear when one operand is a constant of the expansion (read at its value)."""

_FLAT = {lax.sign_p, lax.floor_p, lax.ceil_p, lax.round_p}
"""Piecewise constant: no coefficients above the value."""


class _Plan(NamedTuple):
    """How :meth:`TaylorProgram.order` gets coefficient k of an equation's outputs: ``how`` is
    "const" (no expanded operand: evaluated), "skip" (no float output), "flat", "linear",
    "jet" or a recurrence of :data:`_RECURRENCES`; ``histories`` and ``values`` are the
    variables whose lower coefficients and values it reads."""

    eqn: jex_core.JaxprEqn
    how: str
    histories: tuple
    values: tuple


def _plan(eqn, dependent: set) -> _Plan:
    """The :class:`_Plan` of ``eqn`` given the variables that depend on the expanded inputs."""
    p, ins = eqn.primitive, eqn.invars
    dep = [isinstance(v, jex_core.Var) and v in dependent for v in ins]
    if not any(dep):
        return _Plan(eqn, "const", (), ())
    if not any(jnp.issubdtype(o.aval.dtype, jnp.inexact) for o in eqn.outvars):
        return _Plan(eqn, "skip", (), ())
    if p in _FLAT:
        return _Plan(eqn, "flat", (), ())
    structural = set(_STRUCTURAL.get(p, ()))
    if p in _BILINEAR and sum(dep) == 1 or p is lax.div_p and not dep[1]:
        structural = {i for i, d in enumerate(dep) if not d}
    if p in _LINEAR or p in _STRUCTURAL or structural:
        return _Plan(eqn, "linear", (), tuple(v for i, v in enumerate(ins) if i in structural and dep[i]))
    how = p.name
    if p is lax.pow_p:
        how = {(True, False): "pow", (False, True): "exp_base"}.get((dep[0], dep[1]), "jet")
    elif p is lax.integer_pow_p and eqn.params["y"] != 2:
        how = "jet"  # the power recurrence divides by u_0, which may vanish
    if how not in _RECURRENCES:
        floats = tuple(v for v, d in zip(ins, dep) if d and jnp.issubdtype(v.aval.dtype, jnp.inexact))
        return _Plan(eqn, "jet", floats, tuple(v for v, d in zip(ins, dep) if d))
    rule, hist, vals = _RECURRENCES[how]
    pick = lambda positions: tuple(eqn.outvars[0] if i < 0 else ins[i] for i in positions)  # noqa: E731
    return _Plan(eqn, how, pick(hist), pick(vals))


class TaylorProgram:
    """Taylor coefficients of ``closed(u_1..u_n, *consts)`` along a path of its first ``n``
    inputs, one order per :meth:`order` call (module docstring).

    The *state* of a path is ``(orders, values)``: ``orders[m]`` holds coefficient m of every
    intermediate whose history a recurrence reads (a list of arrays, one per group of
    intermediates of one shape and dtype: :attr:`history_groups`), ``values`` the values of
    the others that a rule reads (predicates, indices).  :meth:`start` evaluates the function
    at the inputs' values and returns its outputs, ``orders[0]`` and ``values``.
    :meth:`order` takes the inputs' coefficient k, the P orders with zeros (:meth:`zeros`) in
    place of those not known (k and above), and the same orders mirrored about k
    (:func:`mirrored`), and returns coefficient k of the outputs and ``orders[k]``.  Both are
    traceable; :meth:`order` is compiled once for every k < P.

    The caller keeps the orders as separate device arrays and hands them over in the order a
    Cauchy product ``sum_j a_j b_(k-j)`` reads them, a permutation of references: the program
    then reads every coefficient at a fixed place, and its products are plain elementwise
    work that XLA fuses into a few loops.  (Indexing one stacked array at ``k - j`` inside the
    program compiles several times longer, and writing order k into it in place makes XLA copy
    the whole buffer, which it both reads and updates.)
    """

    def __init__(self, closed, n: int):
        self.closed, self.n = closed, n
        jaxpr = closed.jaxpr
        self.eqns = _live(jaxpr)
        dependent = set(jaxpr.invars[:n])
        for eqn in self.eqns:
            if any(isinstance(v, jex_core.Var) and v in dependent for v in eqn.invars):
                dependent.update(eqn.outvars)
        self.dependent = dependent
        self.plans = [_plan(eqn, dependent) for eqn in self.eqns]
        hist = list(dict.fromkeys(v for plan in self.plans for v in plan.histories))
        vals = [v for v in dict.fromkeys(v for plan in self.plans for v in plan.values) if v not in set(hist)]
        self.history_groups, self.history_slots = _groups(hist)
        self.value_groups, self.value_slots = _groups(vals)

    def start(self, inputs, consts):
        """``(outputs, orders[0], values)`` at the inputs' values."""
        env = dict(zip(self.closed.jaxpr.constvars, self.closed.consts))
        env.update(zip(self.closed.jaxpr.invars, [*inputs, *consts]))
        for eqn in self.eqns:
            outs = eqn.primitive.bind(*[_read(env, v) for v in eqn.invars], **eqn.params)
            env.update(zip(eqn.outvars, outs if eqn.primitive.multiple_results else [outs]))
        first = [jnp.stack([env[v] for v in members]) for _, members in self.history_groups]
        values = [jnp.stack([env[v] for v in members]) for _, members in self.value_groups]
        return [_read(env, v) for v in self.closed.jaxpr.outvars], first, values

    def zeros(self) -> list:
        """An order of zeros (to stand for the orders not known yet), numpy arrays."""
        return [np.zeros((len(members), *shape), dtype) for (shape, dtype), members in self.history_groups]

    def order(self, k, new_inputs, orders, mirror, values, consts):
        """Coefficient k (traced, 1 <= k < len(orders)) of the outputs from the inputs'
        coefficient k, and ``orders[k]``."""
        ctx = _Order(self, k, orders, mirror, values, consts)
        ctx.new.update(zip(self.closed.jaxpr.invars[:self.n], new_inputs))
        for plan in self.plans:
            ctx.step(plan)
        outs = [ctx.coefficient(v) for v in self.closed.jaxpr.outvars]
        return outs, [jnp.stack([ctx.coefficient(v) for v in members]) for _, members in self.history_groups]


def _groups(variables: list):
    """``variables`` grouped by shape and dtype: ``[((shape, dtype), members)]`` and, per
    variable, its ``(group, index)``."""
    groups: dict = {}
    slots = {}
    for v in variables:
        members = groups.setdefault((tuple(v.aval.shape), v.aval.dtype), [])
        slots[v] = (list(groups).index((tuple(v.aval.shape), v.aval.dtype)), len(members))
        members.append(v)
    return list(groups.items()), slots


def _zeros(v: Any):
    """Zeros shaped like the variable (or literal) ``v``."""
    return jnp.zeros(v.aval.shape, v.aval.dtype)


def _read(env, v):
    return v.val if isinstance(v, jex_core.Literal) else env[v]


def _live(jaxpr) -> list:
    """The equations the outputs need, in order."""
    needed = {v for v in jaxpr.outvars if isinstance(v, jex_core.Var)}
    live = []
    for eqn in reversed(jaxpr.eqns):
        if any(v in needed for v in eqn.outvars) or eqn.effects:
            live.append(eqn)
            needed.update(v for v in eqn.invars if isinstance(v, jex_core.Var))
    return live[::-1]


class _Order:
    """The tracing context of one :meth:`TaylorProgram.order`: the constants' values, the
    state, and the coefficients k computed so far."""

    def __init__(self, program: TaylorProgram, k, orders, mirror, values, consts):
        self.p, self.k, self.orders, self.mirror, self.values = program, k, orders, mirror, values
        jaxpr = program.closed.jaxpr
        self.const = dict(zip(jaxpr.constvars, program.closed.consts))
        self.const.update(zip(jaxpr.invars[program.n:], consts))
        self.new: dict = {}
        self.capacity = len(orders)

    def dep(self, v) -> bool:
        return isinstance(v, jex_core.Var) and v in self.p.dependent

    def value(self, v):
        """The value (coefficient 0) of ``v``."""
        if not self.dep(v):
            return _read(self.const, v)
        if v in self.p.history_slots:
            g, i = self.p.history_slots[v]
            return self.orders[0][g][i]
        g, i = self.p.value_slots[v]
        return self.values[g][i]

    def history(self, v, mirrored: bool = False):
        """The coefficients 0 .. P-1 of ``v``, a list: those of orders k and above are zero
        (``mirrored``: item j is coefficient k - j, for j = 1 .. k-1, and zero otherwise)."""
        g, i = self.p.history_slots[v]
        return [order[g][i] for order in (self.mirror if mirrored else self.orders)]

    def coefficient(self, v):
        """Coefficient k of ``v``: zero for a constant and for what has no coefficients
        (predicates, indices)."""
        if self.dep(v) and v in self.new:
            return self.new[v]
        return _zeros(v)

    def step(self, plan: _Plan) -> None:
        """Coefficient k of the equation's outputs (for a constant one, their values)."""
        eqn = plan.eqn
        if plan.how == "const":
            outs = eqn.primitive.bind(*[_read(self.const, v) for v in eqn.invars], **eqn.params)
            self.const.update(zip(eqn.outvars, outs if eqn.primitive.multiple_results else [outs]))
            return
        if plan.how == "skip":
            return
        if plan.how == "flat":
            outs = _zeros(eqn.outvars[0])
        elif plan.how == "linear":
            outs = eqn.primitive.bind(*[self.value(v) if v in plan.values or not self.dep(v) and _reads_value(eqn)
                                        else self.coefficient(v) for v in eqn.invars], **eqn.params)
        elif plan.how == "jet":
            outs = _by_jet(self, plan)
        else:
            outs = _RECURRENCES[plan.how][0](self, *eqn.invars, eqn.outvars[0])
        self.new.update(zip(eqn.outvars, outs if eqn.primitive.multiple_results else [outs]))


def _reads_value(eqn) -> bool:
    """Whether a linear equation reads its constant operands at their values (a product or
    quotient by a constant, indices, a predicate) rather than as zero coefficients (a sum)."""
    return eqn.primitive in _BILINEAR or eqn.primitive is lax.div_p or eqn.primitive in _STRUCTURAL


def mirrored(orders: list, zeros, k: int) -> list:
    """``orders`` (P items, those of orders k and above being ``zeros``) mirrored about k for
    :meth:`TaylorProgram.order`: item j is ``orders[k - j]`` for j = 1 .. k-1, else ``zeros``."""
    return [orders[k - j] if 1 <= j < k else zeros for j in range(len(orders))]


def _cauchy(ctx: _Order, a, b, weighted: bool = False):
    """``sum_(j=1)^(k-1) a_j b_(k-j)`` (times j when ``weighted``): elementwise products of
    the orders as handed over (:class:`TaylorProgram`), the unknown ones zero."""
    ha, hb = ctx.history(a), ctx.history(b, mirrored=True)
    total = jnp.zeros(jnp.broadcast_shapes(ha[0].shape, hb[0].shape), jnp.result_type(ha[0], hb[0]))
    for j in range(1, ctx.capacity - 1):  # j <= k - 1 <= P - 2
        total = total + (j * ha[j] if weighted else ha[j]) * hb[j]
    return total


def _mul(ctx, a, b, w):
    return (ctx.value(a) * ctx.coefficient(b) + ctx.coefficient(a) * ctx.value(b)
            + _cauchy(ctx, a, b))


def _square(ctx, u, w):
    return 2.0 * ctx.value(u) * ctx.coefficient(u) + _cauchy(ctx, u, u)


def _div(ctx, a, b, w):  # b w = a
    return (ctx.coefficient(a) - ctx.coefficient(b) * ctx.value(w)
            - _cauchy(ctx, b, w)) / ctx.value(b)


def _exp(ctx, u, v, shift=0.0):  # v = exp(u) + shift: v' = (v - shift) u'
    return ((ctx.value(v) - shift) * ctx.coefficient(u)
            + _cauchy(ctx, u, v, weighted=True) / ctx.k)


def _log(ctx, u, w, shift=0.0):  # w = log(u + shift): (u + shift) w' = u'
    return (ctx.coefficient(u) - _cauchy(ctx, w, u, weighted=True) / ctx.k) / (
        ctx.value(u) + shift)


def _power(ctx, u, w, c):
    """``w = u^c``, c constant: ``u w' = c w u'``, so
    ``k u_0 w_k = c k u_k w_0 + sum_(j=1)^(k-1) ((c + 1) j - k) u_j w_(k-j)``."""
    k = ctx.k
    return (c * k * ctx.coefficient(u) * ctx.value(w) + (c + 1.0) * _cauchy(ctx, u, w, weighted=True)
            - k * _cauchy(ctx, u, w)) / (k * ctx.value(u))


def _exp_base(ctx, base, y, v):  # v = base^y = exp(y log base): v' = log(base) v y'
    return jnp.log(ctx.value(base)) * (ctx.value(v) * ctx.coefficient(y)
                                      + _cauchy(ctx, y, v, weighted=True) / ctx.k)


_RECURRENCES: dict[str, tuple[Callable, tuple, tuple]] = {
    # name: (rule(ctx, *operands, output), histories read, values read); -1 is the output
    "mul": (_mul, (0, 1), (0, 1)),
    "div": (_div, (1, -1), (1, -1)),
    "exp": (_exp, (0, -1), (-1,)),
    "expm1": (lambda ctx, u, v: _exp(ctx, u, v, -1.0), (0, -1), (-1,)),
    "log": (_log, (-1, 0), (0,)),
    "log1p": (lambda ctx, u, w: _log(ctx, u, w, 1.0), (-1, 0), (0,)),
    "pow": (lambda ctx, u, c, w: _power(ctx, u, w, ctx.value(c)), (0, -1), (0, -1)),
    "exp_base": (_exp_base, (1, -1), (-1,)),
    "integer_pow": (_square, (0,), (0,)),  # y = 2 (other powers: by jet)
    "square": (_square, (0,), (0,)),
    # sqrt as the power 1/2, as jet does (exp of half the log): the recurrence of w^2 = u finds
    # 2 w_0 w_k as u_k minus the products of the lower orders, which cancel near u_0 = 0 (a
    # branch of u - sqrt(lam) followed towards lam = 0 lost its accuracy at lam ~ 1e-6)
    "sqrt": (lambda ctx, u, w: _power(ctx, u, w, 0.5), (0, -1), (0, -1)),
    "rsqrt": (lambda ctx, u, w: _power(ctx, u, w, -0.5), (0, -1), (0, -1)),
    "abs": (lambda ctx, u, w: jnp.sign(ctx.value(u)) * ctx.coefficient(u), (), (0,)),
}


def _by_jet(ctx: _Order, plan: _Plan):
    """Coefficient k of any operation jet knows, by jet from its operands' histories (O(P^2))."""
    eqn, k = plan.eqn, ctx.k
    expanded = list(plan.histories)

    def f(*xs):
        given = dict(zip(expanded, xs))
        return eqn.primitive.bind(*[given[v] if v in given else ctx.value(v) for v in eqn.invars], **eqn.params)

    # each operand's coefficients 1 .. P-1: those known, coefficient k, zeros above
    series = [[jnp.where(m == k, ctx.coefficient(v), h) for m, h in enumerate(ctx.history(v)) if m]
              for v in expanded]
    _, terms = jet.jet(f, tuple(ctx.value(v) for v in expanded), tuple(series), factorial_scaled=False)
    if eqn.primitive.multiple_results:
        return [jnp.stack(t)[k - 1] for t in zip(*terms)]
    return jnp.stack([jnp.broadcast_to(t, _zeros(eqn.outvars[0]).shape) for t in terms])[k - 1]
