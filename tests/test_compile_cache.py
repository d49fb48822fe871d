"""The jaxanm command's persistent compilation cache (jaxanm.compile_cache): on by default in a
per-user directory, off by option or environment."""

from __future__ import annotations

import pytest

from jaxanm import compile_cache


@pytest.mark.parametrize("value, on", [("1", True), ("0", False), ("off", False), (" No ", False), ("yes", True)])
def test_environment_turns_the_cache_off(monkeypatch, value, on):
    monkeypatch.setenv("JAXANM_COMPILE_CACHE", value)
    assert compile_cache.requested() is on


def test_default_directory_is_per_user_and_per_jax_version(monkeypatch, tmp_path):
    import jax

    monkeypatch.delenv("JAXANM_COMPILE_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert compile_cache.default_directory() == tmp_path / "jaxanm" / f"jax-{jax.__version__}"
    monkeypatch.setenv("JAXANM_COMPILE_CACHE_DIR", str(tmp_path / "mine"))
    assert compile_cache.default_directory() == tmp_path / "mine"
