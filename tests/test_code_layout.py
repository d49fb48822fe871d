"""The layout rules of the package's code (issue 17)."""

from __future__ import annotations

import ast
import io
import tokenize
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


FSW_IMPORTS = {
    # the data flow: scene -> geometry -> physics -> discretisation -> (start) -> record -> lagrangian -> simulate
    "scene_sections": set(),
    "scene": {"scene_sections"},
    "scene_text": set(),
    "geometry": {"scene"},
    "physics": {"scene", "geometry"},
    "discretisation": {"scene", "geometry", "physics"},
    "start": {"scene", "geometry", "physics", "discretisation"},
    "record": {"scene", "geometry", "discretisation", "start"},
    "lagrangian": {"scene", "geometry", "discretisation", "start", "record"},
    "simulate": {"scene", "geometry", "discretisation", "start", "record", "lagrangian", "stability"},
    # results: files and figures of an FSWResult
    "io": set(),
    "io.figures": {"scene", "record", "io.weld_figures"},
    "io.weld_figures": {"io.figures"},
    "io.output": {"scene", "geometry", "record", "axisymmetric", "oscillation", "io", "io.figures"},
    # analyses of a scene or of results, beside the flow
    "axisymmetric": {"scene"},
    "oscillation": set(),
    "compare": set(),
    "energy": {"scene", "geometry", "physics", "discretisation"},
    "calibration": {"scene", "geometry", "physics", "discretisation", "record"},
    "ida_scene": {"scene", "geometry", "discretisation", "record"},
    "stability": {"geometry", "discretisation"},
}
"""The :mod:`jaxanm.fsw` modules each fsw module may import (docs/architecture.md): a module
imports only those upstream of it in the data flow, never one downstream."""

FSW = PACKAGE / "fsw"


def _fsw_imports(path: Path) -> set:
    """The fsw modules ``path`` imports (relative or absolute, at the top or inside functions)."""
    package = list(path.relative_to(FSW).parent.parts)  # [] for jaxanm.fsw, ["io"] for jaxanm.fsw.io
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.level:
            if node.level > len(package) + 1:  # above jaxanm.fsw: the core
                continue
            base = package[:len(package) - node.level + 1]
            names = ([".".join(base + node.module.split("."))] if node.module
                     else [".".join(base + [a.name]) for a in node.names])
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("jaxanm.fsw"):
            rest = node.module[len("jaxanm.fsw"):].lstrip(".")
            names = [rest] if rest else [a.name for a in node.names]
            if rest == "io":
                names = ["io." + a.name for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name[len("jaxanm.fsw."):] for a in node.names if a.name.startswith("jaxanm.fsw.")]
        else:
            continue
        found |= {n for n in names if n}
    return found


def test_fsw_modules_import_only_upstream_modules():
    """Each fsw module imports only the fsw modules :data:`FSW_IMPORTS` allows it (upstream in
    the data flow), and every fsw module is listed there (a new one says where it belongs)."""
    problems = []
    for path in sorted(FSW.rglob("*.py")):
        module = ".".join(path.relative_to(FSW).with_suffix("").parts).removesuffix(".__init__")
        if module == "__init__":
            continue  # the package's exports
        if module not in FSW_IMPORTS:
            problems.append(f"{module}: not in FSW_IMPORTS (say what it may import)")
            continue
        extra = _fsw_imports(path) - FSW_IMPORTS[module] - {module}
        if extra:
            problems.append(f"{module} imports {sorted(extra)}, allowed {sorted(FSW_IMPORTS[module])}")
    assert not problems, "\n".join(problems)


def test_the_core_knows_nothing_about_fsw():
    """No module of the engine (``jaxanm/*.py`` but the command line, and the step solvers of
    ``jaxanm/_solver/``) imports :mod:`jaxanm.fsw`."""
    offenders = []
    for path in sorted([*PACKAGE.glob("*.py"), *PACKAGE.glob("_solver/*.py")]):
        if path.name in ("cli.py", "__main__.py"):
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            names = ([node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0
                     else ["." * node.level + (node.module or "")] if isinstance(node, ast.ImportFrom)
                     else [a.name for a in node.names] if isinstance(node, ast.Import) else [])
            if any(n.startswith("jaxanm.fsw") or n.lstrip(".").startswith("fsw") for n in names):
                offenders.append(f"{path.name}:{node.lineno}")
    assert not offenders, "the core imports jaxanm.fsw at " + ", ".join(offenders)


def _absolute_imports(path: Path) -> set:
    """Every module ``path`` imports, as absolute dotted names (``from . import x`` counts as
    importing the package's ``x``, which may be a module), at the top or inside functions."""
    package = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)[:-1]  # the containing package
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            found.add(module)
            found |= {f"{module}.{a.name}" for a in node.names}
    return found


def test_the_command_line_is_a_leaf():
    """No library module imports :mod:`jaxanm.cli`: the library is used from notebooks and
    scripts without its command-line front end, and the front end depends on the library, never
    the other way round (``__main__`` is the front end's own entry point)."""
    offenders = [str(path.relative_to(PACKAGE.parent)) for path in sorted(PACKAGE.rglob("*.py"))
                 if path.name not in ("cli.py", "__main__.py") or path.parent != PACKAGE
                 if "jaxanm.cli" in _absolute_imports(path)]
    assert not offenders, "library modules importing jaxanm.cli: " + ", ".join(offenders)


MAX_MODULE_CODE_LINES = 400


def _code_lines(source: str) -> int:
    """Lines of ``source`` that hold code: not blank, not only a comment, not in a docstring."""
    tree = ast.parse(source)
    docstrings = set()
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body:
            first = body[0]
            value = first.value if isinstance(first, ast.Expr) else None
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                docstrings.update(range(first.lineno, first.end_lineno + 1))
    lines = set()
    skip = (tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT, tokenize.ENDMARKER)
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type not in skip:
            lines.update(n for n in range(tok.start[0], tok.end[0] + 1) if n not in docstrings)
    return len(lines)


def test_no_module_longer_than_400_lines_of_code():
    """No module in jaxanm/ holds more than 400 lines of code (docstrings and comments aside): a
    module holds one idea; a longer one is split by idea, as the solvers and the loop were."""
    too_long = [f"{path.relative_to(PACKAGE.parent)} ({n} lines of code)" for path in sorted(PACKAGE.rglob("*.py"))
                if (n := _code_lines(path.read_text())) > MAX_MODULE_CODE_LINES]
    assert not too_long, "modules over 400 lines of code:\n" + "\n".join(too_long)
