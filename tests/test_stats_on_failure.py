"""A run that is interrupted or fails keeps the work it did in its statistics.

The statistics an interrupted or failed :func:`jaxanm.integrate` run reports (on the exception,
``exc.stats``, and in the checkpoint it writes) must count every factorisation, continuation
sub-step and dt halving done, those of the step that was interrupted or failed included, not
only the accepted steps'.  The first step of ``impulsive_cubic`` with a strict ANM (order 4,
tol 1e-8, at most 2 sub-steps per series) fails and is halved many times, each attempt
factorising and taking sub-steps: a small problem with all three kinds of work inside one step.
The FSW layer's partial result (written by ``jaxanm run`` when interrupted) is checked end to
end on a tiny scene (slow).
"""

from __future__ import annotations

import copy
import dataclasses
import json

import pytest
from model_problems import impulsive_cubic

import jaxanm
import jaxanm._problem
from jaxanm.checkpoint import read
from jaxanm.errors import RunInterrupted, run_stopped

STRICT = jaxanm.ANM(order=4, tol=1e-8, max_substeps=2)
FACTORIZE = jaxanm._problem.factorize
COUNTERS = [f.name for f in dataclasses.fields(jaxanm.Stats) if f.name not in ("wall_time_s", "wall_time")]


def _run(**kw):
    residual, x0, params = impulsive_cubic()
    return jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.02, dt=1e-2, solver=STRICT, **kw)


def _counters(stats) -> dict:
    return {name: copy.deepcopy(getattr(stats, name)) for name in COUNTERS}


class _Seen(Exception):
    """Ends a run once its statistics were recorded."""


class _Factorizations:
    """Counts the factorisations the solvers make (outside ``Stats``); at the ``stop``-th,
    raises KeyboardInterrupt instead of factorising, or records the run's statistics then
    (``seen``) and ends the run."""

    def __init__(self, stop=None, interrupt=False):
        self.made, self.stop, self.interrupt, self.seen = 0, stop, interrupt, None

    def __call__(self, matrix, stats):
        if self.made + 1 == self.stop:
            if self.interrupt:
                raise KeyboardInterrupt
            self.seen = _counters(stats)
            raise _Seen
        made = FACTORIZE(matrix, stats)
        self.made += 1
        return made


def test_an_interruption_inside_a_step_reports_the_work_of_that_step(monkeypatch, tmp_path):
    """Interrupted at its 25th factorisation, inside the first step: the exception's statistics
    and the checkpoint's are those the same run had at that moment when not interrupted
    (24 factorisations, and the halvings and sub-steps of the failed attempts so far)."""
    watch = _Factorizations(stop=25)
    monkeypatch.setattr(jaxanm._problem, "factorize", watch)
    with pytest.raises(_Seen):
        _run(max_dt_halvings=30)
    at_25 = watch.seen
    assert at_25["factorizations"] == 24 and at_25["time_steps"] == 0
    assert at_25["dt_halvings"] > 0 and at_25["substeps"] > 0  # the test sees all three kinds of work

    monkeypatch.setattr(jaxanm._problem, "factorize", _Factorizations(stop=25, interrupt=True))
    path = tmp_path / "run.ckpt"
    with pytest.raises(KeyboardInterrupt) as info:
        _run(max_dt_halvings=30, checkpoint=path)
    assert isinstance(info.value, RunInterrupted)  # the interrupt, carrying the run's statistics
    assert _counters(info.value.stats) == at_25
    assert _counters(read(path)["stats"]) == at_25
    assert info.value.stats.wall_time_s > 0


def test_a_stopped_run_raises_a_new_exception_carrying_declared_fields():
    """What a run adds to the exception that stopped it (statistics, a partial result, the
    solver state to retry from) is given to a new exception of the same class, message and
    fields; the caught one is left as it was, and a field the class does not declare is refused."""
    caught = jaxanm.StepFailure("series diverged", step=3, t=0.5, amax=0.01)
    made = caught.carrying(stats=jaxanm.Stats(factorizations=2), partial="so far")
    assert type(made) is jaxanm.StepFailure and str(made) == str(caught) and made.amax == 0.01
    assert made.stats.factorizations == 2 and made.partial == "so far" and caught.stats is None
    with pytest.raises(TypeError, match="declares no field 'extra'"):
        caught.carrying(extra=1)
    interrupt = run_stopped(KeyboardInterrupt(), stats=jaxanm.Stats())
    assert isinstance(interrupt, KeyboardInterrupt) and isinstance(interrupt, RunInterrupted)
    assert isinstance(interrupt.stats, jaxanm.Stats)


@pytest.mark.parametrize("controller", [None, jaxanm.StepController(rtol=1e-3, atol=1e-6)])
def test_a_failed_run_reports_the_work_of_its_failed_step(monkeypatch, controller):
    """A first step that fails after two halvings (fixed steps; with a controller, two retries
    at a quarter of the size) reports every factorisation made (counted outside Stats), the
    two halvings and the sub-steps of the three failed attempts (2 each: ``max_substeps``)."""
    watch = _Factorizations()
    monkeypatch.setattr(jaxanm._problem, "factorize", watch)
    with pytest.raises(jaxanm.StepFailure) as info:
        _run(max_dt_halvings=2, controller=controller)
    stats = info.value.stats
    assert stats.factorizations == watch.made > 0
    assert stats.dt_halvings == 2 and stats.substeps == 3 * STRICT.max_substeps
    assert stats.time_steps == 0 and stats.wall_time_s > 0


@pytest.mark.slow
def test_an_fsw_run_interrupted_in_its_first_step_writes_its_work_to_the_summary(monkeypatch, tmp_path):
    """The reported symptom: ``jaxanm run`` interrupted during its first step wrote a
    ``summary.json`` with 0 factorisations (``simulate.run`` built the partial result from the
    statistics the last accepted step's callback had reported, and there was none).  A tiny
    Lagrangian scene (113 points, Newton: a factorisation per iteration, the one of
    tests/test_cli.py), interrupted at its 3rd factorisation: the summary counts 2."""
    from test_cli import RESUME_TOML

    from jaxanm import cli

    path = tmp_path / "tiny.toml"
    path.write_text(RESUME_TOML)
    monkeypatch.setattr(jaxanm._problem, "factorize", _Factorizations(stop=3, interrupt=True))
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 130
    stats = json.loads((tmp_path / "out" / "summary.json").read_text())["stats"]
    assert stats["factorizations"] == 2 and stats["time_steps"] == 0 and stats["wall_time_s"] > 0
