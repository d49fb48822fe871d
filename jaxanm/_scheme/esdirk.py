"""L-stable, stiffly accurate ESDIRK schemes with an embedded error estimate (Kværnø's).

**Step.**  An ESDIRK of ``s`` stages has an explicit first stage (its slope is the
derivative at the step's start) and ``s - 1`` implicit ones with the same diagonal ``gamma``:

    Y_i = z_i + gamma h Y'_i,    z_i = x_n + h sum_{j < i} a_ij Y'_j,
    F(Y_i, Y'_i, t_n + c_i h) = 0,

so each stage is one implicit-Euler-shaped equation ``F(Y_i, (Y_i - z_i) / (gamma h), t_i) = 0``
and one K* (made at ``gamma h``) serves every stage of every step of that size.  The schemes
are stiffly accurate (the last stage is the solution, at ``c_s = 1``): the last stage's slope
satisfies ``F = 0`` at the new state, and is the next step's first slope (first same as last),
so no derivative is ever computed apart from a stage.  Each stage is solved from
``z_i + gamma h Y'_{i-1}`` (the previous stage's slope for its own: ``z_i`` alone is
``gamma h Y'_i`` away), as diffrax predicts its stages.

**Estimate.**  Kværnø's embedded solution is the stage before the last (also at ``c = 1``),
one order lower; the local error estimate is the difference of the two solutions,
``O(h^order)``, so the controller's exponent is ``1 / order``.

**Start.**  The first step of a run (and the first after a :class:`~jaxanm.Remap`) has no
derivative at its start.  It is taken by Alexander's three-stage SDIRK of order 3 (L-stable,
stiffly accurate, with ESDIRK3's gamma: the same K*), whose stages are all implicit; its
last slope starts the ESDIRK steps.  Its local error is ``O(h^4)``, so the global order of
either ESDIRK stays; it has no embedded estimate, and the first step is taken at the
proposed size, as with the other schemes.

Coefficients: A. Kværnø, "Singly diagonally implicit Runge-Kutta methods with an explicit
first stage", BIT 44 (2004) 489-502 (the 3(2) and 4(3) methods, as documented by diffrax's
``Kvaerno3`` and ``Kvaerno4``); R. Alexander, SIAM J. Numer. Anal. 14 (1977) 1006-1021
(Hairer and Wanner, *Solving ODEs II*, section IV.6).  Gamma is the root of the L-stability
condition ``L_k(1 / gamma) = 0`` (the Laguerre polynomial of degree k, the number of
implicit stages) in double precision, not the published 10 digits;
``tests/test_schemes.py`` checks every order condition, the stiff accuracy and the
stability functions.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from .._acceptance import evaluate_series
from .._checks import integer
from .._hermite import hermite_terms
from .base import Interpolant, SchemeStep, TimeScheme, register


@dataclasses.dataclass(frozen=True, eq=False)
class Tableau:
    """A diagonally implicit Runge-Kutta tableau: ``a`` (s, s) lower triangular, its diagonal
    ``gamma`` but for an explicit first stage (0), ``b_hat`` the embedded weights (None: no
    estimate); stiffly accurate (``b`` is the last row of ``a``), ``c`` the row sums."""

    name: str
    gamma: float
    a: np.ndarray
    b_hat: np.ndarray | None

    @property
    def c(self) -> np.ndarray:
        """The stage times, as fractions of the step."""
        return self.a.sum(axis=1)


def _kvaerno3() -> Tableau:
    """Kværnø's ESDIRK 3(2) with 4 stages (gamma: root of 6 g^3 - 18 g^2 + 9 g - 1, i.e. L_3)."""
    g = 0.43586652150845900
    a = np.zeros((4, 4))
    a[1, :2] = g, g
    a[2, :3] = (-4 * g**2 + 6 * g - 1) / (4 * g), (-2 * g + 1) / (4 * g), g
    a[3, :4] = (6 * g - 1) / (12 * g), -1 / ((24 * g - 12) * g), (-6 * g**2 + 6 * g - 1) / (6 * g - 3), g
    return Tableau("Kværnø ESDIRK3(2)4", g, a, a[2].copy())


def _kvaerno4() -> Tableau:
    """Kværnø's ESDIRK 4(3) with 5 stages (gamma: root of 24 g^4 - 96 g^3 + 72 g^2 - 16 g + 1,
    i.e. L_4)."""
    g = 0.57281606248213485

    def p(*coefficients):
        return np.polyval(coefficients, g)

    a = np.zeros((5, 5))
    a[1, 0] = g
    a[2, :2] = p(144, -180, 81, -15, 1) * g / p(12, -6, 1) ** 2, p(-36, 39, -15, 2) * g / p(12, -6, 1) ** 2
    a[3, :3] = (p(-144, 396, -330, 117, -18, 1) / (12 * g**2 * p(12, -9, 2)),
                p(72, -126, 69, -15, 1) / (12 * g**2 * p(3, -1)),
                p(-6, 6, -1) * p(12, -6, 1) ** 2 / (12 * g**2 * p(12, -9, 2) * p(3, -1)))
    a[4, :4] = (p(288, -312, 120, -18, 1) / (48 * g**2 * p(12, -9, 2)),
                p(24, -12, 1) / (48 * g**2 * p(3, -1)),
                -(p(12, -6, 1) ** 3) / (48 * g**2 * p(3, -1) * p(12, -9, 2) * p(6, -6, 1)),
                p(-24, 36, -12, 1) / p(24, -24, 4))
    a[np.arange(1, 5), np.arange(1, 5)] = g
    return Tableau("Kværnø ESDIRK4(3)5", g, a, a[3].copy())


def _alexander3() -> Tableau:
    """Alexander's SDIRK3 with 3 implicit stages (ESDIRK3's gamma), no embedded estimate."""
    g = 0.43586652150845900
    a = np.zeros((3, 3))
    a[0, 0] = g
    a[1, :2] = (1 - g) / 2, g
    a[2, :3] = -(6 * g**2 - 16 * g + 1) / 4, (6 * g**2 - 20 * g + 5) / 4, g
    return Tableau("Alexander SDIRK3", g, a, None)


TABLEAUS = {3: _kvaerno3(), 4: _kvaerno4()}
"""The ESDIRK tableau of each order."""

START = _alexander3()
"""The tableau of the first step (module docstring, "Start")."""


def dirk_step(tableau: Tableau, x, t: float, h: float, slope, solve):
    """The stages of ``tableau`` from ``x`` at ``t`` over ``h`` (``slope``: the derivative at
    ``x``, for an explicit first stage): ``(end state, its slope, embedded solution or None)``."""
    a, c, gamma_h = tableau.a, tableau.c, tableau.gamma * h
    s = a.shape[0]
    slopes = []
    y = x
    for i in range(s):
        if a[i, i] == 0:  # the explicit first stage: its slope is the derivative at the start
            slopes.append(slope)
            continue
        z = x + h * sum(a[i, j] * slopes[j] for j in range(i)) if i else x
        # solved from the stage with the previous stage's slope (z itself lacks gamma h Y'_i)
        start = z + gamma_h * slopes[-1] if slopes else None
        y = solve(z, t + c[i] * h, gamma_h, last=i == s - 1, start=start)
        slopes.append((y - z) / gamma_h)
    embedded = None
    if tableau.b_hat is not None:
        embedded = x + h * sum(w * k for w, k in zip(tableau.b_hat, slopes) if w != 0)
    return y, slopes[-1], embedded


def hermite(x0, dx0, x1, dx1, order: int) -> Interpolant:
    """The cubic with values ``x0``, ``x1`` and derivatives (in the step's fraction) ``dx0``,
    ``dx1`` at 0 and 1; without ``dx0`` (None) the quadratic with ``x0``, ``x1`` and ``dx1``.
    ``order``: the order its values are given (:class:`~jaxanm.TimeScheme.interpolant`)."""
    delta = x1 - x0
    terms = np.array([2 * delta - dx1, dx1 - delta]) if dx0 is None else hermite_terms(delta, dx0, dx1)
    return Interpolant(lambda theta: x0 + evaluate_series(terms, theta), order=order)


@dataclasses.dataclass(frozen=True)
class ESDIRK(TimeScheme):
    """Kværnø's L-stable, stiffly accurate ESDIRK of ``order`` 3 (name ``"esdirk3"``: four stages,
    three implicit, embedded order 2) or 4 (``"esdirk4"``: five stages, four implicit, embedded
    order 3), with the embedded solution's error estimate and Alexander's SDIRK3 as the first
    step (module docstring).  Its history is the derivative at the step's start.  Needs a
    :class:`~jaxanm.SemiDiscrete` residual.

    The stages of the 4th-order scheme are at ``c = 0, 1.146, 0.597, 1, 1`` of the step: its
    second stage evaluates the residual a little past the step's end.
    """

    order: int = 3

    def __post_init__(self):
        integer("ESDIRK.order", self.order, min(TABLEAUS), max(TABLEAUS),
                hint="Kværnø's ESDIRK3(2)4 and ESDIRK4(3)5; for order 1 use jaxanm.ImplicitEuler(), for order 2 "
                     "jaxanm.BDF2()")
        object.__setattr__(self, "name", f"esdirk{self.order}")
        object.__setattr__(self, "error_order", self.order - 1)

    @property
    def tableau(self) -> Tableau:
        """The tableau of this order."""
        return TABLEAUS[self.order]

    def step(self, history, x, t, h, solve) -> SchemeStep:
        """One ESDIRK step from the derivative ``history`` (the start's SDIRK step without one)."""
        if history is None:
            y, slope, _ = dirk_step(START, x, t, h, None, solve)
            return SchemeStep(y, slope)
        y, slope, embedded = dirk_step(self.tableau, x, t, h, history, solve)
        return SchemeStep(y, slope, embedded)

    def interpolant(self, history, x, step, h) -> Interpolant:
        """Cubic Hermite from the states and slopes at the step's ends (the slopes the stages
        carry: ``history`` at the start, ``step.history`` at the end), as diffrax interpolates
        its ESDIRKs: its own error is ``O(h^4)`` and is not carried to later steps, so the
        values keep the scheme's order.  The start's step has no slope at its start: the
        quadratic with the end's slope, ``O(h^3)`` on that one step."""
        if history is None:
            return hermite(x, None, step.x, h * step.history, order=min(self.order, 3))
        return hermite(x, h * history, step.x, h * step.history, order=self.order)

    def local_error(self, y_new, y_embedded, y_now, past, h):
        """The difference of the solution and the embedded one (None on the start's step)."""
        return None if y_embedded is None else y_new - y_embedded


register("esdirk3", lambda: ESDIRK(order=3))
register("esdirk4", lambda: ESDIRK(order=4))
