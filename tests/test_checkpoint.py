"""Checkpoint and resume: an interrupted run keeps its results and resumes bit-identically."""

from __future__ import annotations

import os
import re
import signal

import jax.numpy as jnp
import numpy as np
import pytest
from model_problems import heat_1d

import jaxanm


def _integrate(tmp_path, solver, **kw):
    residual, x0, params = heat_1d(12)
    observe = lambda t, x, p: {"mid": x[6]}  # noqa: E731  (a probe history)
    return jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.6, dt=1e-2, solver=solver,
                            saveat=jaxanm.SaveAt(steps=7, fn=observe), checkpoint=tmp_path / "run.ckpt", **kw)


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


def test_host_state_is_checkpointed_and_restored(tmp_path):
    """host_state=(get, set): the caller's own state travels in the checkpoint."""
    residual, x0, params = heat_1d(6)
    kept = {"steps": []}

    def after_step(t, x, p):
        kept["steps"].append(round(t / 1e-2))
        return p

    def run(callback=None, resume=False):
        return jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.1, dt=1e-2, solver=jaxanm.Newton(),
                                after_step=after_step, callback=callback, checkpoint=tmp_path / "c.ckpt",
                                checkpoint_every=2, resume=resume,
                                host_state=(lambda: dict(kept, steps=list(kept["steps"])), kept.update))

    with pytest.raises(KeyboardInterrupt):
        run(callback=_interrupt_at(5, "sigint"))
    kept["steps"] = ["lost"]  # what a fresh process would have
    run(resume=True)
    assert kept["steps"] == list(range(1, 11))


def test_signal_during_step_recording_is_deferred(tmp_path):
    """SIGTERM arriving inside after_step waits until the step is recorded: the checkpoint then
    holds that step, consistent with the host state."""
    residual, x0, params = heat_1d(6)
    seen = []

    def after_step(t, x, p):
        seen.append(t)
        if len(seen) == 3:
            os.kill(os.getpid(), signal.SIGTERM)  # would interrupt here without the guard
            seen.append("after the signal")
        return p

    with pytest.raises(KeyboardInterrupt):
        jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.1, dt=1e-2, solver=jaxanm.Newton(),
                         after_step=after_step, checkpoint=tmp_path / "c.ckpt")
    assert seen[3] == "after the signal"
    from jaxanm.checkpoint import read

    payload = read(tmp_path / "c.ckpt")
    assert payload["k"] == 3 and payload["stats"].time_steps == 3


def test_failure_inside_after_step_writes_no_half_recorded_checkpoint(tmp_path):
    residual, x0, params = heat_1d(6)

    def after_step(t, x, p):
        if t > 0.045:
            raise RuntimeError("hook broke")
        return p

    # the hook may have changed its own state half-way: a checkpoint now could pair the run's
    # step 4 with a host state of step 5, so none is written (a periodic one would stay)
    with pytest.raises(RuntimeError, match="hook broke"):
        jaxanm.integrate(residual, x0, params, t0=0.0, t1=0.1, dt=1e-2, solver=jaxanm.Newton(),
                         after_step=after_step, checkpoint=tmp_path / "c.ckpt")
    assert not (tmp_path / "c.ckpt").exists()
    # a failure of the solver itself does write one (the last accepted step)
    with pytest.raises(jaxanm.NonFiniteError):
        jaxanm.integrate(lambda u, uo, t, dt, p: residual(u, uo, t, dt, p) + jnp.where(t > 0.045, jnp.nan, 0.0),
                         x0, params, t0=0.0, t1=0.1, dt=1e-2, solver=jaxanm.Newton(), checkpoint=tmp_path / "c.ckpt")
    from jaxanm.checkpoint import read

    assert read(tmp_path / "c.ckpt")["k"] == 4


def test_checkpoint_of_another_version_is_refused_naming_file_and_version(tmp_path):
    """A run checkpoint whose layout predates this jaxanm's (version 1 had no "version" key)
    is refused before any step, with the file and both versions named, by a resume and by
    jaxanm.stored_host_state alike."""
    from jaxanm._run_checkpoint import VERSION
    from jaxanm.checkpoint import write_atomic

    residual, x0, params = heat_1d(4)
    path = tmp_path / "old.ckpt"
    write_atomic(path, {"k": 3, "t": 0.03, "host_state": {"step": 3}})  # a version-1 layout
    expected = f"checkpoint {path} holds a run state of version 1; this jaxanm reads version {VERSION}"
    with pytest.raises(jaxanm.InputError, match=re.escape(expected)):
        jaxanm.integrate(residual, x0, params, t0=0, t1=0.1, dt=0.01, solver=jaxanm.ANM(), checkpoint=path,
                         resume=True)
    with pytest.raises(jaxanm.InputError, match=re.escape(expected)):
        jaxanm.stored_host_state(path)


def test_unreadable_checkpoint_is_an_input_error(tmp_path):
    residual, x0, params = heat_1d(4)
    (tmp_path / "c.ckpt").write_bytes(b"garbage")
    with pytest.raises(jaxanm.InputError, match="not a readable jaxanm checkpoint"):
        jaxanm.integrate(residual, x0, params, t0=0, t1=0.1, dt=0.01, solver=jaxanm.ANM(),
                         checkpoint=tmp_path / "c.ckpt", resume=True)
    with pytest.raises(jaxanm.InputError, match="host_state"):
        jaxanm.integrate(residual, x0, params, t0=0, t1=0.1, dt=0.01, solver=jaxanm.ANM(), host_state=(1, 2))


def test_fsw_host_state_refuses_another_scene():
    """simulate.run's checkpointed host state: the recorder round-trips through its layout;
    another scene is refused."""
    from jaxanm.fsw.lagrangian import RunRecorder
    from jaxanm.fsw.scene import load_scene
    from jaxanm.fsw.simulate import _host_state

    def recorder(value):  # the layout methods need only the attributes they store
        rec = object.__new__(RunRecorder)
        for name in RunRecorder.CHECKPOINTED:
            setattr(rec, name, value)
        return rec

    scene = load_scene("couette_small")
    get, _ = _host_state(scene, recorder(np.ones((2, 2))), {"checkpoint_every": 2})
    snapshot = get()
    assert snapshot["settings"] == {"checkpoint_every": 2} and snapshot["scene"] == scene.to_dict()
    fresh = recorder(np.zeros((2, 2)))
    _host_state(scene, fresh, {})[1](snapshot)
    assert all(np.all(getattr(fresh, name) == 1) for name in RunRecorder.CHECKPOINTED)
    other = scene.with_overrides({"material.n": "0.5", "time.dt": "0.5"})
    with pytest.raises(jaxanm.InputError, match=r"another scene \(material.n, time.dt differ\)"):
        _host_state(other, fresh, {})[1](snapshot)


@pytest.mark.slow
def test_fsw_anm_run_resumes_bit_identically(tmp_path):
    """simulate.run with the ANM (K* carried across steps) on a tiny Lagrangian thermo-mechanical
    scene: interrupted after 3 of 4 steps and resumed, every field, probe and section is
    bit-identical to the uninterrupted run (about a minute: the order-7 jet compiles)."""
    from jaxanm.fsw.scene import load_scene
    from jaxanm.fsw.simulate import run

    scene = load_scene("fsw_small").with_overrides(
        {"geometry.dr": "1.125e-3", "time.t_end": "4e-4", "time.save": "2e-4", "solver.kind": "anm"})
    ref = run(scene)

    def stop(t, stats):
        if stats.time_steps == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt) as info:
        run(scene, callback=stop, checkpoint=tmp_path / "c.pkl", checkpoint_every=2)
    np.testing.assert_allclose(info.value.partial.probes["t"], [0.0, 1e-4, 2e-4, 3e-4], rtol=1e-12)
    res = run(scene, checkpoint=tmp_path / "c.pkl", resume=True)
    for key in ("t", "points", "u", "v", "T"):
        np.testing.assert_array_equal(getattr(res, key), getattr(ref, key), err_msg=key)
    for name in ref.probes:
        if name != "t":
            for k in "xyuvT":
                np.testing.assert_array_equal(res.probes[name][k], ref.probes[name][k])
    for name in ref.sections:
        if name != "t":
            for k in "uvT":
                np.testing.assert_array_equal(res.sections[name][k], ref.sections[name][k])
    assert res.stats.resumes == 1 and res.stats.factorizations == ref.stats.factorizations


def test_probes_sampled_on_the_dense_output_resume_bit_identically(tmp_path):
    """A fixed-point scene whose probes are sampled every time.probe_dt on ESDIRK3's dense
    output (steps of 0.05 s, samples every 0.02 s): the histories are at exactly those times,
    and a run interrupted after 3 of its steps and resumed records the same histories bit for
    bit as an uninterrupted one (the loop's observations and the recorder's are checkpointed
    together)."""
    from jaxanm.fsw.scene import load_scene
    from jaxanm.fsw.simulate import run

    scene = load_scene("conduction_small").with_overrides(
        {"time.scheme": "esdirk3", "time.t_end": "0.3", "time.save": "0.1", "time.probe_dt": "0.02"})
    ref = run(scene)
    np.testing.assert_allclose(ref.probes["t"], np.arange(16) * 0.02, rtol=0, atol=1e-15)

    def stop(t, stats):
        if stats.time_steps == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run(scene, callback=stop, checkpoint=tmp_path / "c.pkl", checkpoint_every=2)
    res = run(scene, checkpoint=tmp_path / "c.pkl", resume=True)
    np.testing.assert_array_equal(res.probes["t"], ref.probes["t"])
    for k in "uvT":
        np.testing.assert_array_equal(res.probes["1"][k], ref.probes["1"][k])
    np.testing.assert_array_equal(res.T, ref.T)
