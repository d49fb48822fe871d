"""The whole ``jaxanm run`` command from an empty compile cache, and again with it filled.

Each repeat runs, in fresh processes one after the other, ``jaxanm run SCENE --t-end T``
(default: the main job, one step) with ``JAXANM_COMPILE_CACHE_DIR`` pointing at a new empty
directory (*cold*: everything is traced and compiled), then the same command again on that
directory (*warm*: what a second run on the machine costs).  The walls are of the whole
command (interpreter start, imports, scene, cloud, start flow, the step, the files written).
Every compilation is logged (``JAX_LOG_COMPILES=1``): the cold run's compilations are
counted and summed per compiled function, which says what is compiled and why.

    python benchmarks/cold_start.py [--scene fsw] [--t-end 1e-4] [--repeats 3] \
        [--label after] [--out benchmarks/results/cold_start]

Another checkout is measured with ``--jaxanm /path/to/checkout/.venv/bin/jaxanm`` (its own
command and code).  Writes ``OUT.json`` (one entry per label, earlier labels kept) and
``OUT.md`` (every label).
"""

from __future__ import annotations

import argparse
import collections
import datetime
import json
import os
import pathlib
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = pathlib.Path(__file__).resolve().parent
COMPILED = re.compile(r"Finished XLA compilation of (\S+) in ([0-9.]+) sec")


def one_run(command: list, cache: str, log: pathlib.Path) -> dict:
    """The wall of ``command`` with the compile cache in ``cache``, and its compilations."""
    env = dict(os.environ, JAXANM_COMPILE_CACHE_DIR=cache, JAX_LOG_COMPILES="1", JAXANM_COMPILE_CACHE="1")
    load = os.getloadavg()[0]
    start = time.perf_counter()
    with open(log, "w") as out:
        done = subprocess.run(command, env=env, stdout=out, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - start
    if done.returncode:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}): see {log}")
    compiles = COMPILED.findall(log.read_text())
    per_function: dict = collections.defaultdict(lambda: [0, 0.0])
    for name, seconds in compiles:
        per_function[name][0] += 1
        per_function[name][1] += float(seconds)
    return {"wall_s": wall, "load": [load, os.getloadavg()[0]], "compilations": len(compiles),
            "compile_s": sum(float(s) for _, s in compiles),
            "per_function": {k: {"count": c, "seconds": round(s, 3)}
                             for k, (c, s) in sorted(per_function.items(), key=lambda kv: -kv[1][1])}}


def table(entries: dict) -> str:
    """The markdown tables of every label."""
    lines = ["| label | commit | scene, t_end | cold wall s (median; runs) | warm wall s (median; runs) | "
             "compilations cold / warm | XLA compile s cold | load |",
             "| --- | --- | --- | ---: | ---: | ---: | ---: | --- |"]
    for label, e in entries.items():
        cold, warm = e["cold"], e["warm"]
        loads = [r["load"][0] for r in cold + warm]
        cold_walls, warm_walls = ([r["wall_s"] for r in runs] for runs in (cold, warm))
        lines.append(
            f"| {label} | {e['commit']} | {e['scene']}, {e['t_end']:g} | "
            f"**{statistics.median(cold_walls):.1f}** ({', '.join(format(w, '.1f') for w in cold_walls)}) | "
            f"{statistics.median(warm_walls):.1f} ({', '.join(format(w, '.1f') for w in warm_walls)}) | "
            f"{cold[0]['compilations']} / {warm[0]['compilations']} | "
            f"{statistics.median(r['compile_s'] for r in cold):.1f} | "
            f"{min(loads):.1f}-{max(loads):.1f} |")
    for label, e in entries.items():
        lines += ["", f"**{label}**: compilations of the first cold run, per compiled function", "",
                  "| function | compilations | XLA seconds |", "| --- | ---: | ---: |"]
        lines += [f"| `{name}` | {d['count']} | {d['seconds']:.2f} |"
                  for name, d in e["cold"][0]["per_function"].items()]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="fsw")
    ap.add_argument("--t-end", type=float, default=1e-4)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--label", required=True)
    ap.add_argument("--jaxanm", default=str(pathlib.Path(sys.executable).parent / "jaxanm"),
                    help="the jaxanm command to run (another checkout's, for a before/after)")
    ap.add_argument("--out", default=str(HERE / "results" / "cold_start"))
    a = ap.parse_args(argv)
    checkout = pathlib.Path(a.jaxanm).resolve().parents[2]
    commit = subprocess.run(["git", "-C", str(checkout), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()
    work = pathlib.Path(tempfile.mkdtemp(prefix="cold_start_"))
    entry = {"date": datetime.date.today().isoformat(), "commit": commit, "cpus": os.cpu_count(),
             "scene": a.scene, "t_end": a.t_end, "command": a.jaxanm, "cold": [], "warm": []}
    try:
        for r in range(a.repeats):
            cache = work / f"cache{r}"
            command = [a.jaxanm, "run", a.scene, "--t-end", repr(a.t_end), "--out", str(work / f"out{r}"),
                       "--no-progress"]
            for kind in ("cold", "warm"):
                row = one_run(command, str(cache), work / f"{kind}{r}.log")
                entry[kind].append(row)
                print(f"{a.label} {kind} #{r}: {row['wall_s']:.1f} s, {row['compilations']} compilations "
                      f"({row['compile_s']:.1f} s), load {row['load'][0]:.1f}", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    out = pathlib.Path(a.out)
    path = out.with_suffix(".json")
    entries = json.loads(path.read_text()) if path.exists() else {}
    entries[a.label] = entry
    path.write_text(json.dumps(entries, indent=1))
    out.with_suffix(".md").write_text(
        "# The whole `jaxanm run` command from an empty compile cache (`benchmarks/cold_start.py`)\n\n"
        "Cold: a new empty `JAXANM_COMPILE_CACHE_DIR`; warm: the same command again on it. Whole-command "
        "walls of fresh processes; compilations from `JAX_LOG_COMPILES=1`.\n\n" + table(entries) + "\n")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
