"""Pages generated at build time (mkdocs-gen-files), from files committed elsewhere in the repository.

- ``results/``: every file of ``benchmarks/results/`` (the committed benchmark outputs: .md
  pages as they are, their .png figures, .json/.csv data), and an index of them;
- ``notebooks/``: each ``notebooks/*.ipynb`` as a page (markdown cells as written, code cells as
  code blocks; the notebooks are committed without outputs and are not executed here);
- ``changelog.md``: ``CHANGELOG.md``;
- ``guide/cli-help.md``: the ``--help`` text of every ``jaxanm`` command;
- ``guide/scene-keys.md``: every scene key with its default, from :mod:`jaxanm.fsw.scene`.

Nothing is copied into ``docs/`` on disk: the pages exist only in the build.  Links between
the repository's files are rewritten to these pages by ``hooks.py``.
"""

from __future__ import annotations

import dataclasses
import io
import json
import re
from contextlib import redirect_stdout
from pathlib import Path

import mkdocs_gen_files

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"
NOTEBOOKS = ROOT / "notebooks"

# Which benchmark produced which results, for the index (prefix of the file stem -> script).
PRODUCERS = [
    ("accuracy_cost_paper", "benchmarks/accuracy_cost_paper.py (from a jaxanm sweep)"),
    ("accuracy_cost_tracers", "benchmarks/accuracy_cost_paper.py (from a jaxanm sweep)"),
    ("accuracy_cost_lagrangian", "benchmarks/accuracy_cost_paper.py (from a jaxanm sweep)"),
    ("accuracy_cost", "benchmarks/accuracy_cost.py"),
    ("table1", "benchmarks/table1.py"),
    ("scaling_steps", "benchmarks/scaling_steps.py"),
    ("scaling", "benchmarks/scaling.py"),
    ("hard_cases", "benchmarks/hard_cases.py"),
    ("fsw_paper_anm_vs", "benchmarks/compare_runs.py"),
    ("series_vs_newton", "benchmarks/series_vs_newton.py"),
    ("series_cost", "benchmarks/series_cost.py"),
    ("spatial_convergence", "benchmarks/spatial_convergence.py"),
    ("time_steps", "benchmarks/time_steps.py"),
    ("profile_host_step", "benchmarks/profile_host_step.py"),
    ("profile_anm_step", "benchmarks/profile_anm_step.py"),
    ("lu_orderings", "benchmarks/lu_orderings.py"),
    ("sweep_couette_demo", "jaxanm sweep benchmarks/grids/couette_demo.toml"),
    ("main_job", "benchmarks/main_job.py"),
    ("continuum_front", "benchmarks/continuum_front.py (from a jaxanm sweep)"),
    ("anm_vs_mnewton_fine", "benchmarks/anm_vs_mnewton_fine.py"),
    ("start_from_rest", "benchmarks/start_from_rest.py"),
    ("stiff_controller", "benchmarks/stiff_controller.py"),
]


def producer(stem: str) -> str:
    return next((script for prefix, script in PRODUCERS if stem.startswith(prefix)), "")


def title_of(md: str, fallback: str) -> str:
    match = re.search(r"^#\s+(.+)$", md, flags=re.M)
    return match.group(1).strip() if match else fallback


def results_pages() -> None:
    pages, data = [], []
    for path in sorted(RESULTS.iterdir()):
        if path.name.startswith(".") or not path.is_file():
            continue
        if path.suffix == ".md":
            text = path.read_text(encoding="utf-8")
            if not re.match(r"\s*#\s", text):  # every page gets a title
                text = f"# {path.stem}\n\n{text}"
            with mkdocs_gen_files.open(f"results/{path.name}", "w") as out:
                out.write(text)
            mkdocs_gen_files.set_edit_path(f"results/{path.name}", f"../benchmarks/results/{path.name}")
            pages.append((path.stem, title_of(text, path.stem)))
        else:
            with mkdocs_gen_files.open(f"results/{path.name}", "wb") as out:
                out.write(path.read_bytes())
            if path.suffix in (".json", ".csv"):
                data.append(path.name)
    md_stems = {stem for stem, _ in pages}
    lines = ["# Results", "",
             "The measured results, as the benchmark scripts wrote them into `benchmarks/results/` "
             "(these pages are those files, not copies edited by hand). Each page says how it was "
             "made and with which command; the explanations that use them are in the "
             "[method](../method/index.md), [physics](../physics/index.md) and [notes](../notes/index.md).",
             "", "The four studies the documentation leans on:", "",
             "- accuracy against cost: [accuracy_cost_paper](accuracy_cost_paper.md) (the fsw_tracers "
             "front), [accuracy_cost_lagrangian](accuracy_cost_lagrangian.md), "
             "[accuracy_cost](accuracy_cost.md) (small problems);",
             "- the paper's Table 1: [table1_0.7s](table1_0.7s.md), [table1_0.05s](table1_0.05s.md);",
             "- scaling to finer clouds: [scaling_steps](scaling_steps.md);",
             "- hard cases (stability, clear failures): [hard_cases](hard_cases.md).",
             "", "| page | made by |", "| --- | --- |"]
    lines += [f"| [{title}]({stem}.md) | `{producer(stem)}` |" for stem, title in pages]
    lines += ["", "Data files without a page of their own (JSON/CSV, downloadable):", ""]
    lines += [f"- [{name}]({name})" + ("" if Path(name).stem in md_stems else "") for name in data]
    with mkdocs_gen_files.open("results/index.md", "w") as out:
        out.write("\n".join(lines) + "\n")


def notebook_pages() -> None:
    index = ["# Notebooks", "",
             "The research notebooks of `notebooks/`, shown here as committed: without outputs "
             "(see [their README](README.md)). Run them to see the figures "
             "(`pip install jupyterlab`, then `jupyter lab` in `notebooks/`); each takes a minute or two.", ""]
    readme = (NOTEBOOKS / "README.md").read_text(encoding="utf-8")
    with mkdocs_gen_files.open("notebooks/README.md", "w") as out:
        out.write(readme)
    for path in sorted(NOTEBOOKS.glob("*.ipynb")):
        nb = json.loads(path.read_text(encoding="utf-8"))
        parts = [f"!!! note \"Notebook `{path.name}`\"\n    Rendered without outputs and not executed: "
                 f"open `notebooks/{path.name}` in Jupyter to run it.\n"]
        for cell in nb["cells"]:
            source = "".join(cell["source"]) if isinstance(cell["source"], list) else cell["source"]
            if not source.strip():
                continue
            if cell["cell_type"] == "markdown":
                parts.append(source)
            elif cell["cell_type"] == "code":
                parts.append(f"```python\n{source}\n```")
        text = "\n\n".join(parts) + "\n"
        if not re.search(r"^#\s", text, flags=re.M):
            text = f"# {path.stem}\n\n{text}"
        else:  # the title first, then the note
            title = re.search(r"^#\s.*$", text, flags=re.M).group(0)
            text = title + "\n\n" + text.replace(title, "", 1)
        with mkdocs_gen_files.open(f"notebooks/{path.stem}.md", "w") as out:
            out.write(text)
        mkdocs_gen_files.set_edit_path(f"notebooks/{path.stem}.md", f"../notebooks/{path.name}")
        index.append(f"- [{title_of(text, path.stem)}]({path.stem}.md)")
    with mkdocs_gen_files.open("notebooks/index.md", "w") as out:
        out.write("\n".join(index) + "\n")


def changelog_page() -> None:
    with mkdocs_gen_files.open("changelog.md", "w") as out:
        out.write((ROOT / "CHANGELOG.md").read_text(encoding="utf-8"))


def cli_help_page() -> None:
    from jaxanm import cli

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.__class__.__name__ == "_SubParsersAction")
    lines = ["# Command-line reference", "",
             "The `--help` text of each command, as `jaxanm` prints it (generated from "
             "`jaxanm/cli.py` at build time). How to use them: [the CLI guide](cli.md).", "",
             "## jaxanm", "", "```text", parser.format_help().rstrip(), "```", ""]
    for name, command in sub.choices.items():
        lines += [f"## jaxanm {name}", "", "```text", command.format_help().rstrip(), "```", ""]
    with mkdocs_gen_files.open("guide/cli-help.md", "w") as out:
        out.write("\n".join(lines))


def scene_keys_page() -> None:
    from jaxanm.fsw import scene as sc

    lines = ["# Scene keys", "",
             "Every key a scene TOML table (or `--set KEY=VALUE`) may set, with its default "
             "(generated from `jaxanm/fsw/scene.py` at build time). The default is that of a "
             "`Scene()` built in Python; the shipped scenes set most keys themselves "
             "(see [Scenes](scenes.md)), and each section's meaning is in its class: "
             "[API: FSW model](../api/fsw.md).", "",
             "Top level: `name` (a string), `effects` (a list of the names below), "
             "`[[probes]]` (registration points: `name`, `x`, `y`) and `[[sections]]` "
             "(registration lines: `name`, `start`, `end`, `samples`).", "",
             "## Effects", "",
             "One record per effect (`jaxanm.fsw.effects.REGISTRY`): what it needs, what it cannot be "
             "combined with, its keys (each must keep its default unless the effect is listed) and what "
             "it adds.", "",
             "| effect | needs | excludes | keys (range) | adds |", "| --- | --- | --- | --- | --- |"]
    from jaxanm.fsw.effects import REGISTRY

    def names(items):
        return ", ".join(f"`{x}`" for x in items) or "—"

    for e in REGISTRY.values():
        keys = ", ".join(f"`{p.key}` [{p.low:g}, {p.high:g}] {p.unit}" for p in e.parameters) or "—"
        lines.append(f"| `{e.name}` | {names(e.requires)} | {names(o for o, _ in e.excludes)} | {keys} | "
                     f"{', '.join(sorted(e.roles)) or '—'} |")
    lines += ["", "What each effect adds to the model: [Equations](../physics/index.md).", ""]
    for section, cls in sc._SECTIONS.items():
        lines += [f"## [{section}]", "", f"Class `jaxanm.fsw.scene.{cls.__name__}`.", "",
                  "| key | default |", "| --- | --- |"]
        for field in dataclasses.fields(cls):
            if field.name.startswith("_"):
                continue
            default = field.default if field.default is not dataclasses.MISSING else (
                field.default_factory() if field.default_factory is not dataclasses.MISSING else "")
            lines.append(f"| `{section}.{field.name}` | `{default!r}` |")
        lines.append("")
    with mkdocs_gen_files.open("guide/scene-keys.md", "w") as out:
        out.write("\n".join(lines))


results_pages()
notebook_pages()
changelog_page()
cli_help_page()
scene_keys_page()
