"""The compiled MLS kernel: shape functions of all evaluation points in few jitted calls.

The kernel runs on all evaluation points at once (in equal calls of up to :data:`CALL_MAX`,
each a multiple of :data:`CHUNK`) and depends only on that call size and the stencil width m
(and q): rebuilding stencils for a moved cloud with the same ``m_max`` does not recompile, and
the value-only kernel of a run's targets compiles one shape (:func:`call_shape`).
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


@functools.partial(jax.jit, static_argnames=("n", "m"))
def _joined(parts, n, m):
    """The first n rows and m columns of the concatenation of each array's ``parts`` (a tuple
    per call), on the device: the weights stay jax arrays, for the Stencils, without a copy
    through numpy (a copy per rebuild saved).  Compiled per (n, m, calls): a concatenation and
    a slice."""
    return tuple((jnp.concatenate(p) if len(p) > 1 else p[0])[:n, :m] for p in zip(*parts))


VALUE_WIDTH = 64
"""Least stencil width of a :func:`value_kernel` call: the value-only stencils of targets
(probes, sections, outputs) are made once per run, each set with its own neighbour count, and
their calls are padded to this width (or the next multiple of :data:`WIDTH_MULTIPLE`) and to
:data:`CALL_MAX` rows, so that one shape serves them all: one compilation where each set
compiled its own (the value kernel costs a few ms a call, its compilation about a second)."""

WIDTH_MULTIPLE = 16
"""Widths above :data:`VALUE_WIDTH` of value-only calls are padded to a multiple of this."""


def call_shape(n: int, m: int, derivatives: bool) -> tuple[int, int, int]:
    """``(calls, rows, width)`` of the kernel calls for n stencils of width m.

    The cloud's own stencils (``derivatives``, rebuilt at every step of a moving cloud) keep
    their width and are cut into equal calls of a multiple of :data:`CHUNK` rows, one compiled
    shape per build; value-only ones take calls of :data:`CALL_MAX` rows and at least
    :data:`VALUE_WIDTH` columns."""
    calls = -(-n // CALL_MAX)
    if derivatives:
        return calls, CHUNK * -(-n // (calls * CHUNK)), m
    return calls, CALL_MAX, max(VALUE_WIDTH, WIDTH_MULTIPLE * -(-m // WIDTH_MULTIPLE))


_VALUES_AHEAD: dict = {}
"""(c, q) -> the background compilation of :func:`value_kernel` at its one shape."""


def _values_ahead(c: float, q: int):
    """The compilation of the value-only kernel at the shape of a run's targets, started in the
    background (once per (c, q) and process) when a cloud's own stencils are first built:
    their compilation holds one core, and the targets' stencils come after them."""
    if (c, q) not in _VALUES_AHEAD:
        shape = (CALL_MAX, VALUE_WIDTH)
        _VALUES_AHEAD[(c, q)] = compile_ahead(value_kernel, np.zeros(shape), np.zeros(shape), np.zeros(shape, bool),
                                              np.ones(CALL_MAX), c, q)
    return _VALUES_AHEAD[(c, q)]


def run_kernel(x, y, mask, h, c, q, derivatives=True):
    """Run :func:`kernel` on all evaluation points, in calls of at most :data:`CALL_MAX`:
    ``(phi, dx, dy, dxx, dxy, dyy)`` (n, m) as jax arrays, ``bound, finite`` (n,) in numpy.

    The points are padded (with copies of the first stencil) and the calls shaped by
    :func:`call_shape`, so that the compiled shapes do not depend on N itself; value-only
    stencils are also padded with columns outside the support (zero weight), sliced off the
    results.  The numpy inputs go to the jitted kernel as they are (no separate
    ``jnp.asarray`` dispatches), and every call is dispatched before any result is read.
    Without ``derivatives``, :func:`value_kernel` runs instead and the five derivative arrays
    are None.
    """
    n, m = x.shape
    calls, rows, width = call_shape(n, m, derivatives)
    n_pad = calls * rows

    def padded(a, columns=False):
        if n_pad > n:
            a = np.concatenate([a, np.repeat(a[:1], n_pad - n, axis=0)])
        if columns and width > m:
            a = np.concatenate([a, np.zeros((n_pad, width - m), dtype=a.dtype)], axis=1)
        return a

    x, y, mask, h = padded(x, True), padded(y, True), padded(mask, True), padded(h)
    compiled = kernel if derivatives else value_kernel
    ahead = _values_ahead(c, q)
    if not derivatives and width == VALUE_WIDTH:
        wait(ahead)  # the call below then runs the program compiled in the background
    starts = range(0, n_pad, rows)
    calls_made = [compiled(x[i:i + rows], y[i:i + rows], mask[i:i + rows], h[i:i + rows], c, q) for i in starts]
    weights = _joined(tuple(res[:-2] for res in calls_made), n, m)
    bound, finite = (np.concatenate([np.asarray(res[k]) for res in calls_made])[:n] for k in (-2, -1))
    return (*weights, bound, finite) if derivatives else (*weights, None, None, None, None, None, bound, finite)
