"""Every notebook in ``notebooks/`` runs top to bottom without error, and is committed without outputs.

The notebooks are executed with nbclient in a fresh ipykernel started from *this* interpreter
(``sys.executable``), whatever kernelspecs are installed on the machine: a ``python3`` kernelspec
in the user's Jupyter directory may point at another Python without jaxanm.  Notebooks added
later are picked up automatically.  Outputs are discarded (nothing is written back).
"""

from __future__ import annotations

import pathlib
import sys

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")
from jupyter_client import AsyncKernelManager  # noqa: E402  (installed with nbclient)
from jupyter_client.kernelspec import KernelSpec, KernelSpecManager  # noqa: E402

NOTEBOOKS_DIR = pathlib.Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOKS_DIR.glob("*.ipynb"))
CELL_TIMEOUT_S = 300  # per cell; the notebooks are meant to run in well under a minute in total


class _ThisInterpreter(KernelSpecManager):
    """Resolve every kernel name to an ipykernel running on ``sys.executable``."""

    def get_kernel_spec(self, kernel_name):
        return KernelSpec(
            argv=[sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
            display_name=f"Python {sys.version_info.major}.{sys.version_info.minor} (tests)",
            language="python",
        )


def test_notebooks_exist():
    assert NOTEBOOKS, f"no notebooks found in {NOTEBOOKS_DIR}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_has_no_outputs(path):
    """Policy: notebooks are committed with outputs stripped (see notebooks/README.md)."""
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    dirty = [
        i for i, cell in enumerate(nb.cells)
        if cell.cell_type == "code" and (cell.get("outputs") or cell.get("execution_count") is not None)
    ]
    assert not dirty, f"{path.name}: code cells {dirty} carry outputs or execution counts; clear them before committing"


SLOW_NOTEBOOKS = {"02_jet_vs_handcoded", "03_fsw_scene", "04_effects", "05_accuracy_cost", "06_calibration",
                  "07_continuation"}
"""Notebooks whose execution is a ``slow`` check (15 s to well over a minute each): what each
shows is tested in the default suite on its own (test_jet_vs_hand, test_fsw_examples,
test_core's and test_step_control's ANM against Newton, test_calibration, test_continuation).
The quickstart runs by default."""


@pytest.mark.parametrize("path", [pytest.param(p, id=p.stem,
                                               marks=[pytest.mark.slow] if p.stem in SLOW_NOTEBOOKS else [])
                                  for p in NOTEBOOKS])
def test_notebook_executes(path):
    """Run all cells in a fresh kernel (working directory: notebooks/); any error fails the test."""
    nb = nbformat.read(path, as_version=4)
    km = AsyncKernelManager(kernel_name="python3", kernel_spec_manager=_ThisInterpreter())
    client = nbclient.NotebookClient(
        nb,
        km=km,
        timeout=CELL_TIMEOUT_S,
        allow_errors=False,
        resources={"metadata": {"path": str(NOTEBOOKS_DIR)}},
    )
    try:
        client.execute()
    except nbclient.exceptions.CellExecutionError as err:  # the message holds the traceback
        pytest.fail(f"{path.name} failed:\n{err}", pytrace=False)
