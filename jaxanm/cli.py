"""The ``jaxanm`` command: run an FSW scene and write its results; list the shipped scenes.

::

    jaxanm run [SCENE] [--t-end S] [--solver anm|newton|mnewton] [--order P] [--tol X]
               [--set KEY=VALUE ...] [--out DIR] [--no-progress]
    jaxanm scenes

``SCENE`` is a shipped scene name or a TOML path (default ``fsw_paper``).  ``--set`` overrides
any scene field by dotted key (``--set material.K=2e16 --set effects=viscous,conduction``);
``--t-end``, ``--solver``, ``--order`` and ``--tol`` are shorthands for ``time.t_end``,
``solver.kind``, ``solver.order`` and ``solver.tol`` and are applied after the ``--set``
overrides.  Results go to ``--out`` (default ``results/<scene>-<solver>``), see
:func:`jaxanm.fsw.output.write_outputs`.

Exit status: 0 on success, 2 on bad input (unknown scene, malformed ``--set``, invalid value;
one ``jaxanm: error: ...`` line on stderr, no traceback), 1 when the solver fails or the
results cannot be written, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

from jaxanm.errors import InputError, SingularMatrixError, StepFailure

PROG = "jaxanm"
DEFAULT_SCENE = "fsw_paper"
SOLVER_KINDS = {"anm": "anm", "newton": "newton", "mnewton": "modified_newton"}
"""Command-line solver names -> ``solver.kind`` of the scene."""


class UsageError(Exception):
    """Bad command-line input; reported as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    """Argument parser that raises :class:`UsageError` instead of printing usage and exiting."""

    def error(self, message):
        """Raise :class:`UsageError` (argparse would print usage and exit)."""
        raise UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    """The ``jaxanm`` argument parser (sub-commands ``run`` and ``scenes``)."""
    from jaxanm import __version__

    parser = _Parser(prog=PROG, description="High-order implicit (ANM) friction-stir-welding "
                     "simulations on JAX, in float64.")
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    run = sub.add_parser("run", help="run a scene and write its results",
                         description="Run an FSW scene and write summary.json, fields.npz, "
                         "probes.csv, VTU/PVD files and the paper's figures.")
    run.add_argument("scene", nargs="?", default=DEFAULT_SCENE,
                     help=f"shipped scene name or path to a scene TOML file (default {DEFAULT_SCENE})")
    run.add_argument("--t-end", type=float, metavar="S", help="end time in s (time.t_end)")
    run.add_argument("--solver", choices=tuple(SOLVER_KINDS),
                     help="nonlinear step solver (solver.kind; mnewton = modified Newton)")
    run.add_argument("--order", type=int, metavar="P", help="ANM truncation order (solver.order)")
    run.add_argument("--tol", type=float, metavar="X",
                     help="ANM eta / Newton delta tolerance (solver.tol)")
    run.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="overrides",
                     help="override a scene field by dotted key, e.g. material.K=2e16 (repeatable)")
    run.add_argument("--out", type=Path, metavar="DIR",
                     help="output directory (default results/<scene>-<solver>)")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.set_defaults(func=_cmd_run)

    scenes = sub.add_parser("scenes", help="list the shipped scenes",
                            description="List the shipped scenes with their effects and end time.")
    scenes.set_defaults(func=_cmd_scenes)
    return parser


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


def load_run_scene(args: argparse.Namespace):
    """Load ``args.scene`` and apply ``--set`` overrides, then the shorthand options."""
    overrides = parse_overrides(args.overrides)
    shorthands = {"time.t_end": args.t_end, "solver.order": args.order, "solver.tol": args.tol,
                  "solver.kind": SOLVER_KINDS.get(args.solver)}
    scene = _load_scene(args.scene)
    if overrides:
        scene = scene.with_overrides(overrides)
    shorthands = {k: v for k, v in shorthands.items() if v is not None}
    if shorthands:
        scene = scene.with_overrides(shorthands)
    return scene


class ProgressBar:
    """tqdm bar over simulated time, driven by ``callback(t, stats)`` after each accepted step.

    Shows t / t_end (s), elapsed and remaining wall time, time steps per wall second and the
    factorisations done so far.
    """

    def __init__(self, t_end: float, label: str):
        from tqdm import tqdm

        self.start = time.perf_counter()
        self.bar = tqdm(total=t_end, desc=label, unit="s", dynamic_ncols=True,
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| t = {n:.4g}/{total:.4g} s "
                                   "[{elapsed}<{remaining}{postfix}]")

    def __call__(self, t, stats) -> None:
        """Advance the bar to simulated time ``t`` and show the statistics of ``stats``."""
        rate = stats.time_steps / max(time.perf_counter() - self.start, 1e-9)
        self.bar.set_postfix_str(f"{rate:.1f} steps/s, {stats.factorizations} factorizations",
                                 refresh=False)
        self.bar.update(float(t) - self.bar.n)

    def close(self) -> None:
        """Close the bar (leaves its last state on the terminal)."""
        self.bar.close()


def _load_scene(name_or_path):
    """:func:`jaxanm.fsw.scene.load_scene` (imported on first use)."""
    from jaxanm.fsw.scene import load_scene

    return load_scene(name_or_path)


def _simulate(scene, callback):
    """:func:`jaxanm.fsw.simulate.run` with the CLI's progress callback (imported on first use)."""
    from jaxanm.fsw.simulate import run

    return run(scene, solver=None, progress=False, callback=callback)


def _write_outputs(result, out_dir, solver_settings):
    """:func:`jaxanm.fsw.output.write_outputs` (imported on first use: matplotlib, meshio)."""
    from jaxanm.fsw.output import write_outputs

    return write_outputs(result, out_dir, solver_settings)


def _cmd_run(args: argparse.Namespace) -> int:
    """``jaxanm run``: load, override, simulate with a progress bar, write the results."""
    try:
        scene = load_run_scene(args)
    except ValueError as exc:  # SceneError: unknown scene, bad key or value
        raise UsageError(str(exc)) from exc
    out_dir = args.out or Path("results") / f"{scene.name}-{scene.solver.kind}"
    bar = None if args.no_progress else ProgressBar(scene.time.t_end, scene.name)
    try:
        result = _simulate(scene, bar)
    finally:
        if bar is not None:
            bar.close()
    try:
        paths = _write_outputs(result, out_dir, {"kind": scene.solver.kind, "options": result.solver})
    except OSError as exc:
        return _error(f"cannot write results to {out_dir}: {exc}", 1)
    stats = result.stats
    print(f"{scene.name} ({scene.solver.kind}): t = {float(result.t[-1]):.6g} s, "
          f"{stats.time_steps} steps, {stats.factorizations} factorizations, "
          f"{stats.wall_time_s:.1f} s wall")
    print(f"{len(paths)} files written to {out_dir}")
    return 0


def _cmd_scenes(args: argparse.Namespace) -> int:
    """``jaxanm scenes``: one line per shipped scene (name, effects, end time)."""
    from jaxanm.fsw.scene import shipped_scenes

    for name in shipped_scenes():
        try:
            scene = _load_scene(name)
        except ValueError as exc:
            raise UsageError(str(exc)) from exc
        print(f"{name:<24} t_end = {scene.time.t_end:<8g} effects: {', '.join(scene.effects)}")
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
