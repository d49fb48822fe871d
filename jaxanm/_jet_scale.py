"""A product (or quotient) by a constant that ``jax.experimental.jet`` propagates as linear.

jet has no symbolic zero series for constant operands: before a rule runs it instantiates
zeros for them (``jax/experimental/jet.py``, ``JetTrace.process_primitive``: "TODO(mattjj):
avoid always instantiating zeros").  A constant ``c`` times a series of K terms then goes
through the bilinear rule, ``v_k = sum_{j<=k} u_j w_{k-j}``: (K+1)(K+2)/2 products, all but
K+1 of them with a zero.  In the FSW residual's pointwise part (what the ANM jets, after
:mod:`jaxanm._affine` took the stencil maps out) about two products in three have a constant
operand (material constants, row scalings, ``0.5 *`` of the strain rate), so they are most of
the jet's work and of its compiled size.

:data:`scale_p` computes ``x * c`` or ``x / c`` exactly like ``lax.mul`` / ``lax.div``, and its
jet rule applies the same operation to each term: K+1 operations instead of (K+1)(K+2)/2, and
the same values (the bilinear and quotient rules only add exact zeros to these products, for
finite operands).  :func:`jaxanm._affine.split_affine` binds it in place of ``mul``/``div``
wherever one operand of a non-affine operation is independent of ``x``.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax.experimental import jet
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir

_OPS = {"mul": jnp.multiply, "div": jnp.divide}  # broadcasting like numpy

scale_p = Primitive("jaxanm_scale")


def scale(x, c, op: str):
    """``x * c`` (``op="mul"``) or ``x / c`` (``op="div"``), with ``c`` a constant of the
    expansion: jet propagates it as linear in ``x``."""
    if op not in _OPS:
        raise ValueError(f"scale: op must be one of {sorted(_OPS)}, got {op!r}")
    return scale_p.bind(x, c, op=op)


def _impl(x, c, *, op):
    return _OPS[op](x, c)


def _abstract(x, c, *, op):
    del op
    return x.update(shape=jnp.broadcast_shapes(x.shape, c.shape), weak_type=False)


def _jvp(primals, tangents, *, op):
    # the product/quotient rule, in case a caller differentiates through it (the ANM does not)
    (x, c), (tx, tc) = primals, tangents
    out = scale(x, c, op)
    tx = ad.instantiate_zeros(tx)
    t_out = scale(tx, c, op)
    if type(tc) is not ad.Zero:
        t_out = t_out + (x * tc if op == "mul" else -out * tc / c)
    return out, t_out


def _batch(args, dims, *, op):
    # jacfwd and vmap: both operands with the batch axis first (None: not batched), aligned on
    # the trailing axes
    size = next(a.shape[d] for a, d in zip(args, dims) if d is not None)
    front = [jnp.broadcast_to(a, (size,) + jnp.shape(a)) if d is None else jnp.moveaxis(a, d, 0)
             for a, d in zip(args, dims)]
    rank = max(a.ndim for a in front)
    x, c = (a.reshape(a.shape[:1] + (1,) * (rank - a.ndim) + a.shape[1:]) for a in front)
    return scale(x, c, op), 0


def _jet_rule(primals_in, series_in, **params):
    # jet's rule signature: the primitive's params as keywords (here op alone, see scale)
    op = params["op"]
    (x, c), (terms, _) = primals_in, series_in  # c is constant: its terms are zeros
    return scale(x, c, op), [scale(t, c, op) for t in terms]


scale_p.def_impl(_impl)
scale_p.def_abstract_eval(_abstract)
mlir.register_lowering(scale_p, mlir.lower_fun(_impl, multiple_results=False))
ad.primitive_jvps[scale_p] = _jvp
batching.primitive_batchers[scale_p] = _batch
jet.jet_rules[scale_p] = _jet_rule
