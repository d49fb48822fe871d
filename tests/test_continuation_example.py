"""``examples/bifurcations.py`` runs as a user runs it (small settings), its numbers pinned to the
closed forms it quotes."""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np
import pytest

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "bifurcations.py"


def load():
    spec = importlib.util.spec_from_file_location("bifurcations", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow  # 10-15 s of compiling; notebook 08 runs the same problems in the default suite
def test_bifurcations_example(tmp_path, capsys):
    """Two modes of Chafee-Infante on N = 11 and the elastica of 10 links: the branch points at
    their closed forms (1e-10 relative: located to round-off), k - 1 zeros on mode k, the
    chain's first critical load, its tip rotation reached, the two figures written."""
    example = load()
    trivial, branches = example.chafee_infante(n=11, modes=2, peak=0.5)
    straight, bent = example.elastica(n=10, tip=1.0)
    example.print_table(trivial, branches, straight, bent)
    paths = example.figures(trivial, branches, straight, bent, tmp_path)
    out = capsys.readouterr().out
    assert "branch point lam" in out and "first critical load" in out
    h = 1.0 / 12
    for k, (event, up, down) in enumerate(branches, start=1):
        assert abs(event.lam - 4 / h**2 * np.sin(k * np.pi * h / 2) ** 2) < 1e-10 * event.lam
        assert up.stopped == down.stopped == "stop_at"
        assert np.count_nonzero(np.diff(np.sign(up.u[-1])) != 0) == k - 1
    (event,) = straight.events_of("branch_point")
    assert abs(event.lam - 400 * np.sin(np.pi / 42) ** 2) < 1e-10 * event.lam
    assert bent.stopped == "stop_at" and bent.u[-1, -1] == 1.0
    assert all(path.stat().st_size > 10_000 for path in paths)
