"""Split a function ``f(x, *args)`` into its part affine in ``x`` and the rest, from its jaxpr.

A meshless residual is mostly linear maps of the unknowns (stencil gathers times constant
weights, sums) feeding a few pointwise nonlinear terms.  Along a path ``x(a) = x_0 + sum a^k
c_k`` the Taylor coefficients of an affine intermediate ``v = A x + b`` are ``A c_k``: they need
no series arithmetic, one linear map per new coefficient, where a Taylor arithmetic run
through them would multiply each constant weight by a field series (``jax.experimental.jet``
even instantiates zero series for the weights, ``jax/experimental/jet.py``,
``process_primitive``): O(K^2) products of the widest arrays of the residual.  The series
engine (:class:`jaxanm._series.AffinePath`) expands only the rest.  :func:`split_affine` finds
the *frontier*: the affine intermediates that a non-affine operation (or the output)
consumes.  Then

- ``linear(x, *args)`` returns the frontier values (the affine part, evaluated as is), and
- ``rest(frontier, *args)`` the outputs from the frontier values (the non-affine part),

with ``f(x, *args) == rest(linear(x, *args), *args)``.  The classification is conservative:
an operation is affine in ``x`` only if it is on the whitelist below with every ``x``-dependent
operand affine and every other operand independent of ``x``; anything else (including nested
calls that were not inlined) is "rest", which is always correct, only slower.
"""

from __future__ import annotations

import collections
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
from jax import lax
from jax.extend import core as jex_core

# Linear in all operands jointly (jet's own ``deflinear`` list, restricted to real arithmetic).
_LINEAR = {lax.neg_p, lax.add_p, lax.sub_p, lax.convert_element_type_p, lax.broadcast_in_dim_p,
           lax.concatenate_p, lax.pad_p, lax.reshape_p, lax.squeeze_p, lax.rev_p, lax.transpose_p,
           lax.slice_p, lax.reduce_sum_p, lax.copy_p, lax.cumsum_p, lax.split_p}
# Bilinear: affine when exactly one operand depends on x.
_BILINEAR = {lax.mul_p, lax.dot_general_p}


class AffineSplit(NamedTuple):
    """``f = rest(linear(x, *args), *args)``; ``n_frontier`` values pass between the two;
    ``out_shape`` is the shape of f's (single array) output."""

    linear: Callable
    rest: Callable
    n_frontier: int
    n_affine_eqns: int
    n_rest_eqns: int
    out_shape: tuple


def _affine(eqn, dep: list, aff: list) -> bool:
    """Whether ``eqn``'s outputs are affine in x, given which inputs depend on x (``dep``) and
    which of those are affine (``aff``)."""
    p = eqn.primitive
    if any(d and not a for d, a in zip(dep, aff)):
        return False
    if p in _LINEAR:
        return True
    if p in _BILINEAR:
        return sum(dep) == 1
    if p is lax.div_p:  # x / const
        return dep[0] and not dep[1]
    if p is lax.gather_p:  # operand[const indices]
        return not dep[1]
    if p is lax.scatter_add_p:  # indices const
        return not dep[1]
    if p is lax.select_n_p:  # const predicate chooses between affine cases
        return not dep[0]
    return False


def flat_jaxpr(fun: Callable, x, args):
    """The closed jaxpr of ``fun(x, *args)`` over flat arguments (``x``, then the leaves of
    ``args``), with nested ``jit`` calls inlined so that their insides are seen; ``fun`` must
    have one array output."""
    flat_args, tree = jax.tree_util.tree_flatten(args)

    def flat_fun(x, *flat):
        return fun(x, *jax.tree_util.tree_unflatten(tree, flat))

    with jax.disable_jit():  # inline jnp's internal jit calls, so that their insides are classified
        closed = jax.make_jaxpr(flat_fun)(x, *flat_args)
    if len(closed.jaxpr.outvars) != 1:
        raise ValueError(f"need a function with one array output, got {len(closed.jaxpr.outvars)}")
    return closed


def _scalar_factor(eqn, dep: list, scalars: set) -> bool:
    """Whether ``eqn`` multiplies or divides an x-dependent operand by a scalar (a rank-0
    constant, or one broadcast from a rank-0 constant)."""
    if eqn.primitive not in (lax.mul_p, lax.div_p) or sum(dep) != 1:
        return False
    const = eqn.invars[dep.index(False)]
    return isinstance(const, jex_core.Literal) or const in scalars or not const.aval.shape


def _classify(jaxpr, scalar_factors_affine: bool = True):
    """Each equation's kind ("const": independent of x, "affine", "rest") and the affine
    variables.  With ``scalar_factors_affine=False`` a product or quotient by a scalar constant
    is "rest"."""
    depends = {jaxpr.invars[0]}
    affine = {jaxpr.invars[0]}
    scalars = set()  # x-independent values computed from rank-0 ones only (e.g. broadcast)
    kinds = []
    for eqn in jaxpr.eqns:
        ins = [v for v in eqn.invars]
        dep = [isinstance(v, jex_core.Var) and v in depends for v in ins]
        if not any(dep):
            kinds.append("const")
            if all(isinstance(v, jex_core.Literal) or v in scalars or not v.aval.shape for v in ins):
                scalars.update(eqn.outvars)
            continue
        aff = [isinstance(v, jex_core.Var) and v in affine for v in ins]
        is_affine = _affine(eqn, dep, aff) and (scalar_factors_affine or not _scalar_factor(eqn, dep, scalars))
        kinds.append("affine" if is_affine else "rest")
        depends.update(eqn.outvars)
        if is_affine:
            affine.update(eqn.outvars)
    return kinds, affine


def _frontier(jaxpr, kinds, affine) -> list:
    """The affine variables that a rest equation or the output consumes, in order of first use."""
    frontier, seen = [], set()

    def mark(v):
        if isinstance(v, jex_core.Var) and v in affine and v not in seen:
            seen.add(v)
            frontier.append(v)

    for eqn, kind in zip(jaxpr.eqns, kinds):
        if kind == "rest":
            for v in eqn.invars:
                mark(v)
    for v in jaxpr.outvars:
        mark(v)
    return frontier


def _evaluate(env: dict, eqns) -> None:
    """Bind ``eqns`` in order on the values in ``env`` (variable -> value), adding their outputs."""
    for eqn in eqns:
        vals = [v.val if isinstance(v, jex_core.Literal) else env[v] for v in eqn.invars]
        out = eqn.primitive.bind(*vals, **eqn.params)
        for var, val in zip(eqn.outvars, out if eqn.primitive.multiple_results else [out]):
            env[var] = val


MAX_SPLITS = 16
"""Splits :func:`split_affine` keeps (the most recently made), by function and argument layout:
the sparse tangent and the series of one run split the same residual."""

_splits: collections.OrderedDict = collections.OrderedDict()


def split_affine(fun: Callable, x, *args, scalar_factors_affine: bool = True) -> AffineSplit:
    """Trace ``fun(x, *args)`` (nested ``jit`` calls inlined) and split it at the affine frontier.

    ``args`` are example values (shapes and dtypes matter, values do not); the returned
    functions take ``(x, *args)`` and ``(frontier, *args)`` with ``args`` of the same structure.
    ``scalar_factors_affine=False`` leaves products and quotients by scalar constants (a time
    step, a material constant) to the rest: the linear map then depends only on the array
    arguments (stencil weights), which a tangent can cache (:mod:`jaxanm.jacobian`).  The
    split of a function (by identity) for one layout of its arguments is made once and kept
    (:data:`MAX_SPLITS`).
    """
    leaves, tree = jax.tree_util.tree_flatten((x, args))
    key = (fun, scalar_factors_affine, tree,
           tuple((jnp.shape(v), str(jnp.result_type(v)), bool(getattr(v, "weak_type", False))) for v in leaves))
    if key not in _splits:
        if len(_splits) >= MAX_SPLITS:
            _splits.popitem(last=False)
        _splits[key] = _split(fun, x, args, scalar_factors_affine)
    _splits.move_to_end(key)
    return _splits[key]


def _split(fun: Callable, x, args: tuple, scalar_factors_affine: bool) -> AffineSplit:
    """:func:`split_affine`, made."""
    closed = flat_jaxpr(fun, x, args)
    jaxpr, consts = closed.jaxpr, closed.consts
    kinds, affine = _classify(jaxpr, scalar_factors_affine)
    frontier = _frontier(jaxpr, kinds, affine)

    def start_env(x_or_none, flat):
        env = dict(zip(jaxpr.constvars, consts))
        env.update(zip(jaxpr.invars[1:], flat))
        if x_or_none is not None:
            env[jaxpr.invars[0]] = x_or_none
        return env

    first_part = [e for e, k in zip(jaxpr.eqns, kinds) if k in ("const", "affine")]
    second_part = [e for e, k in zip(jaxpr.eqns, kinds) if k in ("const", "rest")]

    def linear(x, *args):
        """Frontier values: the affine intermediates that the non-affine part consumes."""
        env = start_env(x, jax.tree_util.tree_leaves(args))
        _evaluate(env, first_part)
        return [env[v] for v in frontier]

    def rest(values, *args):
        """Outputs of ``fun`` from the frontier values (the non-affine part)."""
        env = start_env(None, jax.tree_util.tree_leaves(args))
        env.update(zip(frontier, values))
        _evaluate(env, second_part)
        out = jaxpr.outvars[0]
        return out.val if isinstance(out, jex_core.Literal) else env[out]

    return AffineSplit(linear, rest, len(frontier), kinds.count("affine"), kinds.count("rest"),
                       tuple(closed.out_avals[0].shape))
