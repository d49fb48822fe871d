"""integrate.on_device: params go to the device once per change, leaf by leaf."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxanm._run_inputs import on_device
from jaxanm._x64 import entry_point


@entry_point
def _transfer(params, previous=None):
    return on_device(params, previous)


def test_unchanged_leaves_keep_their_device_arrays():
    """A hook's rebuilt params: equal numpy leaves reuse the previous device arrays (the same
    objects, so no copy), changed ones, Python scalars and retyped leaves are transferred; all
    hold the new values with numpy's dtypes."""
    base = {"c": {"K": np.float64(2.0), "n": np.float64(0.13)}, "kind": np.arange(5), "xy": np.ones((5, 2)),
            "st": jnp.zeros(3), "w": 1.5}
    first = _transfer(base)
    rebuilt = {"c": {"K": np.float64(2.0), "n": np.float64(0.14)}, "kind": np.arange(5),
               "xy": np.ones((5, 2)) * 2, "st": jnp.ones(3), "w": 1.5}
    second = _transfer(rebuilt, first)
    assert second["c"]["K"] is first["c"]["K"] and second["kind"] is first["kind"]
    assert second["c"]["n"] is not first["c"]["n"] and second["xy"] is not first["xy"]
    assert second["st"] is rebuilt["st"]  # already on the device
    assert second["w"] is not first["w"]  # a Python scalar (weakly typed): always transferred
    for got, want in zip(jax.tree.leaves(second), jax.tree.leaves(rebuilt)):
        assert isinstance(got, jax.Array)
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    retyped = dict(rebuilt, kind=np.arange(5, dtype=np.int32))
    third = _transfer(retyped, second)
    assert third["kind"] is not second["kind"] and third["kind"].dtype == np.int32


def test_another_structure_is_transferred_whole():
    first = _transfer({"a": np.ones(2)})
    second = _transfer({"a": np.ones(2), "b": np.zeros(1)}, first)
    assert second["a"] is not first["a"]
    np.testing.assert_array_equal(np.asarray(second["b"]), np.zeros(1))
