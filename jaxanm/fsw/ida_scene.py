"""IDA on an FSW scene: the external adaptive baseline, with the results of a ``jaxanm run``.

:func:`run_ida` integrates a fixed-point scene's residual (``tracers`` or no motion) with
SUNDIALS IDA (:func:`jaxanm.ida.integrate_ida`: variable-order BDF, the same residual and
coloured sparse Jacobian as the implicit-Euler solvers) and returns an
:class:`~jaxanm.fsw.record.FSWResult`, so that ``jaxanm.fsw.io.output.write_outputs`` writes the
same files as ``jaxanm run --out`` and errors are measured by the same
:func:`jaxanm.fsw.compare.differences`.  What differs from :func:`jaxanm.fsw.simulate.run`:

- IDA's outputs are the scene's save times t > 0 (``time.save`` and ``t_end``) and its probe
  times (``time.probe_dt``), where it ends a step exactly (no interpolation); the probe
  history holds t = 0 and those times only, not every internal step.  Compare it with other
  runs at those times (``time.save``).
- The registration points are the scene's probe positions, as in
  :func:`~jaxanm.fsw.simulate.run` on fixed points (:class:`~jaxanm.fsw.record.ProbeSites`).
- No tracers: advecting them needs the flow between the outputs (``tracers`` is None; the
  mixing figure then shows the fixed points, i.e. no mixing: read it from an implicit-Euler run).
- ``stats`` is IDA's :class:`jaxanm.ida.IDAStats` (a :class:`jaxanm.Stats`): ``time_steps``
  IDA's internal steps, ``factorizations`` and ``jacobian_evaluations`` its Jacobians (each one
  SuperLU_MT factorisation), ``newton_iterations`` its Newton iterations, ``wall_time_s`` the
  whole call (consistent start and compilation included) split into ``start``, ``residual``,
  ``jacobian`` and ``ida`` (IDA's own linear algebra and bookkeeping).
"""

from __future__ import annotations

from typing import TypedDict

import numpy as np

import jaxanm

from .discretisation import discretise
from .record import FSWResult, Recorder
from .scene import Scene

__all__ = ["IDA_DEFAULTS", "run_ida"]

class IDASettings(TypedDict):
    """The settings of an IDA run that have defaults (:data:`IDA_DEFAULTS`)."""

    rtol: float
    max_order: int


IDA_DEFAULTS: IDASettings = {"rtol": 1e-6, "max_order": 5}
"""IDA settings of a run (:func:`jaxanm.ida.integrate_ida`); ``atol`` (relative to each unknown's
scale: omega R1 for u, v, T0 for T, as ``rtol`` is to its value) defaults to ``rtol``."""


def run_ida(scene: Scene, rtol: float = IDA_DEFAULTS["rtol"], atol: float | None = None,
            max_order: int = IDA_DEFAULTS["max_order"]) -> FSWResult:
    """Integrate ``scene`` over [0, t_end] with IDA; its fields and probes at the save times.

    ``atol`` defaults to ``rtol`` (:data:`IDA_DEFAULTS`).

    Raises :class:`jaxanm.InputError` for a Lagrangian scene (its points move between steps,
    so its step residual is no DAE; :mod:`jaxanm.ida`) and for bad tolerances;
    :class:`jaxanm.ida.IDAFailure` when IDA stops early.
    """
    from jaxanm.ida import integrate_ida

    if scene.has("lagrangian"):
        raise jaxanm.InputError(f"scene {scene.name!r} is Lagrangian: IDA needs fixed points (its points move "
                                "between steps, so the step residual is no DAE); drop 'lagrangian' from its "
                                "effects (add 'tracers' for the mixing picture) or use an implicit-Euler solver")
    atol = rtol if atol is None else atol
    cloud, st, model, params, x0 = discretise(scene)
    times = np.array(sorted({*(t for t in scene.time.save_times if t > 0), *scene.time.probe_times}),
                     dtype=np.float64)
    with jaxanm.float64():
        sol = integrate_ida(model.residual, x0, params, t0=0.0, t_out=times, rtol=float(rtol), atol=float(atol),
                            max_order=int(max_order), scale=model.scale(), sparsity=model.sparsity)
    # the same records as a run on fixed points, from IDA's states at its output times
    saved = frozenset(float(t) for t in sol.ts if t in scene.time.save_times)
    recorder = Recorder(scene, model, st, x0, saved, tracers=False)
    for t, x in zip(sol.ts, sol.xs):
        recorder.record_state(t, x, st)
    solver = {"rtol": float(rtol), "atol": float(atol), "max_order": int(max_order)}
    return recorder.result(solver, sol.stats)
