"""float64 for every entry point, without flipping JAX's global configuration.

Taylor coefficients lose everything in float32 (a 7th-order coefficient is a
difference of terms ~1e7 times larger), so every public entry point of jaxanm
runs inside ``jax.enable_x64(True)``.  The global flag is left as the user set it.
"""

from __future__ import annotations

import functools

import jax

float64 = jax.enable_x64
"""Context manager: ``with jaxanm.float64(): ...`` runs user jnp code in float64."""


def entry_point(fn):
    """Decorate a public function so that it always runs in float64."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with jax.enable_x64(True):
            return fn(*args, **kwargs)

    return wrapper
