"""The time schemes (jaxanm.ImplicitEuler, BDF2, ESDIRK) against closed forms.

What is checked, and against what nobody here tuned:

- the tableaux: every Runge-Kutta order condition up to the scheme's order (and the
  embedded method's up to its own), stiff accuracy, gamma the root of the L-stability
  polynomial, and the stability function (|R| <= 1 on the imaginary axis, R -> 0 at
  infinity);
- the observed order of convergence under step refinement (the fitted slope of log error
  against log h) on three problems with closed-form solutions: the linear test equation, a
  nonlinear time-dependent scalar ODE (u' = -2 t u^2, u = 1 / (1 + t^2)) and a small heat
  equation written as a DAE (its Dirichlet values and a w = sin t as algebraic rows) whose
  semi-discrete solution is one mode (exp(lambda_1 t) sin(pi x), lambda_1 the discrete
  Laplacian's eigenvalue, so only the time error is measured);
- L-stability in use: a stiff Prothero-Robinson problem from a perturbed start;
- the ANM, Newton and modified Newton solving every scheme's stages to the same states;
- the step controller reaching its tolerance with each scheme's own estimate, the number of
  steps scaling as the estimate's order says;
- a checkpointed run resuming bit-identically with a scheme's history;
- bad input named.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import jaxanm
from jaxanm._scheme.esdirk import START, TABLEAUS

SCHEMES = [jaxanm.ImplicitEuler(), jaxanm.BDF2(), jaxanm.ESDIRK(order=3), jaxanm.ESDIRK(order=4)]
NEWTON = jaxanm.Newton(tol=1e-13)  # far below every time error measured here


# -- the tableaux ------------------------------------------------------------------------------

def _order_conditions(a, b, order):
    """The residuals of the Runge-Kutta order conditions up to ``order`` (Butcher's trees)."""
    c = a.sum(axis=1)
    conditions = [b.sum() - 1]
    if order >= 2:
        conditions += [b @ c - 1 / 2]
    if order >= 3:
        conditions += [b @ c**2 - 1 / 3, b @ a @ c - 1 / 6]
    if order >= 4:
        conditions += [b @ c**3 - 1 / 4, (b * c) @ a @ c - 1 / 8, b @ a @ c**2 - 1 / 12, b @ a @ a @ c - 1 / 24]
    return np.array(conditions)


def _stability(a, b, z):
    s = b.size
    return 1 + z * b @ np.linalg.solve(np.eye(s) - z * a, np.ones(s))


@pytest.mark.parametrize("order", sorted(TABLEAUS))
def test_esdirk_tableau_order_conditions_and_l_stability(order):
    tab = TABLEAUS[order]
    a, b = tab.a, tab.a[-1]  # stiffly accurate: the solution is the last stage
    # every condition holds to rounding of coefficients of size ~1 (1e-13: 1000 ulps)
    assert np.max(np.abs(_order_conditions(a, b, order))) < 1e-13
    assert np.max(np.abs(_order_conditions(a, tab.b_hat, order - 1))) < 1e-13
    # the embedded method is exactly one order lower: its next conditions fail
    assert np.max(np.abs(_order_conditions(a, tab.b_hat, order)[len(_order_conditions(a, b, order - 1)):])) > 1e-3
    assert a[0, 0] == 0 and np.all(np.diag(a)[1:] == tab.gamma) and tab.c[-1] == pytest.approx(1, abs=1e-15)
    # gamma: the root of L_k(1 / gamma) = 0, k = order implicit stages (Laguerre), times gamma^k k!
    laguerre = {3: [6, -18, 9, -1], 4: [24, -96, 72, -16, 1]}[order]
    assert abs(np.polyval(laguerre, tab.gamma)) < 1e-13
    ys = np.logspace(-3, 6, 400)
    assert max(abs(_stability(a, b, 1j * y)) for y in ys) <= 1 + 1e-12  # A-stable on the axis
    assert abs(_stability(a, b, -1e8)) < 1e-6  # L-stable: R(z) ~ C / z at infinity


def test_the_start_tableau_is_an_l_stable_sdirk3_with_esdirk3s_gamma():
    a = START.a
    assert np.max(np.abs(_order_conditions(a, a[-1], 3))) < 1e-13
    assert np.all(np.diag(a) == START.gamma) and START.gamma == TABLEAUS[3].gamma
    assert abs(_stability(a, a[-1], -1e8)) < 1e-6


# -- observed order of convergence ---------------------------------------------------------------

def _decay(u, u_dot, t, p):
    return u_dot + u


def _riccati(u, u_dot, t, p):
    return u_dot + 2 * t * u**2


N_HEAT = 15


def _heat(x, x_dot, t, p):
    """Unknowns [u_0 .. u_{N+1}, w]: u_0 = u_{N+1} = 0 and w = sin t algebraic, the interior
    u' = u_xx by central differences."""
    import jax.numpy as jnp

    u = x[:-1]
    interior = x_dot[1:-2] - (u[2:] - 2 * u[1:-1] + u[:-2]) * (N_HEAT + 1) ** 2
    return jnp.concatenate([u[:1], interior, u[-1:], x[-1:] - jnp.sin(t)])


X_HEAT = np.arange(N_HEAT + 2) / (N_HEAT + 1)
LAMBDA_1 = -4 * (N_HEAT + 1) ** 2 * math.sin(math.pi / (2 * (N_HEAT + 1))) ** 2  # the discrete Laplacian's


def _heat_exact(t):
    return np.concatenate([math.exp(LAMBDA_1 * t) * np.sin(math.pi * X_HEAT), [math.sin(t)]])

PROBLEMS = {
    # name: (F, u0, t1, exact solution at t1)
    "decay": (jaxanm.SemiDiscrete(_decay), np.ones(1), 1.0, np.array([math.exp(-1.0)])),
    "riccati": (jaxanm.SemiDiscrete(_riccati), np.ones(1), 2.0, np.array([1 / 5])),
    "heat": (jaxanm.SemiDiscrete(_heat), _heat_exact(0.0), 0.05, _heat_exact(0.05)),
}


def _fixed_step_error(name, scheme, n):
    F, u0, t1, exact = PROBLEMS[name]
    sol = jaxanm.integrate(F, u0, None, t0=0.0, t1=t1, dt=t1 / n, solver=NEWTON, scheme=scheme,
                           jacobian="dense", saveat=jaxanm.SaveAt(ts=[]))
    return np.max(np.abs(sol.xs[-1] - exact))


@pytest.mark.parametrize("name", sorted(PROBLEMS))
@pytest.mark.parametrize("scheme", SCHEMES, ids=lambda s: s.name)
def test_observed_order_of_convergence(name, scheme):
    """The fitted slope of log(error) against log(h) over h, h/2, h/4 is the scheme's order p:
    within 0.2 below it and 0.5 above.  The next term of the error expansion moves a fitted
    slope by O(h) over this range; above p where that term is still comparable (ESDIRK3 on the
    Riccati problem, whose h^3 coefficient is small: local slopes 3.42, 3.29, 3.17 between
    h = 1/32 and 1/256, falling to 3), below p otherwise (ESDIRK4 there: 3.85, 3.93, 3.97).  A
    scheme one order short or long is off by 1.  The finest step keeps the error above 1e-11 (well
    above the Newton tolerance and the rounding of the difference quotients)."""
    ns = {"decay": (8, 16, 32), "riccati": (32, 64, 128), "heat": (4, 8, 16)}[name]
    errors = [_fixed_step_error(name, scheme, n) for n in ns]
    slope = -np.polyfit(np.log(ns), np.log(errors), 1)[0]
    assert scheme.order - 0.2 < slope < scheme.order + 0.5, (errors, slope)
    assert min(errors) > 1e-11


def _dense_error(scheme, n):
    """The largest error of the dense output between the steps' ends on the Riccati problem
    (observed at fractions 0.37 and 0.87 of every step, the step's ends excluded)."""
    F, u0, t1, _ = PROBLEMS["riccati"]
    ts = (np.arange(2 * n) + 0.37) * t1 / (2 * n)
    sol = jaxanm.integrate(F, u0, None, t0=0.0, t1=t1, dt=t1 / n, solver=NEWTON, scheme=scheme, jacobian="dense",
                           saveat=jaxanm.SaveAt(ts=[], fn=lambda t, x, p: {"u": x[0]}, fn_ts=ts))
    t, u = sol.observed["t"], sol.observed["u"]
    np.testing.assert_array_equal(t[1:], ts)  # t0, then exactly the asked times
    return np.max(np.abs(u[1:] - 1 / (1 + t[1:] ** 2)))


@pytest.mark.parametrize("scheme", SCHEMES, ids=lambda s: s.name)
def test_dense_output_keeps_the_schemes_order_between_steps(scheme):
    """SaveAt(fn_ts=...) observes the scheme's dense output between the steps' ends: its
    error against the closed form converges at the scheme's order (the line for implicit
    Euler, BDF2's quadratic, the ESDIRKs' cubic Hermite, whose own O(h^4) error is not carried
    to later steps); bounds as in the test above."""
    ns = (32, 64, 128)
    errors = [_dense_error(scheme, n) for n in ns]
    slope = -np.polyfit(np.log(ns), np.log(errors), 1)[0]
    assert scheme.order - 0.2 < slope < scheme.order + 0.5, (errors, slope)


def test_dense_output_under_a_controller_observes_the_asked_times():
    """Observation times do not change the controller's steps, and the values between the
    steps' ends are as accurate as those at the ends (ESDIRK3 on the Riccati problem: at most
    twice the largest error at the steps' ends, i.e. the interpolant adds less than the
    accumulated time error)."""
    F, u0, t1, _ = PROBLEMS["riccati"]
    ts = np.linspace(0.01, t1, 200)
    controller = jaxanm.StepController(rtol=1e-6, atol=1e-6)
    run = dict(t0=0.0, t1=t1, dt=1e-3, solver=NEWTON, scheme=jaxanm.ESDIRK(order=3), jacobian="dense",
               controller=controller)
    steps = jaxanm.integrate(F, u0, None, saveat=jaxanm.SaveAt(steps=1), **run)
    dense = jaxanm.integrate(F, u0, None, saveat=jaxanm.SaveAt(ts=[], fn=lambda t, x, p: {"u": x[0]}, fn_ts=ts),
                             **run)
    assert dense.stats.time_steps == steps.stats.time_steps < len(ts) / 2
    t, u = dense.observed["t"][1:], dense.observed["u"][1:]
    np.testing.assert_array_equal(t, ts)
    at_steps = np.max(np.abs(steps.xs[:, 0] - 1 / (1 + steps.ts**2)))
    assert np.max(np.abs(u - 1 / (1 + t**2))) < 2 * at_steps


# -- L-stability on a stiff problem ---------------------------------------------------------------

def _prothero_robinson(u, u_dot, t, p):
    import jax.numpy as jnp

    return u_dot - (-1e6 * (u - jnp.sin(t)) + jnp.cos(t))


@pytest.mark.parametrize("scheme", SCHEMES, ids=lambda s: s.name)
def test_stiff_component_is_damped_at_large_steps(scheme):
    """u' = lambda (u - sin t) + cos t, lambda = -1e6, from u(0) = 1 (sin 0 + a perturbation of
    1 along the stiff mode), 10 steps of 0.1 (lambda h = -1e5).  An L-stable scheme damps the
    perturbation to about 1 / |lambda h| = 1e-5 in its first step, and a stiffly accurate one
    then follows sin t to O(h^2 / |lambda|); the trapezoidal rule (A- but not L-stable) would
    keep the perturbation's sign flipping at magnitude ~1.  Asserted: within 1e-4 of sin t at
    t = 1 (ten times the first step's damping)."""
    sol = jaxanm.integrate(jaxanm.SemiDiscrete(_prothero_robinson), np.ones(1), None, t0=0.0, t1=1.0, dt=0.1,
                           solver=NEWTON, scheme=scheme, jacobian="dense", saveat=jaxanm.SaveAt(steps=1))
    assert abs(sol.xs[-1, 0] - math.sin(1.0)) < 1e-4
    assert np.all(np.abs(sol.xs[1:, 0] - np.sin(sol.ts[1:])) < 1e-4)


# -- the solvers agree on every scheme ---------------------------------------------------------

SOLVERS = {"anm": jaxanm.ANM(order=5, tol=1e-10), "newton": jaxanm.Newton(tol=1e-11),
           "mnewton": jaxanm.ModifiedNewton(tol=1e-11)}


@pytest.mark.parametrize("scheme", SCHEMES, ids=lambda s: s.name)
def test_anm_newton_and_modified_newton_solve_the_same_stages(scheme):
    """The heat problem, 8 fixed steps: the three solvers' states agree to 1e-8 of the
    solution's size at every step (each solves every stage to ~1e-10 of the state, and the
    steps do not amplify errors), while the time error itself is 1e-4-1e-7: they solve the
    same stage equations.  The ANM reuses one K* for every stage with the same gamma h."""
    F, u0, t1, _ = PROBLEMS["heat"]
    runs = {}
    for name, solver in SOLVERS.items():
        runs[name] = jaxanm.integrate(F, u0, None, t0=0.0, t1=t1, dt=t1 / 8, solver=solver, scheme=scheme,
                                      jacobian="dense", saveat=jaxanm.SaveAt(steps=1))
    reference = runs["newton"].xs
    for name in ("anm", "mnewton"):
        assert np.max(np.abs(runs[name].xs - reference)) < 1e-8 * np.max(np.abs(u0))
    # one K* per gamma h: the steps share a size, so the ANM factorises about once (a stage
    # size differs at the start: BDF2's first step is implicit Euler's)
    assert runs["anm"].stats.factorizations <= 2


# -- the controller with each scheme's estimate ----------------------------------------------------

@pytest.mark.parametrize("scheme", SCHEMES, ids=lambda s: s.name)
def test_controller_reaches_its_tolerance_with_the_schemes_estimate(scheme):
    """u' = -2 t u^2 on [0, 2] under StepController(rtol=0, atol=tol), steps ending at 1.0.

    - The error at a save time and at t1 stays within the sum of the local errors allowed
      (steps x tol): the flow contracts (d f / d u = -4 t u < 0), so the global error is at
      most the sum of the true local errors, which the estimate follows (ESDIRK's estimate,
      that of its embedded method, is one order above the solution's error).
    - From tol = 1e-5 to 1e-7 the number of steps grows as the estimate's order says, tol^(-1 /
      (q + 1)): 100^(1 / (q + 1)), asserted within a factor 1.6 (the start, the save time and
      the safety factor move the counts by a few steps)."""
    F, u0, t1, exact = PROBLEMS["riccati"]
    steps = {}
    for tol in (1e-5, 1e-7):
        sol = jaxanm.integrate(F, u0, None, t0=0.0, t1=t1, dt=1e-3, solver=NEWTON, scheme=scheme, jacobian="dense",
                               controller=jaxanm.StepController(rtol=0.0, atol=tol), saveat=jaxanm.SaveAt(ts=[1.0]))
        assert list(sol.ts) == [0.0, 1.0, 2.0]
        n = sol.stats.time_steps
        assert abs(sol.xs[1, 0] - 0.5) <= n * tol and abs(sol.xs[2, 0] - exact[0]) <= n * tol
        steps[tol] = n
    expected = 100 ** (1 / (scheme.error_order + 1))
    assert expected / 1.6 < steps[1e-7] / steps[1e-5] < 1.6 * expected, steps


# -- checkpoints, remaps ----------------------------------------------------------------------------

@pytest.mark.parametrize("scheme", SCHEMES[1:], ids=lambda s: s.name)
def test_resume_with_a_schemes_history_is_bit_identical(tmp_path, scheme):
    F, u0, t1, _ = PROBLEMS["riccati"]
    kw = dict(t0=0.0, t1=t1, dt=1e-2, solver=jaxanm.ModifiedNewton(tol=1e-10), scheme=scheme, jacobian="dense",
              controller=jaxanm.StepController(rtol=0.0, atol=1e-6), saveat=jaxanm.SaveAt(steps=1))
    full = jaxanm.integrate(F, u0, None, **kw)
    path = tmp_path / "run.ckpt"

    def stop_at_5(t, x, stats):
        if stats.time_steps == 5:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        jaxanm.integrate(F, u0, None, checkpoint=path, callback=stop_at_5, **kw)
    resumed = jaxanm.integrate(F, u0, None, checkpoint=path, resume=True, **kw)
    assert np.array_equal(resumed.xs, full.xs) and resumed.stats.step_sizes == full.stats.step_sizes


def test_a_remap_restarts_bdf2_as_implicit_euler():
    """A hook that remaps (here to the same state) at every step restarts BDF2 every step: its
    steps are then implicit Euler's, to the bit."""
    F, u0, t1, _ = PROBLEMS["riccati"]
    kw = dict(t0=0.0, t1=t1, dt=0.1, solver=NEWTON, jacobian="dense", saveat=jaxanm.SaveAt(steps=1))
    remapped = jaxanm.integrate(F, u0, None, scheme=jaxanm.BDF2(), after_step=lambda t, x, p: jaxanm.Remap(p, x),
                                **kw)
    euler = jaxanm.integrate(F, u0, None, **kw)
    assert np.array_equal(remapped.xs, euler.xs)


# -- bad input ----------------------------------------------------------------------------------------

def _one_step(x, x_old, t, dt, p):
    return (x - x_old) / dt + x


@pytest.mark.parametrize("make, match", [
    (lambda: jaxanm.integrate(_one_step, np.ones(1), None, t0=0.0, t1=1.0, dt=0.1, solver=NEWTON,
                              scheme=jaxanm.BDF2()), "cannot use a one-step residual"),
    (lambda: jaxanm.ESDIRK(order=5), "ESDIRK.order must be an integer from 3 to 4"),
    (lambda: jaxanm.ESDIRK(order=2), "for order 1 use jaxanm.ImplicitEuler"),
    (lambda: jaxanm.integrate(PROBLEMS["decay"][0], np.ones(1), None, t0=0.0, t1=1.0, dt=0.1, solver=NEWTON,
                              scheme="bdf2"), "scheme must be jaxanm.ImplicitEuler"),
    (lambda: jaxanm.SemiDiscrete(_decay, step_residual=_one_step), "exactly one of"),
    (lambda: jaxanm.SemiDiscrete(), "exactly one of"),
    (lambda: jaxanm.make_scheme("bdf3"), "unknown time scheme 'bdf3'"),
])
def test_bad_input_is_named(make, match):
    with pytest.raises(jaxanm.InputError, match=match):
        make()


def test_sensitivities_refuse_another_scheme():
    from jaxanm.sensitivity import ForwardSensitivity

    with pytest.raises(jaxanm.InputError, match="sensitivity supports only scheme=jaxanm.ImplicitEuler"):
        jaxanm.integrate(PROBLEMS["decay"][0], np.ones(1), {"k": 1.0}, t0=0.0, t1=1.0, dt=0.1, solver=NEWTON,
                         scheme=jaxanm.BDF2(),
                         sensitivity=ForwardSensitivity(_one_step, {"k": 1.0}, {"k": 1.0},
                                                        lambda t, x, p: {"x": x}))
