"""Hard cases stay numerically stable: a finite, checked solution or a named error.

The cases live in ``tests/hard_problems.py`` (``benchmarks/hard_cases.py`` runs them all and
writes the table of benchmarks/results/hard_cases.md); here the fast ones run and their
outcomes are asserted:

- converged cases pass the independent check of that module: the Newton distance
  ``|J(x)^-1 R(x)|`` of the accepted state, by a dense ``jax.jacfwd`` Jacobian, is within ten
  times what the solver's tolerance promises (``check_ratio <= 10``);
- failing cases raise the documented error, whose message names step, t, a_max and |R|, and
  the statistics carried by the exception show the path taken (halvings, sub-steps).

The second half checks the step control directly on small residuals: NaN injected into the
residual, the Jacobian, the series or the accepted state always ends in a NonFiniteError that
locates it, for ANM, Newton and modified Newton.
"""

from __future__ import annotations

import hard_problems as hc
import jax.numpy as jnp
import numpy as np
import pytest

import jaxanm
from jaxanm.fsw.scene import SceneError, SolverSpec


def _run(key):
    fast, make = hc.CASES[key]
    return make()


def _converged(out):
    assert out.converged, f"{out.case}: {out.error}: {out.message}"
    if out.check_ratio is not None:
        assert np.isfinite(out.check_ratio) and out.check_ratio <= hc.CHECK_LIMIT, out
    return out


def _named_error(out, kind):
    """The case ended in exactly ``kind``, whose message locates and quantifies the failure."""
    assert not out.converged and out.error == kind.__name__, out
    exc = out.exception
    assert type(exc) is kind
    if isinstance(exc, jaxanm.StepFailure):
        assert exc.step >= 1 and np.isfinite(exc.t)
        for token in (f"step {exc.step} ", "t = ", "a_max = ", "|R|_inf = "):
            assert token in out.message, (token, out.message)
    return out


# --------------------------------------------------------------------------------- FSW cases

def test_impulsive_start_advances_by_continuation():
    out = _converged(_run("impulsive"))
    assert out.substeps > 0  # a fresh K* at rest cannot reach a = 1 in one series
    # each sub-step but the last needs a fresh K*; the first K* is factorised at rest
    assert out.factorizations <= out.substeps + 1 and out.check_ratio is not None


@pytest.mark.parametrize("key", ["n005_newton", "n005_anm"])
def test_extreme_shear_thinning_n_005(key):
    out = _converged(_run(key))
    assert out.check_ratio is not None


def test_newtonian_n_1_is_linear():
    """n = 1 and constant viscosity: the step residual is linear in V, so the ANM series is exact
    after order 1 (one K*, no sub-step) and Newton lands in one iteration (plus the one that
    confirms it)."""
    anm = _converged(_run("n1_anm"))
    assert (anm.factorizations, anm.substeps) == (1, 0)
    newton = _converged(_run("n1_newton"))
    assert newton.factorizations == 2


def test_epsbar_to_zero():
    """eps0 = 1e-9: uncapped Newton converges to a checked state; capped at one iteration fewer
    than its step needed, it fails with a named error after every dt halving.

    The cap comes from the uncapped run on this machine, not from a constant: how many
    iterations the step takes depends on round-off, but whatever that count N is, the capped
    run repeats the same iterates and stops at N - 1, before the one that met the tolerance.
    The step is quasi-static (effects ``viscous`` only: no inertia, no heat capacity), so the
    residual ignores dt, t and x_old, checked here bit for bit; each halved attempt starts
    from the same x_old and is the same Newton sequence, so halving cannot rescue it and every
    one of the 1 + 4 attempts runs to the cap.
    """
    out = _converged(_run("eps0_newton100"))
    assert out.check_ratio is not None and out.dt_halvings == 0 and out.time_steps == 1
    assert out.step_iterations and sum(out.step_iterations) == out.factorizations  # Newton: one per iteration
    needed = max(out.step_iterations)
    assert needed >= 2  # a cap of needed - 1 >= 1 iteration is a valid Newton.max_iter

    capped = _named_error(hc.epsbar_zero_capped(needed), jaxanm.StepFailure)
    exc = capped.exception
    assert f"did not converge in {needed - 1} iterations" in capped.message
    assert capped.dt_halvings == 4 and exc.step == 1 and exc.t == 1.0 / 2**4  # dt = 1 halved 4 times
    assert exc.stats.newton_iterations == 5 * (needed - 1) and capped.time_steps == 0

    # the premise: the quasi-static residual does not depend on dt, t or x_old
    from jaxanm.fsw.discretisation import discretise
    from jaxanm.fsw.scene import load_scene

    scene = load_scene("fsw_small").with_overrides({**hc.TINY, **hc.EPS0_ZERO})
    _, _, model, params, x0 = discretise(scene)
    rng = np.random.default_rng(0)
    x = x0 + model.scale() * rng.standard_normal(x0.shape)
    with jaxanm.float64():
        full = np.asarray(model.residual(jnp.asarray(x), jnp.asarray(x0), 1.0, 1.0, params))
        half = np.asarray(model.residual(jnp.asarray(x), jnp.asarray(x), 1.0 / 16, 1.0 / 16, params))
    np.testing.assert_array_equal(full, half)


@pytest.mark.parametrize("key", ["penalty_newton", "penalty_anm"])
def test_penalty_1e8(key):
    assert _converged(_run(key)).check_ratio is not None


@pytest.mark.parametrize("key", ["dt_1e-2", "dt_1e-7"])
def test_extreme_time_steps(key):
    out = _converged(_run(key))
    assert out.time_steps == 2 and out.check_ratio is not None


@pytest.mark.parametrize("key", ["omega_200", "hot_softening"])
def test_fast_tool_and_hot_soft_material(key):
    out = _converged(_run(key))
    assert out.time_steps == 2 and out.check_ratio is not None


def test_lagrangian_points_drifting_together():
    """Two plate points drifted to 0.1 dr of each other: the collocation rows of the pair are
    nearly the same equation and Newton no longer converges (a named error after every dt
    halving, never a NaN); drifted onto each other, the stencil builder refuses the cloud."""
    out = _named_error(_run("coincident_0.1"), jaxanm.StepFailure)
    assert out.exception.step == 1 and out.dt_halvings == 4
    out = _named_error(_run("coincident_0"), jaxanm.InputError)
    assert "coincide" in out.message and "remove duplicate points" in out.message


def test_coarse_conduction_grows_an_edge_mode_and_ends_named():
    """conduction_small at twice its spacing: the implicit-Euler heat step has a mode with
    mu > 0 on the tool/plate edge pairs (r = R1) that the scene's dt amplifies by about -15 a
    step.  The run ends in a DivergenceError that names it, after about a dozen steps of
    round-off growth (the step varies with round-off: not pinned).

    Independent check of the eigen-analysis: two short runs by the solver, from the initial
    state and from it plus the mode's nodal parameters; their difference must be multiplied by
    the computed amplification at every step (the heat rows are linear, and Newton solves each
    step to round-off), and the growth rate it implies must be positive."""
    from jaxanm.fsw.discretisation import discretise
    from jaxanm.fsw.scene import load_scene
    from jaxanm.fsw.stability import DivergenceError

    out = _named_error(_run("conduction_2dr"), DivergenceError)
    exc = out.exception
    scene = load_scene("conduction_small").with_overrides(hc.COARSE_CONDUCTION)
    R1, dt = scene.geometry.R1, scene.time.dt
    assert exc.kind in ("TOOL_EDGE", "PLATE_EDGE") and exc.radius == pytest.approx(R1)
    assert exc.value < exc.bound < scene.thermal.Ta and 1 < exc.step < 40 and exc.t == pytest.approx(exc.step * dt)
    mode = exc.modes[0]
    assert mode.mu.real > 0 and abs(mode.amplification) > 1 and "mu = +" in out.message
    assert mode.share["TOOL_EDGE"] + mode.share["PLATE_EDGE"] > 0.9 and mode.radius == pytest.approx(R1)

    _, _, model, params, x0 = discretise(scene)
    kick = np.real(mode.nodal) / np.abs(mode.nodal).max()  # 1 K at most: real for a real eigenvalue
    assert np.abs(mode.nodal.imag).max() < 1e-9 * np.abs(mode.nodal).max()

    def steps(x):
        return jaxanm.integrate(model.residual, x, params, t0=0.0, t1=3 * dt, dt=dt, solver=jaxanm.Newton(tol=1e-12),
                                scale=model.scale(), jacobian="dense").xs

    d = steps(x0 + kick) - steps(x0)
    measured = [float(d[k + 1] @ d[k] / (d[k] @ d[k])) for k in range(3)]
    np.testing.assert_allclose(measured, mode.amplification.real, rtol=1e-6)
    assert (1 - 1 / measured[-1]) / dt > 0  # the growth rate mu of the measured amplification


# --------------------------------------------------------------------------------- series cases

def test_forced_divergence_refactorises_and_continues():
    out = _converged(_run("forced_divergence"))
    assert out.substeps > 0 and out.factorizations > 1 and out.dt_halvings == 0


def test_forced_divergence_without_continuation_halves_dt():
    failed = _named_error(_run("forced_halving_4"), jaxanm.StepFailure)
    assert failed.dt_halvings == 4 and failed.substeps == 0
    out = _converged(_run("forced_halving_30"))
    assert out.dt_halvings > 4 and out.substeps == 0 and out.check_ratio is not None


def test_series_order_25():
    out = _converged(_run("order_25"))
    assert out.check_ratio is not None


def test_series_order_1_is_rejected_with_the_allowed_range():
    out = _named_error(_run("order_1"), jaxanm.InputError)
    assert "ANM.order must be an integer >= 2, got 1" in out.message and "eq. 26" in out.message
    with pytest.raises(SceneError, match=r"solver.order.*ANM.order must be an integer >= 2"):
        SolverSpec(order=1)  # the solver's own check, under the scene's key
    with pytest.raises(SceneError, match=r"solver.order.*at most 30"):
        SolverSpec(order=31)  # the scene's cap on the compile time


# --------------------------------------------------------------------------------- step control

SOLVERS = [jaxanm.ANM(order=5, tol=1e-8), jaxanm.Newton(tol=1e-10), jaxanm.ModifiedNewton(tol=1e-10)]


def _integrate(residual, solver, t1=0.3, dt=0.05, n=4, **kw):
    return jaxanm.integrate(residual, np.zeros(n), {}, t0=0.0, t1=t1, dt=dt, solver=solver, jacobian="dense", **kw)


def _nonfinite(residual, solver, **kw):
    with pytest.raises(jaxanm.NonFiniteError) as info:
        _integrate(residual, solver, **kw)
    err = info.value
    for token in (f"step {err.step} ", "t = ", "a_max = ", "|R|_inf = "):
        assert token in str(err)
    return err


@pytest.mark.parametrize("solver", SOLVERS, ids=lambda s: type(s).__name__)
def test_nan_in_the_residual(solver):
    def residual(u, u_old, t, dt, p):
        return (u - u_old) / dt - 1.0 + jnp.where(t > 0.15 + 1e-9, jnp.nan, 0.0)

    err = _nonfinite(residual, solver)
    assert err.step == 4 and 0.15 < err.t <= 0.2 and "not finite" in str(err)
    assert err.residual_norm is not None and np.isnan(err.residual_norm)
    assert err.stats.time_steps == 3 and err.stats.dt_halvings == 4  # every halving was tried


@pytest.mark.parametrize("solver", SOLVERS, ids=lambda s: type(s).__name__)
def test_nan_in_the_jacobian(solver):
    """|u| written as sqrt(u^2): finite value, NaN derivative at u = 0."""
    def residual(u, u_old, t, dt, p):
        return (u - u_old) / dt - 1.0 + jnp.sqrt(u * u)

    err = _nonfinite(residual, solver)
    assert err.step == 1 and "tangent matrix K* cannot be factorised" in str(err) and "non-finite" in str(err)
    assert err.residual_norm == pytest.approx(1.0)  # the residual itself was finite
    assert err.stats.factorizations == 0 and err.stats.jacobian_evaluations > 0


def test_nan_in_the_series():
    """u^2.5 at u = 0: finite value and Jacobian, infinite third Taylor coefficient."""
    def residual(u, u_old, t, dt, p):
        return (u - u_old) / dt - 1.0 + u ** 2.5

    err = _nonfinite(residual, jaxanm.ANM(order=5, tol=1e-8))
    assert err.step == 1 and "series coefficients are not finite" in str(err)
    assert err.amax == 0.0 and err.stats.factorizations >= 1 and err.stats.series_orders > 0
    # Newton never forms the series: it solves the same problem
    sol = _integrate(residual, jaxanm.Newton(tol=1e-10))
    assert np.all(np.isfinite(sol.xs))


@pytest.mark.parametrize("solver", SOLVERS, ids=lambda s: type(s).__name__)
def test_nan_at_the_accepted_state(solver):
    """The residual is finite at the start of each step and NaN once u > 0.5: the solver's state
    is fine, its residual is not.  Recorded as a NonFiniteError, never appended as a NaN norm."""
    def residual(u, u_old, t, dt, p):
        return (u - u_old) / dt - 10.0 + jnp.where(u > 0.5, jnp.nan, 0.0)

    err = _nonfinite(residual, solver, t1=0.2, dt=0.1)
    assert err.step == 1 and err.stats.dt_halvings == 4
    # ANM reaches the bad state by its series (a_max = inf: the residual is linear in u there);
    # Newton's second iteration evaluates the residual there
    expected = "the accepted state" if isinstance(solver, jaxanm.ANM) else "Newton residual is not finite"
    assert expected in str(err)
    assert not any(np.isnan(err.stats.residual_norm))
