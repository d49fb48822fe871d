"""Every effect lives in one record (jaxanm.fsw.effects.REGISTRY), and every reader of effects
reads it: scene validation, the residual's flags and constants, the unknown layout, the start
flow, the temperature guard.  A record without its rows, a parameter without its scene field
or constant, or a name checked in the code that no record holds fails here.
"""

from __future__ import annotations

import ast
import dataclasses
import re
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import jaxanm
from jaxanm.fsw import effects as fx
from jaxanm.fsw.discretisation import discretise
from jaxanm.fsw.physics import CONSTANTS
from jaxanm.fsw.scene import Scene, SceneError, override_keys
from jaxanm.fsw.stability import TemperatureGuard
from jaxanm.fsw.start import flow_scene

FSW = Path(jaxanm.__file__).parent / "fsw"
DOCS = Path(__file__).resolve().parents[1] / "docs"


def _on(name: str) -> tuple:
    """The smallest effect list with ``name`` and what it requires (requirements first)."""
    out: list = []

    def add(e):
        for r in fx.REGISTRY[e].requires:
            add(r)
        if e not in out:
            out.append(e)

    add(name)
    return tuple(out)


def _excluded(a: str, b: str) -> bool:
    return any(o == b for o, _ in fx.REGISTRY[a].excludes) or any(o == a for o, _ in fx.REGISTRY[b].excludes)


def _needs(a: str, b: str) -> bool:
    return b in fx.REGISTRY[a].requires or any(_needs(r, b) for r in fx.REGISTRY[a].requires)


def _context(name: str) -> tuple:
    """Every effect that can be listed beside ``name`` and does not need it, so that the terms an
    effect adds to (transport terms to the inertia and heat rows, say) are all there; of effects
    that exclude each other, the one excluding most goes (with what needs it)."""
    out = [e for e in fx.EFFECTS if e != name and not _needs(e, name) and not _excluded(e, name)]
    while True:
        clashes = {e: sum(_excluded(e, o) for o in out) for e in out}
        worst = max(clashes, key=clashes.get)
        if not clashes[worst]:
            return tuple(out)
        out = [e for e in out if e != worst and not _needs(e, worst)]


def _default(key: str):
    section, field = key.split(".")
    return Scene().to_dict()[section][field]


def _on_values(name: str, effects: tuple) -> dict:
    """Values of ``name``'s parameters in their ranges and off their defaults (the effect then
    acts) that a scene listing ``effects`` accepts (the effect's own checks across fields)."""
    values: dict = {}
    for p in fx.REGISTRY[name].parameters:
        for f in (0.7, 0.3, 0.1, 0.03, 0.01, 0.003):
            value = p.low + f * (p.high - p.low)
            if value == _default(p.key):
                continue
            try:
                _scene(effects, {**values, p.key: value})
            except SceneError:
                continue
            values[p.key] = value
            break
        else:
            raise AssertionError(f"no value of {p.key} in its range is accepted")
    return values


TINY = {"geometry.dr": 1.125e-3, "geometry.c": 0.3}
"""A 113-point cloud: rows differ or not the same on any cloud."""


def _scene(effects: tuple, values: dict | None = None) -> Scene:
    return Scene(effects=effects).with_overrides({**TINY, **(values or {})})


def _rows(scene: Scene) -> np.ndarray:
    """The residual at a fixed random state near the initial one (every row's terms exercised)."""
    cloud, st, model, params, x0 = discretise(scene)
    rng = np.random.default_rng(3)
    scale = model.scale()
    x = x0 + 0.05 * scale * rng.standard_normal(x0.size)
    x_old = x0 + 0.05 * scale * rng.standard_normal(x0.size)
    with jaxanm.float64():
        return np.asarray(model.residual(jnp.asarray(x), jnp.asarray(x_old), 1e-3, 1e-3, params))


def test_every_record_is_complete():
    """Names match their keys; requirements and exclusions name records; roles are known ones;
    parameters name a scene key, a constant of the residual and a finite range."""
    assert fx.EFFECTS == tuple(fx.REGISTRY)
    keys = set(override_keys())
    for name, e in fx.REGISTRY.items():
        assert e.name == name and e.doc
        assert set(e.requires) <= set(fx.EFFECTS), name
        assert all(other in fx.EFFECTS and why for other, why in e.excludes), name
        assert set(e.roles) <= set(fx.ROLES), name
        assert set(e.fields) <= set(fx.FIELDS), name
        for p in e.parameters:
            assert p.key in keys, (name, p.key)
            assert p.constant in CONSTANTS, (name, p.constant)
            assert np.isfinite(p.low) and np.isfinite(p.high) and p.low < p.high, (name, p.key)
    constants = [p.constant for e in fx.REGISTRY.values() for p in e.parameters]
    assert len(set(constants)) == len(constants) and not set(constants) & set(fx.BASE_CONSTANTS)


@pytest.mark.parametrize("name", fx.EFFECTS)
def test_every_effect_reaches_flags_fields_and_constants(name):
    """A scene listing the effect (and its requirements) has its flag on, its fields among the
    unknowns, and its parameters' values in ``params["c"]``."""
    effect = fx.REGISTRY[name]
    values = _on_values(name, _on(name))
    scene = _scene(_on(name), values)
    flags = fx.Effects.of(scene)
    assert getattr(flags, name) and not any(getattr(flags, o) for o in fx.EFFECTS if o not in _on(name))
    assert set(effect.fields) <= set(flags.fields)
    cloud, st, model, params, x0 = discretise(scene)
    assert set(params["c"]) == set(CONSTANTS)
    for p in effect.parameters:
        assert params["c"][p.constant] == np.float64(values[p.key])
    assert x0.size == len(flags.fields) * cloud.size


@pytest.mark.parametrize("name", [e for e in fx.EFFECTS if {"momentum rows", "heat rows"} & fx.REGISTRY[e].roles
                                  and "unknowns" not in fx.REGISTRY[e].roles])
def test_every_effect_with_rows_changes_the_residual(name):
    """Switching on an effect that adds rows changes the residual (its parameters off their
    defaults): a record whose rows were never written fails here."""
    base = _context(name)
    values = _on_values(name, base + (name,))
    without, with_ = _scene(base), _scene(base + (name,), values)
    assert not np.array_equal(_rows(without), _rows(with_)), name


def test_roles_drive_the_start_flow_and_the_guard():
    """The start flow keeps exactly the effects with the role ``start flow`` (and what they
    require); the guard leaves the upper bound open exactly for a ``heat source``."""
    full = tuple(e for e in fx.EFFECTS if e not in ("lagrangian",))
    values = {k: v for e in full for k, v in _on_values(e, full).items()}
    scene = _scene(full, values)
    kept = set(flow_scene(scene).effects)
    starts = {e for e in full if "start flow" in fx.REGISTRY[e].roles}
    assert kept == {"viscous"} | starts | {r for e in starts for r in fx.REGISTRY[e].requires}
    for name in fx.EFFECTS:
        if "conduction" not in _on(name) and name != "viscous":
            continue
        effects = tuple(dict.fromkeys(("viscous", "conduction") + _on(name)))
        if "lagrangian" in effects:
            continue
        model = discretise(_scene(effects))[2]
        assert TemperatureGuard(model).heated == ("heat source" in fx.REGISTRY[name].roles), name


def test_scene_validation_reads_the_records():
    """Unknown names, missing requirements, exclusions, parameters out of range or set without
    their effect: each refused naming the key, with the record's own words."""
    with pytest.raises(SceneError, match="unknown effect"):
        Scene(effects=("viscous", "sticking"))
    for name, e in fx.REGISTRY.items():
        for req in e.requires:
            effects = tuple(x for x in _on(name) if x != req and req not in fx.REGISTRY[x].requires)
            if name in effects:
                with pytest.raises(SceneError, match=re.escape(f"effect {name!r} needs")):
                    _scene(effects)
        for other, why in e.excludes:
            with pytest.raises(SceneError, match=re.escape(why[:40])):
                _scene(tuple(dict.fromkeys(_on(name) + _on(other))))
        for p in e.parameters:
            with pytest.raises(SceneError, match=re.escape(p.key) + ".*must be in"):
                _scene(_on(name), {p.key: p.high + (p.high - p.low)})
            base = tuple(x for x in ("viscous", "conduction") if x != name)
            with pytest.raises(SceneError, match=re.escape(p.key) + f".*does not list the '{name}' effect"):
                _scene(base, {p.key: _on_values(name, _on(name))[p.key]})


def _names_checked_in_code() -> set:
    """Effect names the package's code asks about: ``x.has("name")``, ``effects.name`` /
    ``flags.name`` attributes and ``getattr(effects, "name")``."""
    names = set()
    for path in FSW.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "has"
                    and node.args and isinstance(node.args[0], ast.Constant) and isinstance(node.args[0].value, str)):
                names.add(node.args[0].value)
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute)
                    and node.value.attr == "effects" and node.attr not in ("fields", "any", "names", "of")):
                names.add(node.attr)
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "flags" \
                    and node.attr not in ("fields", "any", "names", "of"):
                names.add(node.attr)
    return names


def test_every_name_the_code_checks_is_a_record():
    """No effect name in the code that the registry does not hold (a hidden list of names)."""
    names = _names_checked_in_code()
    assert names, "the scan found no effect checks: it is broken"
    assert names <= set(fx.EFFECTS), sorted(names - set(fx.EFFECTS))


def test_every_effect_is_documented():
    """The guide's effect table lists every record (and only them)."""
    text = (DOCS / "guide" / "scenes.md").read_text()
    section = text.split("## Effects", 1)[1].split("\n## ", 1)[0]
    listed = re.findall(r"^\| `(\w+)` \|", section, flags=re.M)
    assert listed == list(fx.EFFECTS)


def test_effects_flags_are_values():
    """Flags compare and hash by their names (one compiled residual per combination), pickle,
    and refuse unknown names and attributes."""
    import pickle

    a, b = fx.Effects(("viscous", "slip")), fx.Effects(["slip", "viscous"])
    assert a == b and hash(a) == hash(b) and pickle.loads(pickle.dumps(a)) == a
    assert a.slip and not a.traverse and a.fields == ("u", "v")
    with pytest.raises(jaxanm.InputError, match="unknown effects"):
        fx.Effects(("sticking",))
    with pytest.raises(AttributeError):
        a.sticking  # noqa: B018 - the attribute access is the test
    assert dataclasses.is_dataclass(fx.REGISTRY["slip"])
