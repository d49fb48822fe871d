"""MkDocs hook: links written for the repository also work on the site.

The markdown files of ``docs/`` link the way they read on a repository browser: relative to
their own place in the repository (``../../benchmarks/results/series_cost.md`` from
``docs/notes/``).  On the site, ``benchmarks/results/``, ``notebooks/`` and ``CHANGELOG.md``
are pages of their own (``gen_pages.py``); this hook rewrites each relative link whose target
lies outside ``docs/`` to that page, and a link to any other file of the repository (source
code, tests, scripts) to its path as inline code, since the site does not hold it.
"""

from __future__ import annotations

import posixpath
import re

LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)")

# site page (docs-relative) -> the repository file it comes from
GENERATED = {"changelog.md": "CHANGELOG.md"}


def _repo_path(src_uri: str) -> str:
    """The repository path of a page (generated pages: the file they come from)."""
    if src_uri in GENERATED:
        return GENERATED[src_uri]
    if src_uri.startswith("results/"):
        return "benchmarks/" + src_uri
    if src_uri.startswith("notebooks/"):
        name = src_uri.split("/", 1)[1]
        return "notebooks/" + (name if name in ("README.md", "index.md") else name[:-3] + ".ipynb")
    return "docs/" + src_uri


def _site_path(repo_target: str) -> str | None:
    """The docs-relative site path of a repository file, or None when the site does not hold it."""
    if repo_target.startswith("docs/"):
        return repo_target[len("docs/"):]
    if repo_target == "benchmarks/results":  # the folder (a listing in the repository): the results index
        return "results/index.md"
    if repo_target.startswith("benchmarks/results/"):
        return "results/" + repo_target[len("benchmarks/results/"):]
    if repo_target.startswith("notebooks/"):
        name = repo_target[len("notebooks/"):]
        if name.endswith(".ipynb"):
            return "notebooks/" + name[:-len(".ipynb")] + ".md"
        return "notebooks/" + name if name == "README.md" else None
    if repo_target == "CHANGELOG.md":
        return "changelog.md"
    return None


def on_page_markdown(markdown, page, config, files):  # noqa: ARG001 - MkDocs' hook signature
    """Rewrite the page's relative links from repository paths to site paths."""
    src = page.file.src_uri
    repo_dir = posixpath.dirname(_repo_path(src))
    site_dir = posixpath.dirname(src)

    def rewrite(match):
        bang, text, target = match.groups()
        if re.match(r"^[a-z]+:|^#|^/", target):
            return match.group(0)
        path, _, anchor = target.partition("#")
        repo_target = posixpath.normpath(posixpath.join(repo_dir, path))
        site = _site_path(repo_target)
        if site is None:  # a file the site does not hold: name it
            if bang:
                return match.group(0)
            label = text.strip().strip("`")
            same = label in (repo_target, path, posixpath.basename(repo_target))
            return f"`{repo_target}`" if same else f"{text} (`{repo_target}`)"
        new = posixpath.relpath(site, site_dir or ".")
        return f"{bang}[{text}]({new}{'#' + anchor if anchor else ''})"

    # leave fenced code blocks alone
    parts = re.split(r"(^```.*?^```)", markdown, flags=re.S | re.M)
    return "".join(p if p.startswith("```") else LINK.sub(rewrite, p) for p in parts)
