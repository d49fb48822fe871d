"""The layout rules of the package's code: sizes, the import order, the boundaries between
modules, one owner for each rule that can be checked."""

from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "jaxanm"
MAX_FUNCTION_LINES = 80


def test_no_function_longer_than_80_lines():
    """No function in jaxanm/ exceeds 80 lines, from its ``def`` line to its last line,
    docstring included (a function holds one idea a reader follows in one view;
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
    "effects": set(),
    "scene": {"scene_sections", "effects"},
    "scene_text": set(),
    "geometry": {"scene"},
    "physics": {"scene", "geometry", "effects"},
    "discretisation": {"scene", "geometry", "physics", "effects"},
    "start": {"scene", "geometry", "physics", "discretisation", "effects"},
    "record": {"scene", "geometry", "discretisation", "start"},
    "lagrangian": {"scene", "geometry", "discretisation", "start", "record"},
    "simulate": {"scene", "geometry", "discretisation", "start", "record", "lagrangian", "stability"},
    # results: files and figures of an FSWResult
    "io": set(),
    "io.figures": {"scene", "record"},
    "io.weld_figures": {"io.figures"},
    "io.output": {"scene", "geometry", "record", "continuum_error", "oscillation", "io", "io.figures",
                  "io.weld_figures", "process"},
    # analyses of a scene or of results, beside the flow
    "axisymmetric": {"scene"},
    "continuum_error": {"scene", "axisymmetric"},
    "oscillation": set(),
    "compare": set(),
    "energy": {"scene", "geometry", "physics", "discretisation"},
    "mass_flux": {"energy"},
    "process": {"scene", "energy", "mass_flux"},
    "manufactured": {"discretisation", "geometry", "physics"},
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
    """No module of the engine (``jaxanm/*.py`` but the command line, the step solvers of
    ``jaxanm/_solver/``, the MLS stencils of ``jaxanm/mls/``) imports :mod:`jaxanm.fsw`."""
    offenders = []
    for path in sorted([*PACKAGE.glob("*.py"), *PACKAGE.glob("_solver/*.py"), *PACKAGE.glob("mls/*.py")]):
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


# --------------------------------------------------------------------------- boundaries

SUBPACKAGES = ("jaxanm.fsw", "jaxanm.sweep")
"""Packages built on the core (as a user's model would be): they reach the core's internal
modules only through :mod:`jaxanm.internal`."""

FACADE = "jaxanm.internal"


def _module_name(path: Path) -> str:
    """``jaxanm/fsw/io/figures.py`` -> ``jaxanm.fsw.io.figures``; a package's ``__init__`` -> the package."""
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}
"""Every module of the package by its dotted name."""

def _import_froms(path: Path, name: str | None = None):
    """``(line, absolute module, imported name)`` of every import in ``path`` (at the top,
    inside functions, under ``TYPE_CHECKING``; ``import m`` gives ``(line, m, None)``), with
    relative modules resolved from the module's ``name`` (default: from its path)."""
    package = (name or _module_name(path)).split(".")
    if path.name != "__init__.py":
        package = package[:-1]
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom):
            base = package[:len(package) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            for alias in node.names:
                yield node.lineno, module, alias.name
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, None


def _imported_modules(path: Path, modules: dict = MODULES, name: str | None = None) -> set:
    """The ``modules`` the module at ``path`` imports (``from . import x`` imports module ``x``)."""
    found = set()
    for _, module, imported in _import_froms(path, name):
        full = f"{module}.{imported}" if imported else module
        found.add(full if full in modules else module)
    return {m for m in found if m in modules}


def _cycles(modules: dict = MODULES) -> list[list[str]]:
    """The import cycles among the package's modules: strongly connected components of the
    import graph with more than one module (Tarjan).  Package ``__init__`` modules are left
    out: they are namespaces that import their modules, and a module that reads a name
    through its package (``jaxanm.integrate``, or the lazily imported ``jaxanm.fsw``) is not in
    a cycle with that name's own module."""
    packages = {m for m, p in modules.items() if p.name == "__init__.py"}
    graph = {m: sorted(_imported_modules(p, modules, m) - packages - {m}) for m, p in modules.items()
             if m not in packages}
    index: dict = {}
    low: dict = {}
    stack: list = []
    cycles = []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    return cycles


def test_no_import_cycles():
    """No two modules of the package import each other, directly or through others (imports
    inside functions and under ``TYPE_CHECKING`` count): the modules form layers, each read
    and tested without the ones above it."""
    cycles = _cycles()
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_cycle_finder_finds_a_cycle(tmp_path):
    """The check above can fail: two modules that import each other (one inside a function, as
    the cycles it replaced did) are found, and a module that only imports them is not."""
    texts = {"a": "from . import b\n", "b": "def f():\n    from .a import g\n", "c": "from .a import x\n"}
    for name, text in texts.items():
        (tmp_path / f"{name}.py").write_text(text)
    assert _cycles({f"jaxanm.{n}": tmp_path / f"{n}.py" for n in texts}) == [["jaxanm.a", "jaxanm.b"]]


PRIVATE_IMPORTS_TO_MOVE = {
}
"""Private names still imported across modules, each in a file another change is rewriting
(the reason says what replaces the import); emptied once those changes have landed."""


def _private_imports() -> dict:
    """``(file, name) -> line`` of every private name (``_x``, not a module) imported from
    another module of the package."""
    found = {}
    for path in MODULES.values():
        for line, module, imported in _import_froms(path):
            if (module.startswith("jaxanm") and imported and imported.startswith("_")
                    and not imported.startswith("__") and f"{module}.{imported}" not in MODULES):
                found[(str(path.relative_to(PACKAGE.parent)), imported)] = line
    return found


def test_no_private_name_imported_from_another_module():
    """A name with a leading underscore is its module's own: another module that needs it
    gets it made public where it belongs (or, for jaxanm's subpackages, through
    :mod:`jaxanm.internal`).  The entries of :data:`PRIVATE_IMPORTS_TO_MOVE` are the ones
    left to move; an entry no longer needed fails too, so the list only shrinks."""
    found = _private_imports()
    new = [f"{file}:{line} imports {name}" for (file, name), line in sorted(found.items())
           if (file, name) not in PRIVATE_IMPORTS_TO_MOVE]
    stale = [f"{file} {name}" for file, name in PRIVATE_IMPORTS_TO_MOVE if (file, name) not in found]
    assert not new, "private names imported from another module:\n" + "\n".join(new)
    assert not stale, "PRIVATE_IMPORTS_TO_MOVE entries no longer needed (remove them):\n" + "\n".join(stale)


FACADE_BYPASSES_TO_MOVE = {
}
"""Subpackage modules that still import a private core module directly, each in a file
another change is rewriting; emptied once those changes have landed."""


def _private_core(module: str) -> bool:
    """``jaxanm._x`` or below it: a private module of the core."""
    parts = module.split(".")
    return len(parts) > 1 and parts[0] == "jaxanm" and parts[1].startswith("_") and not parts[1].startswith("__")


def test_subpackages_reach_the_core_only_through_public_modules_and_the_facade():
    """``jaxanm.fsw`` and ``jaxanm.sweep`` import the core's public modules (``jaxanm``,
    ``jaxanm.errors``, ``jaxanm.mls``, ...) and its internals only through :mod:`jaxanm.internal`,
    so that what they take from the core's private modules is listed in one place.
    :data:`FACADE_BYPASSES_TO_MOVE` are the ones left to move (an entry no longer needed fails)."""
    found = set()
    for name, path in MODULES.items():
        if name.startswith(SUBPACKAGES):
            found |= {(name, m) for m in _imported_modules(path) if _private_core(m)}
    new = sorted(found - set(FACADE_BYPASSES_TO_MOVE))
    stale = sorted(set(FACADE_BYPASSES_TO_MOVE) - found)
    assert not new, "private core modules imported by a subpackage (use jaxanm.internal):\n" + "\n".join(
        f"{a} imports {b}" for a, b in new)
    assert not stale, "FACADE_BYPASSES_TO_MOVE entries no longer needed (remove them):\n" + "\n".join(
        f"{a} {b}" for a, b in stale)


def test_the_core_does_not_import_the_facade():
    """:mod:`jaxanm.internal` points one way, from the subpackages and the command line into
    the core: no core module imports it (it would import the core back)."""
    offenders = [name for name, path in MODULES.items()
                 if not name.startswith(SUBPACKAGES) and name not in (FACADE, "jaxanm.cli", "jaxanm.__main__")
                 and FACADE in _imported_modules(path)]
    assert not offenders, "core modules importing jaxanm.internal: " + ", ".join(offenders)


# --------------------------------------------------------------------------- one owner per rule

CHECKS = "jaxanm._checks"
INLINE_CHECKS_TO_MOVE = {
    "jaxanm/fsw/scene_sections.py": (2, "weld rewrites it: the scene converters' real and integer checks"),
}
"""Files that still check a scalar's type inline, with how many such checks, each in a file
another change is rewriting; emptied once those changes have landed."""


def _checks_a_type(test: ast.expr) -> bool:
    """Whether an ``if`` test asks ``isinstance(value, int / float / bool / np.integer ...)``."""
    for node in ast.walk(test):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "isinstance" \
                and len(node.args) == 2:
            kinds = ast.unparse(node.args[1])
            if any(k in kinds.replace("(", " ").replace(")", " ").replace(",", " ").split()
                   for k in ("int", "float", "bool", "np.integer", "np.floating", "np.bool_")):
                return True
    return False


def _refuses(node: ast.AST) -> bool:
    """Whether ``node`` raises, or calls a ``fail`` helper (``_fail(field, value, why)``) that does."""
    return isinstance(node, ast.Raise) or (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                                           and node.func.id.lstrip("_").startswith("fail"))


def _inline_checks_in(source: str) -> int:
    """The ``if`` statements of ``source`` that test a value's scalar type and refuse it
    (inline copies of a check :mod:`jaxanm._checks` owns)."""
    return sum(1 for node in ast.walk(ast.parse(source)) if isinstance(node, ast.If) and _checks_a_type(node.test)
               and any(_refuses(n) for statement in node.body for n in ast.walk(statement)))


def _inline_checks() -> dict:
    """File -> number of inline scalar checks, outside :mod:`jaxanm._checks` itself."""
    counts = {str(path.relative_to(PACKAGE.parent)): _inline_checks_in(path.read_text())
              for name, path in MODULES.items() if name != CHECKS}
    return {file: n for file, n in counts.items() if n}


def test_the_inline_check_finder_finds_one():
    """The check below can fail: an integer test written inline is found, a string test and a
    call of the checks module are not."""
    source = ("def f(n, name):\n"
              "    if isinstance(n, bool) or not isinstance(n, int):\n        raise ValueError(n)\n"
              "    if not isinstance(name, str):\n        raise ValueError(name)\n"
              "    integer('n', n, 1)\n")
    assert _inline_checks_in(source) == 1


def test_scalar_inputs_are_checked_by_the_checks_module():
    """An option that must be an integer, a number in a range or a flag is checked by
    :mod:`jaxanm._checks` (through :mod:`jaxanm.internal` in the subpackages), which gives every
    refusal one shape ("ANM.order must be an integer >= 2, got 1.5"), not by an inline
    ``isinstance`` test.  :data:`INLINE_CHECKS_TO_MOVE` counts the ones left; a file with
    fewer than its count fails too, so the list only shrinks."""
    counts = _inline_checks()
    allowed = {file: n for file, (n, _) in INLINE_CHECKS_TO_MOVE.items()}
    more = [f"{file}: {n} inline checks (allowed {allowed.get(file, 0)})" for file, n in sorted(counts.items())
            if n > allowed.get(file, 0)]
    fewer = [f"{file}: {counts.get(file, 0)} inline checks, listed with {n}" for file, n in sorted(allowed.items())
             if counts.get(file, 0) < n]
    assert not more, "scalar types checked inline (use jaxanm._checks):\n" + "\n".join(more)
    assert not fewer, "INLINE_CHECKS_TO_MOVE counts to lower:\n" + "\n".join(fewer)


STATS_OWNERS = {
    "jaxanm.stats": "the statistics classes themselves (closing the wall time)",
    "jaxanm._problem": "work counters: factorisations, residual and Jacobian evaluations, series orders, solves, "
                       "their times (count, work, record, factorize, counted_solve)",
    "jaxanm._loop": "a run's step counters and the solvers' step reports (_Tally)",
    "jaxanm._walk": "a branch's counters, built from the walk of the path follower",
}
"""The modules that write statistics fields; everyone else records through them."""


def _stats_names(tree: ast.AST) -> set:
    """Local names bound to a statistics object: ``st = self.problem.stats``, ``s = Stats()``."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign):
            value = ast.unparse(node.value)
            if value.endswith("stats") or value.endswith("Stats()"):
                names.update(t.id for t in node.targets if isinstance(t, ast.Name))
    return names


def _stats_writes_in(source: str) -> list:
    """``line: statement`` of every write to a statistics object in ``source``: an assignment
    or augmented assignment to an attribute (or to an entry of ``wall_time``) of something
    named ``...stats`` or bound to one, every ``<stats>.<list>.append/extend(...)`` and every
    ``<stats>.timer(...)``."""
    tree = ast.parse(source)
    aliases = _stats_names(tree)

    def stats_object(expr: ast.expr) -> bool:
        text = ast.unparse(expr)
        return text.endswith("stats") or text in aliases

    writes = []
    for node in ast.walk(tree):
        targets = node.targets if isinstance(node, ast.Assign) else \
            [node.target] if isinstance(node, (ast.AugAssign, ast.AnnAssign)) else []
        for target in targets:
            if isinstance(target, ast.Subscript) and isinstance(target.value, ast.Attribute) \
                    and target.value.attr == "wall_time":
                target = target.value
            if isinstance(target, ast.Attribute) and stats_object(target.value):
                writes.append(f"{node.lineno}: {ast.unparse(node)}")
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and (
                (node.func.attr == "timer" and stats_object(node.func.value))
                or (node.func.attr in ("append", "extend") and isinstance(node.func.value, ast.Attribute)
                    and stats_object(node.func.value.value))):
            writes.append(f"{node.lineno}: {ast.unparse(node)}")
    return writes


def test_the_stats_write_finder_finds_them():
    """The check below can fail: direct writes, writes through an alias, ``wall_time`` entries
    and timers are found; reading a counter and recording through the owner are not."""
    source = ("def f(problem, report):\n"
              "    problem.stats.factorizations += 1\n"
              "    st = problem.stats\n    st.solves = 2\n"
              "    report.stats.wall_time['x'] += 1.0\n"
              "    with problem.stats.timer('series'):\n        pass\n"
              "    st.amax.append(0.5)\n"
              "    n = problem.stats.solves\n    count(problem.stats, 'solves')\n"
              "    report.substeps += 1\n    report.amax.append(0.5)\n")
    assert sorted(int(w.split(":")[0]) for w in _stats_writes_in(source)) == [2, 4, 5, 6, 8]


def test_statistics_are_written_by_their_owners_only():
    """One owner per counter (:data:`STATS_OWNERS`): ``Problem``'s module counts and times the
    work (factorisations, evaluations, solves), the time loop the steps and what each solve
    reports, the path follower's walk a branch's counters.  Any other module records through
    them (``jaxanm._problem.count`` / ``work`` / ``record``, a solver's ``StepReport``), never by writing a
    field of ``Stats``, ``IDAStats`` or ``SensitivityStats`` itself."""
    offenders = [f"{MODULES[name].relative_to(PACKAGE.parent)}:{write}" for name in sorted(MODULES)
                 if name not in STATS_OWNERS for write in _stats_writes_in(MODULES[name].read_text())]
    assert not offenders, "statistics written outside their owners:\n" + "\n".join(offenders)
