"""The motion of passive material points (tracers): :func:`jaxanm.fsw.lagrangian.advect`, the
update the run's recorder calls, on prescribed velocity fields.

The tool turns at omega = 20 rad/s; a step controller's largest steps (5e-3 to 1e-2 s) turn the
flow by 0.1-0.2 rad.  ``x + dt V`` drifts outwards on circles by ``omega^2 r dt / 2`` per unit
time (1.4 % of r over 0.7 s at dt = 1e-4; at dt = 1e-2 the radius grows to
``(1 + (omega dt)^2)^(n/2)`` = 3.9 times r, out of the plate); the polar midpoint rule of
``advect`` keeps every circle and turns by the exact angle, and is second order along other flows.

Round-off bounds used below (eps the float64 unit round-off, n steps): the polar velocity of
``V = f(r) (-y, x)`` has ``v_theta / r = f (1 + 4 eps)`` and ``|v_r| <= 2 eps |f| r`` (two
products of equal size cancel); a turn by ``dt v_theta / r`` and the radius factor
``1 + dt v_r / r`` change the radius by at most ``(4 + 2 |f| dt) eps`` of itself (a rotated
vector, ``cos^2 + sin^2 = 1 + 2 eps``, the factor) and the angle by ``4 |f| dt eps`` (the rate)
plus ``2 eps`` (the rounded vector).  Over n steps: radius within ``n (4 + 2 |f| dt) eps``,
angle within ``n (4 |f| dt + 2) eps``; both are far below the 1e-6 of r asked of the motion.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from jaxanm.fsw.axisymmetric import couette_exact
from jaxanm.fsw.lagrangian import advect
from jaxanm.fsw.scene import Scene

G = Scene().geometry
R1, R2, OMEGA, N_POWER = G.R1, G.R2, 20.0, 0.1324
EPS = np.finfo(np.float64).eps / 2  # unit round-off
T_END = 0.7


def _start(count: int = 64, seed: int = 0) -> np.ndarray:
    """Points across the plate, R1 < r < R2, at random angles."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(R1 * (1 + 1e-3), R2 * (1 - 1e-3), count)
    theta = rng.uniform(0.0, 2 * np.pi, count)
    return np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1)


def _run(points, velocity, dt, t_end=T_END):
    """``advect`` over [0, t_end] in steps of dt, the polar velocity carried from step to step."""
    steps = round(t_end / dt)
    carried = None
    for _ in range(steps):
        points, carried = advect(points, velocity, dt, carried)
    return points, steps


def _turned_by(start, end) -> np.ndarray:
    """Angle from ``start`` to ``end`` about the origin, in (-pi, pi]."""
    return np.angle((end[:, 0] + 1j * end[:, 1]) / (start[:, 0] + 1j * start[:, 1]))


def _rotation(at):
    return OMEGA * np.stack([-at[:, 1], at[:, 0]], axis=1)


def _couette_rate(r):
    """``v_theta / r`` of the isothermal power-law Couette flow (paper's n), the oracle's."""
    return couette_exact(r, R1, R2, OMEGA, N_POWER) / r


def _couette(at):
    return _couette_rate(np.hypot(at[:, 0], at[:, 1]))[:, None] * np.stack([-at[:, 1], at[:, 0]], axis=1)


@pytest.mark.parametrize("dt", [1e-2, 5e-3])
def test_rigid_rotation_keeps_circles_and_turns_by_omega_t(dt):
    """V = omega (-y, x): every point stays on its circle and turns by omega t, to round-off
    (bounds in the module docstring: 70 steps of 0.2 rad give 1.1e-13 of r and 1.3e-13 rad)."""
    start = _start()
    end, steps = _run(start, _rotation, dt)
    r0, r = np.hypot(*start.T), np.hypot(*end.T)
    radius_bound = steps * (4 + 2 * OMEGA * dt) * EPS
    angle_bound = steps * (4 * OMEGA * dt + 2) * EPS
    assert np.max(np.abs(r / r0 - 1)) <= min(radius_bound, 1e-6)
    turn_error = _turned_by(start, end) - np.angle(np.exp(1j * OMEGA * steps * dt))
    assert np.max(np.abs(np.angle(np.exp(1j * turn_error)))) <= angle_bound
    # explicit Euler, for scale: r grows by (1 + (omega dt)^2)^(n/2), 1.4 % at dt = 1e-4 over 0.7 s
    euler = start.copy()
    for _ in range(steps):
        euler = euler + dt * _rotation(euler)
    assert np.allclose(np.hypot(*euler.T) / r0, (1 + (OMEGA * dt) ** 2) ** (steps / 2), rtol=1e-12)


@pytest.mark.parametrize("dt", [1e-2, 5e-3])
def test_power_law_couette_keeps_circles_and_turns_by_the_oracle_angle(dt):
    """The isothermal power-law Couette flow (v_theta(r) of :func:`couette_exact`, n = 0.1324:
    v_theta / r falls from omega to 0 within 0.1 mm of the tool): circles kept to round-off, and
    each point turns by ``t v_theta(r) / r``.

    The angle bound adds to the module's ``n (4 |f| dt + 2) eps`` what the rate ``f = v_theta / r``
    makes of the radius error and of its own evaluation: ``|r f'(r)| <= a omega`` with
    ``a = 2 / n`` (``f = omega (r^-a - R2^-a) / (R1^-a - R2^-a)``), so a radius off by
    ``delta r / r`` turns the rate by ``a omega delta r / r``, and ``r^-a`` is rounded within
    ``(a + 4) eps`` of itself: over t, ``t a omega (n (4 + 2 omega dt) + a + 4) eps``.
    """
    start = _start(seed=1)
    end, steps = _run(start, _couette, dt)
    r0, r = np.hypot(*start.T), np.hypot(*end.T)
    assert np.max(np.abs(r / r0 - 1)) <= min(steps * (4 + 2 * OMEGA * dt) * EPS, 1e-6)
    a, t = 2 / N_POWER, steps * dt
    angle_bound = (steps * (4 * OMEGA * dt + 2) + t * a * OMEGA * (steps * (4 + 2 * OMEGA * dt) + a + 4)) * EPS
    turn_error = _turned_by(start, end) - t * _couette_rate(r0)
    assert np.max(np.abs(np.angle(np.exp(1j * turn_error)))) <= angle_bound


def _translated_rotation(at, speed=1e-2):
    """``omega (-y, x) + (U, 0)``: rigid rotation about ``(0, U / omega)``, not about the axis."""
    return _rotation(at) + np.array([speed, 0.0])


STRAIN = np.array([[0.3 * OMEGA, -OMEGA], [OMEGA, -0.3 * OMEGA]])
"""A linear flow ``V = A x`` turning on ellipses (strain 0.3 omega): no circle about any centre."""


@pytest.mark.parametrize("velocity, exact", [
    (_translated_rotation, lambda p0, t: np.array([0.0, 1e-2 / OMEGA])
     + (p0 - [0.0, 1e-2 / OMEGA]) @ np.array([[np.cos(OMEGA * t), np.sin(OMEGA * t)],
                                               [-np.sin(OMEGA * t), np.cos(OMEGA * t)]])),
    (lambda at: at @ STRAIN.T, lambda p0, t: p0 @ expm(STRAIN * t).T),
], ids=["translation+rotation", "elliptic-strain"])
def test_second_order_along_non_circular_flows(velocity, exact):
    """Steady flows whose paths are no circles about the tool axis, with known trajectories: the
    error after 0.7 s falls by 4 per halving of dt (second order), from dt = 1e-2 down; the
    carried velocity (one evaluation a step) keeps the midpoint rule's order.  At dt = 1e-2 the
    error is below the Cartesian midpoint rule's (which turns the rotation part approximately)
    and 50 times below explicit Euler's (measured: 2.5e-4 m against 5.3e-4 and 1.6e-2 m on the
    ellipses, 3.0e-6 m against 5.7e-4 and 1.8e-2 m on the shifted circles)."""
    start = _start(count=32, seed=2)
    start = start[np.hypot(*start.T) > 2.5e-3]  # the translated circles stay clear of the axis
    errors = []
    for dt in (1e-2, 5e-3, 2.5e-3, 1.25e-3):
        end, steps = _run(start, velocity, dt)
        errors.append(np.max(np.abs(end - exact(start, steps * dt))))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all((ratios > 3.5) & (ratios < 5.0)), (errors, ratios)
    euler, midpoint = start.copy(), start.copy()
    for _ in range(round(T_END / 1e-2)):
        euler = euler + 1e-2 * velocity(euler)
        midpoint = midpoint + 1e-2 * velocity(midpoint + 5e-3 * velocity(midpoint))
    reached = exact(start, round(T_END / 1e-2) * 1e-2)
    assert errors[0] < np.max(np.abs(midpoint - reached))
    assert errors[0] < np.max(np.abs(euler - reached)) / 50


def test_flow_changing_between_steps_is_taken_at_each_step_end():
    """A rotation whose rate changes from step to step (a spin-up): each step turns by
    ``dt omega_k`` of the flow at its end, exactly, although the carried velocity predicting
    the midpoint belongs to the previous step's flow."""
    start = _start(count=16, seed=3)
    rates = OMEGA * np.linspace(0.1, 1.0, 20)
    dt, points, carried = 1e-2, start, None
    for rate in rates:
        points, carried = advect(points, lambda at, w=rate: w * np.stack([-at[:, 1], at[:, 0]], axis=1), dt, carried)
    assert np.max(np.abs(np.hypot(*points.T) / np.hypot(*start.T) - 1)) < 1e-13
    turn_error = _turned_by(start, points) - np.angle(np.exp(1j * dt * rates.sum()))
    assert np.max(np.abs(np.angle(np.exp(1j * turn_error)))) < 1e-13


def test_one_velocity_evaluation_per_step_once_started():
    """The first step samples the flow twice (at the points, at the midpoints), every later step
    once (the midpoints predicted with the carried velocity)."""
    calls = []

    def counted(at):
        calls.append(len(at))
        return _couette(at)

    points, carried = _start(count=8), None
    for _ in range(5):
        points, carried = advect(points, counted, 1e-2, carried)
    assert calls == [8] * 6


def test_points_at_the_centre_take_the_cartesian_midpoint_rule():
    """A point at the centre (no polar angle) moves by the Cartesian midpoint rule, in a uniform
    flow by dt U exactly; the centre may be anywhere (a travelling tool's axis).  The points
    beside it keep the polar rule (a uniform flow is no rotation about the centre: second-order
    error)."""
    centre = np.array([1e-3, -2e-3])
    points = np.array(centre)[None] + np.array([[0.0, 0.0], [2e-3, 0.0], [0.0, -3e-3]])
    uniform = np.array([0.05, -0.02])
    moved, carried = advect(points, lambda at: np.broadcast_to(uniform, at.shape), 1e-2, centre=centre)
    assert np.allclose(moved[0], centre + 1e-2 * uniform, rtol=0, atol=1e-18)
    assert np.all(np.isfinite(moved)) and np.all(np.isfinite(carried))
    step = 1e-2 * np.hypot(*uniform)
    r = np.hypot(*(points[1:] - centre).T)
    assert np.all(np.hypot(*(moved[1:] - points[1:] - 1e-2 * uniform).T) < (step / r) ** 2 * step)
