"""Checkpoint and resume: an interrupted run keeps its results and resumes bit-identically."""

from __future__ import annotations

import os
import signal

import numpy as np
import pytest

import jaxanm
from model_problems import heat_1d


def _integrate(tmp_path, solver, **kw):
    residual, x0, params = heat_1d(12)
    observe = lambda t, x, p: {"mid": x[6]}  # noqa: E731  (a probe history)
    return jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.6, dt=1e-2, solver=solver, save_every=7,
                            observe=observe, checkpoint=tmp_path / "run.ckpt", **kw)


def _interrupt_at(step, how):
    def callback(t, x, stats):
        if stats.time_steps == step:
            if how == "sigterm":
                os.kill(os.getpid(), signal.SIGTERM)
            raise KeyboardInterrupt

    return callback


@pytest.mark.parametrize("solver", [jaxanm.ANM(order=5, tol=1e-7), jaxanm.ModifiedNewton(tol=1e-9)])
@pytest.mark.parametrize("how", ["sigint", "sigterm"])
def test_interrupted_run_resumes_bit_identically(tmp_path, solver, how):
    reference = _integrate(tmp_path / "ref", solver)
    with pytest.raises(KeyboardInterrupt):
        _integrate(tmp_path, solver, checkpoint_every=10, callback=_interrupt_at(37, how))
    assert (tmp_path / "run.ckpt").exists()
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".ckpt-")]  # no half-written file
    resumed = _integrate(tmp_path, solver, resume=True)
    np.testing.assert_array_equal(resumed.ts, reference.ts)
    np.testing.assert_array_equal(resumed.xs, reference.xs)  # bit-identical
    np.testing.assert_array_equal(resumed.observed["mid"], reference.observed["mid"])
    assert resumed.stats.time_steps == reference.stats.time_steps == 60
    assert resumed.stats.resumes == (1 if solver.__class__ is not jaxanm.Newton else 0)
    assert resumed.stats.factorizations == reference.stats.factorizations


def test_resume_refuses_a_checkpoint_of_another_run(tmp_path):
    _integrate(tmp_path, jaxanm.ANM(), checkpoint_every=20)
    residual, x0, params = heat_1d(12)
    with pytest.raises(jaxanm.InputError, match="belongs to another run"):
        jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.6, dt=2e-2, solver=jaxanm.ANM(),
                         checkpoint=tmp_path / "run.ckpt", resume=True)


def test_checkpoint_options_are_checked():
    residual, x0, params = heat_1d(4)
    with pytest.raises(jaxanm.InputError, match="checkpoint path"):
        jaxanm.integrate(residual, x0, params, t0=0, t1=0.1, dt=0.01, solver=jaxanm.ANM(), checkpoint_every=3)
