"""The ``jaxanm`` command line: parsing, scene overrides, progress, outputs and error paths.

The simulation is replaced by a fake ``run`` (monkeypatched ``jaxanm.cli._simulate``) that
reports a few steps through the CLI's callback and returns the synthetic result of
``test_output``, so these tests exercise the command without the FSW model.
"""

from __future__ import annotations

import json
import logging
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_output import fake_result

from jaxanm import cli
from jaxanm._progress import ProgressBar
from jaxanm.errors import StepFailure
from jaxanm.fsw.scene import Scene, shipped_scenes
from jaxanm.fsw.scene_text import scene_description
from jaxanm.stats import Stats

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

    def simulate(scene, callback, **checkpointing):
        calls["scene"], calls["callback"], calls["checkpointing"] = scene, callback, checkpointing
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

    def write(result, out_dir, scene):
        calls.update(out_dir=out_dir, scene=scene)
        return []

    monkeypatch.setattr(cli, "_write_run", write)
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
    assert isinstance(fake_run["callback"], ProgressBar) and fake_run["callback"].bar.disable  # shows nothing
    assert "%|" not in capsys.readouterr().err
    # the CLI guide's table of output files names every file and folder a run writes
    guide = (Path(cli.__file__).resolve().parents[1] / "docs" / "guide" / "cli.md").read_text(encoding="utf-8")
    table = guide[guide.index("### Output files"):guide.index("### Exit status")]
    written = {re.sub(r"^fig\d\d_.*", "fig", p.name) for p in out.iterdir() if not p.name.startswith(".")}
    assert written and not [name for name in written if f"`{name}" not in table and f"`{name}/" not in table]


def test_shorthands_and_set_overrides_reach_the_scene(tiny, tmp_path, fake_run, no_files):
    argv = ["run", str(tiny), "--t-end", "0.002", "--solver", "mnewton", "--tol", "1e-8",
            "--set", "material.K=2e16", "--set", "time.dt = 5e-5", "--set", "solver.order=9",
            "--out", str(tmp_path), "--no-progress"]
    assert cli.main(argv) == 0
    scene = fake_run["scene"]
    assert scene.name == "tiny" and scene.time.t_end == 0.002 and scene.time.dt == 5e-5
    assert scene.material.K == 2e16
    assert (scene.solver.kind, scene.solver.order, scene.solver.tol) == ("mnewton", 9, 1e-8)
    assert no_files["scene"].solver.kind == "mnewton"  # the files describe the overridden scene


def test_set_switches_the_pade_option(tiny, tmp_path, fake_run, no_files):
    argv = ["run", str(tiny), "--set", "solver.pade=true", "--out", str(tmp_path), "--no-progress"]
    assert cli.main(argv) == 0
    assert fake_run["scene"].solver.pade is True and fake_run["scene"].solver.make().pade is True


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
    assert isinstance(fake_run["callback"], ProgressBar)
    err = capsys.readouterr().err
    assert "tiny: 100%" in err and "t = 0.001/0.001 s" in err
    assert "steps/s, 3 factorizations" in err


def test_progress_bar_tracks_simulated_time():
    bar = ProgressBar(0.7, "x")
    stats = Stats(time_steps=5, factorizations=2)
    bar(0.35, stats)
    assert bar.bar.n == pytest.approx(0.35)
    bar(0.7, stats)
    assert bar.bar.n == pytest.approx(0.7)
    assert "2 factorizations" in bar.bar.postfix
    bar.close()


@pytest.mark.parametrize("argv, expected", [
    (["run", "no_such_scene"], "unknown scene 'no_such_scene'"),
    (["run", "fsw_smal"], "unknown scene 'fsw_smal' (did you mean 'fsw_small'?)"),
    (["run", "fsw.toml"], "scene file 'fsw.toml' does not exist; the shipped scene is 'fsw'"),
    (["run", "{tiny}", "--set", "material.nn=0.3"], "material.nn: no such scene key (did you mean 'material.n'?)"),
    (["run", "{tiny}", "--solver", "mnewton", "--order", "5"], "--order sets the ANM's series order"),
    (["run", "{tiny}", "--solver", "newton", "--order", "5"], "the newton solver has none"),
    (["run", "missing.toml"], "does not exist"),
    (["run", "{tiny}", "--set", "material.K"], "--set expects KEY=VALUE"),
    (["run", "{tiny}", "--set", "=3"], "--set expects KEY=VALUE"),
    (["run", "{tiny}", "--set", "time.dt=1e-4", "--set", "time.dt=2e-4"], "given twice"),
    (["run", "{tiny}", "--set", "material.nope=1"], "material.nope: no such scene key ([material] has K, A, n,"),
    (["run", "{tiny}", "--set", "material.K=abc"], "material.K"),
    (["run", "{tiny}", "--tol", "2"], "solver.tol"),
    (["run", "{tiny}", "--set", "solver.pade=maybe"], "solver.pade"),
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


def test_a_misspelt_key_is_answered_with_the_closest_key_not_all_of_them(tiny, fake_run, capsys):
    assert cli.main(["run", str(tiny), "--set", "materal.K=2e16"]) == 2
    line = one_error_line(capsys.readouterr().err)
    assert "did you mean 'material.K'?" in line and "material.rho" not in line


def test_a_time_dependent_scene_s_failure_suggests_a_step_below_the_halvings_reached(tiny):
    """Four halvings reach dt / 16: the suggestion is a hundredth of the scene's dt."""
    scene = cli._load_scene(str(tiny)).with_overrides({"effects": "viscous,inertia"})
    advice = cli.what_to_try(scene, StepFailure("x", step=3, t=3e-4))
    assert "--set time.dt=1e-06" in advice and "quasi_static" not in advice


def test_set_solver_option_the_solver_does_not_take_is_named(tiny, tmp_path, fake_run, no_files, capsys):
    argv = ["run", str(tiny), "--solver", "mnewton", "--set", "solver.pade=true", "--out", str(tmp_path),
            "--no-progress"]
    assert cli.main(argv) == 0
    assert "--set solver.pade: not used by the mnewton solver (it takes tol, max_iter, max_rate)" \
        in capsys.readouterr().err
    assert fake_run["scene"].solver.kind == "mnewton"


def test_a_folder_named_like_a_shipped_scene_does_not_hide_it(tmp_path, monkeypatch, fake_run, no_files, capsys):
    """``jaxanm run fsw`` after ``jaxanm run --out fsw`` in the same folder runs the shipped scene."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "fsw").mkdir()
    assert cli.main(["run", "fsw", "--out", "out", "--no-progress"]) == 0
    assert fake_run["scene"].name == "fsw"
    assert "note:" not in capsys.readouterr().err  # a folder is never a scene file: nothing to warn of


@pytest.mark.parametrize("file_name", ["couette_small", "couette_small.toml"])
def test_a_file_named_like_a_shipped_scene_is_named_in_a_warning(file_name, tmp_path, monkeypatch, fake_run,
                                                                  no_files, capsys):
    """The shipped scene is taken, the warning says how to run the file, and that way runs it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / file_name).write_text(TINY_TOML)
    assert cli.main(["run", "couette_small", "--out", "out", "--no-progress"]) == 0
    assert fake_run["scene"].name == "couette_small"
    err = capsys.readouterr().err
    explicit = os.path.join(".", file_name)
    assert f"running the shipped scene; to run the file, give its path, e.g. {explicit}" in err
    assert cli.main(["run", explicit, "--out", "out", "--no-progress"]) == 0
    assert fake_run["scene"].name == "tiny"


def test_a_folder_is_not_a_scene_file(tmp_path, fake_run, capsys):
    assert cli.main(["run", str(tmp_path)]) == 2
    assert "is a folder, not a scene file" in one_error_line(capsys.readouterr().err)


def test_bad_toml_exits_2(tmp_path, capsys):
    path = tmp_path / "broken.toml"
    path.write_text("name = [unclosed\n")
    assert cli.main(["run", str(path)]) == 2
    assert "is not valid TOML" in one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize("stop, status", [(KeyboardInterrupt, 130), (StepFailure("diverged", step=2, t=2e-4), 1)])
def test_the_progress_bar_closes_once_before_the_error_line(tiny, tmp_path, monkeypatch, capsys, stop, status):
    """However the run ends, the bar is closed once, before the error line is printed."""
    events = []
    monkeypatch.setattr(ProgressBar, "close", lambda self: events.append("closed"))
    monkeypatch.setattr(cli, "_error", lambda message, code: events.append("error line") or code)

    def stopping(scene, callback, **checkpointing):
        callback(scene.time.t_end / 2, Stats(time_steps=1))
        raise stop

    monkeypatch.setattr(cli, "_simulate", stopping)
    assert cli.main(["run", str(tiny), "--out", str(tmp_path / "o")]) == status
    assert events == ["closed", "error line"]


def test_solver_failure_exits_1_with_its_message(tiny, tmp_path, monkeypatch, capsys):
    def failing(scene, callback, **checkpointing):
        raise StepFailure("series diverged", step=3, t=3e-4, amax=1e-3)

    monkeypatch.setattr(cli, "_simulate", failing)
    assert cli.main(["run", str(tiny), "--out", str(tmp_path / "o"), "--no-progress"]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert line.startswith("jaxanm: error: solver failed: step 3 (t = 0.0003): series diverged; a_max = 0.001, "
                           "|R|_inf = n/a; to get past it try ")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("solver, step, expected, absent", [
    # the ANM: more sub-steps (4 x the scene's 50), the other solvers; on the first step from
    # rest the quasi-static start; the tiny scene (viscous only) solves the same flow whatever dt
    ("anm", 1, ["--set solver.max_substeps=200", "--solver newton", "--solver mnewton",
                "--set mechanics.start=quasi_static", cli.TROUBLESHOOTING], ["--solver anm", "max_iter", "time.dt"]),
    # Newton: twice its default 30 iterations; past the first step the start is not the cause
    ("newton", 5, ["--set solver.max_iter=60", "--solver anm"], ["max_substeps", "quasi_static", "--solver newton"]),
])
def test_a_failed_run_says_what_to_try(solver, step, expected, absent, tiny, tmp_path, monkeypatch, capsys):
    def failing(scene, callback, **checkpointing):
        raise StepFailure("series from a fresh K* cannot reach a = 1", step=step, t=step * 1e-4, amax=2e-4,
                          residual_norm=0.2)

    monkeypatch.setattr(cli, "_simulate", failing)
    argv = ["run", str(tiny), "--solver", solver, "--out", str(tmp_path / "o"), "--no-progress"]
    assert cli.main(argv) == 1
    line = one_error_line(capsys.readouterr().err)
    assert all(hint in line for hint in expected), line
    assert not any(hint in line for hint in absent), line


def test_unwritable_output_exits_1(tiny, tmp_path, fake_run, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert cli.main(["run", str(tiny), "--out", str(blocker / "sub"), "--no-progress"]) == 1
    assert "cannot write results to" in one_error_line(capsys.readouterr().err)


@pytest.mark.parametrize("points, explained", [(0.14, True), (1.2, False)])
def test_a_coarse_cloud_s_large_error_is_explained(points, explained, tmp_path):
    """Under one point across the tool-edge shear band the summary says why the rise error is
    large and where the accuracy of each scene is; a resolved band gets no such line."""
    summary = tmp_path / "summary.json"
    summary.write_text(json.dumps({"spatial_accuracy": {
        "shear_band_width_m": 1.04e-4, "shear_band_points": points, "edge_spacing_m": 1.04e-4 / points,
        "rise_error": {"t": 0.01, "rel_l2": 0.29, "mean_ratio": 0.936, "max_abs_K": 3.88}}}))
    lines = cli._accuracy_lines([summary])
    assert f"{points:.2f} points across" in lines[0] and "29 % rel. L2 error" in lines[1]
    why = [line for line in lines if line.startswith("why so large")]
    assert bool(why) is explained
    if explained:
        assert "docs/physics/accuracy.md" in why[0]  # that it exists: tests/test_docs_claims.py


def test_help_and_version_exit_0(capsys):
    assert cli.main(["--help"]) == 0
    assert "run" in capsys.readouterr().out
    assert cli.main(["run", "--help"]) == 0
    assert "--set KEY=VALUE" in capsys.readouterr().out
    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("jaxanm ")


def test_version_is_the_package_version(capsys):
    """``jaxanm --version`` prints ``jaxanm.__version__``, the version pip installed."""
    import importlib.metadata

    import jaxanm

    assert cli.main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"jaxanm {jaxanm.__version__}"
    assert importlib.metadata.version("jaxanm") == jaxanm.__version__


def test_scenes_lists_shipped(capsys):
    """Two lines per shipped scene: name, end time and a description; then its effects."""
    assert cli.main(["scenes"]) == 0
    lines = capsys.readouterr().out.splitlines()
    names, effects = lines[0::2], lines[1::2]
    assert [line.split()[0] for line in names] == list(shipped_scenes())
    assert all(line.split()[0] == "effects:" for line in effects)
    for line in names:
        name, t_end, unit, *description = line.split()
        assert unit == "s" and float(t_end) == cli._load_scene(name).time.t_end
        assert description, f"{name} has no description"
    assert "The friction-stir-welding example of the paper" in "\n".join(names)


@pytest.mark.parametrize("name", ["fsw_small", "fsw_weld_slip"])
def test_scenes_name_prints_a_scene_file_that_loads_back_to_the_scene(name, tmp_path, capsys):
    """``jaxanm scenes NAME`` writes every key (a scene built on others resolved), each section key
    marked with its default; the output is a scene file of the same scene."""
    from jaxanm.fsw.scene import load_scene

    assert cli.main(["scenes", name]) == 0
    out = capsys.readouterr().out
    path = tmp_path / "copy.toml"
    path.write_text(out)
    assert load_scene(path) == load_scene(name)
    lines = out.splitlines()
    assert "dr = 0.00075  # default 0.000375" in lines or name != "fsw_small"  # changed: the default shown
    assert "R1 = 0.0015  # default" in lines  # kept: marked as the default
    assert len([line for line in lines if line.startswith("[") and not line.startswith("[[")]) == 7


def test_scene_description_is_the_first_sentence_of_the_opening_comment(tmp_path):
    scene = tmp_path / "s.toml"
    scene.write_text("# A scene for tests: V . grad T kept.  Second sentence.\n"
                     "# More.\nname = 's'\n# not the opening block\n", encoding="utf-8")
    assert scene_description(scene) == "A scene for tests: V . grad T kept."
    scene.write_text("# " + "word " * 60 + "\nname = 's'\n", encoding="utf-8")
    short = scene_description(scene, width=40)
    assert len(short) <= 40 and short.endswith("word...")
    scene.write_text("name = 's'\n", encoding="utf-8")
    assert scene_description(scene) == ""


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


# --------------------------------------------------------------------------- checkpoint / resume

RESUME_TOML = """
# fsw_small at (R2 - R1) / 4 (113 points) for 5 steps, Newton: a few seconds per run
name = "resume_tiny"
effects = ["inertia", "viscous", "softening", "conduction", "tool_conduction", "dissipation", "robin",
           "lagrangian"]
[geometry]
dr = 1.125e-3
[mechanics]
penalty = 4.08e5
[time]
dt = 1e-4
t_end = 5e-4
save = [2e-4, 4e-4]
[solver]
kind = "newton"
tol = 1e-8
[[probes]]
name = "1"
x = 1.875e-3
y = 0.0
[[sections]]
name = "A-A"
start = [-6e-3, 0.0]
end = [6e-3, 0.0]
samples = 21
"""


@pytest.fixture(scope="module")
def resume_scene(tmp_path_factory):
    """A tiny Lagrangian thermo-mechanical scene file and its uninterrupted results directory."""
    root = tmp_path_factory.mktemp("resume")
    path = root / "resume_tiny.toml"
    path.write_text(RESUME_TOML)
    ref = root / "ref"
    assert cli.main(["run", str(path), "--out", str(ref), "--no-progress"]) == 0
    return path, ref


def _interrupt_after(monkeypatch, steps, how):
    """Make the CLI's simulation stop after ``steps`` accepted steps (KeyboardInterrupt or SIGTERM)."""
    real = cli._simulate

    def simulate(scene, callback, **checkpointing):
        def stop(t, stats):
            if stats.time_steps == steps:
                if how == "sigterm":
                    os.kill(os.getpid(), signal.SIGTERM)  # the run turns it into an interruption
                raise KeyboardInterrupt

        return real(scene, stop, **checkpointing)

    monkeypatch.setattr(cli, "_simulate", simulate)


def _same_results(a: Path, b: Path):
    with np.load(a / "fields.npz") as fa, np.load(b / "fields.npz") as fb:
        assert sorted(fa.files) == sorted(fb.files)
        for key in fa.files:
            np.testing.assert_array_equal(fa[key], fb[key], err_msg=key)  # bit-identical
    assert (a / "probes.csv").read_text() == (b / "probes.csv").read_text()


@pytest.mark.parametrize("how", ["sigint", "sigterm"])
def test_interrupted_run_resumes_to_the_same_fields(resume_scene, tmp_path, monkeypatch, capsys, how):
    path, ref = resume_scene
    out = tmp_path / "run"
    _interrupt_after(monkeypatch, 3, how)
    assert cli.main(["run", str(path), "--out", str(out), "--checkpoint-every", "2", "--no-progress"]) == 130
    line = one_error_line(capsys.readouterr().err)
    assert "interrupted" in line and f"resume with: jaxanm run --resume {out}" in line
    assert (out / "checkpoint.npz").is_file()
    assert not [f for f in os.listdir(out) if f.startswith(".")]  # no half-written file left
    with np.load(out / "fields.npz") as partial:  # the results so far were written
        assert list(partial["t"]) == [0.0, 2e-4]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["t_end"] == pytest.approx(3e-4)
    monkeypatch.undo()
    # nothing but the directory is needed; options that agree with the stored scene are accepted
    extra = [] if how == "sigint" else [str(path), "--out", str(out), "--solver", "newton"]
    assert cli.main(["run", "--resume", str(out), *extra, "--no-progress"]) == 0
    _same_results(ref, out)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stats"]["resumes"] == 0  # Newton keeps no K* across steps
    assert summary["stats"]["time_steps"] == 5


def _write_checkpoint(directory: Path, scene: Scene, every=3):
    from jaxanm._run_checkpoint import VERSION
    from jaxanm.checkpoint import write_atomic

    host = {"scene": scene.to_dict(), "settings": {"checkpoint_every": every}}
    write_atomic(directory / cli.CHECKPOINT_NAME, {"version": VERSION, "host_state": host})


@pytest.mark.parametrize("extra, expected", [
    (["--set", "material.K=2e16"], "change material.K"),
    (["--t-end", "0.002"], "change time.t_end"),
    (["--solver", "newton"], "change solver.kind"),
    (["{other}"], "change name"),
    (["--out", "{elsewhere}"], "conflicts with --resume"),
])
def test_resume_refuses_conflicting_options(extra, expected, tiny, tmp_path, fake_run, capsys):
    stored = Scene.from_dict({"name": "tiny", "effects": ["viscous"], "time": {"dt": 1e-4, "t_end": 0.001}})
    _write_checkpoint(tmp_path, stored)
    other = tmp_path / "other.toml"
    other.write_text(TINY_TOML.replace('"tiny"', '"other"'))
    extra = [a.format(other=other, elsewhere=tmp_path / "x") for a in extra]
    assert cli.main(["run", "--resume", str(tmp_path), *extra, "--no-progress"]) == 2
    assert expected in one_error_line(capsys.readouterr().err)
    assert "scene" not in fake_run


def test_resume_takes_scene_and_settings_from_the_checkpoint(tmp_path, fake_run, no_files):
    stored = Scene.from_dict({"name": "tiny", "effects": ["viscous"], "time": {"dt": 1e-4, "t_end": 0.001}})
    _write_checkpoint(tmp_path, stored, every=7)
    assert cli.main(["run", "--resume", str(tmp_path), "--no-progress"]) == 0
    assert fake_run["scene"] == stored
    assert fake_run["checkpointing"] == {"checkpoint": tmp_path / cli.CHECKPOINT_NAME, "checkpoint_every": 7,
                                         "resume": True}
    assert no_files["out_dir"] == tmp_path


@pytest.mark.parametrize("content, expected", [
    (None, "no checkpoint.npz there"),
    (b"not a pickle", "not a readable jaxanm checkpoint"),
])
def test_resume_without_a_usable_checkpoint_exits_2(content, expected, tmp_path, fake_run, capsys):
    if content is not None:
        (tmp_path / cli.CHECKPOINT_NAME).write_bytes(content)
    assert cli.main(["run", "--resume", str(tmp_path)]) == 2
    assert expected in one_error_line(capsys.readouterr().err)


def test_checkpoint_every_goes_into_the_output_directory(tiny, tmp_path, fake_run, no_files):
    assert cli.main(["run", str(tiny), "--out", str(tmp_path), "--checkpoint-every", "5", "--no-progress"]) == 0
    assert fake_run["checkpointing"] == {"checkpoint": tmp_path / "checkpoint.npz", "checkpoint_every": 5,
                                         "resume": False}
    assert cli.main(["run", str(tiny), "--checkpoint-every", "0"]) == 2
