"""What the documentation names exists, and the numbers its guide quotes come from what it links.

The staleness a reader meets first: a link that works only after ``mkdocs build``, a module
renamed since a page was written (``jaxanm.linalg``, ``jaxanm/solvers.py``), a ``jaxanm.x.y``
that does not resolve after ``import jaxanm``, a ``--set`` key or scene that no longer exists,
a measured number that no page it links contains, a generated reference page older than the
code, an extras table older than ``pyproject.toml``.  All checks read files and import
modules; none runs a simulation.
"""

from __future__ import annotations

import importlib
import importlib.util
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import jaxanm
from jaxanm.fsw.scene import override_keys, shipped_scenes

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = sorted(p for p in DOCS.rglob("*.md") if "_mkdocs" not in p.parts) + [ROOT / "README.md"]
"""The documentation as a reader of the repository meets it: docs/ and the README."""
RESULTS = sorted((ROOT / "benchmarks" / "results").glob("*.md"))
"""The committed benchmark pages, shown on the site beside docs/."""
GUIDE = sorted((DOCS / "guide").glob("*.md")) + [DOCS / "getting-started.md", DOCS / "index.md",
                                                 ROOT / "README.md"]
"""The pages a newcomer reads first: their numbers must come from what they link."""

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _links(path: Path) -> list[str]:
    """Relative link targets of a markdown page (fenced code left out), anchors dropped."""
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    return [t.split("#")[0] for t in LINK.findall(text)
            if not re.match(r"^[a-z]+:|^#|^/", t) and t.split("#")[0]]


def test_every_link_resolves_in_the_repository():
    """A page read in the repository (GitHub, an editor) finds every file it links: no link
    to a page that exists only in the built site."""
    broken = [f"{_rel(page)} -> {target}" for page in PAGES for target in _links(page)
              if not (page.parent / target).exists()]
    assert not broken, "links to nothing in the repository:\n" + "\n".join(broken)


MODULE_PATH = re.compile(r"(?<![\w./~-])jaxanm/(?:[\w-]+/)*[\w-]+(?:\.\w+)?/?")


def test_every_module_path_named_exists():
    """``jaxanm/fsw/scene.py``, ``jaxanm/_solver/``: every path under the package that a page
    names is there (a rename leaves no page behind)."""
    missing = sorted({f"{_rel(page)}: {name}" for page in PAGES + RESULTS
                      for name in MODULE_PATH.findall(page.read_text(encoding="utf-8"))
                      if not (ROOT / name.rstrip("/")).exists()})
    assert not missing, "paths that do not exist:\n" + "\n".join(missing)


DOTTED = re.compile(r"(?<![\w.])jaxanm(?:\.[A-Za-z_]\w*)+")


def _resolves(dotted: str) -> bool:
    """Whether ``jaxanm.a.b.c`` is a module or an attribute chain reachable after ``import jaxanm``."""
    parts = dotted.split(".")
    obj = jaxanm
    for i, part in enumerate(parts[1:], start=2):
        try:  # a module first: jaxanm.continuation is a module and the function it exports
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            if not hasattr(obj, part):
                return False
            obj = getattr(obj, part)
    return True


def test_every_jaxanm_name_resolves():
    """Each ``jaxanm.x.y`` in the documentation and the results pages names a module, class,
    function or constant that exists: modules renamed (``jaxanm.linalg``) are caught."""
    names = {(page, name) for page in PAGES + RESULTS
             for name in DOTTED.findall(page.read_text(encoding="utf-8"))}
    missing = sorted(f"{_rel(page)}: {name}" for page, name in names if not _resolves(name))
    assert not missing, "names that do not resolve:\n" + "\n".join(missing)


def test_names_the_guides_use_resolve_after_a_bare_import_without_loading_them_eagerly():
    """``jaxanm.compile_cache.enable``, ``jaxanm.fsw.run``, ``jaxanm.sweep.run_sweep`` after
    ``import jaxanm`` alone, and none of those submodules imported by ``import jaxanm`` itself."""
    code = ("import sys, jaxanm\n"
            "lazy = [m for m in jaxanm.SUBMODULES if m != 'checkpoint']\n"
            "assert not [m for m in lazy if 'jaxanm.' + m in sys.modules], sys.modules.keys()\n"
            "jaxanm.compile_cache.enable, jaxanm.fsw.run, jaxanm.sweep.run_sweep, jaxanm.ida.integrate_ida\n"
            "assert set(jaxanm.SUBMODULES) <= set(dir(jaxanm))\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


INLINE = re.compile(r"`([^`\n]+)`")


def _code(path: Path) -> str:
    """The code of a page: fenced blocks and inline code spans."""
    text = path.read_text(encoding="utf-8")
    return "\n".join(FENCE.findall(text) + INLINE.findall(FENCE.sub("", text)))


MISSPELT = {"material.nn"}
"""The misspelt key the pages show on purpose, with the answer the command gives."""


def test_every_set_key_and_scene_named_exists():
    """``--set KEY=VALUE`` names a scene key and ``jaxanm run NAME`` a shipped scene (or a file),
    in every command a page shows."""
    keys, scenes = set(override_keys()) | MISSPELT, set(shipped_scenes())
    bad = []
    for page in PAGES:
        code = _code(page)
        bad += [f"{_rel(page)}: --set {k}" for k in re.findall(r"--set\s+([\w.]+)=", code)
                if k not in keys and k != "KEY"]
        bad += [f"{_rel(page)}: {k}" for k in re.findall(r"\b((?:material|geometry|tool|thermal|mechanics|time|"
                                                          r"solver)\.\w+)\s*=", code) if k not in keys]
        bad += [f"{_rel(page)}: jaxanm run {s}" for s in re.findall(r"jaxanm run ([A-Za-z_][\w]*)(?=\s|$)", code)
                if s not in scenes and s.upper() != s]
    assert not bad, "keys or scenes that do not exist:\n" + "\n".join(sorted(set(bad)))


NUMBER = re.compile(r"(?<![\w.\-/−])[-+−]?\d+(?:[.,]\d+)*(?:[eE][-+−]?\d+)?(?!\w)")

NOT_MEASURED = {
    "cli.md": {"130": "an exit status"},
    "cli-help.md": {"8786": "the port of a Dask scheduler address, an example"},
    "getting-started.md": {"3.11": "the Python version pyproject.toml requires",
                           "20000": "a constant of the code: jaxanm._factorization.SYMMETRIC_MAX_UNKNOWNS",
                           "5000": "a constant of the code: jaxanm._factorization.GUARDED_ABOVE"},
    "scenes.md": {"0.5625": "couette_small's and conduction_small's dr = 5.625e-4 m, in mm"},
}
"""Numbers of the first pages that are no measurement and no value of a linked file, with why."""


def _prose(text: str) -> str:
    """A page without code, link targets and comments: where quoted numbers are claims."""
    for pattern in (FENCE, re.compile(r"`[^`\n]*`"), re.compile(r"\]\([^)]*\)"), re.compile(r"<!--.*?-->", re.S)):
        text = pattern.sub(" ", text)
    return text


def _sources(page: Path) -> str:
    """The text of every file the page links (a results page with its .json beside it)."""
    texts = []
    for target in _links(page):
        path = (page.parent / target).resolve()
        for candidate in (path, path.with_suffix(".json")):
            if candidate.is_file() and (candidate == path or path.suffix == ".md"):
                texts.append(candidate.read_text(encoding="utf-8", errors="replace"))
    return "\n".join(texts)


@pytest.mark.parametrize("page", GUIDE, ids=_rel)
def test_every_number_of_a_first_page_is_in_a_file_it_links(page):
    """A number quoted in the prose of a guide page (getting started, the index, the README)
    appears in a file the page links (a results page, a note, a scene file) or in the page's
    own code; numbers of one digit and the few of :data:`NOT_MEASURED` aside.  So a measured
    number comes with its source, and one that changes there leaves no stale copy here."""
    text = page.read_text(encoding="utf-8")
    sources, code = _sources(page), _code(page)
    allowed = NOT_MEASURED.get(page.name, {})
    numbers = {n.replace("−", "-").lstrip("+") for n in NUMBER.findall(_prose(text))}
    unsourced = sorted(n for n in numbers
                       if len(n.lstrip("-")) > 1 and n not in allowed and n not in sources and n not in code)
    assert not unsourced, (f"{_rel(page)} quotes numbers that no file it links contains: {unsourced}; "
                           "link the results page or note they come from (or say in NOT_MEASURED why one is none)")


def test_the_allowed_code_constant_is_the_code_s():
    from jaxanm._factorization import GUARDED_ABOVE, SYMMETRIC_MAX_UNKNOWNS

    assert {str(SYMMETRIC_MAX_UNKNOWNS), str(GUARDED_ABOVE)} <= set(NOT_MEASURED["getting-started.md"])


def test_paths_of_docs_named_in_messages_exist():
    """An error or summary line that sends the reader to ``docs/...md`` sends them to a page."""
    named = {(path, m) for path in (ROOT / "jaxanm").rglob("*.py")
             for m in re.findall(r"docs/[\w/.-]+\.md", path.read_text(encoding="utf-8"))}
    missing = sorted(f"{_rel(p)}: {m}" for p, m in named if not (ROOT / m).is_file())
    assert not missing, "\n".join(missing)


def test_committed_reference_pages_are_current():
    """``docs/guide/scene-keys.md`` and ``cli-help.md`` are what the code gives today; after a
    change of a scene key or a command-line option, ``python docs/_mkdocs/reference_pages.py``."""
    spec = importlib.util.spec_from_file_location("reference_pages", DOCS / "_mkdocs" / "reference_pages.py")
    pages = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pages)
    stale = [_rel(path) for path, make in pages.PAGES.items() if path.read_text(encoding="utf-8") != make() + "\n"]
    assert not stale, f"stale: {stale}; run python docs/_mkdocs/reference_pages.py and commit"


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def test_the_extras_table_lists_what_pyproject_installs():
    """Getting started's table of extras names every package of each extra (and no other)."""
    extras = _pyproject()["project"]["optional-dependencies"]
    text = (DOCS / "getting-started.md").read_text(encoding="utf-8")
    rows = dict(re.findall(r"^\| `(\w+)` \| ([^|]*) \|", text, flags=re.M))
    assert set(rows) == set(extras)
    for extra, requirements in extras.items():
        if extra == "all":
            continue
        wanted = {re.split(r"[<>=\[ ]", r)[0].lower() for r in requirements}
        listed = {re.split(r"\[", w.strip())[0].lower() for w in rows[extra].split(",")}
        assert listed == wanted, (extra, listed ^ wanted)


def test_licence_and_citation_agree_with_the_package():
    """LICENSE is the licence pyproject.toml declares; CITATION.cff has the package's version."""
    project = _pyproject()["project"]
    assert project["license"]["text"] == "MIT"
    assert (ROOT / "LICENSE").read_text(encoding="utf-8").startswith("MIT License")
    cff = (ROOT / "CITATION.cff").read_text(encoding="utf-8")
    assert re.search(r"^version: (\S+)$", cff, flags=re.M).group(1) == jaxanm.__version__
    assert "10.1007/s00366-017-0504-3" in cff and "preferred-citation:" in cff
