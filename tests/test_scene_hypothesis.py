"""Property-based checks of scene validation: malformed scenes and TOML never escape as anything
but a :class:`SceneError` naming the offending field (or a valid scene).

Three generators: (1) a valid scene dictionary with one value replaced by a random value of a
random type (or a random unknown key added, or a section replaced by a non-table); (2) random
``--set``-style overrides (string values, as the command line gives them); (3) the TOML text
of a valid scene with random characters inserted, deleted or replaced.  Every case must end in
a :class:`Scene` (then re-validated by a round trip) or in a :class:`SceneError` whose message
names the field that was broken; any other exception fails the test.
"""

from __future__ import annotations

import math

import pytest
import tomli_w
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxanm.fsw.scene import Scene, SceneError, load_scene, override_keys

BASE = load_scene("fsw_small").to_dict()
SECTIONS = [k for k, v in BASE.items() if isinstance(v, dict)]
FIELDS = [(sec, key) for sec in SECTIONS for key in BASE[sec]]
SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

ANY_VALUE = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-10**30, max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
    st.lists(st.one_of(st.floats(allow_nan=False), st.text(max_size=3)), max_size=3),
    st.dictionaries(st.text(max_size=4), st.integers(), max_size=2),
)
NUMBER_LIKE = st.one_of(st.floats(min_value=-1e9, max_value=1e9), st.floats(min_value=-1e-2, max_value=1e-2),
                        st.integers(min_value=-5, max_value=50))


def _outcome(build, *names):
    """Run ``build()``: a valid Scene passes a round trip; a SceneError must name one of ``names``."""
    try:
        scene = build()
    except SceneError as exc:
        message = str(exc)
        assert any(name in message for name in names), f"{message!r} names none of {names}"
        return None
    assert isinstance(scene, Scene)
    assert Scene.from_dict(scene.to_dict()) == scene
    return scene


def _copy(d):
    return {k: (dict(v) if isinstance(v, dict) else [dict(x) for x in v] if isinstance(v, list)
                and v and isinstance(v[0], dict) else v) for k, v in d.items()}


@SETTINGS
@given(field=st.sampled_from(FIELDS), value=st.one_of(ANY_VALUE, NUMBER_LIKE))
def test_one_bad_section_value(field, value):
    sec, key = field
    data = _copy(BASE)
    data[sec][key] = value
    _outcome(lambda: Scene.from_dict(data), f"{sec}.{key}",
             # cross-field rules name the partner field; probes and sections name themselves
             *(f"{sec}.{other}" for other in BASE[sec]), "probes[", "sections[")


@SETTINGS
@given(key=st.sampled_from(["name", "effects", "probes", "sections", *SECTIONS]), value=ANY_VALUE)
def test_one_bad_top_level_value(key, value):
    data = _copy(BASE)
    data[key] = value
    names = (f"[{key}]", f"[[{key}]]", key)
    _outcome(lambda: Scene.from_dict(data), *names)


@SETTINGS
@given(where=st.sampled_from([None, *SECTIONS]), key=st.text(min_size=1, max_size=8), value=ANY_VALUE)
def test_unknown_keys_are_named(where, key, value):
    data = _copy(BASE)
    target = data if where is None else data[where]
    if key in target:
        return
    target[key] = value
    with pytest.raises(SceneError) as info:
        Scene.from_dict(data)
    assert repr(key) in str(info.value) and "known keys" in str(info.value)


@SETTINGS
@given(index=st.integers(0, 1), field=st.sampled_from(["name", "x", "y", "z"]), value=ANY_VALUE)
def test_bad_probe_entries(index, field, value):
    data = _copy(BASE)
    data["probes"][index][field] = value
    _outcome(lambda: Scene.from_dict(data), f"probes.{field}", f"probes[{index}]", "[[probes]]", "probes")


@SETTINGS
@given(items=st.dictionaries(st.sampled_from([*override_keys(), "material.nope", "bogus"]),
                             st.one_of(st.text(max_size=10), NUMBER_LIKE.map(repr)), min_size=1, max_size=3))
def test_random_set_overrides(items):
    scene = load_scene("fsw_small")
    _outcome(lambda: scene.with_overrides(items), "override key", *items,
             *(f"{k.split('.')[0]}." for k in items), "probes[", "sections[", "time.", "geometry.")


VALID_TOML = tomli_w.dumps(BASE)


@SETTINGS
@given(edits=st.lists(st.tuples(st.sampled_from(["insert", "delete", "replace"]),
                                st.floats(0, 1, exclude_max=True),
                                st.sampled_from(list("[]{}=\"',.#\n -_0123456789eEaxz") + ["inf", "nan", "true"])),
                      min_size=1, max_size=4))
def test_broken_toml_text(tmp_path_factory, edits):
    text = VALID_TOML
    for op, where, chars in edits:
        i = int(where * len(text))
        if op == "insert":
            text = text[:i] + chars + text[i:]
        elif op == "delete":
            text = text[:i] + text[i + len(chars):]
        else:
            text = text[:i] + chars + text[i + 1:]
    path = tmp_path_factory.mktemp("toml") / "scene.toml"
    path.write_text(text)
    try:
        scene = load_scene(path)
    except SceneError as exc:
        message = str(exc)
        assert str(path) in message or "scene field" in message or "name" in message, message
        return
    assert isinstance(scene, Scene)
    assert all(math.isfinite(v) for sec in SECTIONS for v in scene.to_dict()[sec].values()
               if isinstance(v, float))
