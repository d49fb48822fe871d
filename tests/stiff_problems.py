"""Classical stiff initial-value problems as implicit-Euler step residuals and in semi-discrete
form, with references.

Each problem ``x' = f(x)`` is written as the step residual ``(x - x_old) / dt - f(x)`` that
:func:`jaxanm.integrate` solves by implicit Euler, and as ``F(u, u_dot) = u_dot - f(u)``
(:attr:`Stiff.semi_discrete`) for every time scheme and for IDA.  :func:`problem` returns a
:class:`Stiff` with the residuals, the initial state, the span and the reference solution at
its end: the published value of the Test Set for IVP Solvers (Mazzia and Magherini, release
2.4, 2008) where the span is the test set's (HIRES, OREGO), else scipy's
``solve_ivp(method="Radau", rtol=1e-12)`` computed once and stored here
(:func:`radau_reference` recomputes it; the test set's values are checked against it in
tests/test_stiff_controller.py).

- ``robertson``: Robertson's chemical kinetics (ROBER), rate constants 0.04, 1e4, 3e7.
- ``vanderpol``: the van der Pol relaxation oscillator ``y'' = mu (1 - y^2) y' - y`` with
  mu = 1000 (MATLAB's vdp1000), from (2, 0): two relaxation jumps in [0, 3000], one in
  ``problem("vanderpol", t1=1000.0)``.
- ``hires``: the 8-species HIRES photochemistry (Schäfer 1975), over [0, 321.8122].
- ``orego``: the Oregonator (OREGO, the Belousov-Zhabotinskii reaction), over [0, 360].
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np


@dataclasses.dataclass(frozen=True, eq=False)
class Stiff:
    """One stiff problem: ``rhs(y)`` (traceable by jax), ``x0``, the span ``[0, t1]``, a first step ``dt0``,
    ``scale`` (the largest magnitude of each unknown over the span) and ``reference`` (the
    solution at ``t1``)."""

    name: str
    rhs: object
    x0: np.ndarray
    t1: float
    dt0: float
    scale: np.ndarray
    reference: np.ndarray

    @property
    def residual(self):
        """Implicit Euler step residual ``(x - x_old) / dt - f(x)``."""
        return _residual(self.rhs)

    @property
    def semi_discrete(self):
        """``jaxanm.SemiDiscrete(F)`` with ``F(u, u_dot, t, params) = u_dot - f(u)``."""
        return _semi_discrete(self.rhs)


@functools.lru_cache(maxsize=None)
def _residual(rhs):
    """The step residual of ``rhs``: one function per right-hand side, so that every run of it
    shares the compiled code."""

    def residual(x, x_old, t, dt, params):
        return (x - x_old) / dt - rhs(x)

    return residual


@functools.lru_cache(maxsize=None)
def _semi_discrete(rhs):
    """The semi-discrete residual of ``rhs``: one object per right-hand side (shared compiled code)."""
    import jaxanm

    def F(u, u_dot, t, params):
        return u_dot - rhs(u)

    return jaxanm.SemiDiscrete(F)


# Each right-hand side is written as a jaxanm residual is meant to be, on arrays: its linear
# part as one matrix product, its nonlinear part as elementwise products (component by
# component with scalars, the affine split of the series would carry 7-16 scalar frontier
# values and each series order would cost 3-6 residual evaluations in dispatch alone).

ROBERTSON_LINEAR = np.array([[-0.04, 0.0, 0.0], [0.04, 0.0, 0.0], [0.0, 0.0, 0.0]])


def _robertson(y):
    """ROBER: y1' = -0.04 y1 + 1e4 y2 y3, y2' = 0.04 y1 - 1e4 y2 y3 - 3e7 y2^2, y3' = 3e7 y2^2."""
    y2 = y[1]
    return (ROBERTSON_LINEAR @ y + (1e4 * y2 * y[2]) * np.array([1.0, -1.0, 0.0])
            + (3e7 * y2 * y2) * np.array([0.0, -1.0, 1.0]))


VDP_MU = 1000.0


def _vanderpol(y):
    """y1' = y2, y2' = mu (1 - y1^2) y2 - y1."""
    return np.array([[0.0, 1.0], [-1.0, VDP_MU]]) @ y - (VDP_MU * y[0] ** 2 * y[1]) * np.array([0.0, 1.0])


HIRES_LINEAR = np.array([
    [-1.71, 0.43, 8.32, 0.0, 0.0, 0.0, 0.0, 0.0],
    [1.71, -8.75, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, -10.03, 0.43, 0.035, 0.0, 0.0, 0.0],
    [0.0, 8.32, 1.71, -1.12, 0.0, 0.0, 0.0, 0.0],
    [0.0, 0.0, 0.0, 0.0, -1.745, 0.43, 0.43, 0.0],
    [0.0, 0.0, 0.0, 0.69, 1.71, -0.43, 0.69, 0.0],
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.81, 0.0],
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.81, 0.0],
])
HIRES_SOURCE = np.array([0.0007, 0, 0, 0, 0, 0, 0, 0])
HIRES_REACTION = np.array([0.0, 0, 0, 0, 0, -280.0, 280.0, -280.0])


def _hires(y):
    """HIRES: linear rates, a source and the one bimolecular reaction 280 y6 y8."""
    return HIRES_LINEAR @ y + HIRES_SOURCE + (y[5] * y[7]) * HIRES_REACTION


OREGO_LINEAR = np.array([[77.27, 77.27, 0.0], [0.0, -1.0 / 77.27, 1.0 / 77.27], [0.161, 0.0, -0.161]])


def _orego(y):
    """OREGO: y1' = 77.27 (y2 + y1 (1 - 8.375e-6 y1 - y2)), y2' = (y3 - (1 + y1) y2) / 77.27,
    y3' = 0.161 (y1 - y3)."""
    y1, y2 = y[0], y[1]
    return (OREGO_LINEAR @ y + (y1 * y2) * np.array([-77.27, -1.0 / 77.27, 0.0])
            - (77.27 * 8.375e-6 * y1 * y1) * np.array([1.0, 0.0, 0.0]))


# Test Set for IVP Solvers, release 2.4: HIRES at t = 321.8122, OREGO at t = 360
HIRES_REFERENCE = np.array([0.7371312573325668e-3, 0.1442485726316185e-3, 0.5888729740967575e-4,
                            0.1175651343283149e-2, 0.2386356198831331e-2, 0.6238968252742796e-2,
                            0.2849998395185769e-2, 0.2850001604814231e-2])
OREGO_REFERENCE = np.array([0.1000814870318523e1, 0.1228178521549917e4, 0.1320554942846706e3])
# radau_reference() (atol 1e-14)
ROBERTSON_REFERENCE = np.array([7.158270687193e-01, 9.185534764557e-06, 2.841637457462e-01])
VANDERPOL_REFERENCE = np.array([-1.5106069367441899e+00, 1.1783800007307121e-03])
VANDERPOL_1000_REFERENCE = np.array([-1.8636462548081227e+00, 7.5354308654355169e-04])  # one jump, at t ~ 807

# scale: max |y_i(t)| over the span (Radau, rtol 1e-7), rounded up
PROBLEMS = {
    "robertson": dict(rhs=_robertson, x0=np.array([1.0, 0.0, 0.0]), t1=40.0, dt0=1e-6,
                      scale=np.array([1.0, 3.7e-5, 0.29]), reference=ROBERTSON_REFERENCE),
    "vanderpol": dict(rhs=_vanderpol, x0=np.array([2.0, 0.0]), t1=3000.0, dt0=1e-6,
                      scale=np.array([2.0, 1334.0]), reference=VANDERPOL_REFERENCE),
    "hires": dict(rhs=_hires, x0=np.array([1.0, 0, 0, 0, 0, 0, 0, 0.0057]), t1=321.8122, dt0=1e-6,
                  scale=np.array([1.0, 0.133, 0.0196, 0.459, 0.187, 0.75, 0.00566, 0.0057]),
                  reference=HIRES_REFERENCE),
    "orego": dict(rhs=_orego, x0=np.array([1.0, 2.0, 3.0]), t1=360.0, dt0=1e-6,
                  scale=np.array([1.18e5, 1769.0, 31264.0]), reference=OREGO_REFERENCE),
}


SHORTER = {("vanderpol", 1000.0): VANDERPOL_1000_REFERENCE}
"""References at other ends of the span, by (name, t1)."""


@functools.lru_cache(maxsize=None)
def problem(name: str, t1: float | None = None) -> Stiff:
    """The stiff problem ``name`` (a key of :data:`PROBLEMS`), over its span or, with ``t1``,
    over ``[0, t1]`` (a key of :data:`SHORTER`)."""
    spec = dict(PROBLEMS[name])
    if t1 is not None:
        spec.update(t1=t1, reference=SHORTER[(name, t1)])
    return Stiff(name=name, **spec)


def error(p: Stiff, x) -> float:
    """The largest relative error ``|x_i - ref_i| / |ref_i|`` at ``t1`` (no reference component is 0)."""
    return float(np.max(np.abs(np.asarray(x) - p.reference) / np.abs(p.reference)))


def radau_reference(p: Stiff, atol: float = 1e-14) -> np.ndarray:
    """``solve_ivp(method="Radau", rtol=1e-12)`` at ``p.t1``, with the analytic Jacobian."""
    import jax
    import scipy.integrate

    with jax.enable_x64(True):
        f = jax.jit(p.rhs)
        jac = jax.jit(jax.jacfwd(p.rhs))
        sol = scipy.integrate.solve_ivp(lambda t, y: np.asarray(f(y)), (0.0, p.t1), p.x0, method="Radau",
                                        rtol=1e-12, atol=atol, jac=lambda t, y: np.asarray(jac(y)))
    return sol.y[:, -1]
