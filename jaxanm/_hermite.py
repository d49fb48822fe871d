"""The cubic Hermite interpolant of a step, as the coefficients of a polynomial in the step's
parameter: the dense output of the ESDIRK time schemes and the step of Newton's path follower
share it (each evaluates it with :func:`jaxanm._acceptance.evaluate_series`)."""

from __future__ import annotations

import numpy as np


def hermite_terms(delta, d0, d1, a: float = 1.0) -> np.ndarray:
    """The coefficients of ``a, a^2, a^3`` of the cubic ``p`` with ``p(0) = 0``, ``p(a) = delta``,
    ``p'(0) = d0`` and ``p'(a) = d1`` (arrays of one shape): ``(3, ...)``."""
    mean = delta / a
    return np.array([d0, (3 * mean - 2 * d0 - d1) / a, (d0 + d1 - 2 * mean) / a**2])
