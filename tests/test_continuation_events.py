"""Events on a branch (:class:`jaxanm.Event`): folds, simple branch points, and switching onto
the bifurcated branch, against closed forms and independent solves.

The discretised Chafee-Infante problem ``u'' + lam (u - u^3) = 0`` on (0, 1), u(0) = u(1) = 0,
central differences on N interior points (h = 1 / (N + 1)): ``u = 0`` is a solution for every
lam, and R_u = A / h^2 + lam I there, singular where lam is an eigenvalue of -A / h^2,

    lam_k = (4 / h^2) sin^2(k pi h / 2),        eigenvector sin(k pi x_i),

each a simple branch point (a pitchfork: the mode-k branch, with k - 1 interior zeros, leaves
u = 0 there).  With N + 1 = 24 the points x = 1 / (2k), k = 1, 2, 3, where the mode-k solution
peaks (it is the mode-1 solution of an interval of length 1 / k, reflected), are grid
points.  The continuum's mode-k branch with peak A has (first integral, u = A sin(theta))

    lam = 4 k^2 K(m)^2 / (1 - A^2 / 2),    m = A^2 / (2 - A^2)

(K the complete elliptic integral of the first kind, parameter m), which the discrete branches
approach at O(h^2).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
import pytest
import scipy.special

import jaxanm

N = 23
H = 1.0 / (N + 1)
ORDER = 8  # series order: the events do not depend on it, and order 8 compiles 6 jets where 15 needs 9
X = np.linspace(H, 1.0 - H, N)
LAM_K = 4.0 / H**2 * np.sin(np.arange(1, 5) * np.pi * H / 2) ** 2


def chafee_infante(u, lam, params):
    """The discrete Chafee-Infante residual; ``params["w"]`` shifts the unknowns,
    ``u = v - sin(lam / 10) w``, so that the trivial branch ``v = sin(lam / 10) w`` has a
    series that is not exact (zero for ``w = 0``)."""
    u = u - jnp.sin(lam / 10.0) * params["w"]
    up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
    return (up[2:] - 2.0 * u + up[:-2]) / H**2 + lam * (u - u**3)


FLAT = {"w": np.zeros(N)}
CURVED = {"w": 2.0 * X * (1.0 - X)}


@functools.lru_cache(maxsize=None)
def trivial_branch(method: str = "anm", curved: bool = False) -> jaxanm.Branch:
    """The trivial branch from lam = 0 to midway between lam_3 and lam_4.  Its series is exact
    (flat), so the steps are bounded by ``max_step`` (ANM) / ``ds_max`` (Newton), below the
    gaps between branch points; the curved one's steps are the series' own."""
    end = 0.5 * (LAM_K[2] + LAM_K[3])
    params = CURVED if curved else FLAT
    if method == "anm":
        return jaxanm.continuation(chafee_infante, np.zeros(N), 0.0, params, lam_end=end, max_steps=100,
                                   max_step=np.inf if curved else 5.0, order=ORDER)
    return jaxanm.newton_continuation(chafee_infante, np.zeros(N), 0.0, params, lam_end=end, max_steps=200,
                                      ds_max=5.0)


@pytest.mark.parametrize("method, curved", [("anm", False), ("newton", False), ("anm", True)])
def test_branch_points_of_the_trivial_branch_at_the_discrete_eigenvalues(method, curved):
    """Three branch points, at lam_1, lam_2, lam_3 to 1e-8 relative (located by Newton on the
    augmented system: measured 1e-14), nothing else; the bifurcated tangent is the
    eigenvector sin(k pi x) (the lam component zero: a pitchfork), to 1e-8."""
    branch = trivial_branch(method, curved)
    assert branch.stopped == "lam_end"
    points = branch.events_of("branch_point")
    assert [e.kind for e in branch.events] == ["branch_point"] * 3
    np.testing.assert_allclose([e.lam for e in points], LAM_K[:3], rtol=1e-8)
    for k, event in enumerate(points, start=1):
        t2 = event.data["tangents"][1]
        mode = np.sin(k * np.pi * X)
        if curved:  # v = u + sin(lam / 10) w: the tangent's v part is u's plus w times d sin / d lam
            t2 = t2[:-1] - np.cos(event.lam / 10.0) / 10.0 * t2[-1] * CURVED["w"]
        else:
            assert abs(t2[-1]) < 1e-8
            t2 = t2[:-1]
        np.testing.assert_allclose(t2 / np.linalg.norm(t2), mode / np.linalg.norm(mode), atol=1e-8)
        assert event.step in range(branch.a.size) and branch.s[event.step] <= event.s <= branch.s[event.step + 1]


def independent_mode(k: int, peak: float) -> float:
    """lam on the discrete mode-k branch where u peaks at ``peak`` (at x = 1 / (2k)), solved
    independently: Newton (dense numpy, the Jacobian by hand) on R(u, lam) = 0 with that value
    fixed, from the eigenvector's shape and lam_k, until its step is below 1e-13 of the state."""
    i = (N + 1) // (2 * k) - 1
    lap = (np.diag(np.full(N, -2.0)) + np.diag(np.ones(N - 1), 1) + np.diag(np.ones(N - 1), -1)) / H**2

    def equations(z):
        u, lam = z[:-1], z[-1]
        return np.append(lap @ u + lam * (u - u**3), u[i] - peak)

    def jacobian(z):
        u, lam = z[:-1], z[-1]
        top = np.column_stack([lap + lam * np.diag(1 - 3 * u**2), u - u**3])
        return np.vstack([top, np.eye(1, N + 1, i)])

    z = np.append(peak * np.sin(k * np.pi * X) / np.sin(k * np.pi * X[i]), LAM_K[k - 1])
    for _ in range(30):
        step = np.linalg.solve(jacobian(z), -equations(z))
        z = z + step
        if np.max(np.abs(step)) < 1e-13 * np.max(np.abs(z)):
            return float(z[-1])
    raise AssertionError(f"the independent solve of mode {k} did not converge")


@pytest.mark.parametrize("method", ["anm", "newton"])
def test_switching_onto_each_mode_follows_it_to_the_peak_asked(method):
    """``branch.switch(event, stop_at=(i, 0.5))`` at each branch point: the branch leaves
    along the mode, reaches u = 0.5 at the mode's peak, has k - 1 interior zeros there, and its
    lam is the independent solve's to 1e-8 relative (both solve the same equations to
    round-off; the branch's points are within tol = 1e-8 of the branch, scaled)."""
    branch = trivial_branch(method)
    for k, event in enumerate(branch.events_of("branch_point"), start=1):
        i = (N + 1) // (2 * k) - 1
        mode = branch.switch(event, stop_at=(i, 0.5))
        print(f"\nmode {k} ({method}): {mode.a.size} steps, {mode.stats.factorizations} factorisations, "
              f"lam = {mode.lam[-1]:.12g}")
        assert mode.stopped == "stop_at" and mode.u[-1, i] == 0.5
        assert mode.lam[0] == event.lam and np.all(mode.u[0] == event.u)  # it starts at the branch point
        u = mode.u[-1]
        assert np.count_nonzero(np.diff(np.sign(u)) != 0) == k - 1
        assert abs(mode.lam[-1] - independent_mode(k, 0.5)) <= 1e-8 * mode.lam[-1]
        assert np.all(mode.residual_norm[1:] <= 1e-6)  # terms of size 4 |u| / h^2 ~ 1e3: 1e-9 relative


def test_the_other_half_of_a_pitchfork_is_the_mirror_image():
    """``direction=-1`` follows -t_2: the Chafee-Infante problem is odd in u, so the other half
    of each pitchfork is the first one with u -> -u, at the same lam (1e-10: both are
    computed to round-off of the same steps)."""
    branch = trivial_branch()
    event = branch.events_of("branch_point")[1]
    up, down = branch.switch(event, stop_at=(5, 0.5)), branch.switch(event, direction=-1, stop_at=(5, -0.5))
    assert up.stopped == down.stopped == "stop_at"
    assert abs(up.lam[-1] - down.lam[-1]) < 1e-10 * up.lam[-1]
    np.testing.assert_allclose(down.u[-1], -up.u[-1], atol=1e-9)


@pytest.mark.slow
def test_mode_branches_converge_to_the_continuum_elliptic_solution_at_second_order():
    """lam at peak A = 0.5 on the mode-k branches (k = 1, 2, 3) for N + 1 = 24, 48, 96 against
    the continuum's ``4 k^2 K(m)^2 / (1 - A^2 / 2)``: errors fall by 4 per halving of h (the
    central difference's O(h^2)); observed orders within 0.05 of 2 (the h^4 term's shift at
    these h, measured below 0.01)."""
    peak, m = 0.5, 0.5**2 / (2 - 0.5**2)
    errors = {}
    for n in (23, 47, 95):
        h = 1.0 / (n + 1)

        def residual(u, lam, params, h=h):
            up = jnp.concatenate([jnp.zeros(1), u, jnp.zeros(1)])
            return (up[2:] - 2.0 * u + up[:-2]) / h**2 + lam * (u - u**3)

        lam_k = 4.0 / h**2 * np.sin(np.arange(1, 5) * np.pi * h / 2) ** 2
        trivial = jaxanm.continuation(residual, np.zeros(n), 0.0, {}, lam_end=0.5 * (lam_k[2] + lam_k[3]),
                                      max_step=5.0, max_steps=100, order=ORDER)
        for k, event in enumerate(trivial.events_of("branch_point"), start=1):
            mode = trivial.switch(event, stop_at=((n + 1) // (2 * k) - 1, peak))
            exact = 4 * k**2 * scipy.special.ellipk(m) ** 2 / (1 - peak**2 / 2)
            errors[n, k] = exact - mode.lam[-1]
    for k in (1, 2, 3):
        e = np.array([errors[n, k] for n in (23, 47, 95)])
        orders = np.log2(e[:-1] / e[1:])
        print(f"mode {k}: errors {e}, observed orders {orders}")
        assert np.all(np.abs(orders - 2.0) < 0.05)


def exponential(u, lam, params):
    """``u - lam e^u = 0``: one unknown, one fold at lam = 1/e (u = 1); past it lam = u e^-u
    falls towards 0 as u grows."""
    return u - lam * jnp.exp(u)


@pytest.mark.parametrize("method", ["anm", "newton"])
def test_only_real_turning_points_are_folds(method):
    """From u = 0 the branch passes its fold at 1/e and runs on where lam ~ u e^-u is flat and
    tiny (its points wobble within tol of it), the ANM's until e^u overflows: exactly one fold, at 1/e to 1e-12 relative
    (polished on the augmented system), not the wiggles of an interpolant or of the points
    (a Newton branch's cubic interpolant had 21 spurious roots of d lam / d a there)."""
    options = dict(order=ORDER) if method == "anm" else {}
    follow = jaxanm.continuation if method == "anm" else jaxanm.newton_continuation
    branch = follow(exponential, np.zeros(1), 0.0, max_steps=1000 if method == "anm" else 200, **options)
    if method == "anm":  # its steps reach u ~ 700, where e^u overflows: the branch ends there, all kept
        assert branch.stopped == "non_finite" and "not finite" in branch.message and branch.a.size > 100
    folds = branch.limit_points()
    assert folds.lam.size == 1 and abs(folds.lam[0] - np.exp(-1.0)) < 1e-12 * np.exp(-1.0)
    assert abs(folds.u[0, 0] - 1.0) < 1e-6  # u at the fold: lam is stationary there, u to sqrt of lam's accuracy
    (fold,) = branch.events
    assert fold.kind == "fold" and fold.data["located"] == "augmented"
    np.testing.assert_allclose(abs(fold.data["left_null_vector"]), [1.0])  # R_u = 1 - lam e^u = 0 at the fold


def test_the_step_hook_sees_every_point_with_its_factorisation():
    """``on_step`` is called at every point, the start included, with the factorised bordered
    matrix (solving with it costs no factorisation), and the events it returns join the
    branch's, in branch order."""
    seen = []

    def hook(end: jaxanm.StepEnd):
        before = end.system.stats.factorizations
        x = end.linearisation.solve(np.ones(N))
        assert end.system.stats.factorizations == before and np.all(np.isfinite(x))
        seen.append((end.index, end.linearisation.slogdet()[0]))
        if end.step is not None and end.step.start[-1] < 20.0 <= end.point[-1]:
            return [jaxanm.Event("crossing", 20.0, end.point[:-1], end.index - 1, end.s, end.tangent)]
        return []

    branch = jaxanm.continuation(chafee_infante, np.zeros(N), 0.0, FLAT, lam_end=45.0, max_step=5.0, on_step=hook,
                                 order=ORDER)
    assert [i for i, _ in seen] == list(range(branch.lam.size))
    assert [e.kind for e in branch.events] == ["branch_point", "crossing", "branch_point"]
    assert sum(a != b for (_, a), (_, b) in zip(seen, seen[1:])) == 2  # det B changed sign twice


def test_events_can_be_turned_off():
    branch = jaxanm.continuation(chafee_infante, np.zeros(N), 0.0, FLAT, lam_end=45.0, max_step=5.0, events=(),
                                 order=ORDER)
    assert branch.events == () and branch.stats.factorizations == branch.lam.size


BAD_STARTS = [
    (lambda b: dict(start=b.events[0], u0=np.zeros(N), lam0=0.0), "either u0 and lam0 or start"),
    (lambda b: dict(start="the first one"), "start must be an Event"),
    (lambda b: dict(start=jaxanm.Event("fold", 1.0, np.zeros(N), 0, 0.0, np.zeros(N + 1))), "branch-point event"),
    (lambda b: dict(start=b.events[0], params={"w": np.ones(N)}), "not a branch point of this problem"),
    (lambda b: dict(start=b.events[0], events=("fold", "hopf")), "events must be"),
    (lambda b: dict(start=b.events[0], on_step=3), "on_step"),
]


@pytest.mark.parametrize("change, words", BAD_STARTS, ids=[w for _, w in BAD_STARTS])
def test_a_bad_start_is_refused_naming_it(change, words):
    """A start event of another problem (other params), of the wrong kind, or given with u0:
    an InputError naming it, before any step."""
    args = dict(params=FLAT)
    args.update(change(trivial_branch()))
    with pytest.raises(jaxanm.InputError, match=words):
        jaxanm.continuation(chafee_infante, **args)
