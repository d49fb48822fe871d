"""jaxanm.fsw.compare and benchmarks/compare_runs.py on hand-made run directories: known perturbations
are reported exactly."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
import compare_runs  # noqa: E402

from jaxanm.fsw.compare import cost_row, differences, load_run  # noqa: E402

T0, OMEGA, R1 = 300.0, 10.0, 1e-3


def write_run(path: Path, *, T_shift=0.0, v_shift=0.0, kind="anm", factorizations=5, wall=10.0):
    """A run directory with 3 saved times, 4 points, 2 probes; perturbations at point 2 / probe 1."""
    path.mkdir()
    t = np.array([0.0, 0.1, 0.2])
    rng = np.random.default_rng(0)
    points = np.repeat(rng.random((1, 4, 2)), 3, axis=0)
    u = np.outer(t, [1.0, 2.0, 3.0, 4.0]) * 1e-3
    v = np.zeros((3, 4))
    T = T0 + np.outer(t, [10.0, 20.0, 40.0, 5.0])
    T[1:, 2] += T_shift
    v[1:, 2] += v_shift
    np.savez(path / "fields.npz", t=t, points=points, u=u, v=v, T=T, material=np.zeros(4))
    rows = ["t,1_u,1_v,1_T,2_u,2_v,2_T"] + [f"{s},0,{v_shift if s else 0},{T0 + s + (T_shift if s else 0)},0,0,{T0}"
                                            for s in (0.0, 0.1, 0.2)]
    (path / "probes.csv").write_text("\n".join(rows) + "\n")
    stats = {"time_steps": 2, "factorizations": factorizations, "newton_iterations": 0, "series_orders": 7,
             "wall_time_s": wall, "wall_time": {"series": wall / 2, "other": wall / 2}}
    summary = {"scene": {"thermal": {"T0": T0}, "tool": {"omega": OMEGA}, "geometry": {"R1": R1}},
               "solver": {"kind": kind, "options": {"order": 7, "tol": 1e-6}}, "t_end": 0.2, "stats": stats}
    (path / "summary.json").write_text(json.dumps(summary))
    return path


def test_identical_runs_differ_by_nothing(tmp_path):
    a = load_run(write_run(tmp_path / "a"))
    b = load_run(write_run(tmp_path / "b"))
    d = differences(b, a)
    assert d["max_rel_dV"] == d["max_rel_dT"] == d["max_dpoints_m"] == 0.0
    assert d["probe_max_dT_K"] == d["probe_max_dV_over_omegaR1"] == 0.0


def test_known_perturbations_are_reported_relative_to_their_yardsticks(tmp_path):
    ref = load_run(write_run(tmp_path / "ref"))
    run = load_run(write_run(tmp_path / "run", T_shift=0.04, v_shift=2e-6, kind="newton",
                                          factorizations=60, wall=30.0))
    d = differences(run, ref)
    # each saved time is measured against its own max |T - T0| (point 2: 40 t K) and max |V|
    # (point 4: 4e-3 t m/s), so the earliest time, with the smallest yardstick, gives the maximum;
    # the velocity difference is the vector's (v shifted by 2e-6 at point 2), not the speed's.
    # rel=1e-9: a few roundings of numbers of order 1 (the exact values are these quotients)
    assert d["max_rel_dT"] == pytest.approx(0.04 / (40.0 * 0.1), rel=1e-9)
    assert d["max_rel_dV"] == pytest.approx(2e-6 / (4e-3 * 0.1), rel=1e-9)
    assert d["probe_max_dT_K"] == pytest.approx(0.04, rel=1e-9)
    # the probes' T relative to the reference's largest |T - T0| at the registration points (0.2 K)
    assert d["probe_rel_dT"] == pytest.approx(0.04 / 0.2, rel=1e-9)
    assert d["n_field_times"] == d["n_probe_times"] == 2
    assert d["probe_max_dV_over_omegaR1"] == pytest.approx(2e-6 / (OMEGA * R1), rel=1e-12)
    costs = [cost_row(r) for r in (ref, run)]
    table = compare_runs.markdown(costs, [d])
    assert "| 60 |" in table and "| 3.00 |" in table  # factorisations and the wall ratio to the first run


@pytest.mark.filterwarnings("error")  # no 0/0 warning: an absent field is NaN by definition
def test_a_field_the_reference_lacks_is_nan_not_a_warning(tmp_path):
    """Pure conduction (no velocity) and a first saved time with T = T0 at every point."""
    ref = load_run(write_run(tmp_path / "ref"))
    run = load_run(write_run(tmp_path / "run", T_shift=0.04))
    for r in (ref, run):
        r["fields"]["u"][:] = r["fields"]["v"][:] = 0.0
    ref["fields"]["T"][1] = T0  # the reference's yardstick at t = 0.1 is 0: only t = 0.2 counts
    d = differences(run, ref)
    assert np.isnan(d["max_rel_dV"]) and np.isnan(d["per_saved_time"]["rel_dV"]).all()
    assert d["max_rel_dT"] == pytest.approx(0.04 / (40.0 * 0.2), rel=1e-9)
    assert np.isnan(d["per_saved_time"]["rel_dT"][0])
    run["fields"]["T"][2, 0] = np.nan  # a non-finite field of the run itself is not hidden
    assert np.isnan(differences(run, ref)["max_rel_dT"])


def test_runs_saved_at_no_common_time_are_refused(tmp_path):
    ref = load_run(write_run(tmp_path / "ref"))
    run = load_run(write_run(tmp_path / "run"))
    run["fields"]["t"] = run["fields"]["t"] * 3  # 0, 0.3, 0.6 against 0, 0.1, 0.2: only t = 0
    with pytest.raises(ValueError, match=r"recorded fields at no common time t > 0 \(0.3, 0.6 against 0.1, 0.2\)"):
        differences(run, ref)


def test_a_directory_without_run_outputs_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="not the output directory.*summary.json"):
        load_run(tmp_path)
