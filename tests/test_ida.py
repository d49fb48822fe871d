"""jaxanm.ida: SUNDIALS IDA on a jaxanm step residual (the DAE F(t, y, y') = R(y, y - h0 y', t, h0)).

Expected values come from closed forms (a discrete heat equation's eigenmode, sin t) and from
jaxanm's own implicit-Euler solvers Richardson-extrapolated, never from IDA's output.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanm
from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.scene import load_scene
from jaxanm.ida import IDAFailure, dae_residual, integrate_ida

# --- a closed form: the 1-D heat equation's discrete eigenmode, with algebraic rows ---------
# Unknowns [u_0 .. u_M, w]: u_0 = u_M = 0 (Dirichlet rows, algebraic), interior rows
# (u - u_old)/dt = (u_{j-1} - 2 u_j + u_{j+1}) / h^2 scaled by dt (as the FSW rows are), and an
# algebraic w = sin(t).  From u_j(0) = sin(k pi j / M) the exact solution is
# u_j(t) = exp(-lam t) sin(k pi j / M), lam = (4 / h^2) sin^2(k pi h / 2) (h = 1 / M): the
# discrete Laplacian's eigenvalue, a closed form independent of any integrator.
M, K_MODE = 16, 2
H = 1.0 / M
LAM = 4.0 / H**2 * math.sin(K_MODE * math.pi * H / 2) ** 2


def heat_residual(x, x_old, t, dt, p):
    """Implicit-Euler step residual of the heat DAE above (rows scaled by dt / (1 + dt/h^2))."""
    u, uo = x[:-1], x_old[:-1]
    lap = (u[:-2] - 2 * u[1:-1] + u[2:]) / H**2
    s = dt / (1.0 + dt / H**2)  # a dt-dependent row scaling, like the FSW rows'
    interior = ((u[1:-1] - uo[1:-1]) / dt - lap) * s
    return jnp.concatenate([u[:1], interior, u[-1:], (x[-1:] - jnp.sin(t)) * p["c"]])


def heat_exact(t):
    """Closed-form state at time t."""
    j = np.arange(M + 1)
    return np.concatenate([np.exp(-LAM * t) * np.sin(K_MODE * np.pi * j / M), [math.sin(t)]])


def test_heat_dae_closed_form():
    """IDA's error against the closed form is within a small multiple of rtol.

    With error weights 1/(rtol |y| + atol), IDA keeps each step's local error below ~rtol in the
    weighted RMS norm; on this dissipative mode the local errors are damped, not accumulated,
    and the measured global error is a small multiple of rtol.  Bound: 20 rtol (max-norm, relative
    to the initial amplitude 1): BDF's global error is not bounded by rtol itself, and the max
    norm exceeds the RMS norm by up to sqrt(n) = 4.2; 20 leaves a factor ~5 for the accumulation
    over the ~30 steps.  The two rtols must also order the errors (the tolerance does something).
    """
    x0 = heat_exact(0.0)
    t_out = np.array([0.01, 0.05, 0.1])
    errs = []
    for rtol in (1e-4, 1e-7):
        sol = integrate_ida(heat_residual, x0, {"c": np.float64(1.0)}, t0=0.0, t_out=t_out, rtol=rtol, atol=rtol)
        assert np.allclose(sol.ts, t_out, rtol=0, atol=1e-15)  # outputs exactly at the asked times (tstop)
        err = max(np.max(np.abs(x - heat_exact(t))) for t, x in zip(sol.ts, sol.xs))
        assert err < 20 * rtol, (rtol, err)
        errs.append(err)
        s = sol.stats
        assert s.time_steps > 0 and s.jacobian_evaluations > 0 and s.newton_iterations == s.residual_evaluations
        assert s.factorizations == s.jacobian_evaluations  # each IDA matrix setup is one SuperLU factorisation
        assert isinstance(s, jaxanm.Stats) and s.wall_time_s >= sum(v for k, v in s.wall_time.items() if k != "ida")
        for old, new in (("steps", "time_steps"), ("wall_s", "wall_time_s"), ("linear_solves", "newton_iterations")):
            with pytest.warns(DeprecationWarning, match=f"IDAStats.{old} is deprecated: use IDAStats.{new}"):
                assert getattr(s, old) == getattr(s, new)
    assert errs[1] < errs[0] / 10  # 1000x tighter rtol: the error must drop by far more than 10x


def heat_semi_discrete(u_all, u_dot, t, p):
    """The heat DAE above as ``F(u, u_dot, t)`` (unscaled rows), for jaxanm.SemiDiscrete."""
    u, ud = u_all[:-1], u_dot[:-1]
    lap = (u[:-2] - 2 * u[1:-1] + u[2:]) / H**2
    return jnp.concatenate([u[:1], ud[1:-1] - lap, u[-1:], (u_all[-1:] - jnp.sin(t)) * p["c"]])


def test_semi_discrete_residual_closed_form():
    """The same DAE given as jaxanm.SemiDiscrete(F) reaches the closed form within the bound of
    test_heat_dae_closed_form (20 rtol), and agrees with the step-residual run to 50 rtol (two
    error-controlled runs of the same DAE, each within 20 rtol of the solution)."""
    x0, t_out, rtol = heat_exact(0.0), np.array([0.01, 0.05, 0.1]), 1e-7
    params = {"c": np.float64(1.0)}
    sol = integrate_ida(jaxanm.SemiDiscrete(heat_semi_discrete), x0, params, t0=0.0, t_out=t_out, rtol=rtol,
                        atol=rtol)
    err = max(np.max(np.abs(x - heat_exact(t))) for t, x in zip(sol.ts, sol.xs))
    assert err < 20 * rtol, err
    step = integrate_ida(heat_residual, x0, params, t0=0.0, t_out=t_out, rtol=rtol, atol=rtol)
    assert np.max(np.abs(sol.xs - step.xs)) < 50 * rtol


def test_newton_matrix_equals_dense_derivative():
    """The coloured sparse matrix handed to IDA equals dF/dy + cj dF/dy' by dense jacfwd of F.

    Exact algebra on both sides (forward-mode derivatives of the same function): agreement to
    1e-12 relative to the matrix's largest entry (round-off of a few flops per entry).
    """
    from jaxanm.ida import _csc_pattern, _newton_matrix_residual
    from jaxanm.jacobian import SparseJacobian, detect_sparsity

    with jaxanm.float64():
        rng = np.random.default_rng(1)
        n = M + 2
        y, yp = rng.standard_normal(n), rng.standard_normal(n)
        h0, cj, t = 1e-3, 2.7e3, 0.3
        p = {"c": np.float64(1.0)}
        F = dae_residual(heat_residual)
        dense = (np.asarray(jax.jacfwd(lambda z: F(t, z, yp, h0, p))(y))
                 + cj * np.asarray(jax.jacfwd(lambda z: F(t, y, z, h0, p))(yp)))
        g = _newton_matrix_residual(heat_residual)
        pattern = _csc_pattern(detect_sparsity(g, y, (y, jnp.zeros(n), 0.37 / h0), t, h0, p), n)
        sparse = SparseJacobian(g, pattern)(y, (y, yp, cj), t, h0, p).toarray()
    assert np.max(np.abs(sparse - dense)) <= 1e-12 * np.max(np.abs(dense))


# --- the FSW rows ------------------------------------------------------------------------------


def _fsw_small_fixed():
    """fsw_small on fixed points (tracers instead of the Lagrangian motion): 239 points, 717 unknowns."""
    scene = load_scene("fsw_small")
    effects = [e for e in scene.effects if e != "lagrangian"] + ["tracers"]
    return scene.with_overrides({"effects": ",".join(effects), "time.save": ""})


def test_fsw_residual_is_an_exact_dae():
    """R(y, y - h y', h) = D(h) G(y, y') on the FSW rows (module docstring of jaxanm.ida).

    For two step sizes h, h', the row-wise ratio R(y, y - h y', h) / R(y, y - h' y', h') must be
    the same for two independent random (y, y'): a ratio that depended on (y, y') would mean that
    x_old enters otherwise than through (L x - L x_old)/dt, or dt otherwise than through the row
    scalings.  Agreement to 1e-8 relative: each ratio is a quotient of two rows that are
    themselves differences of O(1) terms (cancellation of ~1e-5 in the momentum rows at this
    small y'), so round-off of ~1e-16 / 1e-5 per row, with a margin of 1000.
    """
    scene = _fsw_small_fixed()
    _, _, model, params, x0 = discretise(scene)
    scale = model.scale()
    F = dae_residual(model.residual)
    rng = np.random.default_rng(0)
    ratios = []
    with jaxanm.float64():
        p = jax.device_put(params)
        for _ in range(2):
            y = x0 + 0.05 * scale * rng.standard_normal(x0.size)
            y[2 * model.cloud.size:] = np.abs(y[2 * model.cloud.size:])  # T > 0 (softening T^A)
            yp = 100.0 * scale * rng.standard_normal(x0.size)
            r1 = np.asarray(F(0.0, y, yp, 1e-4, p))
            r2 = np.asarray(F(0.0, y, yp, 3e-6, p))
            ratios.append(r1 / r2)
    assert np.all(np.isfinite(ratios[0])) and np.all(np.abs(ratios[0]) > 0)
    assert np.max(np.abs(ratios[0] / ratios[1] - 1)) < 1e-8
    # and the scalings do depend on h (else this test would not test the dt rows)
    assert np.max(np.abs(ratios[0])) / np.min(np.abs(ratios[0])) > 1.5


def _ie_fields(model, params, x0, t_end, dt):
    """Field values at the points at t_end from implicit Euler at fixed dt (modified Newton, tight)."""
    sol = jaxanm.integrate(model.residual, x0, params, t0=0.0, t1=t_end, dt=dt,
                           solver=jaxanm.ModifiedNewton(tol=1e-11), scale=model.scale(), jacobian="sparse",
                           sparsity=model.sparsity, saveat=jaxanm.SaveAt(ts=[t_end]))
    return sol.xs[-1]


def test_fsw_small_against_richardson_reference():
    """IDA on fsw_small (fixed points) against a Richardson reference of jaxanm's implicit Euler.

    Reference: implicit Euler at dt, dt/2, dt/4 (first order), extrapolated 2 x(dt/4) - x(dt/2)
    and 2 x(dt/2) - x(dt); the extrapolations are second order, so the finer one's own error
    is estimated as |difference| / 3.  Errors are max-norms of T (relative to the largest rise
    of T - T0) and of V (relative to omega R1) over the points at t_end.

    Bound for IDA at rtol = atol = 1e-6 (atol relative to the scales T0 and omega R1): its error
    weights allow a local error of rtol |T| + atol T0 in T, i.e. (2 T0 + rise) rtol / rise of the
    rise (65 rtol here: the rise is 1.5 % of T), and (|V| / U + 1) rtol <= 2 rtol of omega R1 in V.
    The global error is a small multiple of that (3.1x on the closed-form problem): allowed 5x,
    plus twice the reference's estimated error (an estimate is not a bound).
    """
    scene = _fsw_small_fixed()
    _, st, model, params, x0 = discretise(scene)
    t_end, dt = 0.004, 2e-4
    T0, U = scene.thermal.T0, scene.tool.omega * scene.geometry.R1
    xs = {h: model.values(_ie_fields(model, params, x0, t_end, h), st) for h in (dt, dt / 2, dt / 4)}
    fine = 2 * xs[dt / 4] - xs[dt / 2]
    coarse = 2 * xs[dt / 2] - xs[dt]
    rise = np.max(fine[:, 2] - T0)

    def err(v):
        return (np.max(np.abs(v[:, 2] - fine[:, 2])) / rise,
                np.max(np.hypot(v[:, 0] - fine[:, 0], v[:, 1] - fine[:, 1])) / U)

    ref_err = np.array(err(coarse)) / 3
    first_order = np.array(err(xs[dt / 4]))
    assert np.all(ref_err < first_order / 5)  # the extrapolation is well below the IE error it removes
    rtol = 1e-6
    sol = integrate_ida(model.residual, x0, params, t0=0.0, t_out=[t_end], rtol=rtol, atol=rtol,
                        scale=model.scale(), sparsity=model.sparsity)
    e = np.array(err(model.values(sol.xs[-1], st)))
    allowed = 5 * rtol * np.array([(2 * T0 + rise) / rise, 2.0]) + 2 * ref_err
    assert np.all(e < allowed), (e, allowed)


# --- input errors and failures -------------------------------------------------------------------


@pytest.mark.parametrize("kwargs, match", [
    ({"t_out": [0.1, 0.05]}, "t_out must increase"),
    ({"t_out": [0.1], "rtol": 0.0}, "rtol must be"),
    ({"t_out": [0.1], "atol": -1.0}, "atol must be"),
    ({"t_out": [0.1], "ic_dt": 0.06}, "ic_dt must be"),
    ({"t_out": [0.1], "yp0": np.ones(M + 2)}, "yp0 is not consistent"),
    ({"t_out": [0.1], "sparsity": np.ones((3, 3))}, "sparsity must be"),
])
def test_bad_input_is_named(kwargs, match):
    """Each bad input raises InputError naming the input and the fix, before IDA runs."""
    with pytest.raises(jaxanm.InputError, match=match):
        integrate_ida(heat_residual, heat_exact(0.0), {"c": np.float64(1.0)}, t0=0.0, **kwargs)


def test_failure_says_why():
    """A residual that is non-finite for every t > 0 stops IDA at its first step with its flag,
    message and time; too many steps stop it with a message naming max_steps."""

    def broken(x, x_old, t, dt, p):
        return heat_residual(x, x_old, t, dt, p) + jnp.where(t > 0.0, jnp.nan, 0.0)

    # a consistent start from the closed form: u' = -lam u, w' = cos(0) = 1
    yp0 = np.concatenate([-LAM * heat_exact(0.0)[:-1], [1.0]])
    with pytest.raises(IDAFailure) as info:
        integrate_ida(broken, heat_exact(0.0), {"c": np.float64(1.0)}, t0=0.0, t_out=[0.1], rtol=1e-6, yp0=yp0)
    assert info.value.t == 0.0 and info.value.status < 0 and info.value.reason and info.value.stats.time_steps == 0
    with pytest.raises(IDAFailure, match="max_steps"):
        integrate_ida(heat_residual, heat_exact(0.0), {"c": np.float64(1.0)}, t0=0.0, t_out=[0.1], max_steps=3)
