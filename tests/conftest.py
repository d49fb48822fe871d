"""Shared test fixtures: small model problems with known behaviour.

No global JAX configuration is changed here: jaxanm's entry points must keep float64 on
their own (tests/test_core.py checks it).
"""

import os

# The jaxanm command keeps compiled code in ~/.cache/jaxanm by default (jaxanm.compile_cache):
# the tests that call it in-process must not write there nor change JAX's configuration for
# the tests after them; tests/test_compile_cache.py turns it on explicitly, in a temporary dir.
os.environ.setdefault("JAXANM_COMPILE_CACHE", "0")
