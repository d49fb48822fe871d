"""The layout rules of the package's code (issue 17)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jaxanm"
MAX_FUNCTION_LINES = 80


def test_no_function_longer_than_80_lines():
    """No function in jaxanm/ exceeds 80 lines, from its ``def`` line to its last line,
    docstring included (issue 17: a function holds one idea a reader follows in one view;
    a longer one is split into named helpers)."""
    too_long = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES:
                    too_long.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {node.name} ({lines} lines)")
    assert not too_long, "functions longer than 80 lines:\n" + "\n".join(too_long)
