"""Pages generated at build time (mkdocs-gen-files), from files committed elsewhere in the repository.

- ``results/``: every file of ``benchmarks/results/`` (the committed benchmark outputs: .md
  pages as they are, their .png figures, .json/.csv data), and an index of them;
- ``notebooks/``: each ``notebooks/*.ipynb`` as a page (markdown cells as written, code cells as
  code blocks; the notebooks are committed without outputs and are not executed here);
- ``changelog.md``: ``CHANGELOG.md``.

Nothing is copied into ``docs/`` on disk: the pages exist only in the build, and the
repository's files they come from are what ``docs/`` links to (``hooks.py`` rewrites those
links to these pages).  The reference pages generated from the code (scene keys, command
reference) are committed instead, so that they read in the repository too:
``reference_pages.py``.
"""

from __future__ import annotations

import json
import re
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
    ("main_job_schemes", "benchmarks/main_job_schemes.py"),
    ("main_job_clouds", "benchmarks/main_job_clouds.py"),
    ("main_job", "benchmarks/main_job.py"),
    ("scheme_front", "benchmarks/scheme_front.py"),
    ("continuum_front", "benchmarks/continuum_front.py (from a jaxanm sweep)"),
    ("anm_vs_mnewton_fine", "benchmarks/anm_vs_mnewton_fine.py"),
    ("start_from_rest", "benchmarks/start_from_rest.py"),
    ("stiff_controller", "benchmarks/stiff_controller.py"),
    ("process_window", "benchmarks/process_window.py (from a jaxanm sweep)"),
    ("window_corners", "benchmarks/window_corners.py"),
    ("window_limits", "benchmarks/window_limits.py"),
    ("heat_peclet", "benchmarks/heat_peclet.py"),
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


results_pages()
notebook_pages()
changelog_page()
