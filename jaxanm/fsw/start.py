"""The flow at t = 0: the quasi-static velocity the initial temperature holds, not rest.

The momentum rows of :mod:`jaxanm.fsw.physics` are quasi-static: their inertia term weighs
``rho dr^2 / (mu dt)`` against the viscous ones, below 1e-5 at the FSW scenes' dt, so the
plate spins up within ``rho (R2 - R1)^2 / mu ~ 1e-8 s`` (:mod:`jaxanm.fsw.axisymmetric`) and
the velocity a step solves for is the stationary flow at the step's temperature.  Started from
rest (``mechanics.start = "rest"``, the default), the first step's nonlinear iteration must
travel from V = 0 to that flow, and at n = 0.1324 Newton does not get there on fine clouds
(docs/notes/start_from_rest.md: the updates overshoot in the slow zone where the strain rate
is within a decade of eps0 and the viscosity law bends).

``mechanics.start = "quasi_static"`` starts the run from that flow instead:
:func:`quasi_static_state` solves the stationary momentum rows at T = T0 on the run's own cloud
and stencils (the scene's residual with the ``viscous`` effect alone: no inertia, mu at T0)
by Newton with a backtracking line search on the residual, from rest.  The line search is
what the step solvers lack there: undamped, Newton's updates overshoot in that slow zone and
diverge on the 0.075 mm graded cloud; damped, it converges from rest on every cloud tried
(6-13 iterations).  The run's first step then starts next to its root and only adds the
change of one time step.

``mechanics.start = "continuation"`` solves the same flow by the ANM's own path following
(:func:`continuation_state`, :func:`jaxanm.continuation`): the regularisation eps0 is
continued from ``eps0 e^s0``, where the flow is Newtonian and its solve linear, down to eps0,
in the parameter ``lam = -ln(eps0_eff / eps0)``.  The law's branch points ``epsbar^2 =
-eps0_eff^2`` lie at ``lam = ln(eps0 / epsbar) -/+ i pi/2`` for the strain rate epsbar of
each point, so along the whole path the branch is analytic only in a strip of half-width
pi/2: each series reaches about a radian, whatever its order, and the path of length s0
takes of the order of s0 steps, each with its own factorisation
(docs/notes/start_from_rest.md has the measurements against the damped-Newton start).
The 1-D Couette profile fitted to the cloud is no better a start: it saves Newton iterations
on a fine graded cloud but costs some on a coarse one, where its MLS fit oscillates (the note
has the table).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..checkpoint import stored_type
from ..continuation import continuation
from ..errors import StepFailure
from ..internal import Problem, count, entry_point, factorize, relative_change
from ..stats import Stats
from .discretisation import Model, make_model
from .effects import REGISTRY

__all__ = ["StartReport", "continuation_state", "quasi_static_state"]

_SUFFICIENT_DECREASE = 1e-4
"""Armijo's constant: a step of length a must cut |R|_2 by at least this fraction of a."""

_MIN_STEP = 2.0 ** -12
"""Shortest line-search step; below it the iteration is declared failed."""


@stored_type("fsw.StartReport")
@dataclasses.dataclass
class StartReport:
    """How the start flow was solved.

    Attributes
    ----------
    iterations : int
        Newton iterations (one tangent and one factorisation each).
    step_lengths : list of float
        The line search's step length of each iteration (1: a full Newton step).
    residual_norms : list of float
        ``|R|_2`` of the scaled rows at each iterate, the start's first.
    stats : jaxanm.Stats
        Counters and wall time of the solve (factorisations, Jacobians, residuals).
    path : list of (float, float, int)
        The points of the path from the tool turning in place at :data:`START_OMEGA` (or the
        scene's omega if slower) to the scene's omega and travel speed
        (:func:`quasi_static_state`): ``(omega, U, Newton iterations)`` each; empty when the
        flow was solved at once.
    """

    iterations: int
    step_lengths: list
    residual_norms: list
    stats: Stats
    path: list = dataclasses.field(default_factory=list)

    def to_plain(self) -> dict:
        """Every field as it is (how a checkpoint stores the report; :meth:`from_plain`)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_plain(cls, state: dict) -> StartReport:
        """The report :meth:`to_plain` gave."""
        return cls(**state)


def _line_search(problem: Problem, x, dx, r_norm: float, args: tuple):
    """Longest step ``a`` in 1, 1/2, 1/4, ... with ``|R(x + a dx)|_2 <= (1 - c a) |R(x)|_2``;
    returns ``(a, x + a dx, R there)``, or None if no step down to :data:`_MIN_STEP` decreases."""
    a = 1.0
    while a >= _MIN_STEP:
        x_new = x + a * dx
        r_new = problem.residual(x_new, *args)
        if np.all(np.isfinite(r_new)) and np.linalg.norm(r_new) <= (1.0 - _SUFFICIENT_DECREASE * a) * r_norm:
            return a, x_new, r_new
        a *= 0.5
    return None


def _damped_newton(problem: Problem, x, args: tuple, tol: float, max_iter: int):
    """Newton with a backtracking line search on ``|R|_2``, from ``x``; returns ``(x, report)``.

    Converged when a full step's scaled change ``|dx| / |x|`` is at most ``tol``.
    """
    r = problem.residual(x, *args)
    lengths, norms = [], [float(np.linalg.norm(r))]
    for it in range(1, max_iter + 1):
        dx = -problem.solve(factorize(problem.tangent(x, *args), problem.stats), r)
        found = _line_search(problem, x, dx, norms[-1], args)
        if found is None:
            raise StepFailure(f"the quasi-static start flow: no step along Newton's direction reduces the "
                              f"residual (iteration {it}, |R|_2 = {norms[-1]:.3g})", step=0, t=0.0,
                              residual_norm=norms[-1])
        a, x, r = found
        lengths.append(a)
        norms.append(float(np.linalg.norm(r)))
        if a == 1.0 and relative_change(problem, dx, x) <= tol:
            return x, StartReport(it, lengths, norms, problem.stats)
    raise StepFailure(f"the quasi-static start flow did not converge in {max_iter} iterations "
                      f"(|R|_2 = {norms[-1]:.3g}, last step length {lengths[-1]:g})", step=0, t=0.0,
                      residual_norm=norms[-1])


def flow_scene(scene):
    """The scene of the stationary flow rows: ``viscous`` with the scene's effects whose records
    have the role ``"start flow"`` (:data:`jaxanm.fsw.effects.REGISTRY`: the boundary's kinematics,
    e.g. ``slip``'s plate edge at delta omega, ``traverse``'s ring at (-U, 0)) and what those
    require (``traverse`` needs ``tracers``, whose transport terms the stationary rows drop with
    the inertia)."""
    kept = {"viscous"} | {e for e in scene.effects if "start flow" in REGISTRY[e].roles}
    return scene.restricted_to(kept | {r for e in kept for r in REGISTRY[e].requires})


def _with_flow(model: Model, flow: Model, x) -> np.ndarray:
    """The initial unknowns of ``model`` with the fields of the start flow's unknowns ``x`` (of
    ``flow``: velocity, and pressure with ``incompressible``) in place of their initial values."""
    x0 = model.initial_state(model.cloud.points).reshape(len(model.fields), -1)
    solved = np.asarray(x).reshape(len(flow.fields), -1)
    for k, name in enumerate(flow.fields):
        x0[model.fields.index(name)] = solved[k]
    return x0.reshape(-1)


def _without_pressure(begin: Model, cloud, stencils, tol: float, max_iter: int):
    """The first iterate of the start flow ``begin`` at rest, and the report of what made it.

    Without ``incompressible``: rest (no report).  With it, the flow without the pressure (the
    momentum rows at the penalty 0: in the tool's circular flow div V vanishes by symmetry)
    solved from rest by damped Newton, with p = 0: from rest, the damped iteration converges on
    those rows and not on the pressure's (on the 0.06 mm graded cloud it finds no descent),
    and from their root the pressure's rows converge in a few iterations.
    """
    rest = begin.initial_state(cloud.points)
    if not begin.effects.incompressible:
        return rest, None
    plain = make_model(begin.scene.restricted_to(set(begin.scene.effects) - {"incompressible"}), cloud)
    problem = Problem(plain.residual, plain.scale(), Stats(), "sparse", plain.sparsity)
    x0, one = plain.initial_state(cloud.points), np.float64(1.0)
    x, report = _damped_newton(problem, x0, (x0, one, one, plain.params(cloud.points, stencils)), tol, max_iter)
    return _with_flow(begin, plain, x), report


START_OMEGA = 20.0
"""The rotation speed (rad/s) at which the start flow is solved from rest when the scene's tool
turns faster: damped Newton from rest converges at 10-50 rad/s on the shipped clouds, and not at
200 rad/s (the regularised law's slow zone, where the strain rate is within a decade of eps0,
then lies where the first Newtonian update overshoots: docs/notes/traverse_and_slip.md)."""

PATH_ITERATIONS = 12
"""Newton iterations allowed at a point of the start flow's path before its step is halved."""

PATH_TOL = 1e-8
"""Newton's tolerance (scaled change) at the path's intermediate points; the end is solved to the
start's own ``tol``."""

MIN_PATH_STEP = 2.0 ** -12
"""Shortest step of the path (a fraction of its length): below it the path stops, named."""


@dataclasses.dataclass
class _Leg:
    """One leg of the start flow's path: a constant of ``params["c"]`` from ``begin`` to ``end``,
    geometrically (``omega``) or linearly (``U_tr``)."""

    constant: str
    begin: float
    end: float

    def at(self, s: float) -> float:
        if s >= 1.0:
            return self.end
        if self.constant == "omega":
            return self.begin * (self.end / self.begin) ** s
        return self.begin + (self.end - self.begin) * s

    def name(self, value: float, c: dict) -> str:
        if self.constant == "omega":
            return f"omega = {value:.4g} rad/s"
        advance = 2e3 * np.pi * value / float(c["omega"])
        return f"U = {value:.4g} m/s (an advance of {advance:.3g} mm per revolution at omega = {float(c['omega']):g})"


def _follow(problem: Problem, x, params: dict, leg: _Leg, report: StartReport) -> np.ndarray:
    """The flow at the end of ``leg`` from ``x`` (the flow at its beginning): damped Newton at points
    of the leg, each started from the last point's flow (a secant through the last two points
    was tried: where the plate's slow zones stiffen, the pressure there moves erratically from
    point to point, and the extrapolation failed where the last flow converged); a point that
    fails halves the step, one that converges in few iterations doubles it.  Extends ``report``."""
    one = np.float64(1.0)
    s, step = 0.0, 0.25
    while s < 1.0:
        t = min(1.0, s + step)
        guess = x
        p = dict(params, c=dict(params["c"], **{leg.constant: np.float64(leg.at(t))}))
        try:
            y, done = _damped_newton(problem, guess, (guess, one, one, p), PATH_TOL, PATH_ITERATIONS)
        except StepFailure:
            step *= 0.5
            if step < MIN_PATH_STEP:
                raise StepFailure(
                    f"the start flow's path stopped at {leg.name(leg.at(s), p['c'])}: no flow found a step "
                    f"of {step * 2:.2g} of the leg further on; the cloud does not resolve the flow beyond "
                    f"(refine geometry.dr and geometry.dr_far, or lower the speed)", step=0, t=0.0) from None
            continue
        report.iterations += done.iterations
        report.step_lengths += done.step_lengths
        report.residual_norms += done.residual_norms[1:]
        report.path.append((float(p["c"]["omega"]), float(p["c"]["U_tr"]) if "U_tr" in p["c"] else 0.0,
                            done.iterations))
        x, s = y, t
        if done.iterations <= 4:
            step *= 2.0
    return x


@entry_point
def quasi_static_state(scene, model: Model, stencils, tol: float = 1e-8, max_iter: int = 50):
    """Initial unknowns of ``model`` with the quasi-static flow at T0; returns ``(x0, StartReport)``.

    The velocity (and pressure, with ``incompressible``) is the root of the stationary momentum
    rows at T = T0 on the model's cloud and ``stencils`` (:func:`flow_scene`: the scene's rows
    without the inertia term), to ``tol`` in the scaled change of a full Newton step (1e-8:
    Newton converges quadratically there, so the state is then a root to round-off, and the
    first step only adds the change of its own time step); T = T0.

    The tool turning in place at ``min(omega, START_OMEGA)`` is solved from rest by damped
    Newton; a faster tool, and a travelling one, are then reached along a path (the ANM's
    home regime, here by damped Newton at points of it): omega up to the scene's
    (geometrically), then the travel speed from 0 up to the scene's.  From rest, the damped
    iteration stalls where the plate streams past the turning tool (the slow zones of the
    regularised law move with every update), and at a fast tool; along the path each point
    starts next to its root.  The report's ``path`` lists the points.

    Raises :class:`jaxanm.StepFailure` if the iteration from rest does not converge in
    ``max_iter`` Newton iterations or its line search finds no decrease, or if the path stops
    (the message names the speed it reached).  The report's ``stats.wall_time_s`` is the whole
    start, compilation included.
    """
    began = time.perf_counter()
    flow = make_model(flow_scene(scene), model.cloud)
    params = flow.params(model.cloud.points, stencils)
    problem = Problem(flow.residual, flow.scale(), Stats(), "sparse", flow.sparsity)
    c = params["c"]
    legs = [_Leg("omega", min(float(c["omega"]), START_OMEGA), float(c["omega"]))]
    if flow.effects.traverse:
        legs.append(_Leg("U_tr", 0.0, float(c["U_tr"])))
    first = scene.with_overrides({"tool.omega": legs[0].begin, **({"tool.traverse_speed": 0.0}
                                                                  if flow.effects.traverse else {})})
    begin = make_model(flow_scene(first), model.cloud)
    one = np.float64(1.0)  # t and dt: the rows hold no time derivative
    rest, before = _without_pressure(begin, model.cloud, stencils, tol, max_iter)
    start = dict(params, c=dict(c, **{leg.constant: np.float64(leg.begin) for leg in legs}))
    x, report = _damped_newton(problem, rest, (rest, one, one, start), tol, max_iter)
    if before is not None:
        report.iterations += before.iterations
        report.step_lengths = before.step_lengths + report.step_lengths
        report.residual_norms = before.residual_norms + report.residual_norms
        count(report.stats, "factorizations", before.stats.factorizations)
    for leg in legs:
        if leg.end != leg.begin:
            later = {g.constant: np.float64(g.begin) for g in legs[legs.index(leg) + 1:]}
            x = _follow(problem, x, dict(params, c=dict(c, **later)), leg, report)
    if report.path:  # the end of the path to the start's own tolerance
        x, end = _damped_newton(problem, x, (x, one, one, params), tol, max_iter)
        report.iterations += end.iterations
        report.step_lengths += end.step_lengths
    report.stats.close(time.perf_counter() - began)
    return _with_flow(model, flow, x), report


CONTINUATION_RATIO = 1e3
"""The continuation starts at ``eps0_eff = CONTINUATION_RATIO * omega``: a thousand times the
flow's strain rates (about omega, up to ``2 omega / (sqrt 3 n)`` at the tool edge for the
paper's n), so that the start solve is Newtonian to 1e-3 and converges in a few Newton steps."""


def _regularised_flow(residual):
    """``R(u, lam, params)``: the flow rows with ``eps0 * exp(-lam)`` for eps0 (the continuation
    parameter of :func:`continuation_state`); ``params["rest"]`` is the old state of the rows."""
    import jax.numpy as jnp

    def rows(u, lam, p):
        c = dict(p["c"], eps0=p["c"]["eps0"] * jnp.exp(-lam))
        return residual(u, p["rest"], 1.0, 1.0, dict(p, c=c))

    return rows


@entry_point
def continuation_state(scene, model: Model, stencils, order: int = 15, tol: float = 1e-6, max_steps: int = 60):
    """Initial unknowns of ``model`` with the quasi-static flow at T0, by ANM path following in
    the strain-rate regularisation (module docstring); returns ``(x0, StartReport)``.

    The same stationary rows as :func:`quasi_static_state`, followed by
    :func:`jaxanm.continuation` from ``lam = -ln(CONTINUATION_RATIO omega / eps0)`` (its start
    corrected by Newton at that lam) to ``lam = 0``, steps of order ``order`` with eq. 26's
    ``tol``.  The report's ``iterations`` are the continuation steps, ``step_lengths`` their
    lengths in lam, ``residual_norms`` ``|R|_inf`` at the step ends.
    """
    began = time.perf_counter()
    flow = make_model(flow_scene(scene), model.cloud)
    params = flow.params(model.cloud.points, stencils)
    rest = flow.initial_state(model.cloud.points)
    params["rest"] = rest
    lam0 = -float(np.log(CONTINUATION_RATIO * scene.tool.omega / scene.eps0))
    found = continuation(
        _regularised_flow(flow.residual), rest, lam0, params, lam_end=0.0, order=order, tol=tol,
        scale=flow.scale(), sparsity=flow.sparsity(params), max_steps=max_steps)
    if found.stopped != "lam_end":
        raise StepFailure(f"the continuation start flow stopped at lam = {found.lam[-1]:.3g} ({found.stopped}) "
                          f"after {len(found.lam) - 1} steps, short of lam = 0", step=0, t=0.0,
                          residual_norm=float(found.residual_norm[-1]))
    x0 = _with_flow(model, flow, found.u[-1])
    found.stats.close(time.perf_counter() - began)
    report = StartReport(len(found.lam) - 1, np.diff(found.lam).tolist(), found.residual_norm.tolist(), found.stats)
    return x0, report
