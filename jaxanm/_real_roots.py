"""Real roots of a polynomial along a step of a series, on the host (numpy).

Path following reads its end conditions, folds and crossings off each step's series as real
roots of scalar polynomials in the step's parameter.
"""

from __future__ import annotations

import numpy as np


def real_roots(c, hi: float, closed: bool = True) -> np.ndarray:
    """Real roots in ``[0, hi]`` (``[0, hi)`` if not ``closed``; ``hi`` may be inf) of
    ``sum_k c[k] a^k``, sorted: companion-matrix roots of the polynomial in ``a / hi``,
    polished by Newton iterations, kept where the polynomial is zero to round-off."""
    c = np.asarray(c, dtype=np.float64)
    width = hi if np.isfinite(hi) else 1.0
    ct = c * width ** np.arange(c.size)
    nonzero = np.flatnonzero(ct)
    if nonzero.size == 0 or nonzero[-1] == 0:
        return np.zeros(0)
    ct = ct[: nonzero[-1] + 1]
    roots = np.polynomial.polynomial.polyroots(ct)
    t = roots[np.abs(roots.imag) <= 1e-6 * np.maximum(1.0, np.abs(roots))].real
    dt = np.polynomial.polynomial.polyder(ct)
    for _ in range(4):
        slope = np.polynomial.polynomial.polyval(t, dt)
        t = t - np.divide(np.polynomial.polynomial.polyval(t, ct), slope, out=np.zeros_like(t), where=slope != 0)
    size = np.polynomial.polynomial.polyval(np.abs(t), np.abs(ct))
    upper = 1.0 if np.isfinite(hi) else np.inf
    keep = (np.abs(np.polynomial.polynomial.polyval(t, ct)) <= 1e-9 * size) & (t >= -1e-12)
    keep &= (t <= upper + 1e-12) if closed else (t < upper - 1e-12)
    return np.unique(np.clip(t[keep], 0.0, upper)) * width


def sign_changes(c, roots, hi: float) -> np.ndarray:
    """The roots (sorted, in ``[0, hi]``) of ``sum_k c[k] a^k`` across which it changes sign
    (roots of odd multiplicity): its signs midway between neighbouring roots and the ends."""
    roots = np.asarray(roots, dtype=np.float64)
    if roots.size == 0:
        return roots
    edges = np.concatenate([[0.0], roots, [hi]])
    mids = 0.5 * (edges[1:] + edges[:-1])
    signs = np.sign(np.polynomial.polynomial.polyval(mids, np.asarray(c, dtype=np.float64)))
    return roots[signs[:-1] * signs[1:] < 0]
