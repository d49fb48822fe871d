"""Result files of an FSW run: summary JSON, fields NPZ, probe CSV, VTU/PVD series, figures.

:func:`write_outputs` writes everything a run produces into one directory (:func:`write_run`
for a run of a scene, naming its solver kind)::

    summary.json                   scene, solver settings, t_end, n_points, stats, final probes,
                                   probe_positions, rezone_times (Lagrangian re-seedings),
                                   spatial_accuracy, process (a travelling tool)
    fields.npz                     t (S,), points (S, N, 2), u, v, T (S, N), material (N,);
                                   nodes (S, N, 2) when a Lagrangian run was rezoned
    probes.csv                     t, then <probe>_u, <probe>_v, <probe>_T per registration point
    fields.pvd                     ParaView collection of the VTU files with their times
    vtu/fields_00000.vtu ...       point cloud (VTK vertex cells) with u, v, T, speed, material
    fig02_*.png ... fig11_*.png    the paper's figures (see :mod:`jaxanm.fsw.io.figures`)

Every file is written atomically (:func:`jaxanm.checkpoint.atomic_path`): to
a temporary name in the same directory, then ``os.replace``-d onto its final name, so a reader
never sees a half-written file and an interrupted run leaves no partial file behind.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import logging
import os
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np
from matplotlib.figure import Figure

from jaxanm.checkpoint import atomic_path
from jaxanm.fsw.io import figures
from jaxanm.fsw.io.weld_figures import weld_figures
from jaxanm.fsw.process import process_summary
from jaxanm.internal import missing_extra_message

log = logging.getLogger(__name__)

VTU_DIR = "vtu"
"""Sub-directory of the output directory holding the VTU files."""


def to_jsonable(obj):
    """Convert ``obj`` to plain JSON types (dict, list, str, float, int, bool, None).

    Objects with an ``as_dict()`` or ``to_dict()`` method (:class:`jaxanm.Stats`, the
    scene, in its TOML layout) and dataclasses become dictionaries; numpy/JAX arrays become
    (nested) lists; paths become strings; enums their value; anything else unknown its ``repr``.
    Non-finite floats are kept (JSON ``NaN``/``Infinity``, as Python's ``json`` writes them).
    """
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    if isinstance(obj, np.generic):
        return obj.item()
    for method in ("as_dict", "to_dict"):
        if callable(getattr(obj, method, None)):
            return to_jsonable(getattr(obj, method)())
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_jsonable(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, Mapping):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, enum.Enum):
        return to_jsonable(obj.value)
    if hasattr(obj, "__array__"):
        return np.asarray(obj).tolist()
    return repr(obj)


def probe_names(result) -> list[str]:
    """Names of the registration points of ``result``, in the order the scene lists them."""
    return [name for name in result.probes if name != "t"]


def end_time(result) -> float:
    """Last simulated time: the last accepted step (probe history), else the last saved time."""
    if len(result.probes.get("t", ())):
        return float(np.asarray(result.probes["t"], dtype=np.float64)[-1])
    return float(np.asarray(result.t, dtype=np.float64)[-1])


def spatial_accuracy(result) -> dict | None:
    """How well the run resolves the physics in space (``summary.json``'s ``spatial_accuracy``).

    For a run of a :class:`~jaxanm.fsw.scene.Scene` (None for anything else):

    - with ``viscous``: ``shear_band_width_m``, the width of the shear band at the tool edge
      (:func:`jaxanm.fsw.continuum_error.shear_band_width`, closed-form cheap),
      ``edge_spacing_m``, the radial point spacing there
      (:func:`jaxanm.fsw.geometry.edge_spacing`), and their ratio ``shear_band_points``;
    - with ``conduction``: ``rise_error``, the temperature rise at the last saved time
      against the axisymmetric continuum solution (:func:`jaxanm.fsw.continuum_error.rise_error`,
      about a second of 1-D solve): ``rel_l2``, ``mean_ratio``, ``max_abs_K``, ``t``; and
      ``rise_errors``, the same at every saved time from 0.01 s on (one solve,
      :func:`jaxanm.fsw.continuum_error.rise_errors`).

    How many points the shipped clouds put across the band and how far their rise is off:
    docs/physics/accuracy.md (from benchmarks/results/spatial_convergence.md).
    """
    from jaxanm.fsw import continuum_error, geometry
    from jaxanm.fsw.scene import Scene

    scene = getattr(result, "scene", None)
    if not isinstance(scene, Scene):
        return None
    block: dict[str, Any] = {}
    if scene.has("viscous"):
        width, spacing = continuum_error.shear_band_width(scene), geometry.edge_spacing(scene.geometry)
        block.update(shear_band_width_m=width, edge_spacing_m=spacing, shear_band_points=width / spacing)
    if scene.has("conduction") and len(np.asarray(result.t)):
        errors = continuum_error.rise_errors(result)
        last = errors[-1] if errors and errors[-1]["t"] == float(np.asarray(result.t)[-1]) else None
        block["rise_error"] = last if last is not None else continuum_error.rise_error(result)
        block["rise_errors"] = errors
    return block or None


def time_error(result) -> dict | None:
    """The controller's estimate of the time error at the run's end (``summary.json``'s
    ``time_error``), beside the spatial error: ``{"t", "rel_l2", "max_abs_K"}``, the estimate
    (:attr:`jaxanm.Solution.time_error`: the sum of the steps' local error estimates of T at
    the points) relative to the rise ``T - T0`` there in the L2 norm over the points, and its
    largest value (K).  None for a run without a controller or without temperatures."""
    estimate = getattr(result, "time_error", None)
    scene = getattr(result, "scene", None)
    if estimate is None or scene is None or not scene.has("conduction"):
        return None
    estimate = np.asarray(estimate, dtype=np.float64)
    rise = np.asarray(result.T[-1], dtype=np.float64) - scene.thermal.T0
    norm = float(np.linalg.norm(rise))
    if estimate.shape != rise.shape or not norm > 0:
        return None
    return {"t": float(np.asarray(result.t)[-1]), "rel_l2": float(np.linalg.norm(estimate)) / norm,
            "max_abs_K": float(np.abs(estimate).max())}


def time_error_lines(block: dict | None, spatial: dict | None = None) -> list[str]:
    """The ``time_error`` block of ``summary.json`` as a line, beside the spatial error at
    the same time when the ``spatial_accuracy`` block has it."""
    if not block:
        return []
    line = (f"time error at t = {block['t']:.6g} s, upper estimate (the controller's local errors summed, "
            "their decay left out): "
            f"{100 * block['rel_l2']:.2g} % of the rise, max {block['max_abs_K']:.2g} K")
    err = (spatial or {}).get("rise_error")
    if err and err["t"] == block["t"]:
        line += f", against a spatial error of {100 * err['rel_l2']:.3g} %"
    return [line]


OSCILLATION_WINDOWS = ((0.05, 0.15), (0.3, 0.7))
"""Spans (s) over which :func:`probe_oscillation` measures the registration points' histories:
after the start-up transient, and the late quasi-steady heating."""


OSCILLATION_SAMPLES = 16
"""Fewest samples of a window :func:`probe_oscillation` measures: a quadratic trend leaves
few residuals to measure below that (a scene stepping 0.05 s has 3 in 0.05-0.15 s)."""


def probe_oscillation(result, degree: int = 2) -> dict | None:
    """How much the registration points' histories oscillate (``summary.json``'s
    ``probe_oscillation``): per probe and per window of :data:`OSCILLATION_WINDOWS` that the
    run covers, the amplitude about a trend of ``degree`` (:func:`jaxanm.fsw.oscillation.oscillation`)
    of the speed relative to its mean over the window, and of T relative to the mean rise
    there (T less its value at the first record, the initial temperature).

    Returns ``{"windows": [[t0, t1], ...], "speed": {probe: [...]}, "T": {probe: [...]},
    "max_speed", "max_T"}`` (the maxima over probes per window), or None when no window is
    covered with :data:`OSCILLATION_SAMPLES` samples or the result has no probe histories.
    """
    from jaxanm.fsw.oscillation import oscillation

    names = probe_names(result)
    t = np.asarray(result.probes.get("t", ()), dtype=np.float64) if names else np.zeros(0)
    windows = [w for w in OSCILLATION_WINDOWS if t.size and t[0] <= w[0] and t[-1] >= w[1] - 1e-9
               and np.count_nonzero((t >= w[0]) & (t <= w[1])) >= OSCILLATION_SAMPLES]
    if not windows:
        return None
    block: dict[str, Any] = {"windows": [list(w) for w in windows], "degree": degree, "speed": {}, "T": {}}
    for name in names:
        p = result.probes[name]
        speed = np.hypot(np.asarray(p["u"], dtype=np.float64), np.asarray(p["v"], dtype=np.float64))
        T = np.asarray(p["T"], dtype=np.float64)
        rise = T - T[0]  # T at t = 0 is the initial temperature
        block["speed"][name] = [oscillation(t, speed, w, degree).relative for w in windows]
        block["T"][name] = [oscillation(t, rise, w, degree).relative for w in windows]
    for key in ("speed", "T"):
        block[f"max_{key}"] = [max(v[k] for v in block[key].values()) for k in range(len(windows))]
    return block


def spatial_accuracy_lines(block: dict | None) -> list[str]:
    """The ``spatial_accuracy`` block of ``summary.json`` as lines for the command line."""
    if not block:
        return []
    lines = []
    if "shear_band_points" in block:
        lines.append(f"shear band at the tool edge: {block['shear_band_width_m'] * 1e3:.3g} mm wide, "
                     f"{block['shear_band_points']:.2f} points across (radial spacing "
                     f"{block['edge_spacing_m'] * 1e3:.3g} mm there)")
    err = block.get("rise_error")
    if err:
        lines.append(f"T - T0 at t = {err['t']:.6g} s against the axisymmetric continuum solution: "
                     f"{100 * err['rel_l2']:.3g} % rel. L2 error, mean rise {err['mean_ratio']:.3g} x the "
                     f"continuum's, max error {err['max_abs_K']:.3g} K")
    checked = [e for e in block.get("rise_errors") or [] if e["t"] in CHECKED_TIMES]
    if checked:
        lines.append("rel. L2 error of T - T0 at " + ", ".join(
            f"{e['t']:g} s: {100 * e['rel_l2']:.3g} %" for e in checked))
    return lines


CHECKED_TIMES = (0.1, 0.3, 0.7)
"""Saved times whose rise error the command line prints beside the last one's."""


def probe_oscillation_lines(block: dict | None) -> list[str]:
    """The ``probe_oscillation`` block of ``summary.json`` as lines for the command line."""
    if not block:
        return []
    return [f"registration points, {w[0]:g}-{w[1]:g} s: oscillation about a smooth trend at most "
            f"{100 * s:.2g} % of the mean speed, {100 * r:.2g} % of the mean rise"
            for w, s, r in zip(block["windows"], block["max_speed"], block["max_T"])]


def probe_positions(result) -> dict:
    """Where each registration point of ``result`` was (``summary.json``'s ``probe_positions``).

    ``{name: {"scene": [x, y] or None, "x", "y", "r", "offset_m", "moves"}}``: the scene's
    position (None for a result without a scene), the recorded one at t = 0 and its radius,
    their distance (0 for the fixed probes of a fixed-point scene, which sit at the scene's
    position; in a Lagrangian scene the distance to the plate point nearest it, which the
    probe follows) and whether the recorded position moved during the run.
    """
    from jaxanm.fsw.scene import Scene

    scene = getattr(result, "scene", None)
    given = {p.name: (p.x, p.y) for p in scene.probes} if isinstance(scene, Scene) else {}
    out = {}
    for name in probe_names(result):
        x = np.asarray(result.probes[name]["x"], dtype=np.float64)
        y = np.asarray(result.probes[name]["y"], dtype=np.float64)
        if not x.size:  # no step recorded
            continue
        at = given.get(name)
        out[name] = {"scene": None if at is None else [float(at[0]), float(at[1])],
                     "x": float(x[0]), "y": float(y[0]), "r": float(np.hypot(x[0], y[0])),
                     "offset_m": None if at is None else float(np.hypot(x[0] - at[0], y[0] - at[1])),
                     "moves": bool(np.any(x != x[0]) or np.any(y != y[0]))}
    return out


def write_summary(result, out_dir: str | os.PathLike, solver_settings=None) -> Path:
    """Write ``summary.json``: scene, solver settings, ``t_end``, ``n_points``, stats (counters and
    the wall-time split; the per-step lists are :func:`write_steps`'s), final probes.

    ``solver_settings`` is any dict/dataclass describing the solver; ``None`` takes
    ``result.solver``.  ``probes_final`` holds x, y, u, v, T of every registration point at
    the last accepted step; ``probe_positions`` where each was (:func:`probe_positions`: at
    the scene's position, or the plate point a Lagrangian run followed from near it);
    ``rezone_times`` the times the Lagrangian cloud was re-seeded;
    ``spatial_accuracy`` the resolution of the tool-edge shear band and the error of the
    temperature rise (:func:`spatial_accuracy`; null for a result without a scene);
    ``probe_oscillation`` how far the registration points' histories stray from a smooth
    trend (:func:`probe_oscillation`); ``time_error`` the step controller's estimate of the
    time error (:func:`time_error`; null with fixed steps); ``process`` the process
    quantities of a travelling tool (:func:`jaxanm.fsw.process.process_summary`: peak
    temperature, torque, power, temperature asymmetries, mass-flux error; null otherwise).
    """
    path = Path(out_dir) / "summary.json"
    final = {}
    for name in probe_names(result):
        final[name] = {k: float(np.asarray(v, dtype=np.float64)[-1])
                       for k, v in result.probes[name].items()}
    t = np.asarray(result.t, dtype=np.float64)
    summary = {
        "scene": to_jsonable(result.scene),
        "solver": to_jsonable(result.solver if solver_settings is None else solver_settings),
        "t_end": end_time(result),
        "n_points": int(np.asarray(result.material).shape[0]),
        "n_saved": int(t.shape[0]),
        "t_saved": t.tolist(),
        "stats": _headline(result.stats),
        "probes_final": final,
        "probe_positions": probe_positions(result),
        "rezone_times": [float(t) for t in getattr(result, "rezone_times", [])],
        "spatial_accuracy": spatial_accuracy(result),
        "probe_oscillation": probe_oscillation(result),
        "time_error": time_error(result),
        "process": process_summary(result),
    }
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return path


STEP_LISTS = ("amax", "orders", "residual_norm", "step_sizes")
"""The statistics kept per time step: ``steps.json``, not ``summary.json``."""


def _headline(stats) -> dict:
    """The run's statistics without their per-step lists (:data:`STEP_LISTS`)."""
    return {k: v for k, v in to_jsonable(stats).items() if k not in STEP_LISTS}


def write_steps(result, out_dir: str | os.PathLike) -> Path:
    """Write ``steps.json``: the statistics kept per time step (:data:`STEP_LISTS`: the ANM's a_max
    and series order of each accepted step, the residual norm, the step sizes under a controller),
    thousands long for a run, so that ``summary.json`` stays a page."""
    path = Path(out_dir) / "steps.json"
    stats = to_jsonable(result.stats)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps({k: stats.get(k, []) for k in STEP_LISTS}) + "\n", encoding="utf-8")
    return path


def write_fields(result, out_dir: str | os.PathLike) -> Path:
    """Write ``fields.npz`` with ``t`` (S,), ``points`` (S, N, 2), ``u``, ``v``, ``T`` (S, N), ``material`` (N,).

    ``points`` are the material points (their colours are ``material``); a rezoned Lagrangian
    run also stores the computational points as ``nodes`` (S, N, 2).
    """
    path = Path(out_dir) / "fields.npz"
    arrays: dict[str, np.ndarray] = {
        "t": np.asarray(result.t, dtype=np.float64),
        "points": np.asarray(result.points, dtype=np.float64),
        "u": np.asarray(result.u, dtype=np.float64),
        "v": np.asarray(result.v, dtype=np.float64),
        "T": np.asarray(result.T, dtype=np.float64),
        "material": np.asarray(result.material, dtype=np.int32),
    }
    if getattr(result, "nodes", None) is not None:
        arrays["nodes"] = np.asarray(result.nodes, dtype=np.float64)
    # numpy's stub would match the ** dict against savez's keyword allow_pickle (a bool); every
    # key here is an array's name
    save: Callable[..., None] = np.savez_compressed
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:  # a file object: np.savez would append ".npz" to a name
            save(f, **arrays)
    return path


def write_probes(result, out_dir: str | os.PathLike) -> Path:
    """Write ``probes.csv``: column ``t`` then ``<probe>_u``, ``<probe>_v``, ``<probe>_T`` per point.

    One row per accepted time step, values with 17 significant digits (exact round trip).
    """
    path = Path(out_dir) / "probes.csv"
    columns = [np.asarray(result.probes["t"], dtype=np.float64)]
    header = ["t"]
    for name in probe_names(result):
        for key in ("u", "v", "T"):
            columns.append(np.asarray(result.probes[name][key], dtype=np.float64))
            header.append(f"{name}_{key}")
    with atomic_path(path) as tmp:
        np.savetxt(tmp, np.column_stack(columns), fmt="%.17g", delimiter=",",
                   header=",".join(header), comments="")
    return path


def write_vtu(result, out_dir: str | os.PathLike) -> list[Path]:
    """Write one VTU file per saved time into ``vtu/`` and the collection ``fields.pvd``.

    Each VTU holds the point cloud (z = 0) as VTK ``vertex`` cells with point data ``u``,
    ``v``, ``T``, ``speed``, ``velocity`` (3-vector, for glyphs) and ``material``.  The PVD
    file lists the VTU files with their times; open it in ParaView to get the time series.
    VTU files of an earlier run in the same directory that this run does not list are removed.
    """
    try:
        import meshio
    except ImportError as exc:  # the vtu extra is optional: the other result files do not need it
        log.warning("VTU files skipped: %s", missing_extra_message("vtu", "VTU output", str(exc)))
        return []

    out_dir = Path(out_dir)
    vtu_dir = out_dir / VTU_DIR
    vtu_dir.mkdir(parents=True, exist_ok=True)
    t = np.asarray(result.t, dtype=np.float64)
    points = np.asarray(result.points, dtype=np.float64)
    u = np.asarray(result.u, dtype=np.float64)
    v = np.asarray(result.v, dtype=np.float64)
    T = np.asarray(result.T, dtype=np.float64)
    material = np.asarray(result.material, dtype=np.int32)
    n = material.shape[0]
    cells = [("vertex", np.arange(n, dtype=np.int64).reshape(-1, 1))]
    written = []
    for s in range(t.shape[0]):
        xyz = np.column_stack([points[s], np.zeros(n)])
        mesh = meshio.Mesh(xyz, cells, point_data={
            "u": u[s], "v": v[s], "T": T[s],
            "speed": np.hypot(u[s], v[s]),
            "velocity": np.column_stack([u[s], v[s], np.zeros(n)]),
            "material": material,
        })
        path = vtu_dir / f"fields_{s:05d}.vtu"
        with atomic_path(path) as tmp:
            meshio.write(tmp, mesh, file_format="vtu")
        written.append(path)
    keep = {p.name for p in written}
    for stale in vtu_dir.glob("fields_*.vtu"):
        if stale.name not in keep:
            stale.unlink()
    pvd = out_dir / "fields.pvd"
    lines = ['<?xml version="1.0"?>',
             '<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">',
             "  <Collection>"]
    for ts, path in zip(t, written):
        rel = path.relative_to(out_dir).as_posix()
        lines.append(f'    <DataSet timestep="{float(ts)!r}" group="" part="0" file={quoteattr(rel)}/>')
    lines += ["  </Collection>", "</VTKFile>", ""]
    with atomic_path(pvd) as tmp:
        tmp.write_text("\n".join(lines), encoding="utf-8")
    return [*written, pvd]


def write_outputs(result, out_dir: str | os.PathLike, solver_settings=None) -> list[Path]:
    """Write every output of an FSW run into ``out_dir`` (created if needed); return the paths.

    ``result`` is a :class:`jaxanm.fsw.record.FSWResult` (or any object with its fields);
    ``solver_settings`` describes the solver for ``summary.json`` (``None``: ``result.solver``).
    Figures whose data is absent (no temperature, run too short) are skipped with a logged
    note; see :func:`write_figures`.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = [
        write_summary(result, out_dir, solver_settings),
        write_steps(result, out_dir),
        write_fields(result, out_dir),
        write_probes(result, out_dir),
    ]
    paths += write_vtu(result, out_dir)
    paths += write_figures(result, out_dir)
    log.info("wrote %d files to %s", len(paths), out_dir)
    return paths


def write_run(result, out_dir: str | os.PathLike, scene) -> list[Path]:
    """Write every file of ``jaxanm run --out out_dir`` for ``result``, a run of ``scene``; return the paths.

    ``summary.json`` records the solver as the scene's ``solver.kind`` with the options the run
    used (``result.solver``).  The one writer of a run's directory: ``jaxanm run`` and the tasks
    of ``jaxanm sweep`` both call it.
    """
    return write_outputs(result, out_dir, {"kind": scene.solver.kind, "options": result.solver})


def figure_builders(result) -> list[tuple[str, Callable[[], Figure]]]:
    """Every figure a run writes, as ``(file name, builder)`` pairs: the paper's
    (:func:`jaxanm.fsw.io.figures.paper_figures`), then a travelling tool's
    (:func:`jaxanm.fsw.io.weld_figures.weld_figures`); a builder may raise
    :class:`~jaxanm.fsw.io.figures.FigureSkipped`."""
    return figures.paper_figures(result) + weld_figures(result)


def write_figures(result, out_dir: str | os.PathLike) -> list[Path]:
    """Write the figures of :func:`figure_builders` (PNG, 150 dpi) into ``out_dir``; return the paths written.

    A figure whose data is absent is skipped with a logged note, and a file of that name
    left by an earlier run in the same directory is removed (it would describe another run).
    """
    out_dir = Path(out_dir)
    written = []
    for name, build in figure_builders(result):
        path = out_dir / name
        try:
            fig = build()
        except figures.FigureSkipped as skipped:
            log.info("%s skipped: %s", name.split("_")[0], skipped)
            path.unlink(missing_ok=True)
            continue
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=150)
        written.append(path)
    return written
