"""The ``jaxanm`` command: run an FSW scene and write its results; list the shipped scenes.

::

    jaxanm run [SCENE] [--t-end S] [--solver anm|newton|mnewton] [--order P] [--tol X]
               [--set KEY=VALUE ...] [--out DIR] [--checkpoint-every N] [--no-progress]
               [--no-compile-cache]
    jaxanm run --resume DIR [--checkpoint-every N] [--no-progress]
    jaxanm sweep GRID.toml [--out DIR] [--scheduler ADDRESS] [--workers N] [--reference DIR]
                 [--no-progress] [--no-compile-cache]
    jaxanm scenes

``SCENE`` is a shipped scene name or a TOML path (default ``fsw``, the main job).  ``--set`` overrides
any scene field by dotted key (``--set material.K=2e16 --set effects=viscous,conduction``);
``--t-end``, ``--solver``, ``--order`` and ``--tol`` are shorthands for ``time.t_end``,
``solver.kind``, ``solver.order`` and ``solver.tol`` and are applied after the ``--set``
overrides.  Results go to ``--out`` (default ``results/<scene>-<solver>``), see
:func:`jaxanm.fsw.io.output.write_outputs`.

Checkpoints: ``--checkpoint-every N`` writes ``DIR/checkpoint.npz`` atomically every N time
steps, at the end, and when the run is interrupted (SIGINT/Ctrl-C, SIGTERM) or fails.  It holds
the scene (solver settings included), the solver's state, K* and every result recorded so far,
so ``jaxanm run --resume DIR`` needs no other argument and ends with the same files as an
uninterrupted run (bit-identical fields on the same machine).  Options given with ``--resume``
must agree with the stored scene (else exit 2 naming the differing fields).  An interrupted or
failed run also writes the results of the steps done so far into DIR.

``jaxanm sweep`` runs every task of a grid file (a base scene, scene overrides and solver
settings, :mod:`jaxanm.sweep.grid`) as an independent run on Dask: a local cluster of
``--workers`` processes (default 2), or the workers of the scheduler at ``--scheduler``.  Each
task writes its own ``jaxanm run --out`` directory under ``DIR/runs/``; ``DIR/results.csv``
(default ``DIR`` = ``results/sweep-<grid name>``) gets one row per task as it finishes; tasks
already finished in DIR are not run again.  With a reference (the grid's ``reference`` task,
or ``--reference`` a run directory) the rows get errors against it and ``DIR/pareto.png`` is
drawn (:mod:`jaxanm.sweep`).  Exit status 1 when a task failed (the others still run).

Compiled XLA code is kept on disk for later runs (:mod:`jaxanm.compile_cache`) unless
``--no-compile-cache`` or ``JAXANM_COMPILE_CACHE=0``.

Exit status: 0 on success, 2 on bad input (unknown scene, malformed ``--set``, invalid value,
unusable checkpoint, bad grid file, unusable ``--reference``, unreachable scheduler; one
``jaxanm: error: ...`` line on stderr, no traceback), 1 when the solver fails, the results
cannot be written or a sweep task failed, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from jaxanm import compile_cache
from jaxanm._progress import ProgressBar
from jaxanm.errors import InputError, RunStopped, SingularMatrixError, StepFailure, did_you_mean
from jaxanm.fsw.scene import SOLVER_KINDS, SOLVER_OPTIONS, override_keys

PROG = "jaxanm"
DEFAULT_SCENE = "fsw"
CHECKPOINT_NAME = "checkpoint.npz"
"""File name of the checkpoint inside the output directory (:mod:`jaxanm.checkpoint`'s format)."""
OLD_CHECKPOINT_NAME = "checkpoint.pkl"
"""File name of the pickle checkpoints older jaxanm versions wrote (not read: refused with a message)."""


class UsageError(Exception):
    """Bad command-line input; reported as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """Argument parser that raises :class:`UsageError` instead of printing usage and exiting."""

    def error(self, message):
        """Raise :class:`UsageError` (argparse would print usage and exit)."""
        raise UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    """The ``jaxanm`` argument parser (sub-commands ``run``, ``sweep`` and ``scenes``)."""
    from jaxanm import __version__

    parser = _Parser(prog=PROG, description="High-order implicit (ANM) friction-stir-welding "
                     "simulations on JAX, in float64.")
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser("run", help="run a scene and write its results",
                         description="Run an FSW scene and write summary.json, fields.npz, "
                         "probes.csv, VTU/PVD files and the paper's figures.")
    run.add_argument("scene", nargs="?", default=None,
                     help=f"shipped scene name or path to a scene TOML file (default {DEFAULT_SCENE}; "
                     "with --resume: the scene stored in the checkpoint)")
    run.add_argument("--t-end", type=float, metavar="S", help="end time in s (time.t_end)")
    run.add_argument("--solver", choices=SOLVER_KINDS,
                     help="nonlinear step solver (solver.kind; mnewton = modified Newton)")
    run.add_argument("--order", type=int, metavar="P", help="ANM truncation order (solver.order)")
    run.add_argument("--tol", type=float, metavar="X",
                     help="ANM eta / Newton delta tolerance (solver.tol)")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
                     help="override a scene field by dotted key, e.g. material.K=2e16 (repeatable)")
    run.add_argument("--out", type=Path, metavar="DIR",
                     help="output directory (default results/<scene>-<solver>)")
    run.add_argument("--checkpoint-every", type=_positive_int, metavar="N",
                     help=f"write DIR/{CHECKPOINT_NAME} every N time steps (and on interruption)")
    run.add_argument("--resume", type=Path, metavar="DIR",
                     help=f"continue the run whose {CHECKPOINT_NAME} is in DIR (scene and solver "
                     "come from the checkpoint; results go to DIR)")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.add_argument("--no-compile-cache", action="store_true",
                     help="do not keep compiled XLA code on disk for later runs (default: kept in "
                     "$JAXANM_COMPILE_CACHE_DIR or ~/.cache/jaxanm/jax-<jax version>; JAXANM_COMPILE_CACHE=0 "
                     "also turns it off)")
    run.set_defaults(func=_cmd_run)

    sweep = sub.add_parser("sweep", help="run a grid of scene overrides x solver settings on Dask",
                           description="Run every task of a grid file as an independent run on Dask; write "
                           "one output directory per task, a results table (CSV) and, with a reference, "
                           "the errors and a Pareto plot (error against wall time).")
    sweep.add_argument("grid", type=Path, metavar="GRID.toml", help="grid file (see jaxanm.sweep.grid)")
    sweep.add_argument("--out", type=Path, metavar="DIR",
                       help="sweep directory (default results/sweep-<grid name>)")
    sweep.add_argument("--scheduler", metavar="ADDRESS",
                       help="address of a running Dask scheduler, e.g. tcp://host:8786 (default: a local "
                       "cluster); its workers must see DIR at the same path")
    sweep.add_argument("--workers", type=_positive_int, metavar="N",
                       help="worker processes of the local cluster, one thread each (default 2)")
    sweep.add_argument("--reference", type=Path, metavar="DIR",
                       help="output directory of the run the errors are measured against (default: the "
                       "grid's reference task)")
    sweep.add_argument("--no-progress", action="store_true", help="no progress bar")
    sweep.add_argument("--no-compile-cache", action="store_true",
                       help="the workers do not keep compiled XLA code on disk (as jaxanm run --no-compile-cache)")
    sweep.set_defaults(func=_cmd_sweep)

    scenes = sub.add_parser("scenes", help="list the shipped scenes, or print one with every key",
                            description="Without SCENE: list the shipped scenes, name, end time and what each "
                            "is for (the first sentence of its TOML file's opening comment), then its effects. "
                            "With SCENE (a shipped name or a TOML path): print that scene as a TOML file with every "
                            "key resolved, each marked with its default; a start for a scene of your own "
                            "(jaxanm scenes fsw_small > mine.toml).")
    scenes.add_argument("scene", nargs="?", metavar="SCENE", help="scene to print with every key")
    scenes.set_defaults(func=_cmd_scenes)
    return parser


def _positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1, got {value}")
    return value


def parse_overrides(items: list[str]) -> dict[str, str]:
    """``["a.b=1", "c=x,y"]`` -> ``{"a.b": "1", "c": "x,y"}``; values stay strings (the scene parses them).

    Raises :class:`UsageError` for an item without ``=``, with an empty key, or with a key
    given twice.
    """
    overrides: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise UsageError(f"--set expects KEY=VALUE (e.g. --set material.K=2e16), got {item!r}")
        if key in overrides:
            raise UsageError(f"--set {key} is given twice")
        overrides[key] = value.strip()
    return overrides


def load_run_scene(args: argparse.Namespace, base=None):
    """Load ``args.scene`` (else ``base``, else the default scene) and apply ``--set``
    overrides, then the shorthand options."""
    overrides = parse_overrides(args.overrides)
    known = override_keys()
    for key in overrides:
        if key not in known:
            section, _, field = key.rpartition(".")  # a known section: the closest of its own keys
            fields = [k.split(".", 1)[1] for k in known if section and k.startswith(section + ".")]
            hint = did_you_mean(field, fields, prefix=section + ".") if fields else did_you_mean(key, known)
            if fields and not hint:
                hint = f"[{section}] has {', '.join(fields)}"
            raise UsageError(f"--set {key}: no such scene key{f' ({hint})' if hint else ''}; every key with its "
                             "default: jaxanm scenes SCENE, or docs/guide/scene-keys.md")
    shorthands = {"time.t_end": args.t_end, "solver.order": args.order, "solver.tol": args.tol,
                  "solver.kind": args.solver}
    if args.scene is not None or base is None:
        scene = _load_scene(args.scene or DEFAULT_SCENE)
    else:
        scene = base
    if overrides:
        scene = scene.with_overrides(overrides)
    shorthands = {k: v for k, v in shorthands.items() if v is not None}
    if shorthands:
        scene = scene.with_overrides(shorthands)
    _check_solver_options(scene, overrides, order_given=args.order is not None)
    return scene


def _check_solver_options(scene, overrides: dict, order_given: bool) -> None:
    """Refuse ``--order`` for a solver without a series order; warn of ``--set solver.X`` that the
    scene's solver does not take (a scene file keeps every solver's fields, a command line names
    what it means to change)."""
    kind = scene.solver.kind
    takes = SOLVER_OPTIONS[kind]
    if order_given and "order" not in takes:
        raise UsageError(f"--order sets the ANM's series order (solver.order); the {kind} solver has none "
                         f"(it takes {', '.join(takes)}): drop --order, or add --solver anm")
    unused = sorted(key for key in overrides if key.startswith("solver.") and key != "solver.kind"
                    and key.split(".", 1)[1] not in takes)
    if unused:
        logging.getLogger("jaxanm").warning("--set %s: not used by the %s solver (it takes %s)",
                                            ", ".join(unused), kind, ", ".join(takes))


def _load_scene(name_or_path):
    """:func:`jaxanm.fsw.scene.load_scene` (imported on first use)."""
    from jaxanm.fsw.scene import load_scene

    return load_scene(name_or_path)


def _simulate(scene, callback, **checkpointing):
    """:func:`jaxanm.fsw.simulate.run` with the CLI's progress callback (imported on first use).

    ``checkpointing``: ``checkpoint``, ``checkpoint_every``, ``resume`` of ``run``.
    """
    from jaxanm.fsw.simulate import run

    return run(scene, solver=None, progress=False, callback=callback, **checkpointing)


def _gave_scene_options(args: argparse.Namespace) -> bool:
    """Whether the command line names a scene, ``--set`` overrides or a shorthand option."""
    return (args.scene is not None or bool(args.overrides)
            or any(v is not None for v in (args.t_end, args.solver, args.order, args.tol)))


def _resume_plan(args: argparse.Namespace):
    """``(scene, out_dir, checkpoint_every)`` of ``--resume DIR`` from the stored checkpoint.

    Options given alongside must describe the stored scene exactly (else :class:`UsageError`
    naming the differing fields); ``--out``, if given, must be DIR.
    """
    from jaxanm import stored_host_state
    from jaxanm.fsw.scene import Scene
    from jaxanm.fsw.simulate import scene_differences

    out_dir = args.resume
    path = out_dir / CHECKPOINT_NAME
    if not path.is_file() and (out_dir / OLD_CHECKPOINT_NAME).is_file():
        raise UsageError(f"--resume {out_dir}: its {OLD_CHECKPOINT_NAME} is a pickle checkpoint of an older jaxanm "
                         "version, which this one does not read (a pickle can run code): finish the run with the "
                         "version that wrote it, or start afresh")
    if not path.is_file():
        raise UsageError(f"--resume {out_dir}: no {CHECKPOINT_NAME} there; start the run with "
                         f"--checkpoint-every N --out {out_dir} to make one")
    host = stored_host_state(path)
    if not (isinstance(host, dict) and isinstance(host.get("scene"), dict)):
        raise UsageError(f"--resume {out_dir}: {path} was not written by 'jaxanm run' (no scene stored)")
    try:
        stored = Scene.from_dict(host["scene"], source=str(path))
    except ValueError as exc:
        raise UsageError(f"--resume {out_dir}: the stored scene is invalid: {exc}") from exc
    if _gave_scene_options(args):
        try:
            requested = load_run_scene(args, base=stored)
        except ValueError as exc:
            raise UsageError(str(exc)) from exc
        if requested != stored:
            raise UsageError(f"--resume {out_dir}: the checkpoint holds scene {stored.name!r}; the options given "
                             f"change {scene_differences(host['scene'], requested)}; drop them to resume, "
                             "or start a fresh run in another --out directory")
    if args.out is not None and args.out.resolve() != out_dir.resolve():
        raise UsageError(f"--out {args.out} conflicts with --resume {out_dir}: a resumed run writes into {out_dir}")
    every = args.checkpoint_every
    if every is None:
        every = int(host.get("settings", {}).get("checkpoint_every", 0))
    return stored, out_dir, every


def _write_run(result, out_dir, scene) -> list[Path]:
    """:func:`jaxanm.fsw.io.output.write_run` (imported on first use: matplotlib, meshio)."""
    from jaxanm.fsw.io.output import write_run

    return write_run(result, out_dir, scene)


def _cmd_run(args: argparse.Namespace) -> int:
    """``jaxanm run``: load, override (or resume), simulate with a progress bar, write the results."""
    if args.resume is not None:
        scene, out_dir, every = _resume_plan(args)
    else:
        try:
            scene = load_run_scene(args)
        except ValueError as exc:  # SceneError: unknown scene, bad key or value
            raise UsageError(str(exc)) from exc
        out_dir = args.out or Path("results") / f"{scene.name}-{scene.solver.kind}"
        every = args.checkpoint_every or 0
    if not args.no_compile_cache and compile_cache.requested():
        compile_cache.enable()
    checkpointing = {}
    if every or args.resume is not None:
        checkpointing = {"checkpoint": out_dir / CHECKPOINT_NAME, "checkpoint_every": every,
                         "resume": args.resume is not None}
    try:
        with ProgressBar(scene.time.t_end, scene.name, disable=args.no_progress) as bar:
            result = _simulate(scene, bar, **checkpointing)
    except KeyboardInterrupt as exc:  # the bar is closed: the error line follows it
        return _error(_stopped("interrupted", exc, out_dir, scene, checkpointing), 130)
    except (StepFailure, SingularMatrixError) as exc:
        return _error(_stopped(f"solver failed: {exc}", exc, out_dir, scene, checkpointing)
                      + what_to_try(scene, exc), 1)
    try:
        paths = _write_run(result, out_dir, scene)
    except OSError as exc:
        return _error(f"cannot write results to {out_dir}: {exc}", 1)
    stats = result.stats
    rezoned = getattr(result, "rezone_times", [])
    rezonings = f", rezoned at t = {', '.join(f'{t:.4g}' for t in rezoned)} s" if rezoned else ""
    print(f"{scene.name} ({scene.solver.kind}): t = {float(result.t[-1]):.6g} s, "
          f"{stats.time_steps} steps, {stats.factorizations} factorizations, "
          f"{stats.wall_time_s:.1f} s wall{rezonings}")
    for line in _accuracy_lines(paths):
        print(line)
    print(f"{len(paths)} files written to {out_dir}")
    return 0


TROUBLESHOOTING = "docs/guide/troubleshooting.md"
"""The page on failed and inaccurate runs (in the repository, and on the documentation site)."""


def what_to_try(scene, exc: StepFailure | SingularMatrixError) -> str:
    """What to change when ``scene``'s run failed with ``exc``, as the end of the error line:
    the options that apply to its solver, effects and start, the cheapest first."""
    kind, tries = scene.solver.kind, []
    if kind == "anm":
        more = max(200, 4 * scene.solver.setting("max_substeps"))
        tries.append(f"more continuation sub-steps (--set solver.max_substeps={more})")
    else:
        tries.append(f"more iterations (--set solver.max_iter={2 * scene.solver.setting('max_iter')})")
    if {"inertia", "conduction", "lagrangian", "tracers"} & set(scene.effects):  # else dt changes no step
        tries.append(f"a smaller time step than the run's own halvings reached (--set time.dt={scene.time.dt / 100:g})")
    tries.append("another solver (" + ", ".join(f"--solver {name}" for name in SOLVER_KINDS if name != kind)
                 + ")")
    if "viscous" in scene.effects and scene.mechanics.start == "rest" and getattr(exc, "step", 1) <= 1:
        tries.append("starting from the quasi-static flow instead of rest (--set mechanics.start=quasi_static)")
    return f"; to get past it try {'; '.join(tries)}; more in {TROUBLESHOOTING}"


def _accuracy_lines(paths) -> list[str]:
    """The accuracy lines of the run's ``summary.json`` (none if it was not written): the
    spatial accuracy, the time error estimate and the registration points' oscillation."""
    from jaxanm.fsw.io.output import probe_oscillation_lines, spatial_accuracy_lines, time_error_lines

    summary = next((p for p in paths if Path(p).name == "summary.json"), None)
    if summary is None:
        return []
    block = json.loads(Path(summary).read_text(encoding="utf-8"))
    spatial = block.get("spatial_accuracy")
    return (spatial_accuracy_lines(spatial) + time_error_lines(block.get("time_error"), spatial)
            + probe_oscillation_lines(block.get("probe_oscillation")) + coarse_cloud_lines(spatial))


def coarse_cloud_lines(spatial: dict | None) -> list[str]:
    """Why a run's temperature error is large, when its cloud puts under one point across the
    tool-edge shear band (``summary.json``'s ``spatial_accuracy``); none otherwise."""
    if (spatial or {}).get("shear_band_points", 1.0) >= 1.0:
        return []
    return ["why so large: this cloud puts under one point across the tool-edge shear band, where the heat "
            "is made, so its temperatures are those of a coarse demonstration scene; the main job "
            "(jaxanm run fsw) resolves the band: docs/physics/accuracy.md"]


def _stopped(what: str, exc: BaseException, out_dir, scene, checkpointing) -> str:
    """One-line report of a run that stopped early; writes the partial results it carries."""
    parts = [what]
    partial = exc.partial if isinstance(exc, RunStopped) else None
    if partial is not None:
        logger = logging.getLogger("jaxanm")
        level = logger.level
        logger.setLevel(logging.WARNING)  # the error line says what was written: no per-figure notes
        try:
            from jaxanm.fsw.io.output import end_time

            paths = _write_run(partial, out_dir, scene)
            parts.append(f"results up to t = {end_time(partial):.6g} s ({len(paths)} files) written to {out_dir}")
        except OSError as err:
            parts.append(f"cannot write the results so far to {out_dir}: {err}")
        finally:
            logger.setLevel(level)
    if checkpointing:
        parts.append(f"resume with: jaxanm run --resume {out_dir}")
    return "; ".join(parts)


def _cmd_sweep(args: argparse.Namespace) -> int:
    """``jaxanm sweep``: read and check the grid, run its tasks on Dask, report the table and plot."""
    from jaxanm.sweep import GridError, read_grid, run_sweep

    if args.scheduler is not None and args.workers is not None:
        raise UsageError("--workers sets the size of the local cluster; with --scheduler the scheduler's "
                         "workers run the tasks: drop one of the two")
    try:
        grid = read_grid(args.grid)
    except GridError as exc:
        raise UsageError(str(exc)) from exc
    cache = False if args.no_compile_cache else None
    try:
        result = run_sweep(grid, args.out, scheduler=args.scheduler, workers=args.workers or 2,
                           progress=not args.no_progress, reference=args.reference, compile_cache=cache)
    except KeyboardInterrupt:
        return _error("interrupted; the rows of the finished tasks are in the table, and a rerun of the "
                      "same command runs only the others", 130)
    n = len(result.rows)
    print(f"sweep {grid.name}: {n} tasks ({n - result.reused} run, {result.reused} reused, "
          f"{len(result.failed)} failed) in {result.wall_s:.1f} s")
    print(f"results table: {result.table}")
    if result.reference is not None:
        print(f"errors against {result.reference}" + (f"; Pareto plot: {result.plot}" if result.plot else ""))
    for note in result.notes:
        print(f"note: {note}")
    if result.failed:
        return _error(f"{len(result.failed)} of {n} tasks failed ({', '.join(result.failed)}); their messages "
                      f"are in {result.table}, and a rerun runs them again", 1)
    return 0


def _cmd_scenes(args: argparse.Namespace) -> int:
    """``jaxanm scenes``: per shipped scene, its name, end time and description, then its effects;
    ``jaxanm scenes SCENE``: that scene as TOML, every key resolved (:func:`scene_toml`)."""
    from jaxanm.fsw.scene import SCENES_DIR, shipped_scenes
    from jaxanm.fsw.scene_text import scene_description, scene_toml

    if args.scene is not None:
        try:
            scene = _load_scene(args.scene)
        except ValueError as exc:
            raise UsageError(str(exc)) from exc
        shipped = args.scene in shipped_scenes()
        source = SCENES_DIR / f"{args.scene}.toml" if shipped else Path(args.scene)
        shown = source.relative_to(SCENES_DIR.parents[2]) if shipped else source
        print(f"# {scene.name}: {scene_description(source) or 'a scene'}\n"
              f"# Every key of {shown} resolved (its base scenes, then the defaults); that file's\n"
              f"# comments say why each value.  A start of your own: jaxanm scenes {args.scene} > mine.toml\n")
        print(scene_toml(scene))
        return 0

    for name in shipped_scenes():
        try:
            scene = _load_scene(name)
        except ValueError as exc:
            raise UsageError(str(exc)) from exc
        description = scene_description(SCENES_DIR / f"{name}.toml")
        print(f"{name:<20} {f'{scene.time.t_end:g} s':<8} {description}")
        print(f"{'':<20} effects: {', '.join(scene.effects)}")
    return 0


def _error(message, status: int) -> int:
    """Print ``message`` as one ``jaxanm: error: ...`` line on stderr and return ``status``."""
    print(f"{PROG}: error: {' '.join(str(message).split())}", file=sys.stderr)
    return status


def main(argv: list[str] | None = None) -> int:
    """Run the ``jaxanm`` command with ``argv`` (default ``sys.argv[1:]``); return the exit status."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"{PROG}: note: %(message)s"))
    logger = logging.getLogger("jaxanm")
    logger.addHandler(handler)
    previous_level = logger.level
    logger.setLevel(logging.INFO)
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except SystemExit as exc:  # --help / --version
        return exc.code if isinstance(exc.code, int) else 0
    except (UsageError, InputError) as exc:
        return _error(exc, 2)
    except (StepFailure, SingularMatrixError) as exc:
        return _error(f"solver failed: {exc}", 1)
    except KeyboardInterrupt:
        return _error("interrupted", 130)
    finally:
        logger.removeHandler(handler)
        logger.setLevel(previous_level)
