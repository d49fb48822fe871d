"""The documentation site builds in strict mode (every warning an error), offline.

``mkdocs build --strict`` into a temporary directory: a broken link, a page missing from the
navigation's targets, a docstring the API reference cannot parse, or a generated results
page that lost its source all fail here.  The build reads only the repository (no remote
inventories, no plugin that downloads).  The test command of the README installs the ``docs``
extra, so in CI this test runs; without mkdocs it is skipped.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mkdocs", reason="mkdocs is not installed: pip install -e '.[docs]'")
pytest.importorskip("mkdocstrings", reason="mkdocstrings is not installed: pip install -e '.[docs]'")

ROOT = Path(__file__).resolve().parents[1]
PUBLIC = ["integrate", "ANM", "Newton", "ModifiedNewton", "StepController", "SaveAt",
          "taylor_coefficients", "jaxanm.fsw.run", "load_scene", "Scene", "FSWResult",
          "newton_continuation", "Branch", "jaxanm.mls.build_stencils", "NeighbourList"]


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    out = tmp_path_factory.mktemp("site")
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "DISABLE_MKDOCS_2_WARNING": "true",
           "JAXANM_COMPILE_CACHE": "0"}
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(out)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    warnings = [line for line in done.stderr.splitlines() if "WARNING" in line or "ERROR" in line]
    assert done.returncode == 0, ("mkdocs build --strict failed:\n"
                                  + "\n".join(warnings or done.stderr.splitlines()[-30:]))
    return out


def _text(path: Path) -> str:
    return re.sub(r"<[^>]+>", " ", path.read_text(encoding="utf-8"))


def test_api_reference_has_every_public_name(site):
    api = " ".join(_text(p) for p in (site / "api").rglob("index.html"))
    missing = [name for name in PUBLIC if name not in api]
    assert not missing, f"not in the API reference: {missing}"


def test_results_pages_come_from_the_committed_outputs(site):
    """Every .md and figure of benchmarks/results/ is a page or file of the site."""
    results = ROOT / "benchmarks" / "results"
    for path in results.glob("*.md"):
        assert (site / "results" / path.stem / "index.html").is_file(), path.name
    for path in results.glob("*.png"):
        assert (site / "results" / path.name).read_bytes() == path.read_bytes(), path.name


def test_notebooks_are_rendered(site):
    for path in (ROOT / "notebooks").glob("*.ipynb"):
        assert (site / "notebooks" / path.stem / "index.html").is_file(), path.name
