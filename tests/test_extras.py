"""Optional dependencies (the extras ``sweep``, ``ida``, ``metis``, ``vtu``): with one missing,
the feature that needs it says which extra to install, and the rest of jaxanm works.

A missing package is simulated by ``sys.modules[name] = None``, which makes ``import name``
raise ``ImportError`` as an uninstalled package would (``monkeypatch`` restores the entry).
"""

from __future__ import annotations

import logging
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse

from jaxanm import InputError, cli
from jaxanm._extras import EXTRAS, MissingExtraError, require

ROOT = Path(__file__).resolve().parents[1]


def _hide(monkeypatch, *modules):
    """Make ``import m`` fail for each of ``modules`` (and their submodules already imported)."""
    for name in list(sys.modules):
        if any(name == m or name.startswith(m + ".") for m in modules):
            monkeypatch.delitem(sys.modules, name)
    for m in modules:
        monkeypatch.setitem(sys.modules, m, None)


def test_the_extras_of_the_code_are_those_of_pyproject():
    """Every extra the code names exists in pyproject.toml with the same packages; ``all``
    holds them all, and no core dependency is an optional one."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    optional = project["optional-dependencies"]

    def names(specs):
        return {s.split(">")[0].split("=")[0].split("<")[0].split("[")[0].strip().lower() for s in specs}

    for extra, packages in EXTRAS.items():
        assert names(optional[extra]) == set(packages), extra
        assert set(packages) <= names(optional["all"]), extra
        assert not set(packages) & names(project["dependencies"]), extra


def test_require_names_the_extra(monkeypatch):
    _hide(monkeypatch, "meshio")
    with pytest.raises(MissingExtraError) as info:
        require("meshio", "vtu", "VTU output")
    message = str(info.value)
    assert "pip install 'jaxanm[vtu]'" in message and "meshio" in message and "VTU output" in message
    assert isinstance(info.value, ImportError) and isinstance(info.value, InputError)


def test_sweep_without_dask_names_the_extra(monkeypatch, tmp_path):
    from jaxanm.sweep import grid_from_dict, run_sweep

    _hide(monkeypatch, "dask", "distributed")
    grid = grid_from_dict({"scene": "couette_small", "solvers": [{"kind": "newton"}]})
    with pytest.raises(MissingExtraError, match=r"pip install 'jaxanm\[sweep\]'"):
        run_sweep(grid, tmp_path / "sweep", progress=False)
    assert not (tmp_path / "sweep").exists(), "nothing is written before the check"


def test_sweep_command_without_dask_is_one_line_exit_2(monkeypatch, tmp_path, capsys):
    _hide(monkeypatch, "dask", "distributed")
    grid = tmp_path / "g.toml"
    grid.write_text('scene = "couette_small"\n[[solvers]]\nkind = "newton"\n', encoding="utf-8")
    assert cli.main(["sweep", str(grid), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("jaxanm: error: ") and "jaxanm[sweep]" in err[0]


def test_ida_without_scikit_sundae_names_the_extra(monkeypatch):
    from jaxanm.ida import integrate_ida

    _hide(monkeypatch, "sksundae")

    def residual(x, x_old, t, dt, p):
        return (x - x_old) / dt + x

    with pytest.raises(MissingExtraError, match=r"pip install 'jaxanm\[ida\]'"):
        integrate_ida(residual, np.ones(2), t0=0.0, t_out=[1.0])


def test_ida_sweep_task_without_scikit_sundae_fails_before_running(monkeypatch, tmp_path):
    from jaxanm.sweep import grid_from_dict, run_sweep

    _hide(monkeypatch, "sksundae")
    grid = grid_from_dict({"scene": "conduction_small", "solvers": [{"kind": "ida"}]})
    with pytest.raises(MissingExtraError, match=r"jaxanm\[ida\]"):
        run_sweep(grid, tmp_path / "sweep", progress=False)


def test_large_lu_without_pymetis_names_the_extra(monkeypatch):
    from jaxanm import _factorization as linalg

    _hide(monkeypatch, "pymetis")
    n = linalg.SYMMETRIC_MAX_UNKNOWNS + 1
    matrix = scipy.sparse.diags([-1.0, 4.0, -1.0], [-1, 0, 1], shape=(n, n), format="csc")
    with pytest.raises(MissingExtraError, match=r"pip install 'jaxanm\[metis\]'"):
        linalg.sparse_lu(matrix)
    small = matrix[:100, :100]
    assert np.allclose(small @ linalg.sparse_lu(small).solve(np.ones(100)), 1.0), "small matrices need no METIS"


def test_vtu_without_meshio_is_skipped_with_a_warning(monkeypatch, tmp_path, caplog):
    """The other result files are written; the VTU files are not, and a warning names the extra."""
    from types import SimpleNamespace

    from jaxanm.fsw.io.output import write_vtu

    _hide(monkeypatch, "meshio")
    result = SimpleNamespace(t=np.array([0.0]), points=np.zeros((1, 3, 2)), u=np.zeros((1, 3)),
                             v=np.zeros((1, 3)), T=np.zeros((1, 3)), material=np.zeros(3, dtype=int))
    with caplog.at_level(logging.WARNING, logger="jaxanm"):
        assert write_vtu(result, tmp_path) == []
    assert "pip install 'jaxanm[vtu]'" in caplog.text
    assert not (tmp_path / "fields.pvd").exists()


def test_core_imports_without_any_extra():
    """``import jaxanm``, the FSW run API, the CLI and the grid reader need none of the extras
    (checked in a fresh interpreter, where nothing has imported them yet)."""
    import subprocess

    code = ("import sys\n"
            "for m in ('dask', 'distributed', 'sksundae', 'pymetis', 'meshio'): sys.modules[m] = None\n"
            "import jaxanm, jaxanm.fsw.simulate, jaxanm.fsw.io.output, jaxanm.cli, jaxanm.sweep, jaxanm.ida\n"
            "print(jaxanm.__version__)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
