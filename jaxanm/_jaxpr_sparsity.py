"""The sparsity pattern of a Jacobian from the function's jaxpr, in memory and time O(nnz).

Every array of the jaxpr carries, per element, the set of unknowns it depends on: the rows of
a boolean CSR matrix (elements x unknowns).  The sets go through the jaxpr primitive by
primitive, as the global tracers of SparseConnectivityTracer.jl go through a Julia function
(Hill and Dalle 2025), with vectorised scipy operations per primitive, never a loop over
elements and never a dense Jacobian:

- elementwise arithmetic: the union of its operands' sets, element by element (a rank-0
  operand broadcast);
- zero derivative (comparisons, ``sign``, ``floor``, integer or boolean results): no sets;
- moves (reshape, slice, pad, concatenate, broadcast, transpose, gather, dynamic slices,
  ``select_n`` with a known condition): each output element takes the set of the element it
  copies, found by applying the primitive itself to the elements' numbers;
- reductions, cumulative reductions and ``dot_general``: the union over the elements summed
  (for ``dot_general``, those whose factor in a known operand is nonzero);
- ``scatter-add``: the operand's sets, with each update's set added at its target;
- calls (``jit``, ``custom_jvp``, ``custom_vjp``, ``remat``) and ``cond``: their jaxprs, the
  branch a known index picks or else the union of all branches;
- any other primitive: each output element depends on every unknown its inputs depend on (a
  superset), with a warning that names it.

The function's arguments are the unknowns ``x``, *varying* arguments (lam, a time, an old
state: their values are never read, so the pattern holds for all of them) and *fixed* ones
(the parameters), whose values are read where they decide which elements meet: gather and
scatter indices, a ``where``'s condition, a ``cond``'s index, a constant matrix's zeros.  Such
values are computed on first use, by binding the primitives that make them.  A product by a
constant that happens to be zero is kept: the pattern is structural.

A pattern that would hold more than :data:`PATTERN_ENTRIES_MAX` entries anywhere on the way
(a residual that couples nearly every unknown to every other) is refused with an
:class:`~jaxanm.InputError` before it is built.
"""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import scipy.sparse
from jax import lax
from jax.extend import core as jex_core

from ._affine import flat_jaxpr
from .errors import InputError

PATTERN_ENTRIES_MAX = 2**27
"""The most entries (element, unknown) an array's sets may hold: about 2 GB of index arrays
while they are combined; more means a Jacobian too dense for a sparse pattern to pay."""

_ELEMENTWISE = {
    "neg", "add", "add_any", "sub", "mul", "div", "rem", "pow", "integer_pow", "square", "exp", "exp2", "log",
    "log1p", "expm1", "sqrt", "rsqrt", "cbrt", "sin", "cos", "tan", "asin", "acos", "atan", "atan2", "sinh", "cosh",
    "tanh", "asinh", "acosh", "atanh", "logistic", "abs", "max", "min", "erf", "erfc", "erf_inv", "lgamma",
    "digamma", "polygamma", "igamma", "igammac", "zeta", "bessel_i0e", "bessel_i1e", "regularized_incomplete_beta",
    "convert_element_type", "reduce_precision", "real", "imag", "conj", "complex", "clamp", "copy", "copy_p",
    "jaxanm_scale",
}
_ZERO_DERIVATIVE = {"sign", "floor", "ceil", "round", "is_finite", "stop_gradient", "nextafter"}
_REDUCTIONS = {"reduce_sum", "reduce_max", "reduce_min", "reduce_prod"}
_CUMULATIVE = {"cumsum", "cumprod", "cummax", "cummin", "cumlogsumexp"}
_SCATTERS = {"scatter-add", "scatter_add", "scatter-mul", "scatter_mul", "scatter-min", "scatter-max", "scatter"}
_CALLS = {"jit", "pjit", "closed_call", "core_call", "remat2", "checkpoint", "custom_jvp_call", "custom_vjp_call",
          "custom_vjp_call_jaxpr"}


class _Array:
    """One array of the jaxpr as the detection sees it: its ``shape``, the ``sets`` of its
    elements (CSR rows, elements x unknowns; None: no element depends on the unknowns) and,
    for an array made of fixed arguments only, its value (``compute``, called on first use)."""

    __slots__ = ("shape", "sets", "_compute", "_value")

    def __init__(self, shape, sets=None, compute=None):
        self.shape, self.sets, self._compute, self._value = tuple(shape), sets, compute, None

    @property
    def size(self) -> int:
        return math.prod(self.shape)

    @property
    def known(self) -> bool:
        """Whether the value is known (depends on fixed arguments and constants only)."""
        return self._compute is not None

    def value(self) -> np.ndarray:
        """The known value (computed once)."""
        if self._value is None:
            self._value = np.asarray(self._compute())
        return self._value


def jacobian_pattern(fun, x, varying: tuple, fixed: tuple) -> scipy.sparse.csc_matrix:
    """The sparsity pattern of ``d fun(x, *varying, *fixed) / dx`` (boolean CSC, (m, n) for a
    function of one array output of size m), from the function's jaxpr (module docstring).

    ``x``: the unknowns (their values are not read); ``varying``: arguments whose values the
    pattern must hold for (never read); ``fixed``: arguments whose values are read where they
    decide which elements meet (indices, conditions, a constant matrix's zeros).
    """
    x = jnp.asarray(x)
    closed = flat_jaxpr(lambda y, v, f: fun(y, *v, *f), x, (tuple(varying), tuple(fixed)))
    invars = closed.jaxpr.invars
    n_varying = len(jax.tree_util.tree_leaves(tuple(varying)))
    n = x.size
    inputs = [_Array(x.shape, scipy.sparse.identity(n, dtype=bool, format="csr"))]
    inputs += [_Array(v.aval.shape) for v in invars[1:1 + n_varying]]
    inputs += [_Array(np.shape(leaf), compute=lambda leaf=leaf: leaf) for leaf in jax.tree_util.tree_leaves(fixed)]
    (out,) = _run(closed.jaxpr, closed.consts, inputs, n)
    rows = out.sets if out.sets is not None else scipy.sparse.csr_matrix((out.size, n), dtype=bool)
    return scipy.sparse.csc_matrix(rows, dtype=bool)


def _run(jaxpr, consts, inputs: list, n: int) -> list:
    """The :class:`_Array` of each output of ``jaxpr`` from those of its inputs."""
    env: dict = {}

    def read(v):
        if isinstance(v, jex_core.Literal):
            return _Array(np.shape(v.val), compute=lambda: v.val)
        return env[v]

    env.update({v: _Array(np.shape(c), compute=lambda c=c: c) for v, c in zip(jaxpr.constvars, consts)})
    env.update(zip(jaxpr.invars, inputs))
    for eqn in jaxpr.eqns:
        env.update(zip(eqn.outvars, _apply(eqn, [read(v) for v in eqn.invars], n)))
    return [read(v) for v in jaxpr.outvars]


def _inexact(var) -> bool:
    return jnp.issubdtype(var.aval.dtype, jnp.inexact)


def _apply(eqn, ins: list, n: int) -> list:
    """The outputs of one equation: computed later if made of known values only; without
    sets if no input has any or no output is a float; else by the primitive's rule."""
    shapes = [tuple(v.aval.shape) for v in eqn.outvars]
    if all(a.known for a in ins) and not eqn.effects:
        return _bound_later(eqn, ins, shapes)
    if all(a.sets is None for a in ins) or not any(_inexact(v) for v in eqn.outvars):
        return [_Array(s) for s in shapes]
    outs = _rule(eqn.primitive.name)(eqn, ins, shapes, n)
    return [o if isinstance(o, _Array) else _Array(s, o if _inexact(v) else None)
            for o, s, v in zip(outs, shapes, eqn.outvars)]


def _bound_later(eqn, ins, shapes) -> list:
    """Known outputs, computed on first use by binding the primitive to the known inputs."""
    done: list = []

    def outputs():
        if not done:
            values = [a.value() for a in ins]
            in_numpy = _NUMPY_VALUES.get(eqn.primitive.name)
            out = in_numpy(values, eqn.params) if in_numpy else eqn.primitive.bind(*values, **eqn.params)
            done.append(out if eqn.primitive.multiple_results else [out])
        return done[0]

    return [_Array(s, compute=lambda i=i: outputs()[i]) for i, s in enumerate(shapes)]


def _rule(name: str):
    """The rule ``(eqn, inputs, output shapes, n) -> [sets or _Array per output]`` of a primitive."""
    if name in _ELEMENTWISE:
        return _elementwise
    if name in _ZERO_DERIVATIVE:
        return lambda eqn, ins, shapes, n: [None] * len(shapes)
    if name in _REDUCTIONS:
        return _reduced
    if name in _CUMULATIVE:
        return _cumulative
    if name in _SCATTERS:
        return _scattered
    if name in _CALLS:
        return _called
    return {"select_n": _selected, "dot_general": _dot_general, "cond": _cond}.get(
        name, _moved if name in _MOVES or name in _NUMPY_MOVES else _everything)


def _check(entries: int, name: str) -> None:
    """Refuse sets of more than :data:`PATTERN_ENTRIES_MAX` entries, before they are made."""
    if entries > PATTERN_ENTRIES_MAX:
        raise InputError(f"the Jacobian's sparsity pattern would hold {entries:.3g} entries at the residual's "
                         f"{name!r} (limit {PATTERN_ENTRIES_MAX:.3g}): the residual couples nearly every unknown to "
                         "every other, where a sparse Jacobian does not pay; give jacobian='dense' for a small "
                         "problem, or sparsity= with the pattern you know")


def _take(rows, src: np.ndarray, name: str):
    """``rows[src]`` (CSR), an empty row where ``src`` is -1."""
    src = np.asarray(src, dtype=np.int64).ravel()
    valid = src >= 0
    _check(int(np.diff(rows.indptr)[src[valid]].sum()), name)
    if not valid.all():
        rows = scipy.sparse.vstack([rows, scipy.sparse.csr_matrix((1, rows.shape[1]), dtype=bool)], format="csr")
        src = np.where(valid, src, rows.shape[0] - 1)
    return rows[src]


def _combine(rows, out: np.ndarray, src: np.ndarray, size: int, name: str):
    """The sets of ``size`` elements, element ``out[k]`` holding the union of ``rows[src[k]]``
    over k (a boolean product with the selection matrix)."""
    out, src = np.asarray(out, dtype=np.int64).ravel(), np.asarray(src, dtype=np.int64).ravel()
    _check(int(np.diff(rows.indptr)[src].sum()), name)
    select = scipy.sparse.csr_matrix((np.ones(out.size, dtype=bool), (out, src)), shape=(size, rows.shape[0]))
    return (select @ rows).tocsr()


def _union(parts: list):
    """The elementwise union of equal-shaped sets (None: no part)."""
    parts = [p for p in parts if p is not None]
    if not parts:
        return None
    out = parts[0]
    for part in parts[1:]:
        out = out + part
    return out.tocsr()


def _elementwise(eqn, ins, shapes, n):
    """Union of the operands' sets, a rank-0 operand's broadcast to every element."""
    size = math.prod(shapes[0])
    name = eqn.primitive.name
    return [_union([a.sets if a.size == size else _take(a.sets, np.zeros(size, dtype=np.int64), name)
                    for a in ins if a.sets is not None])]


def _selected(eqn, ins, shapes, n):
    """``select_n``: the case a known condition picks, element by element, else all cases'."""
    return _moved(eqn, ins, shapes, n) if ins[0].known else _elementwise(eqn, ins[1:], shapes, n)


def _broadcast_in_dim(ops, p):
    shape, dims = p["shape"], tuple(p["broadcast_dimensions"])
    x = ops[0]
    return np.broadcast_to(x.reshape([x.shape[dims.index(d)] if d in dims else 1 for d in range(len(shape))]), shape)


def _slice(ops, p):
    strides = p["strides"] or (None,) * len(p["start_indices"])
    return ops[0][tuple(slice(a, b, s) for a, b, s in zip(p["start_indices"], p["limit_indices"], strides))]


_NUMPY_MOVES = {
    "reshape": lambda ops, p: (ops[0] if p.get("dimensions") is None
                               else np.transpose(ops[0], p["dimensions"])).reshape(p["new_sizes"]),
    "squeeze": lambda ops, p: np.squeeze(ops[0], axis=tuple(p["dimensions"])),
    "transpose": lambda ops, p: np.transpose(ops[0], p["permutation"]),
    "rev": lambda ops, p: np.flip(ops[0], axis=tuple(p["dimensions"])),
    "concatenate": lambda ops, p: np.concatenate(ops, axis=p["dimension"]),
    "stack": lambda ops, p: np.stack(ops, axis=p["axis"]),
    "tile": lambda ops, p: np.tile(ops[0], p["reps"]),
    "split": lambda ops, p: np.split(ops[0], np.cumsum(p["sizes"])[:-1], axis=p["axis"]),
    "broadcast_in_dim": _broadcast_in_dim,
    "slice": _slice,
    "select_n": lambda ops, p: np.choose(np.asarray(ops[0], dtype=np.int64), ops[1:]),
}
"""Moves applied in numpy (no compilation) to the elements' numbers, or to known values."""
_MOVES = {"pad", "gather", "dynamic_slice", "dynamic_update_slice"}
"""Moves applied to the elements' numbers by binding the primitive (compiled once per shape)."""
def _on_operands(ufunc):
    return lambda ops, p: ufunc(*ops)


_NUMPY_VALUES = {
    **{name: _on_operands(ufunc) for name, ufunc in (
        ("add", np.add), ("sub", np.subtract), ("mul", np.multiply), ("neg", np.negative), ("max", np.maximum),
        ("min", np.minimum), ("abs", np.abs), ("sign", np.sign), ("lt", np.less), ("le", np.less_equal),
        ("gt", np.greater), ("ge", np.greater_equal), ("eq", np.equal), ("ne", np.not_equal),
        ("and", np.bitwise_and), ("or", np.bitwise_or), ("not", np.invert))},
    "convert_element_type": lambda ops, p: np.asarray(ops[0]).astype(p["new_dtype"]),
    "argmax": lambda ops, p: np.argmax(ops[0], axis=p["axes"][0]).astype(p["index_dtype"]),
    "argmin": lambda ops, p: np.argmin(ops[0], axis=p["axes"][0]).astype(p["index_dtype"]),
    **_NUMPY_MOVES,
}
"""Known values made in numpy (no compilation): the index arithmetic of gathers and masks;
numpy's operations on operands of one dtype are lax's (same dtype, same wrap-around)."""


def _moved(eqn, ins, shapes, n):
    """Each output element takes the set of the element it copies, or none: the primitive is
    applied to the elements' numbers (from 1; 0: no set) in place of its float operands, its
    other operands (indices, conditions) at their known values."""
    numbers, blocks, offset = [], [], 0
    for var, a in zip(eqn.invars, ins):
        if not _inexact(var):
            if not a.known:
                return _everything(eqn, ins, shapes, n, "its indices or condition are not known")
            numbers.append(a.value())
        elif a.sets is None:
            numbers.append(np.zeros(a.shape))
        else:
            numbers.append(np.arange(offset + 1, offset + a.size + 1, dtype=np.float64).reshape(a.shape))
            blocks.append(a.sets)
            offset += a.size
    name = eqn.primitive.name
    move = _NUMPY_MOVES.get(name)
    outs = move(numbers, eqn.params) if move else eqn.primitive.bind(*numbers, **eqn.params)
    outs = outs if eqn.primitive.multiple_results else [outs]
    stacked = blocks[0] if len(blocks) == 1 else scipy.sparse.vstack(blocks, format="csr")
    return [_take(stacked, np.nan_to_num(np.asarray(o, dtype=np.float64)).astype(np.int64) - 1, name)
            for o in outs]


def _reduced(eqn, ins, shapes, n):
    """Each output element: the union over the elements it reduces."""
    a, axes = ins[0], tuple(eqn.params["axes"])
    out = np.arange(math.prod(shapes[0])).reshape(shapes[0])
    target = np.broadcast_to(np.expand_dims(out, axes), a.shape)
    return [_combine(a.sets, target, np.arange(a.size), out.size, eqn.primitive.name)]


def _cumulative(eqn, ins, shapes, n):
    """Each output element: the union over the elements before it along the axis (after it
    with ``reverse``), itself included."""
    a, axis = ins[0], eqn.params["axis"]
    length = a.shape[axis]
    ids = np.moveaxis(np.arange(a.size).reshape(a.shape), axis, -1).reshape(-1, length)
    at, before = np.tril_indices(length)
    if eqn.params["reverse"]:
        at, before = before, at
    return [_combine(a.sets, ids[:, at], ids[:, before], a.size, eqn.primitive.name)]


def _dot_general(eqn, ins, shapes, n):
    """``out[b, i, j] = sum_k lhs[b, i, k] rhs[b, k, j]``: the union over k of ``lhs[b, i, k]``'s
    set where ``rhs[b, k, j]`` may be nonzero, and of ``rhs[b, k, j]``'s where ``lhs[b, i, k]``
    may be (a known operand: where its value is nonzero)."""
    (lc, rc), (lb, rb) = eqn.params["dimension_numbers"]
    lhs, rhs = ins
    lf = [d for d in range(len(lhs.shape)) if d not in lc and d not in lb]
    rf = [d for d in range(len(rhs.shape)) if d not in rc and d not in rb]
    left, right = _grouped(lhs, (lb, lf, lc)), _grouped(rhs, (rb, rc, rf))  # (b, i, k), (b, k, j)
    b, i, _ = left.shape
    j = right.shape[2]
    out = np.arange(b * i * j).reshape(b, i, j)
    name, parts = eqn.primitive.name, []
    if lhs.sets is not None:
        bb, kk, jj = _may_be_nonzero(rhs, right, i, name)
        parts.append(_combine(lhs.sets, out[bb, :, jj], left[bb, :, kk], out.size, name))
    if rhs.sets is not None:
        bb, ii, kk = _may_be_nonzero(lhs, left, j, name)
        parts.append(_combine(rhs.sets, out[bb, ii, :], right[bb, kk, :], out.size, name))
    return [_union(parts)]


def _grouped(a: _Array, groups) -> np.ndarray:
    """The numbers of ``a``'s elements, its axes gathered into ``groups`` (one axis each)."""
    order = [d for group in groups for d in group]
    sizes = [math.prod(a.shape[d] for d in group) for group in groups]
    return np.transpose(np.arange(a.size).reshape(a.shape), order).reshape(sizes)


def _may_be_nonzero(a: _Array, numbers: np.ndarray, width: int, name: str) -> tuple:
    """The positions in ``numbers``' layout where ``a`` may be nonzero (where its value is, when
    known; else all), each to be paired with ``width`` elements (checked against the limit)."""
    mask = a.value().ravel()[numbers] != 0 if a.known else np.ones(numbers.shape, dtype=bool)
    _check(int(np.count_nonzero(mask)) * width, name)
    return np.nonzero(mask)


def _scattered(eqn, ins, shapes, n):
    """The operand's sets, each update's set added at its target (a superset for the
    scatters that overwrite)."""
    operand, indices, updates = ins[:3]
    if not indices.known:
        return _everything(eqn, ins, shapes, n, "its indices are not known")
    p = eqn.params

    def add(u):
        return lax.scatter_add(jnp.zeros(operand.shape), indices.value(), u, p["dimension_numbers"],
                               indices_are_sorted=p["indices_are_sorted"], unique_indices=p["unique_indices"],
                               mode=p["mode"])

    # the transpose of scatter-add is the gather of each update's target (0 where dropped)
    numbers = np.arange(1, operand.size + 1, dtype=np.float64).reshape(operand.shape)
    (target,) = jax.linear_transpose(add, jax.ShapeDtypeStruct(updates.shape, jnp.float64))(numbers)
    target = np.asarray(target).astype(np.int64).ravel() - 1
    parts = [operand.sets]
    if updates.sets is not None:
        keep = target >= 0
        parts.append(_combine(updates.sets, target[keep], np.flatnonzero(keep), operand.size, eqn.primitive.name))
    return [_union(parts)]


def _called(eqn, ins, shapes, n):
    """A call: the sets through the jaxpr it calls."""
    sub = next(eqn.params[k] for k in ("jaxpr", "call_jaxpr", "fun_jaxpr") if k in eqn.params)
    jaxpr, consts = (sub.jaxpr, sub.consts) if isinstance(sub, jex_core.ClosedJaxpr) else (sub, ())
    if len(jaxpr.invars) != len(ins):
        return _everything(eqn, ins, shapes, n, "its jaxpr's inputs are not the call's")
    return _run(jaxpr, consts, ins, n)


def _cond(eqn, ins, shapes, n):
    """``cond``: the branch a known index picks, else the union over all branches."""
    branches, index, operands = eqn.params["branches"], ins[0], ins[1:]
    if index.known:
        branch = branches[int(np.clip(index.value(), 0, len(branches) - 1))]
        return _run(branch.jaxpr, branch.consts, operands, n)
    outs = [_run(b.jaxpr, b.consts, operands, n) for b in branches]
    return [_union([o.sets for o in per_output]) for per_output in zip(*outs)]


def _everything(eqn, ins, shapes, n, why: str = "no rule for it"):
    """The conservative rule: every output element depends on every unknown that any input
    depends on (warned, naming the primitive; refused when too dense to hold)."""
    name = eqn.primitive.name
    columns = np.unique(np.concatenate([a.sets.indices for a in ins if a.sets is not None]))
    sizes = [math.prod(s) for s in shapes]
    _check(sum(sizes) * columns.size, name)
    warnings.warn(f"sparsity detection: {why} (primitive {name!r}); each of its output elements is taken to "
                  f"depend on all {columns.size} unknowns its inputs depend on (a superset of the pattern)",
                  stacklevel=2)
    return [scipy.sparse.csr_matrix((np.ones(size * columns.size, dtype=bool), np.tile(columns, size),
                                     np.arange(size + 1) * columns.size), shape=(size, n)) for size in sizes]
