"""The ``jaxanm`` command line: parsing, scene overrides, progress, outputs and error paths.

The simulation is replaced by a fake ``run`` (monkeypatched ``jaxanm.cli._simulate``) that
reports a few steps through the CLI's callback and returns the synthetic result of
``test_output``, so these tests exercise the command without the FSW model.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from jaxanm import cli
from jaxanm.errors import StepFailure
from jaxanm.fsw.scene import Scene, shipped_scenes
from jaxanm.stats import Stats
from test_output import fake_result

TINY_TOML = """
name = "tiny"
effects = ["viscous"]
[time]
dt = 1e-4
t_end = 0.001
"""


@pytest.fixture
def tiny(tmp_path):
    """Path of a small valid scene TOML file."""
    path = tmp_path / "tiny.toml"
    path.write_text(TINY_TOML)
    return path


@pytest.fixture
def fake_run(monkeypatch):
    """Replace the simulation by a fake; returns the dict of what it was called with."""
    calls = {}

    def simulate(scene, callback):
        calls["scene"], calls["callback"] = scene, callback
        stats = Stats()
        for step in range(1, 11):
            stats.time_steps = step
            stats.factorizations = 1 + step // 4
            if callback is not None:
                callback(step * scene.time.t_end / 10, stats)
        result = fake_result()
        result.stats, result.scene = stats, scene
        return result

    monkeypatch.setattr(cli, "_simulate", simulate)
    return calls


@pytest.fixture
def no_files(monkeypatch):
    """Skip writing outputs (tested in test_output); records the call."""
    calls = {}

    def write(result, out_dir, solver_settings):
        calls.update(out_dir=out_dir, solver_settings=solver_settings)
        return []

    monkeypatch.setattr(cli, "_write_outputs", write)
    return calls


def one_error_line(err: str) -> str:
    """Assert stderr is exactly one ``jaxanm: error:`` line without a traceback; return it."""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("jaxanm: error: ") and "Traceback" not in err
    return lines[0]


def test_run_writes_outputs_and_prints_summary(tiny, tmp_path, fake_run, capsys):
    out = tmp_path / "res"
    assert cli.main(["run", str(tiny), "--out", str(out), "--no-progress"]) == 0
    stdout = capsys.readouterr().out
    assert "tiny (anm): t = 0.7 s, 10 steps, 3 factorizations" in stdout
    assert f"files written to {out}" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["solver"] == {"kind": "anm", "options": {"order": 7, "tol": 1e-6}}
    assert Scene.from_dict(summary["scene"]) == fake_run["scene"]  # the scene round-trips
    assert (out / "fields.npz").exists() and (out / "fields.pvd").exists()
    assert fake_run["callback"] is None


def test_shorthands_and_set_overrides_reach_the_scene(tiny, tmp_path, fake_run, no_files):
    argv = ["run", str(tiny), "--t-end", "0.002", "--solver", "mnewton", "--tol", "1e-8",
            "--set", "material.K=2e16", "--set", "time.dt = 5e-5", "--set", "solver.order=9",
            "--out", str(tmp_path), "--no-progress"]
    assert cli.main(argv) == 0
    scene = fake_run["scene"]
    assert scene.name == "tiny" and scene.time.t_end == 0.002 and scene.time.dt == 5e-5
    assert scene.material.K == 2e16
    assert (scene.solver.kind, scene.solver.order, scene.solver.tol) == ("modified_newton", 9, 1e-8)
    assert no_files["solver_settings"]["kind"] == "modified_newton"


def test_shorthand_wins_over_set(tiny, tmp_path, fake_run, no_files):
    argv = ["run", str(tiny), "--set", "solver.order=9", "--order", "5", "--out", str(tmp_path),
            "--no-progress"]
    assert cli.main(argv) == 0
    assert fake_run["scene"].solver.order == 5


def test_default_output_directory(tiny, tmp_path, monkeypatch, fake_run, no_files):
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", str(tiny), "--solver", "newton", "--no-progress"]) == 0
    assert str(no_files["out_dir"]) == "results/tiny-newton"


def test_progress_bar_driven_by_callback(tiny, tmp_path, fake_run, no_files, capsys):
    assert cli.main(["run", str(tiny), "--out", str(tmp_path)]) == 0
    assert isinstance(fake_run["callback"], cli.ProgressBar)
    err = capsys.readouterr().err
    assert "tiny: 100%" in err and "t = 0.001/0.001 s" in err
    assert "steps/s, 3 factorizations" in err


def test_progress_bar_tracks_simulated_time():
    bar = cli.ProgressBar(0.7, "x")
    stats = Stats(time_steps=5, factorizations=2)
    bar(0.35, stats)
    assert bar.bar.n == pytest.approx(0.35)
    bar(0.7, stats)
    assert bar.bar.n == pytest.approx(0.7)
    assert "2 factorizations" in bar.bar.postfix
    bar.close()


@pytest.mark.parametrize("argv, expected", [
    (["run", "no_such_scene"], "unknown scene 'no_such_scene'"),
    (["run", "missing.toml"], "does not exist"),
    (["run", "{tiny}", "--set", "material.K"], "--set expects KEY=VALUE"),
    (["run", "{tiny}", "--set", "=3"], "--set expects KEY=VALUE"),
    (["run", "{tiny}", "--set", "time.dt=1e-4", "--set", "time.dt=2e-4"], "given twice"),
    (["run", "{tiny}", "--set", "material.nope=1"], "override key"),
    (["run", "{tiny}", "--set", "material.K=abc"], "material.K"),
    (["run", "{tiny}", "--tol", "2"], "solver.tol"),
    (["run", "{tiny}", "--t-end", "-1"], "time.t_end"),
    (["run", "{tiny}", "--t-end", "soon"], "argument --t-end: invalid float value"),
    (["run", "{tiny}", "--solver", "rk4"], "argument --solver: invalid choice"),
    (["run", "{tiny}", "--bogus"], "unrecognized arguments: --bogus"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
    ([], "required: COMMAND"),
])
def test_bad_input_exits_2_with_one_line(argv, expected, tiny, fake_run, capsys):
    argv = [a.format(tiny=tiny) for a in argv]
    assert cli.main(argv) == 2
    captured = capsys.readouterr()
    assert expected in one_error_line(captured.err)
    assert captured.out == "" and "scene" not in fake_run


def test_bad_toml_exits_2(tmp_path, capsys):
    path = tmp_path / "broken.toml"
    path.write_text("name = [unclosed\n")
    assert cli.main(["run", str(path)]) == 2
    assert "is not valid TOML" in one_error_line(capsys.readouterr().err)


def test_solver_failure_exits_1_with_its_message(tiny, tmp_path, monkeypatch, capsys):
    def failing(scene, callback):
        raise StepFailure("series diverged", step=3, t=3e-4, amax=1e-3)

    monkeypatch.setattr(cli, "_simulate", failing)
    assert cli.main(["run", str(tiny), "--out", str(tmp_path / "o"), "--no-progress"]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert line == "jaxanm: error: solver failed: step 3 (t = 0.0003): series diverged; a_max = 0.001"
    assert not (tmp_path / "o").exists()


def test_unwritable_output_exits_1(tiny, tmp_path, fake_run, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert cli.main(["run", str(tiny), "--out", str(blocker / "sub"), "--no-progress"]) == 1
    assert "cannot write results to" in one_error_line(capsys.readouterr().err)


def test_help_and_version_exit_0(capsys):
    assert cli.main(["--help"]) == 0
    assert "run" in capsys.readouterr().out
    assert cli.main(["run", "--help"]) == 0
    assert "--set KEY=VALUE" in capsys.readouterr().out
    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("jaxanm ")


def test_scenes_lists_shipped(capsys):
    assert cli.main(["scenes"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == list(shipped_scenes())
    assert all("effects:" in line for line in lines)


def test_logging_handler_removed_after_main(tiny, tmp_path, fake_run, no_files):
    logger = logging.getLogger("jaxanm")
    before = list(logger.handlers), logger.level
    cli.main(["run", str(tiny), "--out", str(tmp_path), "--no-progress"])
    cli.main(["run", "no_such_scene"])
    assert (list(logger.handlers), logger.level) == before


def test_parse_overrides_keeps_values_as_strings():
    assert cli.parse_overrides(["a.b=1", " c = x,y ", "d="]) == {"a.b": "1", "c": "x,y", "d": ""}


def test_python_dash_m_bad_scene_one_line(tmp_path):
    root = str(Path(cli.__file__).resolve().parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run([sys.executable, "-m", "jaxanm", "run", "no_such_scene"],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    assert "unknown scene 'no_such_scene'" in one_error_line(proc.stderr)


@pytest.mark.slow
def test_end_to_end_smallest_shipped_scene(tmp_path):
    """The real model: the smallest shipped scene for three time steps, all files written."""
    pytest.importorskip("jaxanm.fsw.simulate")
    if not shipped_scenes():
        pytest.skip("no shipped scenes")
    scenes = {name: cli._load_scene(name) for name in shipped_scenes()}
    name = min(scenes, key=lambda n: ((scenes[n].geometry.R2 / scenes[n].geometry.dr) ** 2,
                                      len(scenes[n].effects)))
    t_end = 3 * scenes[name].time.dt
    out = tmp_path / "e2e"
    assert cli.main(["run", name, "--t-end", repr(t_end), "--out", str(out), "--no-progress"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["t_end"] == pytest.approx(t_end, rel=1e-9)
    assert summary["stats"]["time_steps"] >= 3
    with np.load(out / "fields.npz") as f:
        S, N = f["u"].shape
        assert N == summary["n_points"] and f["points"].shape == (S, N, 2) and S >= 2
        assert all(np.all(np.isfinite(f[k])) for k in ("points", "u", "v", "T"))
    assert len(list((out / "vtu").glob("*.vtu"))) == S
    assert (out / "probes.csv").read_text().splitlines()[0].startswith("t")
