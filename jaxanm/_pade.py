"""Padé approximants of the ANM series with a common denominator (host side, numpy).

The ANM series of one step, ``u(a) = u_0 + sum_{i=1}^p a^i c_i`` (``coeffs[i-1] = c_i``, as in
:mod:`jaxanm._solver.anm`), is replaced by the vector rational fraction of Cochelin, Damil and
Potier-Ferry (Cochelin, Damil and Potier-Ferry 1994, "Asymptotic-numerical methods and Padé
approximants for non-linear elastic structures", Int. J. Numer. Meth. Eng. 37; Elhage-Hussein,
Potier-Ferry and Damil 2000, "A numerical continuation method based on Padé approximants",
Int. J. Solids Struct. 37; the form SANM's ``libsanm/pade.h`` takes from "A critical review of
asymptotic numerical methods", appendix 1):

.. math::

    P_p(a) = u_0 + \\sum_{i=1}^{p-1} a^i \\frac{D_{p-1-i}(a)}{D_{p-1}(a)} c_i,
    \\qquad D_m(a) = 1 + \\sum_{k=1}^{m} d_k a^k ,

one scalar denominator for all unknowns, ``D_m`` the truncation of ``D_{p-1}`` to degree m.
The numerator is the part of degree <= p - 1 of ``D_{p-1}(a) (u(a) - u_0)``, so ``P_p`` agrees
with the series to order p - 1 whatever the ``d_k``; they are chosen so that the order-p term
of ``D_{p-1}(a) (u(a) - u_0)``, the vector ``c_p + sum_k d_k c_{p-k}``, has no component in
the span of ``c_1 .. c_{p-1}``: the least-squares problem

.. math::

    \\min_d \\; \\| c_p + \\sum_{k=1}^{p-1} d_k c_{p-k} \\| ,

in the norm of the solvers (2-norm of ``v / scale``).  With the Gram–Schmidt coordinates
``c_i = sum_{j<=i} alpha_ij u*_j`` of the literature this is the triangular system
``sum_k d_k alpha_{p-k,j} = -alpha_{p,j}`` (j = 1 .. p-1) and gives the same ``d``; here the
orthonormal basis comes from a Householder QR of the scaled coefficients (the same triangular
factor up to signs, with orthogonality to round-off), and every norm below is computed from
the p x p factor, not from n-vectors.

**Degenerate series.**  When ``c_1 .. c_{p-1}`` are (numerically) linearly dependent the
system above is singular (the literature's ``alpha_ii = 0``): a geometric series
``c_i = v / R^i`` (rank 1), exactly vanishing higher coefficients, or the parity zeros
``c_2 = c_3 = 0`` of a cubic residual from rest.  This module takes the denominator of lowest
degree: the columns ``c_{p-1}, c_{p-2}, ..`` (multiplying ``d_1, d_2, ..``) are taken in that
order and a column is left out (its ``d_k = 0``) when its part orthogonal to the columns kept
before it is below :data:`DEPENDENCE` times the largest coefficient; the coefficients are
compared after the change of variable ``a = rho b`` with ``rho = (|c_f| / |c_m|)^(1/(m-f))``
(first and last non-zero coefficients), under which the series' terms are of one size at
b = 1.  For linearly independent coefficients this is the classical approximant; for a
geometric series it is the exact ``[p-1/1]`` fraction; for vanishing higher coefficients the
polynomial itself.

**Validity range** (Elhage-Hussein et al. 2000): ``P_p`` is trusted where it agrees
with the approximant ``P_{p-1}`` built the same way from ``c_1 .. c_{p-1}``,

.. math::

    \\| P_p(a) - P_{p-1}(a) \\| \\le \\text{tol} \\; \\| P_p(a) - u_0 \\| ,

the analogue of the series' eq. 26 (last term against the first-order increment).  ``a_pade``
is the first a > 0 where this fails, searched up to ``limit`` and never past the smallest
positive real root of either denominator (:func:`first_pole`): see :func:`pade_validity_range`.
For p = 2, ``P_1 = u_0`` and the criterion fails at every a > 0: ``a_pade = 0``.
"""

from __future__ import annotations

import dataclasses
from typing import cast

import numpy as np

from .errors import InputError

DEPENDENCE = 1e-10
"""A coefficient direction whose part independent of the columns kept before it is below this
fraction of the largest (rescaled) coefficient is left out of the denominator fit.  Its weight in
the series at ``a = rho`` is then below 1e-10 of the largest term, under the tolerances the ANM
is run with (1e-6 .. 1e-8; an end point is judged by the solver's end-point check whatever
was dropped), yet four orders of magnitude above the round-off of the coefficients themselves
(the parity zeros of tests/test_anm_acceptance.py come out at 1e-14 relative): what is dropped
is noise or exact dependence, and a denominator is never fitted to noise."""

ROOT_IMAG = 1e-6
"""A root ``z`` of a denominator counts as real when ``|Im z| <= ROOT_IMAG |z|``: a double real
root comes out of the companion-matrix eigenvalues as a pair with imaginary parts about
``sqrt(eps) |z| = 1.5e-8 |z|``; 1e-6 leaves a factor ~70 for the conditioning of the
polynomial while a genuinely complex pole that close to the axis would be a spike of the
approximant that the agreement criterion does not resolve."""

GRID_PER_OCTAVE = 16
"""Points per factor of two of the scan for the first failure of the criterion (a spacing of
4.4 % in a: a failure confined to a shorter interval can be missed; the solver's end-point check
still judges any end point)."""

GRID_OCTAVES = 52
"""Octaves scanned below the top of the search interval (down to ``2^-52`` of it, a relative
eps: a range shorter than that is reported as 0)."""

BISECTIONS = 30
"""Bisection steps refining the bracketed first failure (relative precision ``2^-30 * 4.4 %``)."""


@dataclasses.dataclass(frozen=True)
class PadeApproximant:
    """The Padé approximants ``P_p`` and ``P_{p-1}`` of one series (build with :func:`approximant`).

    In the variable ``b = a / rho``, with rescaled coefficients ``ct_i = rho^(i-f) c_i`` (``f``
    the first non-zero coefficient, ``a^i c_i = rho^f b^i ct_i``):

    - ``coeffs (p, n)``: the series coefficients c_1 .. c_p as given;
    - ``scale``: the characteristic magnitudes (norms are of ``v / scale``);
    - ``rho``, ``first``: the change of variable and ``f`` (1-based);
    - ``r (p, p)``: column i - 1 holds the coordinates of ``ct_i / scale`` in an orthonormal
      basis (norms of combinations of coefficients are norms of combinations of these columns);
    - ``e (p-1,)``, ``e_lo (p-2,)``: the denominator coefficients ``d_k rho^k`` (k = 1, 2, ..)
      of ``P_p`` and of ``P_{p-1}``.

    ``zero`` marks an all-zero series (``P_p = u_0``, exact).
    """

    coeffs: np.ndarray
    scale: np.ndarray
    rho: float
    first: int
    r: np.ndarray
    e: np.ndarray
    e_lo: np.ndarray
    zero: bool


def approximant(coeffs, scale) -> PadeApproximant:
    """The Padé approximants of the series ``coeffs (p, n)`` (``coeffs[i-1] = c_i``), p >= 2.

    ``scale`` (scalar or ``(n,)``, > 0): per-unknown characteristic magnitudes, as for
    :func:`jaxanm.validity_range`.  Cost: one QR of the ``(n, p)`` scaled coefficients and
    O(p^3) besides.  The denominators are those of the module docstring (least squares in the
    scaled norm, lowest degree for dependent coefficients).
    """
    coeffs = np.asarray(coeffs, dtype=np.float64)
    if coeffs.ndim != 2 or coeffs.shape[0] < 2:
        raise InputError(f"Padé coefficients must be an array (p, n) with p >= 2 (c_1 .. c_p), got shape "
                         f"{coeffs.shape}: the denominator of order p is fitted on c_p, so p = 1 has none")
    if not np.all(np.isfinite(coeffs)):
        raise InputError("Padé coefficients must be finite: a series with non-finite coefficients has no "
                         "approximant (its validity range is 0: refactorise or shorten the step)")
    p, n = coeffs.shape
    scale = np.broadcast_to(np.asarray(scale, dtype=np.float64), (n,))
    if not (np.all(np.isfinite(scale)) and np.all(scale > 0)):
        raise InputError("Padé scale must be finite and > 0 for every unknown (characteristic magnitudes: "
                         "norms are of v / scale)")
    scaled = coeffs / scale
    norms = np.linalg.norm(scaled, axis=1)
    nonzero = np.flatnonzero(norms > 0)
    if nonzero.size == 0:
        return PadeApproximant(coeffs, scale, 1.0, 1, np.zeros((p, p)), np.zeros(p - 1), np.zeros(max(p - 2, 0)),
                               zero=True)
    f, m = int(nonzero[0]), int(nonzero[-1])  # 0-based
    rho = float((norms[f] / norms[m]) ** (1.0 / (m - f))) if m > f else 1.0
    powers = np.zeros(p)
    powers[nonzero] = rho ** (nonzero - f).astype(np.float64)  # zero coefficients stay zero (no inf * 0)
    # numpy's stubs type every mode of qr as QRResult; mode="r" returns the R factor alone
    r = cast(np.ndarray, np.linalg.qr((scaled * powers[:, None]).T, mode="r"))
    r = np.vstack([r, np.zeros((p - r.shape[0], p))])  # n < p: pad the factor to p x p
    largest = float(np.max(np.linalg.norm(r, axis=0)))
    e = _denominator(r, p, largest)
    e_lo = _denominator(r, p - 1, largest)
    return PadeApproximant(coeffs, scale, rho, f + 1, r, e, e_lo, zero=False)


def _denominator(r, q, largest) -> np.ndarray:
    """``e_k`` (k = 1 .. q-1) of the approximant built on ct_1 .. ct_q (coordinates ``r``): least
    squares ``min |ct_q + sum_k e_k ct_{q-k}|`` over the columns kept in the order k = 1, 2, ...
    (a column nearly dependent on those before it is left out, :data:`DEPENDENCE`)."""
    e = np.zeros(q - 1)
    basis: list[np.ndarray] = []
    kept: list[int] = []
    for k in range(1, q):
        v = r[:, q - k - 1].copy()
        for _ in range(2):  # Gram–Schmidt twice: orthogonal to round-off
            for b in basis:
                v -= (b @ v) * b
        size = float(np.linalg.norm(v))
        if size > DEPENDENCE * largest:
            basis.append(v / size)
            kept.append(k)
    if kept:
        columns = np.stack([r[:, q - k - 1] for k in kept], axis=1)
        e[np.array(kept) - 1] = np.linalg.lstsq(columns, -r[:, q - 1], rcond=None)[0]
    return e


def _weights(e, b) -> np.ndarray:
    """``w_i(b) = b^i D_{q-1-i}(b) / D_{q-1}(b)`` for i = 1 .. q-1 (``q - 1 = len(e)``), at each b.

    Returns ``(len(b), q - 1)``; ``D_m`` is the truncation of ``1 + sum_k e_k b^k`` to degree m.
    """
    b = np.asarray(b, dtype=np.float64)[:, None]
    q1 = e.size
    if q1 == 0:
        return np.zeros((b.shape[0], 0))
    k = np.arange(q1 + 1)
    terms = np.concatenate([[1.0], e])[None, :] * b ** k  # e_k b^k, k = 0 .. q-1
    partial = np.cumsum(terms, axis=1)  # D_0(b) .. D_{q-1}(b)
    i = np.arange(1, q1 + 1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        return b ** i * partial[:, q1 - i] / partial[:, q1:q1 + 1]


def evaluate(approx: PadeApproximant, a: float) -> np.ndarray:
    """The increment ``P_p(a) - u_0 = sum_{i=1}^{p-1} a^i D_{p-1-i}(a) / D_{p-1}(a) c_i`` (n-vector),
    the counterpart of :func:`jaxanm.evaluate_series` (non-finite at a pole of ``D_{p-1}``)."""
    inc = np.zeros(approx.coeffs.shape[1])
    if approx.zero:
        return inc
    w = _weights(approx.e, [a / approx.rho])[0]
    for i, wi in enumerate(w, start=1):
        if np.any(approx.coeffs[i - 1]):  # a zero c_i adds nothing (and rho^i may overflow)
            inc += (wi * approx.rho ** i) * approx.coeffs[i - 1]
    return inc


def _roots_positive_real(e, rho) -> float:
    """Smallest positive real root in a (= rho b) of ``1 + sum_k e_k b^k``, or inf."""
    poly = np.trim_zeros(np.concatenate([[1.0], e]), "b")
    if poly.size < 2:
        return np.inf
    z = np.roots(poly[::-1])
    real = z[(np.abs(z.imag) <= ROOT_IMAG * np.abs(z)) & (z.real > 0)].real
    return float(rho * real.min()) if real.size else np.inf


def first_pole(approx: PadeApproximant) -> float:
    """Smallest positive real root in a of the denominators ``D_{p-1}`` (of ``P_p``) and
    ``D_{p-2}`` (of ``P_{p-1}``, the approximant that vouches for it), or inf.

    Real: ``|Im z| <= ROOT_IMAG |z|`` (:data:`ROOT_IMAG`).
    """
    if approx.zero:
        return np.inf
    return min(_roots_positive_real(approx.e, approx.rho), _roots_positive_real(approx.e_lo, approx.rho))


def _ratios(approx: PadeApproximant, a, state_norm: float) -> np.ndarray:
    """``|P_p(a) - P_{p-1}(a)| / max(|P_p(a) - u_0|, state_norm)`` at each a (scaled norm)."""
    b = np.asarray(a, dtype=np.float64) / approx.rho
    p = approx.r.shape[0]
    w_hi = _weights(approx.e, b)  # (len(a), p - 1)
    w_lo = np.zeros_like(w_hi)
    w_lo[:, : p - 2] = _weights(approx.e_lo, b)
    hi = w_hi @ approx.r[:, : p - 1].T  # coordinates of (P_p - u_0) / rho^f
    diff = (w_hi - w_lo) @ approx.r[:, : p - 1].T
    size = np.maximum(np.linalg.norm(hi, axis=1), state_norm / approx.rho ** approx.first)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.linalg.norm(diff, axis=1) / size
    return np.where(np.isfinite(ratio), ratio, np.inf)


def pade_validity_range(approx: PadeApproximant, tol: float, limit: float = 1.0, state=None) -> float:
    """a_pade: the largest a up to which ``P_p`` is trusted, ``0 <= a_pade <= limit``.

    The criterion ``|P_p(a) - P_{p-1}(a)| <= tol |P_p(a) - u_0|`` (with ``state`` the series'
    start u_0: ``tol max(|P_p(a) - u_0|, |u_0|)``, as ``criterion="state"`` of
    :class:`jaxanm.ANM`) is scanned on ``a_k = a_top 2^(-k/16)``, k = 16*52 .. 0, upwards, where
    ``a_top = min(limit, first_pole(approx))``; the top point is left out when it is a pole.
    The first failure is refined by :data:`BISECTIONS` bisections against the point before it,
    and a_pade is the last point where the criterion held (0 when it fails at the smallest);
    ``a_top`` (or the last grid point before the pole) when it never fails.  So a_pade is always
    a point where the criterion was verified and lies strictly before the first pole.
    An all-zero series gives ``limit`` (``P_p = u_0`` is exact).
    """
    if not (np.isfinite(tol) and tol > 0):
        raise InputError(f"Padé tol must be a finite float > 0, got {tol!r}")
    if not (np.isfinite(limit) and limit > 0):
        raise InputError(f"Padé limit must be a finite float > 0 (the farthest a searched), got {limit!r}")
    if approx.zero:
        return float(limit)
    state_norm = 0.0 if state is None else float(np.linalg.norm(np.asarray(state) / approx.scale))
    pole = first_pole(approx)
    top = min(float(limit), pole)
    k = np.arange(GRID_PER_OCTAVE * GRID_OCTAVES, -1, -1)  # a ascending, k = 0 is a_top
    if pole <= limit:
        k = k[:-1]
    grid = top * 2.0 ** (-k / GRID_PER_OCTAVE)
    fails = np.flatnonzero(_ratios(approx, grid, state_norm) > tol)
    if fails.size == 0:
        return float(grid[-1])
    if fails[0] == 0:
        return 0.0
    good, bad = float(grid[fails[0] - 1]), float(grid[fails[0]])
    for _ in range(BISECTIONS):
        mid = 0.5 * (good + bad)
        if _ratios(approx, [mid], state_norm)[0] > tol:
            bad = mid
        else:
            good = mid
    return good
