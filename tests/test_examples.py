"""The examples run as a user runs them (small settings), each pinning a meaningful number."""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np

EXAMPLES = pathlib.Path(__file__).resolve().parents[1] / "examples"


def load_example(name: str):
    """Import ``examples/<name>.py`` as a module."""
    spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_reaction_diffusion_example(capsys):
    example = load_example("reaction_diffusion")
    results = example.compare(n=40, t_end=0.2, dt=2e-3, tol=1e-8)
    example.print_table(results)
    out = capsys.readouterr().out
    assert "factorizations" in out and "ANM p=7" in out
    ref = results["Newton"].xs[-1]
    for name in ("ANM p=7", "modified Newton"):
        assert np.abs(results[name].xs[-1] - ref).max() < 1e-6 * np.abs(ref).max()
    assert results["Newton"].stats.factorizations >= 10 * results["ANM p=7"].stats.factorizations
    # steady balance check: the source amplitude 20 * sin(pi x) is O(10) and the solution stays O(1).
    # Upper bound, a discrete maximum principle: at the largest u_i the diffusion term is <= 0,
    # so k u_i^3 <= 1.5 s there unless u grew, hence max u <= (1.5 s / k)^(1/3) = 1.82 < 10
    assert 0.1 < ref.max() < 10


def test_jet_vs_handcoded_example(capsys):
    example = load_example("jet_vs_handcoded")
    for at_rest in (False, True):
        result = example.compare(order=10, at_rest=at_rest)
        assert result["jet"].shape == (11, 2, example.N_NODES)
        assert np.all(np.isfinite(result["jet"]))
        # every order of both residual fields agrees with the paper's quadratic recast
        assert np.all(result["err_u"] < 1e-10), result["err_u"]
        assert np.all(result["err_T"] < 1e-10), result["err_T"]
    example.print_table(result)
    out = capsys.readouterr().out
    assert "rel. diff u" in out and len(out.splitlines()) == 13
    # the comparison resolves far below the tolerance: a reference with n changed by 1e-8 is seen.
    # The change is first order in n, (d ln R_k / d ln n) 1e-8 (8e-9: a property of the model),
    # 1e6 times the round-off of the two series (err_u above, 1e-15)
    wrong = example.compare(order=10, n=0.1324 * (1 + 1e-8), at_rest=True)
    assert np.max(example.per_order_errors(result["jet"][:, 0], wrong["hand"]["R_u"])) > 1e-9
