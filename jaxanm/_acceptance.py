"""When an ANM series is accepted: its validity range (eq. 26), its sum, and the end-point check.

Shared by the ANM step solver and the ANM path following (:func:`jaxanm.continuation`).
"""

from __future__ import annotations

import numpy as np

CHECK_LIMIT = 10.0
"""An accepted series' end point may miss the accuracy eq. 26 promised (``tol |c_1|``, or
``tol |d_s|`` for ``criterion="state"``) by at most this factor in its Newton distance
``|K*^-1 R(d_end)|`` (a series whose a_max is just above 1 has a tail beyond order p of a few
times ``|c_p|``; ``benchmarks/hard_cases.py`` uses the same limit for its independent check)."""

CHECK_ROUND_OFF = 1e-12
"""Floor of the promised accuracy, relative to the end point: once the increment ``c_1`` of a
(quasi-)steady step is below round-off, ``tol |c_1|`` is below what double precision resolves."""

CRITERIA = ("increment", "state")
"""What the ANM's ``tol`` is relative to (see :class:`jaxanm.ANM`)."""


def reference_state(criterion: str, d_s):
    """The state a criterion measures the series against: ``d_s`` for ``"state"``, else None
    (``"increment"``: the first coefficient alone, the paper's eq. 26)."""
    return d_s if criterion == "state" else None


def validity_range(coeffs: np.ndarray, scale, tol: float, state=None) -> float:
    """a_max of eq. 26: ``(tol ||c_1|| / ||c_p||)^(1/(p-1))`` on the scaled unknowns.

    With ``state`` (the series' starting point d_s), the larger of eq. 26 and the range where
    the last term stays below ``tol`` relative to the state, ``(tol ||d_s|| / ||c_p||)^(1/p)``
    (the criterion of :class:`~jaxanm.ANM` with ``criterion="state"``).
    ``inf`` when the last coefficient vanishes (the series is exact); ``0`` when the first does
    not but a coefficient is non-finite.
    """
    state_norm = None if state is None else float(np.linalg.norm(state / scale))
    return range_of_norms(coeffs.shape[0], float(np.linalg.norm(coeffs[0] / scale)),
                          float(np.linalg.norm(coeffs[-1] / scale)), tol, state_norm)


def range_of_norms(p: int, n1: float, np_: float, tol: float, state_norm: float | None = None) -> float:
    """:func:`validity_range` of a series of order ``p`` from the scaled norms of its first and
    last coefficients (and of the state, for ``criterion="state"``), for a caller that keeps
    the norms that do not change from order to order."""
    if not (np.isfinite(n1) and np.isfinite(np_)):
        return 0.0
    if np_ == 0.0:
        return np.inf
    amax = float((tol * n1 / np_) ** (1.0 / (p - 1)))
    if state_norm is not None:
        amax = max(amax, float((tol * state_norm / np_) ** (1.0 / p)))
    return amax


def next_order_suffices(j: int, n1: float, n_previous: float, n_j: float, tol: float,
                        state_norm: float | None, max_rate: float) -> bool:
    """Whether order ``j + 1`` of a series is predicted to reach a = 1 (:func:`range_of_norms`
    at order j + 1) from the contraction of its last two coefficients, ``|c_j| / |c_(j-1)|``
    (scaled norms ``n_j``, ``n_previous``; ``n1`` that of ``c_1``), when that contraction is at
    most ``max_rate``: the geometric progression of a series whose partial sums are
    modified-Newton iterates (``docs/method/modified-newton.md``).  False for ``max_rate`` 0
    or a last coefficient that vanished (no prediction from a ratio of round-off)."""
    if not (n_previous > 0.0 and n_j > 0.0 and np.isfinite(n_j)):
        return False
    rate = n_j / n_previous
    return rate <= max_rate and range_of_norms(j + 1, n1, rate * n_j, tol, state_norm) >= 1.0


def evaluate_series(coeffs: np.ndarray, a: float) -> np.ndarray:
    """``sum_j a^j c_j`` by Horner's rule (``coeffs[j-1] = c_j``)."""
    acc = np.zeros_like(coeffs[0])
    for c in coeffs[::-1]:
        acc = (acc + c) * a
    return acc


def promised_accuracy(norm, tol: float, c_1, d_end, state=None) -> float:
    """What an accepted series promised of its end point ``d_end``, in the scaled ``norm``:
    ``tol |c_1|`` (with ``state``: at least ``tol |state|``), floored at
    :data:`CHECK_ROUND_OFF` ``|d_end|`` and the smallest positive double."""
    promised = tol * norm(c_1)
    if state is not None:
        promised = max(promised, tol * norm(state))
    return max(promised, CHECK_ROUND_OFF * norm(d_end), np.finfo(float).tiny)
