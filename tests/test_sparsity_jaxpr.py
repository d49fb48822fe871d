"""Sparsity patterns from the residual's jaxpr (``jaxanm.detect_sparsity``, index sets per
element) against dense Jacobians, which nobody tuned: on small residuals the pattern must hold
every nonzero of ``jax.jacfwd`` at random states (a superset), and equal the nonzeros found by
dense probes wherever the structure has no entry that vanishes at every state.  Large requests
are refused before they run."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
from model_problems import bratu_1d, bratu_2d, heat_1d, impulsive_cubic
from test_continuation import bratu, truss_residual

import jaxanm
from jaxanm import detect_sparsity
from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.scene import load_scene

N = 12
RNG = np.random.default_rng(7)
INDEX = RNG.integers(0, N, (N, 3))
WEIGHTS = RNG.standard_normal((N, 3))
MASK = np.arange(N) % 3 == 0
MATRIX = np.where(RNG.random((N, N)) < 0.2, RNG.standard_normal((N, N)), 0.0)


def _dense_nonzeros(residual, x, x_old, t, dt, params, states: int = 3) -> np.ndarray:
    """Where ``jax.jacrev`` of the residual (reverse mode: it takes custom_vjp functions too) is
    nonzero at ``x`` and at ``states`` random states."""
    rng = np.random.default_rng(0)
    with jaxanm.float64():
        jac = jax.jit(jax.jacrev(lambda y: residual(y, x_old, t, dt, params)))
        found = np.zeros((np.size(residual(jnp.asarray(x), x_old, t, dt, params)), np.size(x)), dtype=bool)
        for k in range(states + 1):
            y = np.asarray(x, dtype=np.float64) + (k > 0) * rng.standard_normal(np.shape(x))
            found |= np.asarray(jac(jnp.asarray(y))) != 0.0
    return found


def _detected(residual, x, x_old=None, t=0.3, dt=0.1, params=None) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # none of these needs the conservative fallback
        return detect_sparsity(residual, x, x_old, t, dt, params).toarray()


# One residual per kind of primitive rule; each pattern must equal the dense nonzeros exactly
# (every entry here is nonzero at a random state: no structural zero hides).
PRIMITIVES = {
    "elementwise, scalar broadcast": lambda x, xo, t, dt, p: jnp.exp(x) * jnp.sin(x) + x**3 / (1 + x**2) + x.sum(),
    "gather with index params": lambda x, xo, t, dt, p: (p["w"] * x[p["idx"]]).sum(axis=1) ** 2,
    "scatter-add": lambda x, xo, t, dt, p: jnp.zeros(N).at[p["idx"][:, 0]].add(x**2) + x,
    "where, known condition": lambda x, xo, t, dt, p: jnp.where(p["mask"], x, jnp.roll(x, 1) * x[::-1]),
    "where, varying condition": lambda x, xo, t, dt, p: jnp.where(xo > 0, x, jnp.roll(x, 1) ** 2),
    "cond, known index": lambda x, xo, t, dt, p: jax.lax.cond(p["flag"] > 0, lambda z: z**2, lambda z: z[::-1], x),
    "cond, varying index": lambda x, xo, t, dt, p: jax.lax.cond(t > 0, lambda z: z**2, lambda z: z[::-1] ** 2, x),
    "cumsum, custom_jvp, custom_vjp, remat": lambda x, xo, t, dt, p: jnp.cumsum(x) + jax.nn.softplus(x)
    + _custom_vjp_sin(jnp.roll(x, 2)) + jax.checkpoint(lambda z: z[::-1] ** 2)(x),
    "dot with a known sparse matrix": lambda x, xo, t, dt, p: p["A"] @ jnp.tanh(x) + x,
    "dot with a varying matrix": lambda x, xo, t, dt, p: jnp.tanh(x[:4]) @ xo.reshape(4, 3) @ x[4:7] * x,
    "reshape, transpose, pad, slice": lambda x, xo, t, dt, p: (
        jnp.pad(x.reshape(3, 4).T, ((1, 0), (0, 2)))[:4, 1:4].ravel() ** 2 + x),
    "pad with interior, concatenate, split": lambda x, xo, t, dt, p: jnp.concatenate(
        [jax.lax.pad(x[:6], 0.0, ((0, 0, 1),))[:6], jnp.split(x, 2)[1] ** 2]),
    "dynamic slice, rev, reductions": lambda x, xo, t, dt, p: jnp.tile(
        jax.lax.dynamic_slice(x[::-1], (p["start"],), (4,)), 3) * jnp.max(x[:3]) + jnp.prod(x[-2:]),
    "zero derivatives": lambda x, xo, t, dt, p: jnp.sign(x) * jnp.floor(xo) + (x > 0) * 1.0 + x,
}


@jax.custom_vjp
def _custom_vjp_sin(x):
    return jnp.sin(x)


_custom_vjp_sin.defvjp(lambda x: (jnp.sin(x), x), lambda x, g: (g * jnp.cos(x),))


@pytest.mark.parametrize("name", list(PRIMITIVES))
def test_primitive_rules_give_the_dense_jacobians_nonzeros(name):
    residual = PRIMITIVES[name]
    params = {"idx": INDEX, "w": WEIGHTS, "mask": MASK, "A": MATRIX, "flag": np.float64(1.0), "start": 5}
    x = RNG.standard_normal(N)
    x_old = RNG.standard_normal(N)
    detected = _detected(residual, x, x_old, 0.3, 0.1, params)
    # the varying arguments' values are not read: the pattern is that of every x_old and t
    # (the varying condition and index pick either case; all x_old make the dot's matrix dense)
    dense = _dense_nonzeros(residual, x, x_old, 0.3, 0.1, params)
    if "varying" in name:
        dense |= _dense_nonzeros(residual, x, -x_old, -0.3, 0.1, params)
    np.testing.assert_array_equal(detected, dense)


def test_an_unknown_primitive_falls_back_to_a_superset_with_a_warning():
    def residual(x, x_old, t, dt, params):  # sort: no rule, its output depends on all its input
        return jnp.sort(x[:4]).sum() + x

    x = RNG.standard_normal(N)
    with pytest.warns(UserWarning, match="'sort'"):
        detected = detect_sparsity(residual, x, None, 0.0, 0.1, None).toarray()
    expected = np.eye(N, dtype=bool)
    expected[:, :4] = True
    np.testing.assert_array_equal(detected, expected)


def test_an_index_computed_from_the_unknowns_falls_back_to_a_superset():
    def residual(x, x_old, t, dt, params):  # the element read moves with x: it may be any of x
        return x[jnp.argmax(x[:5])] * x

    x = RNG.standard_normal(N)
    with pytest.warns(UserWarning, match="'dynamic_slice'"):
        detected = detect_sparsity(residual, x, None, 0.0, 0.1, None).toarray()
    assert detected.all()
    assert (detected >= _dense_nonzeros(residual, x, None, 0.0, 0.1, None)).all()


MODEL_PROBLEMS = {"heat_1d": heat_1d(15), "bratu_1d": bratu_1d(15), "impulsive_cubic": impulsive_cubic(5)}


@pytest.mark.parametrize("name", list(MODEL_PROBLEMS))
def test_model_step_residuals_match_dense_probes(name):
    residual, x0, params = MODEL_PROBLEMS[name]
    detected = _detected(residual, x0, x0, 0.1, 0.01, params)
    probes = detect_sparsity(residual, x0, x0, 0.1, 0.01, params, method="probes").toarray()
    np.testing.assert_array_equal(detected, probes)


def _lam_factor(u, lam, params):
    """An entry with a factor lam: the coupling to u[i+1] vanishes at lam = 0."""
    up = jnp.concatenate([u, jnp.zeros(1)])
    return u**3 - 2.0 * u + lam * up[1:]


PATH_RESIDUALS = {"bratu 1D": (bratu(9), 9), "bratu 2D": (bratu_2d(5), 25), "truss": (truss_residual, 2),
                  "factor lam": (_lam_factor, 6)}


@pytest.mark.parametrize("name", list(PATH_RESIDUALS))
def test_path_residuals_hold_every_lam(name):
    """At lam = 0 the dense Jacobian of the lam-factor residual lacks the coupling; the pattern,
    which does not read lam, has it: it equals the dense nonzeros at lam = 1."""
    residual, n = PATH_RESIDUALS[name]
    step = lambda x, x_old, t, dt, params: residual(x, t, params)  # noqa: E731 - lam in t, as path following
    u = np.zeros(n)
    detected = _detected(step, u, None, 0.0, None, None)
    at_zero = _dense_nonzeros(step, u, None, 0.0, None, None)
    at_one = _dense_nonzeros(step, u, None, 1.0, None, None)
    np.testing.assert_array_equal(detected, at_zero | at_one)
    assert (name == "factor lam") == (at_zero != at_one).any()


def test_continuation_without_a_pattern_finds_it_from_the_jaxpr():
    """The sparse bordered matrix of the 2D Bratu with the pattern found equals the one with
    the pattern given: the same branch to the last bit."""
    m = 8
    line = scipy.sparse.diags([1, 1, 1], [-1, 0, 1], shape=(m, m), dtype=bool)
    pattern = scipy.sparse.kron(line, scipy.sparse.eye(m)) + scipy.sparse.kron(scipy.sparse.eye(m), line)
    runs = [jaxanm.newton_continuation(bratu_2d(m), np.zeros(m * m), 0.0, max_steps=3, jacobian="sparse",
                                       sparsity=given) for given in (pattern, None)]
    np.testing.assert_array_equal(runs[0].u, runs[1].u)


def test_integrate_without_a_pattern_finds_it_from_the_jaxpr():
    """A sparse run with no pattern colours the pattern found: the same steps as with the
    pattern given, to the last bit."""
    residual, x0, params = heat_1d(30)
    pattern = scipy.sparse.diags([1, 1, 1], [-1, 0, 1], shape=(30, 30), dtype=bool)
    runs = [jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.05, dt=0.01, solver=jaxanm.Newton(tol=1e-10),
                             jacobian="sparse", sparsity=given) for given in (pattern, None)]
    np.testing.assert_array_equal(runs[0].xs, runs[1].xs)


FSW_SCENES = ["fsw_small", "conduction_small"]  # coupled physics, and heat alone (couette: part of fsw_small)


@pytest.mark.parametrize("name", FSW_SCENES)
def test_fsw_residuals_lie_between_their_jacobians_nonzeros_and_the_models_pattern(name, record_property):
    """The FSW model gives its own pattern (every field of a point coupled to every field of its
    stencil: a superset).  The detected one must hold every nonzero of the Jacobian at a random
    state (coloured on the model's pattern, exact) and lie within the model's."""
    scene = load_scene(name)
    if "lagrangian" in scene.effects:  # fixed points: the stencils stay those of the params
        scene = scene.with_overrides({"effects": ",".join(e for e in scene.effects if e != "lagrangian")})
    model, params, x0 = (lambda d: (d.model, d.params, d.x0))(discretise(scene))
    dt = scene.time.dt
    detected = _detected(model.residual, x0, x0, dt, dt, params)
    given = model.sparsity(params).toarray() != 0
    x = x0 * (1.0 + 0.1 * RNG.standard_normal(x0.size)) + 1e-3 * model.scale() * RNG.standard_normal(x0.size)
    with jaxanm.float64():
        values = jaxanm.SparseJacobian(model.residual, given)(x, x0, dt, dt, jax.device_put(params)).toarray()
    assert not (values != 0)[~detected].any()
    assert not detected[~given].any()
    record_property("nnz", {"detected": int(detected.sum()), "model": int(given.sum()),
                            "jacobian": int((values != 0).sum())})


def test_a_dense_pattern_is_refused_before_it_is_built():
    """Every residual couples to sum(x): n^2 = 4e8 entries, above the limit: an InputError that
    names the fix, raised before the sets are made (no memory is spent)."""
    def residual(x, x_old, t, dt, params):
        return x * jnp.sum(x)

    with pytest.raises(jaxanm.InputError, match="jacobian='dense'.*sparsity="):
        detect_sparsity(residual, np.zeros(20000), None, 0.0, 0.1, None)


def test_a_pattern_with_a_dense_row_is_refused_before_it_is_coloured():
    """One equation reads all 20,000 unknowns (a global constraint): its columns all meet in that
    row, so the colouring needs 20,000 colours and P^T P 4e8 edges; refused, naming the row."""
    n = 20000
    rows = np.concatenate([np.arange(n), np.zeros(n, dtype=int)])
    pattern = scipy.sparse.csr_matrix((np.ones(2 * n, dtype=bool), (rows, np.tile(np.arange(n), 2))), shape=(n, n))
    with pytest.raises(jaxanm.InputError, match="row 0 couples 20000 of 20000.*jacobian='dense'"):
        jaxanm.color_columns(pattern)


def test_dense_jacobians_that_cannot_fit_are_refused_before_they_start():
    """A million unknowns: a dense Jacobian is 8 TB; every entry point says which argument to change."""
    n = 10**6
    residual = bratu_2d(1000)
    with pytest.raises(jaxanm.InputError, match="jacobian='dense'.*jacobian='sparse'"):
        jaxanm.continuation(residual, np.zeros(n), 0.0, jacobian="dense", max_steps=1)
    with pytest.raises(jaxanm.InputError, match="jacobian='dense'.*jacobian='sparse'"):
        jaxanm.integrate(lambda x, xo, t, dt, p: x - xo, np.zeros(n), None, t0=0.0, t1=1.0, dt=0.5,
                         solver=jaxanm.Newton(), jacobian="dense")
    with pytest.raises(jaxanm.InputError, match="method='jaxpr'"):
        detect_sparsity(lambda x, xo, t, dt, p: x, np.zeros(n), None, 0.0, 0.1, None, method="probes")


def test_large_patterns_cost_no_dense_jacobian():
    """The 2D Bratu on 300 x 300 points: 90,000 unknowns, whose dense Jacobian (65 GB) the dense
    probes formed; the jaxpr gives the 5-point pattern (each row its point and its grid
    neighbours: 5 m^2 - 4 m entries)."""
    m = 300
    step = lambda x, x_old, t, dt, params: bratu_2d(m)(x, t, params)  # noqa: E731
    pattern = detect_sparsity(step, np.zeros(m * m), None, 1.0, None, None)
    line = scipy.sparse.diags([1, 1, 1], [-1, 0, 1], shape=(m, m), dtype=bool)
    expected = (scipy.sparse.kron(line, scipy.sparse.eye(m)) + scipy.sparse.kron(scipy.sparse.eye(m), line)) != 0
    assert pattern.nnz == 5 * m * m - 4 * m
    assert (pattern != expected).nnz == 0


def _greedy_reference(pattern) -> np.ndarray:
    """Largest-first greedy colouring of the columns, written out as a plain loop."""
    csc = scipy.sparse.csc_matrix(pattern, dtype=bool)
    rows_of = [set(csc.indices[csc.indptr[j]:csc.indptr[j + 1]]) for j in range(csc.shape[1])]
    colors = np.full(csc.shape[1], -1)
    for j in np.argsort(-np.diff(csc.indptr), kind="stable"):
        taken = {colors[k] for k in range(csc.shape[1]) if colors[k] >= 0 and rows_of[k] & rows_of[j]}
        colors[j] = min(set(range(len(taken) + 1)) - taken)
    return colors


def test_compiled_colouring_is_the_largest_first_greedy():
    pattern = scipy.sparse.random(60, 60, density=0.08, random_state=3, format="csc") != 0
    pattern = pattern + scipy.sparse.eye(60, dtype=bool)
    colors = jaxanm.color_columns(pattern)
    np.testing.assert_array_equal(colors, _greedy_reference(pattern))
