"""examples/calibrate.py on a reduced configuration (experiments of 2 steps instead of 10)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from test_examples import load_example


@pytest.mark.slow  # a minute of FSW runs; the fit itself is checked in the default suite by test_calibration
def test_calibrate_example_fits_noisy_data_within_its_predicted_uncertainty(capsys, tmp_path):
    example = load_example("calibrate")
    # the K-A valley is shallow (Gauss-Newton eigenvalues 2.7e3 against 4e8): 15 simulations
    # stopped short of the minimum on one machine and not on another, so give the fit room
    # and require that it converged before judging its values against their uncertainties
    summary = example.run(overrides={"time.t_end": 8e-3}, seed=1, max_iter=40, verbose=False)
    assert summary["fit"].converged
    example.print_table(summary)
    example.plot(summary, tmp_path / "calibration.png")
    out = capsys.readouterr().out
    assert "fitted" in out and "loss history" in out
    assert (tmp_path / "calibration.png").stat().st_size > 10_000
    record = json.loads(json.dumps({k: v for k, v in summary.items() if k != "fit"}))
    for key in ("true", "start", "fitted"):
        assert set(record[key]) == {"K", "A", "n"}
    assert record["start"]["n"] == 1.2 * record["true"]["n"]
    # the fitted values are consistent with their Gauss-Newton standard deviations
    # (3 sigma; seeded noise, so the check is deterministic)
    std = summary["predicted_std"]
    truth, fitted = summary["true"], summary["fitted"]
    assert abs(math.log(fitted["K"] / truth["K"])) <= 3 * std["K_relative"]
    assert abs(fitted["A"] - truth["A"]) <= 3 * std["A"]
    assert abs(fitted["n"] - truth["n"]) <= 3 * std["n"]
    # at the minimum of 0.5 chi^2 with Gaussian noise, the loss is (N - P) / 2 within a few
    # standard deviations sqrt((N - P) / 2): the model matches the data down to the noise
    n_data = summary["data_points"]
    assert n_data == 3 * 3 * 66  # 3 experiments x 3 times x (3 probes + 19 section points) x (u, v, T)
    dof = n_data - 3
    assert abs(record["loss_history"][-1] - dof / 2) <= 4 * np.sqrt(dof / 2)
    assert record["loss_history"][0] > 1e3 * record["loss_history"][-1]
