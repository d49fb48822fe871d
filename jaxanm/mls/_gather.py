"""Values and derivatives of a nodal-parameter field at the stencils' points: pure gathers and
sums, safe inside ``jax.jit``, ``jax.jacfwd`` and ``jax.experimental.jet``."""

from __future__ import annotations

import jax.numpy as jnp

from .._x64 import entry_point
from ._stencils import Stencils


def _contract(w, st, f):
    """``sum_k w[i, k] * f[index[i, k], ...]`` for a field f of shape (N_nodes, ...)."""
    g = jnp.asarray(f)[st.index]
    return jnp.sum(w.reshape(w.shape + (1,) * (g.ndim - 2)) * g, axis=1)


@entry_point
def value(st: Stencils, f):
    """MLS approximation of nodal parameters ``f`` (N_nodes, ...) at the stencils' points."""
    return _contract(st.phi, st, f)


@entry_point
def grad(st: Stencils, f):
    """Gradient ``(N, 2, ...)`` (last axis of size 2 for a scalar field: ``(N, 2)``)."""
    return jnp.stack([_contract(st.dx, st, f), _contract(st.dy, st, f)], axis=1)


@entry_point
def hessian(st: Stencils, f):
    """Second derivatives ``(N, 2, 2, ...)``: ``[[f_xx, f_xy], [f_xy, f_yy]]`` per point."""
    fxx, fxy, fyy = (_contract(w, st, f) for w in (st.dxx, st.dxy, st.dyy))
    return jnp.stack([jnp.stack([fxx, fxy], axis=1), jnp.stack([fxy, fyy], axis=1)], axis=1)


@entry_point
def laplacian(st: Stencils, f):
    """Laplacian ``f_xx + f_yy`` (N, ...) of nodal parameters ``f`` at the stencils' points."""
    return _contract(st.dxx + st.dyy, st, f)
