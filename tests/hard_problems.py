"""The hard cases: configurations that must each end in a finite, checked solution or in a
specific named error.

Every case is a small, fast configuration (coarse FSW clouds, few steps, or the model problems of
``tests/model_problems.py``) and returns an :class:`Outcome`: whether it converged, or which
error it raised with its message; factorisations, continuation sub-steps, dt halvings, wall time
and, for converged cases, an independent check of the accepted state.

The check (``check_ratio``) does not use the solver's machinery: the dense Jacobian of the step
residual by ``jax.jacfwd`` at the accepted state x gives the Newton correction
``delta = J(x)^-1 R(x)``, the first-order distance from x to the exact solution of the implicit
Euler step.  Its scaled norm is compared with what the solver's tolerance promises:

- ANM (eq. 26): a_max >= 1 means ``|c_p| <= tol |c_1|`` for the accepted series, so the
  truncation error is of order ``tol |c_1| <= tol |x - x_old|``: ``check_ratio =
  |delta| / (tol |x - x_old| + 1e-12 |x|)`` (the second term is the round-off floor of a step
  that no longer changes the state, see :data:`ROUND_OFF`);
- Newton / modified Newton: the last relative change is below tol: ``check_ratio = |delta| /
  (tol |x|)``.

A case passes the check when ``check_ratio <= 10`` (a series whose a_max is just above 1 has a
tail beyond order p of a few times ``|c_p|``).  When the last step was split by dt halvings the
step residual of the full step is not the one solved; the halving case checks its final state
against the quasi-static equation instead (see :func:`forced_halving`).

``tests/test_hard_cases.py`` runs the fast ones and asserts their outcomes;
``benchmarks/hard_cases.py`` runs them all and writes the table of
``benchmarks/results/hard_cases.md``.
"""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp
import numpy as np
from model_problems import heat_1d, impulsive_cubic

import jaxanm
from jaxanm.fsw.axisymmetric import radial_finite_volumes
from jaxanm.fsw.discretisation import discretise, make_model
from jaxanm.fsw.geometry import PLATE, build_cloud, cloud_stencils
from jaxanm.fsw.physics import mu_reference
from jaxanm.fsw.scene import load_scene
from jaxanm.fsw.simulate import run as fsw_run
from jaxanm.fsw.stability import TemperatureGuard, heat_modes

ROUND_OFF = 1e-12
"""Floor of the ANM yardstick, relative to |x|: once a step's increment is below round-off (a
converged steady state), ``tol |x - x_old|`` falls under what double precision can resolve; a
state whose Newton distance is 1e-12 |x| is then as exact as the arithmetic allows."""

CHECK_LIMIT = 10.0
"""A converged case passes when ``check_ratio <= CHECK_LIMIT`` (see the module docstring)."""

TINY = {"geometry.dr": "1.125e-3", "time.save": "", "geometry.c": "0.2"}
"""fsw_small at (R2 - R1) / 4: 113 points, 339 unknowns with temperature, with the paper's MLS
weight c = 0.2 (the outcomes below were established with it).  At the scenes' c = 0.3 on this
coarse cloud, Newton no longer converges from rest for n = 0.05, lambda/mu_ref = 1e8, T0 = 800 K
and eps0 = 1e-9 (StepFailure after 4 halvings; the ANM too for lambda/mu_ref = 1e8), while the
points at 0.1 dr converge (measured: benchmarks/results/hard_cases.md)."""


@dataclasses.dataclass
class Outcome:
    """What a hard case ended in (see the module docstring)."""

    case: str
    converged: bool
    error: str | None = None
    message: str | None = None
    factorizations: int = 0
    substeps: int = 0
    dt_halvings: int = 0
    time_steps: int = 0
    check_ratio: float | None = None
    wall_s: float = 0.0
    note: str = ""
    step_iterations: list = dataclasses.field(default_factory=list)
    """Newton iterations of each accepted time step, for the cases that record them (a step
    done in halves counts the iterations of its failed attempts too)."""
    exception: BaseException | None = dataclasses.field(default=None, repr=False)

    @property
    def outcome(self) -> str:
        """``converged`` or the error's class name."""
        return "converged" if self.converged else self.error


def _newton_distance(residual, x, x_old, t, dt, params, scale) -> float:
    """Scaled 2-norm of ``J(x)^-1 R(x)`` with the dense ``jacfwd`` Jacobian (independent check)."""
    with jaxanm.float64():
        f = lambda z: residual(z, jnp.asarray(x_old), jnp.float64(t), jnp.float64(dt), params)  # noqa: E731
        r = np.asarray(f(jnp.asarray(x)))
        J = np.asarray(jax.jacfwd(f)(jnp.asarray(x)))
    return float(np.linalg.norm(np.linalg.solve(J, r) / scale))


def _ratio(solver, residual, x, x_old, t, dt, params, scale) -> float:
    dist = _newton_distance(residual, x, x_old, t, dt, params, scale)
    if isinstance(solver, jaxanm.ANM):
        yard = solver.tol * np.linalg.norm((x - x_old) / scale) + ROUND_OFF * np.linalg.norm(x / scale)
    else:
        yard = solver.tol * np.linalg.norm(x / scale)
    return dist / max(yard, np.finfo(float).tiny)


def _run_case(name, fn, note=""):
    """Time ``fn() -> (stats, check_ratio)``; turn named errors into an :class:`Outcome`."""
    start = time.perf_counter()
    try:
        stats, ratio = fn()
    except (jaxanm.StepFailure, jaxanm.InputError, jaxanm.SingularMatrixError) as exc:
        st = getattr(exc, "stats", None) or jaxanm.Stats()
        return Outcome(name, False, type(exc).__name__, str(exc), factorizations=st.factorizations,
                       substeps=st.substeps, dt_halvings=st.dt_halvings, time_steps=st.time_steps,
                       wall_s=time.perf_counter() - start, note=note, exception=exc)
    return Outcome(name, True, factorizations=stats.factorizations, substeps=stats.substeps,
                   dt_halvings=stats.dt_halvings, time_steps=stats.time_steps, check_ratio=ratio,
                   wall_s=time.perf_counter() - start, note=note)


def _fsw_integrate(overrides, solver, *, steps=None, callback=None):
    """Integrate a tiny FSW scene on fixed points with :func:`jaxanm.integrate`; return ``(stats, ratio)``.

    Fixed points (no Lagrangian motion) so that the accepted states, the old states and the
    params of the last step are at hand for the independent check.  Halved steps are replayed
    from the recorded sub-step boundaries, so the check uses the last sub-step's x_old and dt.
    """
    scene = load_scene("fsw_small").with_overrides({**TINY, **overrides})
    cloud, stencils, model, params, x0 = discretise(scene)
    tm = scene.time
    t1 = tm.t_end if steps is None else steps * tm.dt
    sol = jaxanm.integrate(
        model.residual,
        x0,
        params,
        t0=0.0,
        t1=t1,
        dt=tm.dt,
        solver=solver,
        scale=model.scale(),
        jacobian="sparse",
        sparsity=model.sparsity,
        saveat=jaxanm.SaveAt(steps=1),
        callback=callback,
    )
    x, x_old = sol.xs[-1], sol.xs[-2]
    dt = sol.ts[-1] - sol.ts[-2]
    if sol.stats.dt_halvings:
        return sol.stats, None  # the last full step was split: see the module docstring
    return sol.stats, _ratio(solver, model.residual, x, x_old, sol.ts[-1], dt, params, model.scale())


def _model_integrate(problem, solver, t1, dt, **kw):
    residual, x0, params = problem
    sol = jaxanm.integrate(
        residual, x0, params, t0=0.0, t1=t1, dt=dt, solver=solver, saveat=jaxanm.SaveAt(steps=1), jacobian="dense", **kw
    )
    ratio = None
    if not sol.stats.dt_halvings:
        ratio = _ratio(
            solver, residual, sol.xs[-1], sol.xs[-2], sol.ts[-1], sol.ts[-1] - sol.ts[-2], params, np.ones_like(x0)
        )
    return sol.stats, ratio


# ----------------------------------------------------------------------------------------- cases

ISO = {"effects": "viscous", "time.dt": "1.0", "time.t_end": "1.0"}
"""Isothermal quasi-static power-law flow: one step from rest (the tool turning at full omega,
the plate at rest: an impulsive start) to the steady Couette-like state."""

THERMO = {"effects": "inertia,viscous,softening,conduction,tool_conduction,dissipation,robin"}
"""The full thermo-mechanical model on fixed points (fsw_tracers' physics without the tracers)."""


def impulsive_start(solver=None):
    """Quasi-static impulsive start at the paper's n and eps0 (ANM p=7 by default)."""
    solver = solver or jaxanm.ANM.paper(order=7, tol=1e-6)
    return _run_case(
        f"impulsive tool start, quasi-static ({type(solver).__name__})", lambda: _fsw_integrate(ISO, solver)
    )


def impulsive_start_inertia():
    """Impulsive start of the full thermo-mechanical model with inertia, one step of 1e-4 s (ANM p=7)."""
    return _run_case(
        "impulsive tool start, full physics, dt = 1e-4 (ANM)",
        lambda: _fsw_integrate(THERMO, jaxanm.ANM.paper(order=7, tol=1e-6), steps=1),
    )


def power_law(n, solver):
    """Couette flow of a power-law fluid with index n (0.05: extreme shear thinning; 1: Newtonian)."""
    return _run_case(
        f"n = {n} ({type(solver).__name__})", lambda: _fsw_integrate({**ISO, "material.n": repr(n)}, solver)
    )


EPS0_ZERO = {**ISO, "material.eps0": "1e-9"}
"""The quasi-static impulsive start with eps0 = 1e-9 1/s."""


def epsbar_zero(solver):
    """eps0 = 1e-9 1/s: where the flow is at rest, mu is (1e-2/1e-9)^(1-n) ~ 1e6 times its value
    at eps0 = 1e-2.  Records the Newton iterations of each step in ``step_iterations``."""
    label = type(solver).__name__ + (f", max_iter {solver.max_iter}" if hasattr(solver, "max_iter") else "")
    per_step = []

    def count(t, x, stats):
        per_step.append(stats.newton_iterations - sum(per_step))

    out = _run_case(f"epsbar -> 0, eps0 = 1e-9 ({label})", lambda: _fsw_integrate(EPS0_ZERO, solver, callback=count))
    out.step_iterations = per_step
    if out.converged and per_step and isinstance(solver, jaxanm.Newton):
        out.note = f"Newton iterations per step: {', '.join(map(str, per_step))}"
    return out


def epsbar_zero_capped(needed=None):
    """Newton capped at one iteration fewer than the uncapped run (max_iter 100) needed.

    ``needed`` is the largest number of iterations a step of the uncapped run took (run here
    if not given).  The cap is derived from that run, not fixed: whatever count this CPU's
    round-off leads to, one fewer cannot reach the tolerance along the same iterates.  The
    step is quasi-static (effects ``viscous`` only, no inertia): its residual ignores dt, t and
    x_old, and every attempt starts from x_old, so each dt halving repeats the same Newton
    sequence and fails the same way; the run ends in a StepFailure after every halving.
    """
    if needed is None:
        ref = epsbar_zero(jaxanm.Newton(tol=1e-8, max_iter=100))
        if not ref.converged:
            return ref
        needed = max(ref.step_iterations)
    return epsbar_zero(jaxanm.Newton(tol=1e-8, max_iter=needed - 1))


def penalty(ratio, solver):
    """Penalised incompressibility with lambda = ratio * mu_ref."""
    scene = load_scene("fsw_small").with_overrides({**TINY, **ISO})
    lam = ratio * mu_reference(scene)
    return _run_case(
        f"penalty lambda/mu_ref = {ratio:.0e} ({type(solver).__name__})",
        lambda: _fsw_integrate({**ISO, "mechanics.penalty": repr(lam)}, solver),
    )


def time_step(dt, solver):
    """Two thermo-mechanical steps of size dt (inertia-dominated at 1e-7, conduction-dominated at 1e-2)."""
    return _run_case(
        f"dt = {dt:g}, full physics ({type(solver).__name__})",
        lambda: _fsw_integrate({**THERMO, "time.dt": repr(dt), "time.t_end": repr(2 * dt)}, solver),
    )


def omega_200():
    """Tool speed 200 rad/s (ten times the paper's): two full-physics steps of 1e-4 s."""
    return _run_case(
        "omega = 200 rad/s, full physics (Newton)",
        lambda: _fsw_integrate({**THERMO, "tool.omega": "200", "time.t_end": "2e-4"}, jaxanm.Newton(tol=1e-8)),
    )


def hot_softening():
    """Strong softening up to high temperature: T0 = Ta = 800 K and A = -8 (mu ~ T^-8), dt = 1e-3."""
    return _run_case(
        "thermal softening, T0 = 800 K, A = -8 (Newton)",
        lambda: _fsw_integrate(
            {
                **THERMO,
                "thermal.T0": "800",
                "thermal.Ta": "800",
                "material.A": "-8",
                "time.dt": "1e-3",
                "time.t_end": "2e-3",
            },
            jaxanm.Newton(tol=1e-8),
        ),
    )


def lagrangian_shear():
    """Lagrangian points sheared by the tool: dt = 1e-2 s at omega = 20 rad/s turns the tool by
    0.2 rad per step, so neighbouring rings slide past each other and points come close."""
    scene = load_scene("fsw_small").with_overrides(
        {
            **TINY,
            "effects": "viscous,lagrangian",
            "time.dt": "1e-2",
            "time.t_end": "3e-2",
            "time.save": "1e-2,2e-2",
            "solver.kind": "newton",
            "solver.tol": "1e-8",
        }
    )
    from scipy.spatial import cKDTree

    def closest(points):
        d = cKDTree(points).query(points, k=2)[0][:, 1]
        return d[d > 0].min() / scene.geometry.dr

    before = closest(build_cloud(scene.geometry).points)
    notes = []

    def go():
        try:
            res = fsw_run(scene)
        except jaxanm.StepFailure as exc:
            notes.append(
                f"closest pair {before:.2f} dr at t = 0, {closest(exc.partial.points[-1]):.2f} dr "
                f"at t = {exc.partial.t[-1]:g} s"
            )
            raise
        notes.append(f"closest pair {before:.2f} dr at t = 0, {closest(res.points[-1]):.2f} dr at the end")
        assert np.all(np.isfinite(res.u)) and np.all(np.isfinite(res.points))
        return res.stats, None

    out = _run_case("Lagrangian points sheared by the tool, 3 steps of 1e-2 s (Newton)", go)
    out.note = "; ".join(notes)
    return out


def near_coincident(delta, solver=None):
    """Two plate points drifted to ``delta * dr`` of each other (what Lagrangian motion would
    produce if the flow brought them together): one quasi-static step on that cloud."""
    solver = solver or jaxanm.Newton(tol=1e-8)
    scene = load_scene("fsw_small").with_overrides({**TINY, **ISO})

    def go():
        cloud = build_cloud(scene.geometry)
        plate = np.flatnonzero(cloud.kind == PLATE)
        from scipy.spatial import cKDTree

        nearest = plate[cKDTree(cloud.points[plate]).query(cloud.points[plate[0]], k=2)[1][1]]
        points = cloud.points.copy()
        away = points[plate[0]] - points[nearest]
        points[plate[0]] = points[nearest] + delta * scene.geometry.dr * away / np.linalg.norm(away)
        stencils = cloud_stencils(points, cloud.n_tool, scene.geometry)  # InputError if they coincide
        model = make_model(scene, cloud)
        params = model.params(points, stencils)
        x0 = model.initial_state(points)
        sol = jaxanm.integrate(
            model.residual,
            x0,
            params,
            t0=0.0,
            t1=1.0,
            dt=1.0,
            solver=solver,
            scale=model.scale(),
            jacobian="sparse",
            sparsity=model.sparsity,
            saveat=jaxanm.SaveAt(steps=1),
        )
        values = model.values(sol.xs[-1], stencils)[:, :2] / (scene.tool.omega * scene.geometry.R1)
        notes.append(
            f"max |nodal parameter| = {np.abs(sol.xs[-1] / model.scale()).max():.3g} omega R1, "
            f"max |value at the points| = {np.abs(values).max():.3g} omega R1"
        )
        return sol.stats, _ratio(solver, model.residual, sol.xs[-1], sol.xs[-2], 1.0, 1.0, params, model.scale())

    notes = []
    out = _run_case(f"Lagrangian points drifted to {delta:g} dr of each other ({type(solver).__name__})", go)
    out.note = "; ".join(notes)
    return out


COARSE_CONDUCTION = {
    "geometry.dr": "1.125e-3",
    "geometry.c": "0.2",
    "thermal.edge_rows": "flux",
    "time.save": "",
    "time.t_end": "2.0",
}
"""conduction_small at twice its spacing, dr = (R2 - R1) / 4 (113 points), over 2 s: 40 steps
of the scene's 0.05 s (the scene itself stops at 0.5 s), with the paper's weight c = 0.2 and
the flux edge rows pinned (the scene's settings when the case was made)."""

STABLE_EDGE = {"geometry.c": "0.3", "thermal.edge_rows": "half_cell"}
"""The FSW scenes' MLS weight and tool-edge rows: no growing heat mode on any conduction_small
cloud from dr = (R2 - R1) / 2 to / 16 (docs/notes/collocation_stability.md)."""


def _conduction_error(scene, model, stencils, x) -> float:
    """Max |T - T_ref| / (T0 - Ta) at the points, T_ref the 1-D radial finite volumes at t_end."""
    tm, th, m, tl, g = scene.time, scene.thermal, scene.material, scene.tool, scene.geometry
    rc, ref = radial_finite_volumes(
        g.R1, g.R2, tl.k, m.k, tl.rho * tl.Cp, m.rho * m.Cp, th.h, th.Ta, th.T0, tm.dt, round(tm.t_end / tm.dt)
    )
    T = model.values(x, stencils)[:, model.fields.index("T")]
    return float(np.max(np.abs(T - np.interp(np.hypot(*model.cloud.points.T), rc, ref))) / (th.T0 - th.Ta))


def coarse_conduction(overrides=None, label="c = 0.2, flux rows"):
    """conduction_small at twice its spacing over 2 s (Newton, the scene's solver), watched by
    :class:`jaxanm.fsw.stability.TemperatureGuard` (the run's callback).

    With c = 0.2 and flux edge rows (pinned) the implicit-Euler step amplifies a spurious
    mode of the tool/plate edge pairs by -14.8 per step: unwatched, every step is accepted and
    the edge temperatures reach 1e35 K at 2 s; watched, the run ends in a DivergenceError that
    names the mode.  With :data:`STABLE_EDGE` it converges; the note then gives the error
    against the 1-D radial reference and the step's most amplified mode."""
    scene = load_scene("conduction_small").with_overrides({**COARSE_CONDUCTION, **(overrides or {})})
    notes = []

    def go():
        _, stencils, model, params, x0 = discretise(scene)
        solver, tm = scene.solver.make(), scene.time
        guard = TemperatureGuard(model, params, x0)
        sol = jaxanm.integrate(
            model.residual,
            x0,
            params,
            t0=0.0,
            t1=tm.t_end,
            dt=tm.dt,
            solver=solver,
            scale=model.scale(),
            jacobian="dense",
            saveat=jaxanm.SaveAt(steps=1),
            callback=guard,
        )
        mode = heat_modes(model, params, x0, tm.dt, count=1, by="amplification")[0]
        notes.append(
            f"max error {_conduction_error(scene, model, stencils, sol.xs[-1]):.2g} of T0 - Ta against "
            f"the 1-D reference; most amplified mode: {mode.describe()}"
        )
        return sol.stats, _ratio(
            solver, model.residual, sol.xs[-1], sol.xs[-2], sol.ts[-1], sol.ts[-1] - sol.ts[-2], params, model.scale()
        )

    out = _run_case(f"conduction_small at 2 dr over 2 s, {label} (Newton)", go)
    out.note = "; ".join(notes)
    return out


def forced_divergence():
    """Stiff impulsive cubic (eps u' = F - u^3 - u, eps = 1e-6, dt = 1e-2): the series from the
    initial tangent cannot reach a = 1, K* is refactorised and the step advances by continuation."""
    return _run_case(
        "series forced to diverge: continuation (ANM p=7)",
        lambda: _model_integrate(impulsive_cubic(5), jaxanm.ANM.paper(order=7, tol=1e-8), 0.05, 1e-2),
    )


def forced_halving(max_dt_halvings):
    """The same with no continuation allowed (max_substeps = 0): only dt halving is left.

    One step of 1e-2.  Check: at t = 0.01 >> eps the state is quasi-static, ``u^3 + u = F``; the Newton distance of
    that equation, ``|J^-1 (u^3 + u - F)|`` with ``J = 3u^2 + 1``, against ``tol |u|``.
    """
    residual, x0, params = impulsive_cubic(5)
    solver = jaxanm.ANM.paper(order=4, tol=1e-8, max_substeps=0)
    forcing = np.linspace(50.0, 200.0, 5)  # as in tests/model_problems.py

    def go():
        sol = jaxanm.integrate(
            residual,
            x0,
            params,
            t0=0.0,
            t1=0.01,
            dt=1e-2,
            solver=solver,
            max_dt_halvings=max_dt_halvings,
            jacobian="dense",
        )
        u = sol.xs[-1]
        return sol.stats, float(
            np.linalg.norm((u**3 + u - forcing) / (3 * u**2 + 1)) / (solver.tol * np.linalg.norm(u))
        )

    return _run_case(f"series forced to diverge: dt halving only (max_dt_halvings = {max_dt_halvings})", go)


def cubic_relaxation():
    """u' = s - u^3 on 3 unknowns: the smallest residual (few jet primitives, fast to compile)."""

    def residual(u, u_old, t, dt, p):
        return (u - u_old) / dt - (p["s"] - u * u * u)

    return residual, np.zeros(3), {"s": np.array([1.0, 2.0, 3.0])}


def order(p, problem="cubic"):
    """ANM of order p (tol 1e-12) for 5 steps of 1e-2 on the cubic relaxation or on heat_1d(8)."""
    prob = cubic_relaxation() if problem == "cubic" else heat_1d(8)
    return _run_case(
        f"series order {p} ({problem})",
        lambda: _model_integrate(prob, jaxanm.ANM.paper(order=p, tol=1e-12), 0.05, 1e-2),
    )


def order_1():
    """Order 1 is rejected: eq. 26 takes the 1/(p-1)-th root."""
    return _run_case("series order 1", lambda: (jaxanm.ANM.paper(order=1), None))


CASES = {
    "impulsive": (True, impulsive_start),
    "impulsive_inertia": (False, impulsive_start_inertia),
    "n005_newton": (True, lambda: power_law(0.05, jaxanm.Newton(tol=1e-8))),
    "n005_anm": (True, lambda: power_law(0.05, jaxanm.ANM.paper(order=7, tol=1e-6))),
    "n1_newton": (True, lambda: power_law(1.0, jaxanm.Newton(tol=1e-8))),
    "n1_anm": (True, lambda: power_law(1.0, jaxanm.ANM.paper(order=7, tol=1e-6))),
    "eps0_newton100": (True, lambda: epsbar_zero(jaxanm.Newton(tol=1e-8, max_iter=100))),
    "eps0_newton_capped": (True, epsbar_zero_capped),
    "eps0_anm": (False, lambda: epsbar_zero(jaxanm.ANM.paper(order=7, tol=1e-6))),
    "penalty_newton": (True, lambda: penalty(1e8, jaxanm.Newton(tol=1e-8))),
    "penalty_anm": (True, lambda: penalty(1e8, jaxanm.ANM.paper(order=7, tol=1e-6))),
    "dt_1e-2": (True, lambda: time_step(1e-2, jaxanm.Newton(tol=1e-8))),
    "dt_1e-7": (True, lambda: time_step(1e-7, jaxanm.Newton(tol=1e-8))),
    "omega_200": (True, omega_200),
    "hot_softening": (True, hot_softening),
    "lagrangian_shear": (False, lagrangian_shear),
    "coincident_0.1": (True, lambda: near_coincident(0.1)),
    "coincident_1e-6": (False, lambda: near_coincident(1e-6, jaxanm.ANM.paper(order=7, tol=1e-6))),
    "coincident_0": (True, lambda: near_coincident(0.0)),
    "conduction_2dr": (True, coarse_conduction),
    "conduction_2dr_stable": (False, lambda: coarse_conduction(STABLE_EDGE, "c = 0.3, half-cell edge rows")),
    "forced_divergence": (True, forced_divergence),
    "forced_halving_4": (True, lambda: forced_halving(4)),
    "forced_halving_30": (True, lambda: forced_halving(30)),
    "order_25": (True, lambda: order(25)),
    "order_25_heat": (False, lambda: order(25, "heat_1d")),
    "order_1": (True, order_1),
}
"""Every hard case: key -> (fast, zero-argument function returning an :class:`Outcome`).
The fast ones run in the default tests; all run in this script."""

