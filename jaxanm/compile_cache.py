"""JAX's persistent compilation cache for the ``jaxanm`` command.

Most of a short run's wall time is XLA compiling the residual, its coloured Jacobian and the
series jets.  JAX can keep compiled executables on disk and reuse them in a later process;
on CPU with the locked jax a second process hits the entries the first wrote (checked with
the cache's debug log; tests/test_compile_cache.py runs two processes).  :func:`enable` stores
every compilation (:data:`MIN_COMPILE_TIME_S`), where JAX by default stores only those that took
at least 1 s: most of a run's programs compile faster than that, and a warm run recompiled them.

The ``jaxanm`` command turns the cache on by default, in a per-user directory; ``--no-compile-
cache`` or the environment variable ``JAXANM_COMPILE_CACHE=0`` turn it off, and
``JAXANM_COMPILE_CACHE_DIR`` moves it.  Library use (``import jaxanm``) never changes JAX's
configuration: call :func:`enable` yourself to get the same behaviour.
"""

from __future__ import annotations

import os
from pathlib import Path

MIN_COMPILE_TIME_S = 0.0
"""Programs that compiled in at least this many seconds are stored (JAX's default is 1 s)."""

OFF_VALUES = ("0", "off", "false", "no")
"""Values of ``JAXANM_COMPILE_CACHE`` that turn the cache off."""


def default_directory() -> Path:
    """``$JAXANM_COMPILE_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxanm/jax-<version>`` (XDG default
    ``~/.cache``): one directory per jax version, since entries of another version never hit."""
    import jax

    explicit = os.environ.get("JAXANM_COMPILE_CACHE_DIR")
    if explicit:
        return Path(explicit)
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "jaxanm" / f"jax-{jax.__version__}"


def requested() -> bool:
    """Whether the environment leaves the cache on (``JAXANM_COMPILE_CACHE`` not in :data:`OFF_VALUES`)."""
    return os.environ.get("JAXANM_COMPILE_CACHE", "1").strip().lower() not in OFF_VALUES


def enable(directory: str | os.PathLike | None = None) -> Path | None:
    """Point JAX's persistent compilation cache at ``directory`` (default :func:`default_directory`).

    Returns the directory, or None when it cannot be created (the run then compiles as
    without a cache; nothing else changes).  Call it before the first compilation.
    """
    import jax

    path = Path(directory) if directory is not None else default_directory()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    # every program, not only those compiling for more than JAX's default 1 s: the MLS kernels
    # and the small jets compile in 0.1-1 s each and would be compiled again by every run
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    return path
