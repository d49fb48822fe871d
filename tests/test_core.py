"""Core engine: ANM vs Newton, validity range, continuation, colouring, float64, errors."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
from model_problems import heat_1d, impulsive_cubic

import jaxanm
from jaxanm import evaluate_series


def _run(problem, solver, **kw):
    residual, x0, params = problem
    kw = {"t0": 0.0, "t1": 1.0, "dt": 1e-2, **kw}
    return jaxanm.integrate(residual, x0, params, solver=solver, **kw)


def test_anm_newton_agree_and_anm_factorizes_10x_less():
    """Same discrete problem: ANM, Newton, modified Newton agree within their tolerances."""
    problem = heat_1d()
    anm = _run(problem, jaxanm.ANM(order=7, tol=1e-8))
    newton = _run(problem, jaxanm.Newton(tol=1e-10))
    mnewton = _run(problem, jaxanm.ModifiedNewton(tol=1e-10))
    ref = newton.xs
    scale = np.abs(ref).max()
    assert np.abs(anm.xs - ref).max() / scale < 1e-6
    assert np.abs(mnewton.xs - ref).max() / scale < 1e-8
    assert anm.stats.time_steps == newton.stats.time_steps == 100
    assert newton.stats.factorizations >= 10 * anm.stats.factorizations
    assert all(a >= 1.0 for a in anm.stats.amax) and len(anm.stats.amax) == 100
    # the accepted ANM states satisfy the step equations to series accuracy (the source is O(5))
    assert max(anm.stats.residual_norm) < 1e-4


def test_tighter_anm_tolerance_gets_closer_to_the_exact_step_solution():
    """Two tolerances that both bind: each run stays within its promise, and the tighter one is closer.

    Every tol from 1e-2 to 1e-7 accepts the same series here (one K*, a_max >= 1.03 at tol 1e-7),
    so only tolerances that change the series can show an effect: 1e-8 (20 factorisations) and
    1e-10 (59).  Each accepted state is within ``CHECK_LIMIT tol |x_k - x_{k-1}|`` of its step's
    solution (the end-point check) and the steps are contractive, so a run errs by at most
    ``CHECK_LIMIT tol sum_k |x_k - x_{k-1}|`` (as in tests/test_anm_pade.py; Newton at tol
    1e-12 is exact to that scale)."""
    problem = heat_1d()
    ref = _run(problem, jaxanm.Newton(tol=1e-12), t1=0.2).xs
    path = np.linalg.norm(np.diff(ref, axis=0), axis=1).sum()
    runs = [_run(problem, jaxanm.ANM.paper(order=7, tol=tol), t1=0.2) for tol in (1e-8, 1e-10)]
    assert 1 < runs[0].stats.factorizations < runs[1].stats.factorizations  # different series
    errs = [np.abs(run.xs - ref).max() for run in runs]
    for err, tol in zip(errs, (1e-8, 1e-10)):
        assert err <= jaxanm._acceptance.CHECK_LIMIT * tol * path
    # The claim itself compares two errors, which no bound orders; the margin is 7e4 (2.9e-10
    # against 3.9e-15).  The loose run's error is a truncation error, not round-off: its worst
    # step (the 5th) is accepted at a_max = 1.01, where eq. 26 leaves a last term of about
    # tol |c_1| = 1.6e-9 (2-norm, 40 unknowns).  The tight run's sits at 35 eps max|x|, which
    # another CPU's rounding moves by ulps, not by 1e4.  The decisions a_max >= 1 lie >= 0.8 %
    # from the threshold, while round-off moves a_max by ~eps |c_1| / |c_7| / 6 ~ 1e-8
    # relative.  Same values with XLA_FLAGS=--xla_cpu_max_isa=AVX2.
    assert errs[1] < errs[0]


def _homotopy_path_quadratic(b, k, a):
    """Exact root of (1-a) k (d - 0) + a (d^2 - b) = 0 through d(0) = 0 (closed form)."""
    return (-(1 - a) * k + np.sqrt(((1 - a) * k) ** 2 + 4 * a * a * b)) / (2 * a)


def test_series_reproduces_exact_homotopy_path_within_amax():
    """Scalar R(d) = d^2 - b from d_s = 0 with K* = 1: the path d(a) is known in closed form."""
    b, k, p, tol = 0.6, 1.0, 15, 1e-6

    def residual(d, d_old, t, dt, params):
        return d**2 - b

    problem = jaxanm._problem.Problem(residual, np.ones(1), jaxanm.Stats(), "dense", None)
    with jaxanm.float64():
        args = (np.zeros(1), jnp.float64(1.0), jnp.float64(1.0), None)
        fact = jaxanm.factorize(np.array([[k]]), problem.stats)
        coeffs = np.zeros((p, 1))
        coeffs[0] = -fact.solve(problem.residual(np.zeros(1), *args))
        for j in range(2, p + 1):
            coeffs[j - 1] = coeffs[j - 2] - fact.solve(problem.series(np.zeros(1), coeffs[: p - 1], *args)[j - 2])
    amax = jaxanm.validity_range(coeffs, np.ones(1), tol)
    # (tol |c_1| / |c_15|)^(1/14) of the closed-form path's Taylor coefficients, computed to
    # round-off: 0.26, a property of the path (its radius is below 1), not of the CPU
    assert 0.1 < amax < 1.0
    for a in (0.25 * amax, 0.5 * amax, amax):
        exact = _homotopy_path_quadratic(b, k, a)
        assert abs(evaluate_series(coeffs, a)[0] - exact) <= 10 * tol * abs(coeffs[0, 0])


def test_validity_range_formula():
    c = np.array([[2.0, 0.0], [0.0, 1.0], [3e-4, 4e-4]])  # |c1| = 2, |c3| = 5e-4
    scale = np.array([1.0, 1.0])
    assert jaxanm.validity_range(c, scale, 1e-6) == pytest.approx((1e-6 * 2 / 5e-4) ** 0.5)
    assert jaxanm.validity_range(np.array([[1.0], [0.0]]), np.ones(1), 1e-6) == np.inf
    assert jaxanm.validity_range(np.array([[1.0], [np.nan]]), np.ones(1), 1e-6) == 0.0
    # criterion "state": the larger of eq. 26 and (tol |d_s| / |c_p|)^(1/p), |d_s| = 10
    state = np.array([10.0, 0.0])
    assert jaxanm.validity_range(c, scale, 1e-6, state=state) == pytest.approx((1e-6 * 10 / 5e-4) ** (1 / 3))
    assert jaxanm.validity_range(c, scale, 1e-6, state=1e-3 * state) == pytest.approx((1e-6 * 2 / 5e-4) ** 0.5)


def test_state_criterion_bounds_the_error_by_tol_times_the_state():
    """criterion="state" accepts when the last term is below tol |x|: each step then errs by about
    tol |x|, and 100 contractive implicit-Euler steps by at most 100 tol |x|; it never needs more
    factorisations than eq. 26, which asks the same relative accuracy of the (smaller) increment."""
    problem = heat_1d()
    tol = 1e-8
    ref = _run(problem, jaxanm.Newton(tol=1e-13)).xs[-1]
    by_increment = _run(problem, jaxanm.ANM.paper(order=5, tol=tol))
    by_state = _run(problem, jaxanm.ANM.paper(order=5, tol=tol, criterion="state"))
    assert np.abs(by_state.xs[-1] - ref).max() < 100 * tol * np.linalg.norm(ref)
    assert by_state.stats.factorizations <= by_increment.stats.factorizations
    assert by_state.stats.series_orders < by_increment.stats.series_orders


def test_impulsive_start_uses_in_step_continuation_and_converges():
    problem = impulsive_cubic()
    anm = _run(problem, jaxanm.ANM.paper(order=7, tol=1e-8), t1=0.05)
    newton = _run(problem, jaxanm.Newton(tol=1e-12), t1=0.05)
    assert anm.stats.substeps > 0
    assert anm.stats.factorizations > 1
    np.testing.assert_allclose(anm.xs[-1], newton.xs[-1], rtol=1e-6)
    forcing = np.linspace(50.0, 200.0, 5)
    u = anm.xs[-1]
    np.testing.assert_allclose(u**3 + u, forcing, rtol=1e-5)  # the quasi-static state


def test_stale_kstar_is_refactorised_when_the_series_fails():
    """Smooth start, then the source doubles at t = 0.5: the old K* fails and is replaced."""
    residual0, x0, params = heat_1d()

    def residual(u, u_old, t, dt, p):
        return residual0(u, u_old, t, dt, p) - jnp.where(t > 0.5, 40.0, 0.0)

    sol = jaxanm.integrate(residual, x0, params, t0=0.0, t1=1.0, dt=1e-2, solver=jaxanm.ANM(order=5, tol=1e-8))
    assert sol.stats.factorizations >= 2
    ref = jaxanm.integrate(residual, x0, params, t0=0.0, t1=1.0, dt=1e-2, solver=jaxanm.Newton(tol=1e-12))
    assert np.abs(sol.xs[-1] - ref.xs[-1]).max() < 1e-5 * np.abs(ref.xs[-1]).max()


@dataclasses.dataclass(frozen=True)
class _AtMost(jaxanm.Newton):
    """Newton that refuses (StepFailure) every step longer than ``h_max``: the fixed-step
    controller's halving is then the only thing that decides the step sizes."""

    h_max: float = 0.0

    def step(self, state, step, x_old, t, dt, params):
        if dt > self.h_max:
            raise jaxanm.StepFailure(f"dt {dt} > {self.h_max}", step=step, t=t)
        return super().step(state, step, x_old, t, dt, params)


@pytest.mark.parametrize("controller", [None, jaxanm.ConstantStepSize()])
def test_fixed_steps_halve_a_failed_step_into_halves_of_one_recorded_step(controller):
    """x' = -lam x with steps of dt that the solver refuses above dt/4: each step is redone as
    two halves, each of them as two quarters (3 halvings a step), recorded once at its end, so
    x_k = x0 (1 + lam dt/4)^(-4k), the closed form of four implicit-Euler quarter steps."""
    lam, dt = 3.0, 0.1
    decay = lambda x, x_old, t, h, p: (x - x_old) / h + p["lam"] * x  # noqa: E731
    solver = _AtMost(tol=1e-12, h_max=dt / 4 * 1.001)
    sol = jaxanm.integrate(decay, np.ones(1), {"lam": lam}, t0=0.0, t1=0.5, dt=dt, solver=solver, controller=controller)
    k = np.arange(6)
    np.testing.assert_allclose(sol.ts, k * dt, rtol=0, atol=1e-15)  # t0 + k dt, rounded once
    # Newton on a linear residual: one iteration, exact up to round-off of a few operations per step
    np.testing.assert_allclose(sol.xs[:, 0], (1 + lam * dt / 4) ** (-4.0 * k), rtol=1e-13)
    assert sol.stats.time_steps == 5 and sol.stats.dt_halvings == 3 * 5


def test_failed_step_is_halved_then_reports_step_time_amax():
    problem = impulsive_cubic()
    strict = jaxanm.ANM.paper(order=4, tol=1e-8, max_substeps=0)
    sol = _run(problem, strict, t1=0.02, max_dt_halvings=30)
    assert sol.stats.dt_halvings > 0 and np.all(np.isfinite(sol.xs))
    with pytest.raises(jaxanm.StepFailure) as info:
        _run(problem, strict, t1=0.02, max_dt_halvings=0)
    err = info.value
    assert err.step == 1 and err.amax is not None and err.amax < 1
    assert "a_max" in str(err) and "step 1" in str(err)


def test_nonfinite_residual_raises_named_error():
    def residual(u, u_old, t, dt, p):
        return (u - u_old) / dt - jnp.sqrt(1.2 - 10 * t) * jnp.ones_like(u)  # NaN from step 3 (t = 0.15) on

    with pytest.raises(jaxanm.NonFiniteError, match="not finite"):
        jaxanm.integrate(residual, np.zeros(3), None, t0=0, t1=0.5, dt=0.05, solver=jaxanm.ANM())
    with pytest.raises(jaxanm.NonFiniteError, match="step 3"):
        jaxanm.integrate(residual, np.zeros(3), None, t0=0, t1=0.5, dt=0.05, solver=jaxanm.Newton())


def _random_stencil_problem(n=60, seed=1):
    rng = np.random.default_rng(seed)
    index = np.stack([np.arange(n), *(rng.integers(0, n, n) for _ in range(4))], axis=1)
    weights = rng.standard_normal(index.shape)

    def residual(x, x_old, t, dt, p):
        g = (p["w"] * x[p["idx"]]).sum(axis=1)
        return x - x_old + dt * (g**3 + jnp.exp(0.1 * g) * x)

    params = {"idx": index, "w": weights}
    rows = np.repeat(np.arange(n), index.shape[1])
    pattern = scipy.sparse.csc_matrix((np.ones(rows.size), (rows, index.ravel())), shape=(n, n))
    pattern = pattern + scipy.sparse.identity(n)
    return residual, rng.standard_normal(n), params, pattern


def test_sparse_coloured_jacobian_equals_dense():
    residual, x, params, pattern = _random_stencil_problem()
    with jaxanm.float64():
        dense = np.asarray(jax.jacfwd(lambda y: residual(y, x, 0.0, 0.1, params))(jnp.asarray(x)))
        sparse = jaxanm.SparseJacobian(residual, pattern)(x, x, 0.0, 0.1, params)
        detected = jaxanm.detect_sparsity(residual, x, x, 0.0, 0.1, params)
        sparse_detected = jaxanm.SparseJacobian(residual, detected)(x, x, 0.0, 0.1, params)
    assert sparse.dtype == np.float64
    np.testing.assert_allclose(sparse.toarray(), dense, rtol=0, atol=1e-12 * np.abs(dense).max())
    np.testing.assert_allclose(sparse_detected.toarray(), dense, rtol=0, atol=1e-12 * np.abs(dense).max())


def test_colours_seeded_in_batches_give_the_same_jacobian(monkeypatch):
    # a memory budget below one batch of all colours: lax.map over batches of a power of two
    # (here 4 colours of the 16 padded), the same jvps as one vmap
    from jaxanm import jacobian

    residual, x, params, pattern = _random_stencil_problem()
    with jaxanm.float64():
        whole = jaxanm.SparseJacobian(residual, pattern)
        monkeypatch.setattr(jacobian, "JACOBIAN_MEMORY_BYTES", 5 * 16 * pattern.nnz)
        batched = jacobian.SparseJacobian(residual, pattern)
        assert whole.batch is None and batched.batch == 4
        a, b = whole(x, x, 0.0, 0.1, params), batched(x, x, 0.0, 0.1, params)
    # the same arithmetic per colour; vmap and the batched loop may vectorise it differently
    np.testing.assert_allclose(b.toarray(), a.toarray(), rtol=0, atol=1e-14 * np.abs(a).max())


def test_colour_batches_are_powers_of_two_within_the_budget():
    from jaxanm.jacobian import color_batch

    assert color_batch(nnz=1000, n_colors=32, budget=16 * 1000 * 32) is None  # all fit
    assert color_batch(nnz=1000, n_colors=32, budget=16 * 1000 * 31) == 16
    assert color_batch(nnz=1000, n_colors=32, budget=16 * 1000 * 5) == 4
    assert color_batch(nnz=1000, n_colors=32, budget=10) == 1


def test_colouring_is_valid_and_tight_on_a_tridiagonal_pattern():
    n = 50
    tri = scipy.sparse.diags([1.0, 1.0, 1.0], [-1, 0, 1], shape=(n, n))
    colors = jaxanm.color_columns(tri)
    assert colors.max() + 1 == 3
    _, x, _, pattern = _random_stencil_problem()
    colors = jaxanm.color_columns(pattern)
    csr = scipy.sparse.csr_matrix(pattern)
    for r in range(csr.shape[0]):
        cols = csr.indices[csr.indptr[r] : csr.indptr[r + 1]]
        assert len(set(colors[cols])) == len(cols)  # no two columns of a row share a colour


def test_float64_end_to_end_without_global_flag():
    assert not jax.config.jax_enable_x64  # the tests never flip it; jaxanm must not either
    residual, x0, params = heat_1d(10)
    sol = _run((residual, x0.astype(np.float32), params), jaxanm.ANM(), t1=0.05)
    assert sol.xs.dtype == np.float64
    terms = jaxanm.taylor_coefficients(lambda x: jnp.exp(x), jnp.zeros(2), [jnp.ones(2)] * 3)
    assert all(t.dtype == jnp.float64 for t in terms)
    assert not jax.config.jax_enable_x64
    with pytest.warns(UserWarning, match="converted to float64"):
        sol = _run((residual, x0, {"c": jnp.asarray(1.0), "r": np.float32(1.0)}), jaxanm.ANM(), t1=0.02)
    assert sol.xs.dtype == np.float64


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"dt": -1.0}, "dt must be > 0"),
        ({"t1": -1.0}, "t1 must be > t0"),
        ({"solver": "anm"}, "solver must be"),
        ({"scale": -1.0}, "scale must be positive"),
        ({"jacobian": "lu"}, "jacobian must be"),
        ({"saveat": [0.05]}, "saveat must be"),
    ],
)
def test_bad_input_is_rejected_before_computing(kwargs, match):
    residual, x0, params = heat_1d(5)
    base = {"t0": 0.0, "t1": 0.1, "dt": 0.01, "solver": jaxanm.ANM()}
    with pytest.raises(jaxanm.InputError, match=match):
        jaxanm.integrate(residual, x0, params, **{**base, **kwargs})


def test_bad_solver_options_are_rejected():
    with pytest.raises(jaxanm.InputError, match="order"):
        jaxanm.ANM(order=1)
    with pytest.raises(jaxanm.InputError, match="tol"):
        jaxanm.Newton(tol=0.0)
    with pytest.raises(jaxanm.InputError, match="criterion must be 'increment'"):
        jaxanm.ANM(criterion="relative")
    with pytest.raises(jaxanm.InputError, match="non-finite"):
        jaxanm.integrate(lambda x, *a: x, np.array([np.nan]), None, t0=0, t1=1, dt=0.1, solver=jaxanm.ANM())


def test_bad_saveat_is_rejected():
    with pytest.raises(jaxanm.InputError, match=r"SaveAt.steps must be an integer >= 1, got 0"):
        jaxanm.SaveAt(steps=0)
    with pytest.raises(jaxanm.InputError, match=r"SaveAt.steps must be an integer >= 1, got True"):
        jaxanm.SaveAt(steps=True)  # a bool is no step count
    with pytest.raises(jaxanm.InputError, match=r"SaveAt.params must be True or False, got 'yes'"):
        jaxanm.SaveAt(params="yes")
    with pytest.raises(jaxanm.InputError, match="not both"):
        jaxanm.SaveAt(ts=[0.1], steps=2)
    with pytest.raises(jaxanm.InputError, match="give fn too"):
        jaxanm.SaveAt(fn_ts=[0.1, 0.2])
    with pytest.raises(jaxanm.InputError, match="fn_ts must be increasing finite times"):
        jaxanm.SaveAt(fn=lambda t, x, p: {}, fn_ts=[0.2, 0.1])


def test_save_at_and_params_history():
    residual, x0, params = heat_1d(8)
    sol = _run((residual, x0, params), jaxanm.ANM(), t1=0.1, saveat=jaxanm.SaveAt(ts=[0.03, 0.05], params=True))
    np.testing.assert_allclose(sol.ts, [0.0, 0.03, 0.05, 0.1])
    assert len(sol.params) == 4 and sol.xs.shape == (4, 8)


def test_after_step_remap_changes_the_discretisation_without_changing_the_solution():
    """A hook that changes the unknowns' basis (here: a per-unknown scaling y = s x, renewed after
    every step, like rebuilt MLS stencils) and remaps the state onto it with ``Remap`` gives the
    same fields as the plain run; changing the basis without remapping does not."""
    residual0, x0, params0 = heat_1d()
    rng = np.random.default_rng(3)

    def residual(y, y_old, t, dt, p):
        return residual0(y / p["s"], y_old / p["s_old"], t, dt, params0)

    def rebasis(remap):
        def after_step(t, y, p):
            s_new = np.asarray(p["s"]) * rng.uniform(0.5, 2.0, y.shape)
            p_new = {"s": s_new, "s_old": s_new}
            return jaxanm.Remap(p_new, np.asarray(y) / np.asarray(p["s"]) * s_new) if remap else p_new
        return after_step

    s0 = np.ones_like(x0)
    kw = dict(t0=0.0, t1=0.3, dt=1e-2, solver=jaxanm.Newton(tol=1e-12),
              saveat=jaxanm.SaveAt(params=True))
    plain = jaxanm.integrate(residual0, x0, params0, **kw)
    remapped = jaxanm.integrate(residual, x0, {"s": s0, "s_old": s0}, after_step=rebasis(True), **kw)
    ignored = jaxanm.integrate(residual, x0, {"s": s0, "s_old": s0}, after_step=rebasis(False), **kw)
    scale = np.abs(plain.xs[-1]).max()
    fields = remapped.xs[-1] / remapped.params[-1]["s"]
    assert np.abs(fields - plain.xs[-1]).max() < 1e-9 * scale
    assert np.abs(ignored.xs[-1] / ignored.params[-1]["s"] - plain.xs[-1]).max() > 1e-3 * scale
    with pytest.raises(jaxanm.InputError, match="Remap state of shape"):
        jaxanm.integrate(residual0, x0, params0, after_step=lambda t, x, p: jaxanm.Remap(p, x[:-1]),
                         **{**kw, "t1": 0.02})


@pytest.mark.parametrize("dominant", ["diagonal", "off-diagonal"])
@pytest.mark.parametrize("limit", [10**6, 10], ids=["symmetric-mode", "nested-dissection"])
def test_sparse_lu_solves_in_both_orderings(limit, dominant, monkeypatch):
    # the symmetric-mode ordering up to SYMMETRIC_MAX_UNKNOWNS unknowns, nested dissection
    # above: both must solve a non-symmetric sparse matrix to backward-stable accuracy, for one
    # or several right-hand sides, also where every pivot has to leave the diagonal (the large
    # entries on a cyclic shift, the diagonal only random fill)
    from jaxanm import _factorization as linalg

    monkeypatch.setattr(linalg, "SYMMETRIC_MAX_UNKNOWNS", limit)
    n = 60
    rng = np.random.default_rng(5)
    big = (scipy.sparse.identity(n) if dominant == "diagonal"
           else scipy.sparse.eye(n, k=1) + scipy.sparse.eye(n, k=1 - n))
    a = scipy.sparse.random(n, n, density=0.08, random_state=rng) + 4.0 * big
    b = rng.standard_normal((n, 3))
    lu = linalg.sparse_lu(a)
    assert isinstance(lu, linalg.NestedDissectionLU) == (limit < n)
    x = lu.solve(b)
    assert x.shape == b.shape
    # LU with (threshold) pivoting on a matrix whose large entries form a permutation (the
    # pivots taken, growth factor ~1) is backward stable: residual ~ n eps |A|_inf |x|_inf,
    # with a factor 10 for the constant of the bound
    norm_a = abs(a).sum(axis=1).max()
    assert np.abs(a @ x - b).max() <= 10 * n * np.finfo(float).eps * norm_a * np.abs(x).max()
    x1 = lu.solve(b[:, 1])  # one right-hand side: the same bound
    assert x1.shape == (n,)
    assert np.abs(a @ x1 - b[:, 1]).max() <= 10 * n * np.finfo(float).eps * norm_a * np.abs(x1).max()
