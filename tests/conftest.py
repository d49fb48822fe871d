"""Shared test fixtures: small model problems with known behaviour.

The one global JAX setting changed here is the persistent compilation cache (below): it only
lets a test reuse the executable another test compiled from the same program, so no result
changes.  Float64 is never turned on globally: jaxanm's entry points must keep it on their own
(tests/test_core.py checks it).
"""

import os
import shutil
import tempfile

# The jaxanm command keeps compiled code in ~/.cache/jaxanm by default (jaxanm.compile_cache):
# the tests that call it in-process must not write there nor change JAX's configuration for
# the tests after them; tests/test_compile_cache.py turns it on explicitly, in a temporary dir.
os.environ.setdefault("JAXANM_COMPILE_CACHE", "0")

TEST_CACHE_ENV = "JAXANM_TEST_XLA_CACHE"
"""Directory of the test run's compilation cache, made by the controlling pytest process and
inherited by its xdist workers."""


def pytest_configure(config):
    """One persistent XLA compilation cache for the whole run, shared by its xdist workers.

    Many tests build the same small scenes and compile the same residuals, Jacobians and jets
    (in another closure, so JAX's in-memory cache misses): with the cache each program compiles
    once per run instead of once per test and worker.  A fresh directory per run keeps runs
    independent; it is removed when the run ends.
    """
    import jax

    if TEST_CACHE_ENV not in os.environ:
        os.environ[TEST_CACHE_ENV] = tempfile.mkdtemp(prefix="jaxanm-test-xla-")
        config._jaxanm_cache_owner = True  # the controlling process removes it at the end
    jax.config.update("jax_compilation_cache_dir", os.environ[TEST_CACHE_ENV])
    # every compilation, not only those over JAX's default of 1 s: most here take 0.1-1 s
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


def pytest_unconfigure(config):
    """Remove the run's compilation cache (in the process that made it)."""
    if getattr(config, "_jaxanm_cache_owner", False):
        shutil.rmtree(os.environ.pop(TEST_CACHE_ENV), ignore_errors=True)

