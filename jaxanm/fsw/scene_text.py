"""A scene as text: the description its TOML file opens with, and the whole resolved scene
written back as TOML (``jaxanm scenes`` and ``jaxanm scenes SCENE`` print them)."""

from __future__ import annotations

import json
import re
from pathlib import Path

__all__ = ["scene_description", "scene_toml"]


def scene_toml(scene) -> str:
    """``scene`` as a scene TOML file: every key with its value, each section key marked with
    the default it keeps or replaces (``# default`` / ``# default 0.1``); loads back to ``scene``."""
    data, defaults = scene.to_dict(), type(scene)().to_dict()
    lines = [f"name = {_toml_value(data['name'])}", f"effects = {_toml_value(data['effects'])}"]
    for section, table in data.items():
        if isinstance(table, dict):
            lines += ["", f"[{section}]"]
            for key, value in table.items():
                lines.append(f"{key} = {_toml_value(value)}  # {_default_note(scene, section, key, value, defaults)}")
    for key in ("probes", "sections"):
        for item in data[key]:
            lines += ["", f"[[{key}]]", *(f"{k} = {_toml_value(v)}" for k, v in item.items())]
    return "\n".join(lines)


def _default_note(scene, section: str, key: str, value, defaults: dict) -> str:
    """``default`` when ``value`` is the key's default, else ``default <it>``; a solver setting's
    default is the scene's solver's own (``not used by <kind>`` when that solver has no such option)."""
    if section == "solver" and key != "kind":
        by_kind = scene.solver.defaults(key)
        if scene.solver.kind not in by_kind:
            return f"not used by {scene.solver.kind}"
        default = by_kind[scene.solver.kind]
    else:
        default = defaults[section][key]
    return "default" if value == default else f"default {_toml_value(default)}"


def _toml_value(value) -> str:
    """A scene value (bool, number, string or list of them) as a TOML value."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, str):
        return json.dumps(value)  # a TOML basic string: the scene's names and choices are ASCII
    return repr(value)


def scene_description(path, width: int = 130) -> str:
    """The first sentence of the comment block that opens the scene TOML at ``path``, on one
    line of at most ``width`` characters (cut at a word, with "..."); ``""`` without one.
    """
    lines = []
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("#").strip())
    text = " ".join(lines).strip()
    match = re.match(r"(.+?[.!?])(?=\s+[A-Z(`]|\s*$)", text)  # "V . grad T" is no sentence end
    sentence = match.group(1) if match else text
    if len(sentence) > width:
        sentence = sentence[:width - 3].rsplit(" ", 1)[0].rstrip(",;:") + "..."
    return sentence
