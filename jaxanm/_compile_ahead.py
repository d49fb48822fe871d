"""Compile a jitted function in the background, before its first call.

XLA compiles with Python's GIL released, so a compilation in another thread runs beside the
caller's own work (another compilation, a factorisation) on a second core.  A program known
before it is needed (the ANM's series programs, as soon as the residual's layout is known; the
value-only MLS kernel, while the cloud's own stencils are built) is handed to
:func:`compile_ahead`, which lowers and compiles it for the arguments' shapes in a small pool
of threads; that fills jax's compilation cache, so the later ordinary call of the same jitted
function on arguments of those shapes runs the compiled program.  The caller waits for the
future before that first call (:func:`wait`): a call that came first would compile the program
again.
"""

from __future__ import annotations

import concurrent.futures

WORKERS = 2
"""Threads of the pool: the machines this runs on have a few cores, and a compilation is
single-threaded."""

_pool: concurrent.futures.ThreadPoolExecutor | None = None


def compile_ahead(jitted, *args) -> concurrent.futures.Future:
    """Lower and compile ``jitted`` for the shapes and dtypes of ``args`` (arrays or
    ``jax.ShapeDtypeStruct``) in a background thread, with the caller's float64 setting."""
    import jax

    global _pool
    if _pool is None:
        _pool = concurrent.futures.ThreadPoolExecutor(WORKERS, thread_name_prefix="jaxanm-compile")
    x64 = bool(jax.config.read("jax_enable_x64"))  # thread-local under jax.enable_x64: the worker sets its own

    def compile_():
        with jax.enable_x64(x64):
            jitted.lower(*args).compile()

    return _pool.submit(compile_)


def wait(future: concurrent.futures.Future | None) -> None:
    """Wait for a compilation started by :func:`compile_ahead` (its error, if any, is raised
    here, as the call it prepared would have raised it); None: nothing to wait for."""
    if future is not None:
        future.result()
