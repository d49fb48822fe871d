"""The differentiable parameters ``theta`` of a sensitivity run: checked and cast to float64,
bound into the residual's ``params`` by dotted paths (the default ``bind``), and the names of
their flattened components."""

from __future__ import annotations

import jax
import numpy as np

from .errors import InputError


def bind_paths(params, theta):
    """Default ``bind``: each key of ``theta`` is a dotted path to a leaf of nested dicts in params.

    ``bind_paths({"c": {"K": 1.0, "n": 0.3}}, {"c.n": 0.2})`` returns a copy of params with
    ``["c"]["n"] = 0.2``.  Traceable (used inside ``jax.jit``); only the dicts on the path are
    copied.
    """
    for key, value in theta.items():
        params = _set_path(params, key.split("."), value)
    return params


def _set_path(tree, path, value):
    """A copy of nested dicts ``tree`` with the leaf at ``path`` (a list of keys) set to ``value``."""
    head, rest = path[0], path[1:]
    new = dict(tree)
    new[head] = value if not rest else _set_path(tree[head], rest, value)
    return new


def check_paths(params, theta) -> None:
    """Every theta key names an existing floating leaf of nested dicts in ``params``."""
    for key in theta:
        node = params
        for part in key.split("."):
            if not (isinstance(node, dict) and part in node):
                known = sorted(_leaf_paths(params))
                raise InputError(
                    f"theta key {key!r} names no leaf of params (dotted path into nested dicts); known "
                    f"leaves: {known[:30]}{' ...' if len(known) > 30 else ''}; or pass bind=(params, theta) -> params")
            node = node[part]


def _leaf_paths(tree, prefix=""):
    """The dotted paths of the leaves of nested dicts ``tree``."""
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield from _leaf_paths(v, f"{prefix}{k}.")
    else:
        yield prefix[:-1]



def theta_float64(theta) -> dict:
    """``theta`` (a non-empty dict name -> real number or array) with float64 array values, or
    :class:`~jaxanm.InputError` naming the bad entry."""
    if not isinstance(theta, dict) or not theta:
        raise InputError("theta must be a non-empty dict name -> value of the differentiable parameters, "
                         f"got {theta!r}")
    out = {}
    for key, value in theta.items():
        arr = np.asarray(value)
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise InputError(f"theta[{key!r}] must be a real number or array, got {value!r}")
        arr = arr.astype(np.float64)
        if not np.all(np.isfinite(arr)):
            raise InputError(f"theta[{key!r}] = {value!r} is not finite")
        out[key] = arr
    return out


def theta_names(theta) -> list:
    """Names of the flattened components, in the order of ``ravel_pytree`` (sorted keys)."""
    names = []
    for path, value in jax.tree_util.tree_flatten_with_path(theta)[0]:
        key = path[0].key
        names += [key] if value.ndim == 0 else [f"{key}[{', '.join(map(str, i))}]" for i in np.ndindex(value.shape)]
    return names

