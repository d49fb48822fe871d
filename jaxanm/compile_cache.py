"""JAX's persistent compilation cache for the ``jaxanm`` command.

Most of a short run's wall time is XLA compiling the residual, its coloured Jacobian and the
series jets.  JAX can keep compiled executables on disk and reuse them in a later process;
on CPU with the locked jax a second process hits the entries the first wrote (checked with
the cache's debug log; tests/test_compile_cache.py runs two processes).  Only compilations that took at least
JAX's ``jax_persistent_cache_min_compile_time_secs`` (1 s by default) are stored.

The ``jaxanm`` command turns the cache on by default, in a per-user directory; ``--no-compile-
cache`` or the environment variable ``JAXANM_COMPILE_CACHE=0`` turn it off, and
``JAXANM_COMPILE_CACHE_DIR`` moves it.  Library use (``import jaxanm``) never changes JAX's
configuration: call :func:`enable` yourself to get the same behaviour.
"""

from __future__ import annotations

import os
from pathlib import Path

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
    return path
