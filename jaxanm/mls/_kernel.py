"""The compiled MLS kernel: shape functions of all evaluation points in few jitted calls.

The kernel runs on all evaluation points at once (in calls of up to :data:`CALL_MAX`, padded
to a multiple of :data:`CHUNK`) and depends only on that padded size and the stencil width m
(and q): rebuilding stencils for a moved cloud with the same ``m_max`` does not recompile.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._compile_ahead import compile_ahead, wait
from ._shape import shape_functions

CHUNK = 128
"""Granularity of the compiled kernel's calls: each takes a multiple of this many evaluation
points (the last call of a build is padded up to one), so that few shapes compile.  A
multiple of :data:`INNER`."""

CALL_MAX = 1024
"""Most evaluation points per call of the compiled kernel (larger builds make several calls).

A call has a fixed cost (its dispatch, and a start for each of its ~200 XLA fusions), so one
call over a whole paper-sized cloud beats several small ones (measured in
``benchmarks/results/profile_host_step.md``).  The compiled shapes are the multiples of :data:`CHUNK` up to
this: at most 8 per (m, q) and kernel, each compiled once."""

INNER = 64
"""Evaluation points per iteration of the loop (``lax.map``) inside each kernel call.

The kernel's ~200 fusions then each work on (64, m) arrays that stay in the L1/L2 caches
instead of streaming whole-cloud (n, m) arrays, which is faster than one pass and than blocks
of 32 or 128 (measured in ``benchmarks/results/profile_host_step.md``); results change by round-off only.
The loop costs compile time, once per shape (``jaxanm run`` keeps it in its compile cache)."""


def _blocks(fn, *arrays):
    """``fn`` applied to blocks of :data:`INNER` rows of the (n, ...) ``arrays`` (n a multiple
    of it) by ``lax.map``, inside the jitted kernels; its results joined back to n rows."""
    k = arrays[0].shape[0] // INNER
    out = jax.lax.map(lambda a: fn(*a), tuple(a.reshape((k, INNER) + a.shape[1:]) for a in arrays))
    return tuple(o.reshape((-1,) + o.shape[2:]) for o in out)


@functools.partial(jax.jit, static_argnames=("q",))
def kernel(x, y, mask, h, c, q):
    """Shape functions and derivatives for n stencils: ``(phi, dx, dy, dxx, dxy, dyy)`` (n, m),
    lower bounds of the moment matrices' rcond (n,) and a finite flag (n,).

    ``x, y`` (n, m): node coordinates relative to each evaluation point, divided by its ``h``
    (n,); ``mask`` (n, m): real (not padding) entries within the support (r <= 1).  Called by
    :func:`run_kernel` with n a multiple of :data:`CHUNK`, in blocks of :data:`INNER`.
    """
    phi, px, py, pxx, pxy, pyy, bound = _blocks(lambda *a: shape_functions(*a, c, q), x, y, mask)
    h1 = h[:, None]
    h2 = h1 * h1
    # the barrier: the finite test reads the outputs instead of fusing (recomputing) them
    out = jax.lax.optimization_barrier((phi, px / h1, py / h1, pxx / h2, pxy / h2, pyy / h2))
    # a * 0 is 0 for finite a and NaN otherwise: one sum instead of six boolean reductions
    finite = jnp.isfinite(jnp.sum(sum(a * 0.0 for a in out), axis=1))
    return (*out, bound, finite)


@functools.partial(jax.jit, static_argnames=("q",))
def value_kernel(x, y, mask, h, c, q):
    """Value-only counterpart of :func:`kernel`: ``(phi, bound, finite)`` for n stencils (phi
    by the same operations, without the derivatives)."""
    phi, bound = _blocks(lambda *a: shape_functions(*a, c, q, derivatives=False), x, y, mask)
    phi = jax.lax.optimization_barrier(phi)
    return phi, bound, jnp.isfinite(phi).all(1)


@functools.partial(jax.jit, static_argnames=("n",))
def _joined(parts, n):
    """The first n rows of the concatenation of each array's ``parts`` (a tuple per call), on
    the device: the weights stay jax arrays, for the Stencils, without a copy through numpy
    (a copy per rebuild saved).  Compiled per (n, calls): a concatenation and a slice."""
    return tuple(jnp.concatenate(p)[:n] if len(p) > 1 else p[0][:n] for p in zip(*parts))


_COMPILED: set = set()
"""(kernel, rows, m, q) of the kernel calls made in this process (:func:`run_kernel`)."""


def run_kernel(x, y, mask, h, c, q, derivatives=True):
    """Run :func:`kernel` on all evaluation points, in calls of at most :data:`CALL_MAX`:
    ``(phi, dx, dy, dxx, dxy, dyy)`` (n, m) as jax arrays, ``bound, finite`` (n,) in numpy.

    The points are padded (with copies of the first stencil) to a multiple of :data:`CHUNK`,
    so that the compiled shapes do not depend on N itself.  The numpy inputs go to the jitted
    kernel as they are (no separate ``jnp.asarray`` dispatches), and every call is dispatched
    before any result is read.  Without ``derivatives``, :func:`value_kernel` runs instead
    and the five derivative arrays are None.
    """
    n = x.shape[0]
    n_pad = -(-n // CHUNK) * CHUNK

    def padded(a):
        return np.concatenate([a, np.repeat(a[:1], n_pad - n, axis=0)]) if n_pad > n else a

    x, y, mask, h = padded(x), padded(y), padded(mask), padded(h)
    compiled = kernel if derivatives else value_kernel
    starts = range(0, n_pad, CALL_MAX)
    # the calls' distinct shapes (a full call and the rest), new to this process, compile side by
    # side in the background rather than one after the other at their calls
    ahead = {(compiled, min(CALL_MAX, n_pad - i), x.shape[1], q): i for i in starts}
    if len(ahead) > 1 and not set(ahead) <= _COMPILED:
        for future in [compile_ahead(compiled, x[i:i + CALL_MAX], y[i:i + CALL_MAX], mask[i:i + CALL_MAX],
                                     h[i:i + CALL_MAX], c, q) for i in ahead.values()]:
            wait(future)
    _COMPILED.update(ahead)
    calls = [compiled(x[i:i + CALL_MAX], y[i:i + CALL_MAX], mask[i:i + CALL_MAX], h[i:i + CALL_MAX], c, q)
             for i in starts]
    weights = _joined(tuple(res[:-2] for res in calls), n)
    bound, finite = (np.concatenate([np.asarray(res[k]) for res in calls])[:n] for k in (-2, -1))
    return (*weights, bound, finite) if derivatives else (*weights, None, None, None, None, None, bound, finite)

