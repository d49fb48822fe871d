"""The MLS kernel: shape functions of all evaluation points, on the host or compiled.

The same formulas (:func:`jaxanm.mls._shape.shape_functions`) run two ways, chosen by the
caller (:func:`run_kernel`'s ``compiled``):

- on the host by numpy (:func:`host_kernel`), in blocks of :data:`HOST_BLOCK` rows, for
  stencils built once (a run's fixed cloud, its probes and sections): a build is slower than
  the compiled kernel's by milliseconds to tens of milliseconds and compiles nothing, where
  each kernel's compilation takes over a second;
- jitted (:func:`kernel`, :func:`value_kernel`), for stencils rebuilt call after call (a
  moving cloud, tracers): on all evaluation points at once, in equal calls of up to
  :data:`CALL_MAX`, each a multiple of :data:`CHUNK`, so that the kernel depends only on
  that call size and the stencil width m (and q): rebuilding stencils for a moved cloud with
  the same ``m_max`` does not recompile, and the value-only kernel compiles one shape
  (:func:`call_shape`).

The two differ by round-off (XLA fuses and contracts operations that numpy rounds one by one).
The measurements are in ``benchmarks/results/mls_host_kernel.md`` (builds) and
``benchmarks/results/cold_start.md`` (a first run).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .._compile_ahead import compile_ahead, wait
from .._x64 import entry_point
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
    *weights, bound = _blocks(lambda *a: shape_functions(*a, c, q), x, y, mask)
    # the barrier: the finite test reads the outputs instead of fusing (recomputing) them
    out = jax.lax.optimization_barrier(_per_length(weights, h))
    return (*out, bound, _finite(out, jnp))


def _per_length(weights, h):
    """The six weight arrays with the derivatives' scaled coordinates undone: first derivatives
    divided by each point's ``h``, second ones by ``h^2``."""
    phi, px, py, pxx, pxy, pyy = weights
    h1 = h[:, None]
    h2 = h1 * h1
    return (phi, px / h1, py / h1, pxx / h2, pxy / h2, pyy / h2)


def _finite(weights, xp):
    """Per row, whether every weight array is finite there: ``a * 0`` is 0 for finite ``a`` and
    NaN otherwise, so one sum instead of a boolean reduction per array."""
    return xp.isfinite(xp.sum(sum(a * 0.0 for a in weights), axis=1))


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


@entry_point
def compile_values_ahead(c: float = 0.2, q: int = 1):
    """Start compiling, in the background, the value-only kernel that ``evaluate_at(...,
    derivatives=False, compiled=True)`` runs for targets of up to :data:`VALUE_WIDTH`
    neighbours (once per ``(c, q)`` and process), and return its pending compilation: for a
    caller that will evaluate moving targets at every step (tracers, material points), so that
    the compilation overlaps its setup instead of delaying its first step."""
    c, q = float(c), int(q)
    if (c, q) not in _VALUES_AHEAD:
        shape = (CALL_MAX, VALUE_WIDTH)
        _VALUES_AHEAD[(c, q)] = compile_ahead(value_kernel, np.zeros(shape), np.zeros(shape), np.zeros(shape, bool),
                                              np.ones(CALL_MAX), c, q)
    return _VALUES_AHEAD[(c, q)]


HOST_BLOCK = 128
"""Rows per block of :func:`host_kernel`: its (block, m) temporaries then stay in the caches,
where whole-cloud arrays would stream through memory for each of the kernel's operations."""


def host_kernel(x, y, mask, h, c, q, derivatives=True):
    """:func:`kernel` (with ``derivatives``) or :func:`value_kernel` evaluated by numpy on the
    host, by blocks of :data:`HOST_BLOCK` rows: the same outputs as :func:`run_kernel`, as
    numpy arrays, without compiling anything."""
    blocks = []
    with np.errstate(all="ignore"):  # a singular moment matrix gives non-finite values: flagged below
        for i in range(0, x.shape[0], HOST_BLOCK):
            rows = slice(i, i + HOST_BLOCK)
            blocks.append(shape_functions(x[rows], y[rows], mask[rows], c, q, derivatives, xp=np))
        *weights, bound = (np.concatenate(p) for p in zip(*blocks))
        if derivatives:
            weights = list(_per_length(weights, h))
        finite = _finite(weights, np)
    if derivatives:
        return (*weights, bound, finite)
    return (weights[0], None, None, None, None, None, bound, finite)


def run_kernel(x, y, mask, h, c, q, derivatives=True, compiled=False):
    """The shape functions of all evaluation points: ``(phi, dx, dy, dxx, dxy, dyy)`` (n, m)
    and ``bound, finite`` (n,) in numpy; ``compiled=False``: by :func:`host_kernel` (the
    weights in numpy), else by :func:`kernel` in calls of at most :data:`CALL_MAX` (the
    weights as jax arrays).

    The points are padded (with copies of the first stencil) and the calls shaped by
    :func:`call_shape`, so that the compiled shapes do not depend on N itself; value-only
    stencils are also padded with columns outside the support (zero weight), sliced off the
    results.  The numpy inputs go to the jitted kernel as they are (no separate
    ``jnp.asarray`` dispatches), and every call is dispatched before any result is read.
    Without ``derivatives``, :func:`value_kernel` runs instead and the five derivative arrays
    are None.
    """
    if not compiled:
        return host_kernel(x, y, mask, h, c, q, derivatives)
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
    program = kernel if derivatives else value_kernel
    if not derivatives and width == VALUE_WIDTH:
        wait(compile_values_ahead(c, q))  # the call below then runs the program compiled in the background
    starts = range(0, n_pad, rows)
    calls_made = [program(x[i:i + rows], y[i:i + rows], mask[i:i + rows], h[i:i + rows], c, q) for i in starts]
    weights = _joined(tuple(res[:-2] for res in calls_made), n, m)
    bound, finite = (np.concatenate([np.asarray(res[k]) for res in calls_made])[:n] for k in (-2, -1))
    return (*weights, bound, finite) if derivatives else (*weights, None, None, None, None, None, bound, finite)
