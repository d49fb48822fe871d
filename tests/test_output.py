"""Output files and figures of an FSW run, on a synthetic result with known fields.

The fake result is a Lagrangian point cloud on a disc turning with a known angular-velocity
profile (rigid inside the tool, decaying to zero at the outer edge) and a radial temperature
bump growing in time, so that every file's content can be checked against closed forms.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import xml.etree.ElementTree as ET
from pathlib import Path

import meshio
import numpy as np
import pytest

from jaxanm.fsw.io import figures, output
from jaxanm.fsw.record import FSWResult
from jaxanm.stats import Stats

R1, R2, OMEGA, DR = 1.5e-3, 6e-3, 20.0, 7.5e-4
SAVED = (0.0, 0.001, 0.01, 0.05, 0.08, 0.3, 0.5, 0.7)
PROBES = {"p1": (2.0e-3, 0.0), "p2": (3.0e-3, 0.0), "p3": (4.5e-3, 0.0)}


@dataclasses.dataclass
class FakeScene:
    """Stand-in for jaxanm.fsw.scene.Scene: a dataclass with a few fields."""

    name: str = "fake_disc"
    R1: float = R1
    R2: float = R2
    omega: float = OMEGA
    probes: dict = dataclasses.field(default_factory=lambda: {k: list(v) for k, v in PROBES.items()})


@dataclasses.dataclass(frozen=True)
class FakeSolver:
    """Stand-in for a solver options dataclass."""

    order: int = 7
    tol: float = 1e-6


def angular_velocity(r):
    """Rigid rotation inside the tool, Couette-like decay to 0 at R2 outside."""
    r = np.asarray(r, dtype=np.float64)
    outside = OMEGA * (R1 / np.maximum(r, R1)) ** 2 * (R2**2 - r**2) / (R2**2 - R1**2)
    return np.where(r <= R1, OMEGA, outside)


def temperature(r, t):
    """Radial bump 300 + 60 (t / 0.7) exp(-(r/R1)^2) K."""
    return 300.0 + 60.0 * (t / 0.7) * np.exp(-((r / R1) ** 2))


def fields_at(xy0, t):
    """Positions (rotated by Omega(r) t), u, v, T of material points starting at ``xy0``."""
    r = np.hypot(xy0[..., 0], xy0[..., 1])
    ang = angular_velocity(r) * t
    c, s = np.cos(ang), np.sin(ang)
    x = c * xy0[..., 0] - s * xy0[..., 1]
    y = s * xy0[..., 0] + c * xy0[..., 1]
    w = angular_velocity(r)
    return np.stack([x, y], axis=-1), -w * y, w * x, temperature(r, t)


def fake_result(saved=SAVED, isothermal=False, n_steps=71) -> FSWResult:
    """A synthetic FSWResult: ~200 points on the disc, saved at ``saved`` times."""
    g = np.arange(-R2, R2 + DR / 2, DR)
    xx, yy = np.meshgrid(g, g)
    xy0 = np.column_stack([xx.ravel(), yy.ravel()])
    r0 = np.hypot(xy0[:, 0], xy0[:, 1])
    xy0 = xy0[(r0 < R1 - DR / 2) | ((r0 > R1 + DR / 2) & (r0 < R2 - DR / 2))]
    # coincident tool-edge / plate-edge pairs on r = R1 and a ring on r = R2, as in the model
    a1 = np.linspace(0, 2 * np.pi, 14, endpoint=False) + np.pi / 14
    a2 = np.linspace(0, 2 * np.pi, 50, endpoint=False) + np.pi / 50
    ring1 = R1 * np.column_stack([np.cos(a1), np.sin(a1)])
    xy0 = np.vstack([xy0, ring1, ring1, R2 * np.column_stack([np.cos(a2), np.sin(a2)])])
    r0 = np.hypot(xy0[:, 0], xy0[:, 1])
    is_tool = r0 < R1 - DR / 2
    is_tool[len(xy0) - 50 - 28:len(xy0) - 50 - 14] = True  # tool side of the edge pairs
    material = np.where(is_tool, 0, np.where(xy0[:, 1] > 0, 1, 2)).astype(np.int32)
    t = np.asarray(saved, dtype=np.float64)
    pts, u, v, T = zip(*(fields_at(xy0, ts) for ts in t))
    T = np.full((len(t), len(xy0)), 300.0) if isothermal else np.array(T)
    tp = np.linspace(0.0, t[-1], n_steps)
    probes = {"t": tp}
    for name, xy in PROBES.items():
        p, pu, pv, pT = fields_at(np.array(xy)[None, :], tp[:, None])
        probes[name] = {"x": p[:, 0, 0], "y": p[:, 0, 1], "u": pu[:, 0], "v": pv[:, 0],
                        "T": np.full(n_steps, 300.0) if isothermal else pT[:, 0]}
    stats = Stats(factorizations=3, time_steps=n_steps - 1, series_orders=7 * 5,
                  amax=list(np.linspace(1.5, 0.9, n_steps - 1)),
                  residual_norm=[1e-9] * (n_steps - 1))
    stats.close(1.25)
    return FSWResult(FakeScene(), t, np.array(pts), np.array(u), np.array(v), T, material,
                      probes, recorded_sections(t, isothermal), stats, FakeSolver())


def recorded_sections(t, isothermal=False, samples=161):
    """Sections A-A (y = 0) and B-B (x = 0) as a run records them (``FSWResult.sections``), here
    the exact fields at the samples: u = -Omega(r) y, v = Omega(r) x, T(r, t)."""
    line = np.linspace(-R2, R2, samples)
    out = {"t": np.asarray(t, dtype=np.float64)}
    for name, (x, y) in {"A-A": (line, 0 * line), "B-B": (0 * line, line)}.items():
        w = angular_velocity(np.hypot(x, y))
        T = [np.full(samples, 300.0) if isothermal else temperature(np.hypot(x, y), ts) for ts in t]
        out[name] = {"x": x, "y": y, "s": line + R2, "u": np.tile(-w * y, (len(t), 1)),
                     "v": np.tile(w * x, (len(t), 1)), "T": np.array(T)}
    return out


ALL_FIGURES = [name for name, _ in output.figure_builders(fake_result())]


def leftovers(directory: Path) -> list[Path]:
    """Temporary files left by an atomic write (hidden ``.name.*.tmp``)."""
    return [p for p in directory.rglob("*") if p.name.startswith(".") or p.suffix == ".tmp"]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """One full write of the synthetic result: (result, directory, returned paths)."""
    res = fake_result()
    out = tmp_path_factory.mktemp("out")
    paths = output.write_outputs(res, out, {"kind": "anm", "order": 7, "tol": 1e-6})
    return res, out, paths


def test_every_file_written_and_no_temporaries(written):
    res, out, paths = written
    expected = {"summary.json", "steps.json", "fields.npz", "probes.csv", "fields.pvd", *ALL_FIGURES}
    assert expected <= {p.name for p in out.iterdir()}
    assert len(list((out / "vtu").glob("fields_*.vtu"))) == len(res.t)
    assert all(p.exists() for p in paths)
    assert len(paths) == len(set(paths)) == len(expected) + len(res.t)
    assert leftovers(out) == []


def test_fields_npz_round_trip(written):
    res, out, _ = written
    with np.load(out / "fields.npz") as f:
        assert set(f.files) == {"t", "points", "u", "v", "T", "material"}
        S, N = len(res.t), len(res.material)
        assert f["points"].shape == (S, N, 2)
        for key in ("u", "v", "T"):
            assert f[key].shape == (S, N) and f[key].dtype == np.float64
            np.testing.assert_array_equal(f[key], getattr(res, key))
        np.testing.assert_array_equal(f["t"], res.t)
        np.testing.assert_array_equal(f["points"], res.points)
        np.testing.assert_array_equal(f["material"], res.material)


def test_probes_csv_columns_and_exact_values(written):
    res, out, _ = written
    header = (out / "probes.csv").read_text().splitlines()[0].split(",")
    assert header == ["t"] + [f"{p}_{k}" for p in PROBES for k in ("u", "v", "T")]
    data = np.loadtxt(out / "probes.csv", delimiter=",", skiprows=1)
    assert data.shape == (len(res.probes["t"]), 1 + 3 * len(PROBES))
    np.testing.assert_array_equal(data[:, 0], res.probes["t"])
    np.testing.assert_array_equal(data[:, header.index("p2_v")], res.probes["p2"]["v"])
    np.testing.assert_array_equal(data[:, header.index("p3_T")], res.probes["p3"]["T"])


def test_summary_json(written):
    res, out, _ = written
    s = json.loads((out / "summary.json").read_text())
    assert {"scene", "solver", "t_end", "n_points", "stats", "probes_final"} <= set(s)
    assert s["scene"]["name"] == "fake_disc" and s["scene"]["R2"] == R2
    assert s["solver"] == {"kind": "anm", "order": 7, "tol": 1e-6}
    assert s["t_end"] == 0.7 and s["n_points"] == len(res.material)
    assert s["t_saved"] == list(SAVED)
    assert s["stats"]["factorizations"] == 3 and s["stats"]["wall_time_s"] == 1.25
    assert set(s["stats"]["wall_time"]) == {"jacobian", "factorize", "series", "solve", "other"}
    assert "amax" not in s["stats"]  # the per-step lists are in steps.json
    steps = json.loads((out / "steps.json").read_text())
    assert len(steps["amax"]) == res.stats.time_steps
    assert set(steps) == {"amax", "orders", "residual_norm", "step_sizes"}
    assert s["probes_final"]["p1"]["v"] == float(res.probes["p1"]["v"][-1])
    assert set(s["probes_final"]["p1"]) == {"x", "y", "u", "v", "T"}


def test_summary_solver_defaults_to_result_solver(tmp_path):
    output.write_summary(fake_result(), tmp_path)
    s = json.loads((tmp_path / "summary.json").read_text())
    assert s["solver"] == {"order": 7, "tol": 1e-6}


def test_vtu_readable_with_point_data_and_pvd_lists_times(written):
    res, out, _ = written
    tree = ET.parse(out / "fields.pvd")
    datasets = tree.getroot().find("Collection").findall("DataSet")
    assert [float(d.get("timestep")) for d in datasets] == list(SAVED)
    s = 6
    mesh = meshio.read(out / datasets[s].get("file"))
    N = len(res.material)
    np.testing.assert_array_equal(mesh.points[:, :2], res.points[s])
    np.testing.assert_array_equal(mesh.points[:, 2], 0.0)
    assert mesh.cells[0].type == "vertex" and mesh.cells[0].data.shape == (N, 1)
    pd = mesh.point_data
    assert {"u", "v", "T", "speed", "material", "velocity"} <= set(pd)
    np.testing.assert_array_equal(pd["u"], res.u[s])
    np.testing.assert_array_equal(pd["T"], res.T[s])
    np.testing.assert_allclose(pd["speed"], np.hypot(res.u[s], res.v[s]), rtol=1e-15)
    np.testing.assert_array_equal(pd["material"], res.material)
    np.testing.assert_array_equal(pd["velocity"][:, 1], res.v[s])


def test_pngs_are_images(written):
    import matplotlib.image

    _, out, _ = written
    for name in ALL_FIGURES:
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n"
        img = matplotlib.image.imread(out / name)
        assert img.shape[0] > 300 and img.shape[1] > 300
        assert np.ptp(img[..., :3]) > 0.5  # not a blank canvas


def test_isothermal_skips_temperature_figures(caplog):
    res = fake_result(isothermal=True)
    assert not figures.has_temperature(res) and figures.has_temperature(fake_result())
    built, skipped = [], {}
    with caplog.at_level(logging.INFO, logger="jaxanm.fsw"):
        for name, build in output.figure_builders(res):
            try:
                fig = build()
            except figures.FigureSkipped as e:
                skipped[name] = str(e)
            else:
                built.append((name, len(fig.axes)))
    assert set(skipped) == {"fig03_temperature_history.png", "fig10_temperature_maps.png",
                            "fig11_temperature_maps.png"}
    assert all(v == "no temperature field (isothermal scene)" for v in skipped.values())
    assert dict(built)["fig09_mixing_t0.7.png"] == 1  # mixing state only, no T panel
    assert dict(built)["fig02_velocity_history.png"] == 2
    assert "fig06: no temperature field (isothermal scene); T panel omitted" in caplog.text


def test_short_run_skips_late_figures_and_removes_stale_files(tmp_path, caplog):
    (tmp_path / "vtu").mkdir()
    stale = [tmp_path / "fig09_mixing_t0.7.png", tmp_path / "vtu" / "fields_00099.vtu"]
    for p in stale:
        p.write_bytes(b"from an earlier, longer run")
    short = fake_result(saved=(0.0, 0.001, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06))
    with caplog.at_level(logging.INFO, logger="jaxanm.fsw"):
        paths = output.write_outputs(short, tmp_path)
    names = {p.name for p in paths}
    assert {"fig06_mixing_t0.01.png", "fig10_temperature_maps.png"} <= names
    for late in ("fig07_mixing_t0.3.png", "fig08_mixing_t0.5.png", "fig09_mixing_t0.7.png",
                 "fig11_temperature_maps.png"):
        assert late not in names and not (tmp_path / late).exists()
    assert "fig11 skipped: the run ended at t = 0.06 s, before t = 0.08 s" in caplog.text
    assert not any(p.exists() for p in stale)
    assert len(list((tmp_path / "vtu").glob("*.vtu"))) == len(short.t)


def test_atomic_path_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "a.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with output.atomic_path(target) as tmp:
            tmp.write_text("half-writ")
            raise RuntimeError("disk full")
    assert target.read_text() == "old"
    assert leftovers(tmp_path) == []
    with output.atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp != target
        tmp.write_text("new")
    assert target.read_text() == "new" and leftovers(tmp_path) == []


def test_failed_vtu_write_leaves_no_temporaries(tmp_path, monkeypatch):
    def broken(path, mesh, file_format):
        Path(path).write_text("partial")
        raise OSError("disk full")

    monkeypatch.setattr(meshio, "write", broken)
    with pytest.raises(OSError, match="disk full"):
        output.write_vtu(fake_result(), tmp_path)
    assert leftovers(tmp_path) == [] and list((tmp_path / "vtu").iterdir()) == []


def test_sections_are_drawn_as_the_run_recorded_them():
    """The figures take the sections the recorder sampled (one sampling per run): the abscissa
    is x along A-A (y = 0) and y along B-B (x = 0), the values those of the saved index asked."""
    res = fake_result()
    for s in (0, len(res.t) - 1):
        x, vals = figures.section(res, s, "A-A")
        recorded = res.sections["A-A"]
        np.testing.assert_array_equal(x, recorded["x"])
        for key in ("u", "v", "T"):
            np.testing.assert_array_equal(vals[key], recorded[key][s])
        y, vals = figures.section(res, s, "B-B")
        np.testing.assert_array_equal(y, res.sections["B-B"]["y"])
        np.testing.assert_array_equal(vals["u"], res.sections["B-B"]["u"][s])


def test_a_section_the_scene_does_not_record_skips_its_figure():
    res = fake_result()
    with pytest.raises(figures.FigureSkipped, match="no section 'C-C'"):
        figures.section(res, 0, "C-C")
    res.sections = None
    with pytest.raises(figures.FigureSkipped, match="no section 'A-A'"):
        figures.section(res, 0, "A-A")


def test_saved_index_nearest_and_beyond_end():
    res = fake_result()
    assert figures.saved_index(res, 0.29) == SAVED.index(0.3)
    assert figures.saved_index(res, 0.7) == len(SAVED) - 1
    assert figures.saved_index(res, 0.71) == len(SAVED) - 1  # within half a save interval
    with pytest.raises(figures.FigureSkipped, match="ended at t = 0.7 s"):
        figures.saved_index(res, 0.9)


def test_registration_point_count_checked():
    res = fake_result()
    res.probes = {"t": res.probes["t"], "p1": res.probes["p1"]}
    with pytest.raises(figures.FigureSkipped, match="needs 2 registration points"):
        figures.fig02_velocity_history(res)


def test_to_jsonable():
    obj = {"a": np.arange(3.0), "b": (np.float64(1.5), np.int32(2)), "c": Path("x/y"),
           "d": FakeSolver(), "e": float("nan"), "f": object}
    out = output.to_jsonable(obj)
    assert out["a"] == [0.0, 1.0, 2.0] and out["b"] == [1.5, 2] and out["c"] == os.fspath("x/y")
    assert out["d"] == {"order": 7, "tol": 1e-6} and np.isnan(out["e"])
    assert out["f"] == repr(object)
    json.dumps(out)
