"""The examples of docs/continuation.md run as written, and find what the page says."""

from __future__ import annotations

import pathlib
import re

import numpy as np
import pytest
from model_problems import discrete_fold

PAGE = pathlib.Path(__file__).resolve().parents[1] / "docs" / "continuation.md"


@pytest.mark.slow  # 10-20 s, two residuals compiled at order 15; what they show is tested by the default suite
def test_the_examples_of_the_path_following_page_run_as_written(capsys):
    """The two code blocks of "Two examples to run", in one namespace as a reader pastes them:
    the Bratu branch ends with max_steps past a fold at the discrete fold (1e-8 relative), the
    Chafee-Infante branch points are the closed form's (1e-8) and mode 2 has one sign change."""
    section = PAGE.read_text(encoding="utf-8").split("## Two examples to run")[1].split("\n## ")[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 2
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, str(PAGE), "exec"), namespace)  # noqa: S102 - the page's own code
    out = capsys.readouterr().out
    assert namespace["branch"].stopped == "max_steps" and "max_steps" in out
    assert abs(namespace["fold"].lam - discrete_fold(63)) < 1e-8 * discrete_fold(63)
    h = namespace["h"]
    lams = [e.lam for e in namespace["trivial"].events_of("branch_point")]
    np.testing.assert_allclose(lams, 4 / h**2 * np.sin(np.arange(1, 3) * np.pi * h / 2) ** 2, rtol=1e-8)
    mode2 = namespace["mode2"]
    assert mode2.stopped == "stop_at" and "sign changes: 1" in out
