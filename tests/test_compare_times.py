"""Errors at common times (jaxanm.fsw.compare) and the Richardson reference (jaxanm.sweep.richardson)
on hand-made histories whose answer is known in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from jaxanm.fsw.compare import common_times, differences, load_run, write_run
from jaxanm.sweep.richardson import extrapolate, reference, write_reference

T0, OMEGA, R1 = 300.0, 10.0, 1e-3
N = 5  # points


def make_run(name: str, t_probes, t_fields, T_of, v_of=lambda t: 0.0 * t) -> dict:
    """A run dict (load_run's layout): one probe "1" at point 0, fields at N points.

    ``T_of(t)`` is T at the probe and at every point; point k has T0 + (k + 1) / N (T_of(t) - T0);
    ``v_of(t)`` is v at the probe and every point, u = OMEGA R1 t at every point.
    """
    t_probes, t_fields = np.asarray(t_probes, dtype=float), np.asarray(t_fields, dtype=float)
    weights = (np.arange(N) + 1.0) / N
    T = T0 + np.outer(T_of(t_fields) - T0, weights[::-1])  # point 0 carries the full T_of
    u = np.outer(OMEGA * R1 * t_fields, np.ones(N))
    v = np.outer(v_of(t_fields), np.ones(N))
    probes = np.zeros(t_probes.size, dtype=[("t", float), ("1_u", float), ("1_v", float), ("1_T", float)])
    probes["t"], probes["1_u"] = t_probes, OMEGA * R1 * t_probes
    probes["1_v"], probes["1_T"] = v_of(t_probes), T_of(t_probes)
    summary = {"scene": {"thermal": {"T0": T0}, "tool": {"omega": OMEGA}, "geometry": {"R1": R1}, "time": {"dt": 0.0}},
               "solver": {"kind": "newton", "options": {}}, "t_end": float(t_fields[-1]),
               "stats": {"time_steps": t_probes.size - 1, "factorizations": 1, "newton_iterations": 2,
                         "series_orders": 0, "wall_time_s": 1.0, "wall_time": {"jacobian": 0.5, "other": 0.5}}}
    points = np.repeat(np.linspace(0.0, 1.0, 2 * N).reshape(1, N, 2), t_fields.size, axis=0)
    return {"dir": name, "summary": summary, "probes": probes,
            "fields": {"t": t_fields, "points": points, "u": u, "v": v, "T": T,
                       "material": np.zeros(N, dtype=np.int32)}}


def rise(t):
    """The reference's T at the probe: T0 + 100 t."""
    return T0 + 100.0 * t


def test_common_times_survive_the_rounding_of_ten_thousand_steps():
    steps = np.concatenate([[0.0], np.cumsum(np.full(10_000, 1e-5))])  # t = 0.1 reached by 10^4 additions
    i, j = common_times(steps, [0.0, 0.01, 0.05, 0.1])
    assert j.tolist() == [1, 2, 3] and i.tolist() == [1000, 5000, 10_000]  # t = 0 is never a comparison time
    assert common_times([0.0, 0.015, 0.025], [0.0, 0.01, 0.02])[0].size == 0


def test_runs_at_different_steps_are_compared_only_where_both_recorded():
    """The reference records every 0.05 s (with wild values between the run's times), the run
    every 0.1 s with T off by 0.5 t K and v off by 1e-6 t: only t = 0.1 .. 0.4 count."""
    t_ref = np.arange(9) * 0.05
    wild = np.where(np.isclose(t_ref * 10 % 1, 0.5), 1e6, 0.0)  # at 0.05, 0.15, ...: never compared

    def ref_T(t):
        return rise(t) + np.interp(t, t_ref, wild)

    ref = make_run("ref", t_ref, t_ref, ref_T)
    t_run = np.arange(5) * 0.1
    run = make_run("run", t_run, t_run[[0, 2, 4]], lambda t: rise(t) + 0.5 * t, lambda t: 1e-6 * t)
    d = differences(run, ref)
    assert (d["n_probe_times"], d["n_field_times"]) == (4, 2)
    # rel=1e-12: each value is one or two roundings of the exact quotient
    assert d["probe_max_dT_K"] == pytest.approx(0.5 * 0.4, rel=1e-12)
    assert d["probe_rel_dT"] == pytest.approx(0.5 * 0.4 / (100.0 * 0.4), rel=1e-12)  # by the largest rise there
    assert d["probe_max_dV_over_omegaR1"] == pytest.approx(1e-6 * 0.4 / (OMEGA * R1), rel=1e-12)
    # fields at 0.2 and 0.4: the dT at point 0 over the largest |T - T0| (point 0's), and the
    # velocity's vector difference over max |V_ref| (u = omega R1 t at every point)
    assert d["max_rel_dT"] == pytest.approx(0.5 / 100.0, rel=1e-12)
    assert d["max_rel_dV"] == pytest.approx(1e-6 / (OMEGA * R1), rel=1e-12)
    assert d["per_saved_time"]["t"] == pytest.approx([0.2, 0.4], abs=0)


def test_no_common_time_is_an_error_naming_both_runs_times():
    ref = make_run("ref", [0.0, 0.1, 0.2], [0.0, 0.1, 0.2], rise)
    run = make_run("run", [0.0, 0.15, 0.25], [0.0, 0.2], rise)
    with pytest.raises(ValueError, match=r"run and ref recorded probes at no common time t > 0 \(0.15, 0.25 against "
                                         r"0.1, 0.2\); .*save both runs at common times \(time.save"):
        differences(run, ref)
    run = make_run("run", [0.0, 0.1], [0.0, 0.3], rise)
    with pytest.raises(ValueError, match="recorded fields at no common time"):
        differences(run, ref)


# --------------------------------------------------------------------------- Richardson

C, D, H = 40.0, 3000.0, 0.04  # T(h) = T* + (C h + D h^2) t: first order with a known second-order term


def ie_run(name: str, h: float) -> dict:
    """Implicit Euler at step h, as a model: probes every step, fields at 0.2 and 0.4, error (C h + D h^2) t."""
    t = np.arange(round(0.4 / h) + 1) * h
    return make_run(name, t, [0.0, 0.2, 0.4], lambda s: rise(s) + (C * h + D * h * h) * s)


def test_richardson_cancels_the_first_order_term_and_estimates_the_rest():
    """2 x(h/2) - x(h) leaves -D h^2 / 2 t (h the coarser step): the fine extrapolation (h = H/2)
    is off by -D H^2 / 8 t, the coarse one (h = H) by -D H^2 / 2 t, and their difference / 3 is
    exactly the fine one's error."""
    runs = [ie_run(f"dt/{2 ** k}", H / 2 ** k) for k in range(3)]
    ref, estimate = reference(runs)
    fine_error = -D * H * H / 8
    assert ref["probes"]["t"] == pytest.approx([0.0, 0.2, 0.4], abs=1e-15)  # the save times only
    # abs=1e-9 K: roundings of T ~ 340 K (ulp 6e-14) through two extrapolations
    assert ref["probes"]["1_T"] == pytest.approx(rise(ref["probes"]["t"]) + fine_error * ref["probes"]["t"], abs=1e-9)
    assert ref["fields"]["T"][:, 0] == pytest.approx(rise(ref["fields"]["t"]) + fine_error * ref["fields"]["t"],
                                                     abs=1e-9)
    assert ref["fields"]["points"] == pytest.approx(runs[2]["fields"]["points"], abs=0)  # a fixed cloud stays
    # rel=1e-6: the estimate's difference (0.4 K at most) carries the 1e-9 K roundings above
    assert estimate["probe_max_dT_K"] == pytest.approx(-fine_error * 0.4, rel=1e-6)
    assert estimate["max_rel_dT"] == pytest.approx(-fine_error / (100.0 + fine_error), rel=1e-6)
    assert estimate["max_rel_dV"] == 0.0 and estimate["n_probe_times"] == 2
    assert ref["summary"]["solver"]["kind"] == "richardson" and ref["summary"]["stats"]["time_steps"] == 10 + 20 + 40


def test_richardson_reference_round_trips_through_a_run_directory(tmp_path):
    dirs = []
    for k in range(3):
        dirs.append(write_run(ie_run(f"dt{k}", H / 2 ** k), tmp_path / f"dt{k}"))
    ref, estimate = write_reference(dirs, tmp_path / "reference")
    again = load_run(tmp_path / "reference")
    assert again["probes"].dtype.names == ("t", "1_u", "1_v", "1_T") and again["fields"]["T"].shape == (3, N)
    assert differences(ref, again)["probe_max_dT_K"] == 0.0  # written with 17 digits: exact
    assert estimate["probe_max_dT_K"] > 0


def test_extrapolating_runs_with_no_common_save_time_is_refused():
    a = make_run("a", [0.0, 0.1], [0.0, 0.1], rise)
    b = make_run("b", [0.0, 0.2], [0.0, 0.2], rise)
    with pytest.raises(ValueError, match="saved their fields at no common time"):
        extrapolate(a, b)
