"""The Python examples of the first pages run as written, and compute what they say.

Each example is read from its page (the fenced ``python`` blocks of one section) and executed
as it stands, so that a page cannot drift from the code: the README's ten lines (the same as
getting started's) and the scenes guide's own scene.
"""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def python_blocks(path: Path, section: str) -> str:
    """The ``python`` code blocks of the section headed ``## section`` of a markdown page."""
    text = path.read_text(encoding="utf-8")
    start = text.index(f"\n## {section}\n")
    end = text.find("\n## ", start + 1)
    body = text[start:end if end > 0 else None]
    blocks = re.findall(r"^```python\n(.*?)^```", body, flags=re.S | re.M)
    assert blocks, f"no python block under '## {section}' in {path.name}"
    return "\n".join(blocks)


def run_page_code(code: str) -> tuple[dict, str]:
    """Execute ``code`` in a fresh namespace; return the namespace and what it printed."""
    namespace: dict = {"__name__": "__docs_example__"}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, "<docs example>", "exec"), namespace)  # noqa: S102 - the page's own code
    return namespace, out.getvalue()


def _implicit_euler(residual_params, n=40, t1=1.0, dt=1e-2):
    """The ten lines' problem solved independently: implicit Euler of u_t = u_xx + s(t) - u^3
    (zero Dirichlet ends), each step by dense Newton in NumPy with the exact Jacobian, to a
    correction of 1e-14 of the state."""
    h = residual_params["h"]
    lap = (np.diag(np.ones(n - 1), -1) - 2 * np.eye(n) + np.diag(np.ones(n - 1), 1)) / h ** 2
    u = np.zeros(n)
    for k in range(1, round(t1 / dt) + 1):
        old, source = u, 5.0 * (1 + np.sin(4 * k * dt))
        for _ in range(50):
            f = (u - old) / dt - lap @ u - source + u ** 3
            du = np.linalg.solve(np.eye(n) / dt - lap + np.diag(3 * u ** 2), f)
            u = u - du
            if np.max(np.abs(du)) <= 1e-14 * max(1.0, np.max(np.abs(u))):
                break
        else:
            raise AssertionError(f"the reference Newton did not converge at step {k}")
    return u


def test_the_ten_lines_run_as_written_and_solve_the_implicit_euler_steps():
    readme = python_blocks(ROOT / "README.md", "Ten lines of Python")
    assert python_blocks(ROOT / "docs" / "getting-started.md", "Ten lines of Python") == readme
    namespace, printed = run_page_code(readme)
    factorizations, top = printed.split()
    sol = namespace["sol"]
    assert int(factorizations) == sol.stats.factorizations >= 1 and float(top) == pytest.approx(sol.xs[-1].max())
    reference = _implicit_euler(namespace["params"])
    # both solve the same 100 implicit-Euler steps; the ANM to eta = 1e-6 of each step's
    # increment, which the contracting steps do not amplify: 1e-5 of the solution's size
    assert np.max(np.abs(np.asarray(sol.xs[-1]) - reference)) < 1e-5 * np.max(np.abs(reference))


def test_the_own_scene_example_runs_as_written():
    """The scenes guide's own scene (a viscous scene built from the defaults, 5 steps) runs to
    its end: the flow is finite, the tool turns rigidly (its edge at omega R1, the boundary
    condition), the plate is slower than the tool edge and at rest on the outer ring."""
    namespace, printed = run_page_code(python_blocks(ROOT / "docs" / "guide" / "scenes.md", "Your own scene"))
    result, scene = namespace["result"], namespace["mine"]
    assert namespace["couette"].material.n == 0.5  # the override the page shows
    steps, factorizations = (int(v) for v in printed.splitlines()[0].split())
    assert steps == 5 and factorizations == result.stats.factorizations
    assert float(result.t[-1]) == pytest.approx(scene.time.t_end, rel=1e-12)
    speed = np.hypot(result.u[-1], result.v[-1])
    r = np.hypot(*np.asarray(result.points[-1]).T)
    edge = scene.tool.omega * scene.geometry.R1
    assert np.all(np.isfinite(speed))
    assert speed.max() == pytest.approx(edge, rel=1e-12)  # the tool's rigid rotation, imposed
    assert np.all(speed[r > scene.geometry.R1 * (1 + 1e-9)] < edge)
    assert np.all(speed[r > scene.geometry.R2 * (1 - 1e-9)] < 1e-12 * edge)  # the fixed ring
    assert float(printed.splitlines()[1]) == pytest.approx(np.abs(result.v[-1]).max())
