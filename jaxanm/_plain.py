"""Plain data: a value as JSON text plus numpy arrays, and back, for files that cannot run code.

:func:`to_plain` turns a value into a JSON-able structure and a dict of numpy arrays the
structure refers to by key; :func:`from_plain` rebuilds the value.  Only these are stored:

- ``None``, ``bool``, ``int``, ``float``, ``str`` as JSON values (a float's ``repr`` reads back
  to the same bits; ``inf`` and ``nan`` as JSON's ``Infinity`` / ``NaN``);
- ``list`` as a JSON array, but a list of numpy scalars of one type (a probe's history) as
  ``{"$scalars": key}``, one array read back as that list; ``tuple`` as ``{"$tuple": [...]}``;
- ``dict`` as a JSON object when its keys are strings not starting with ``$``, otherwise as
  ``{"$items": [[key, value], ...]}``;
- numpy (or JAX) arrays as ``{"$array": key}`` (not of object dtype: they are read with
  ``allow_pickle=False``); numpy scalars as ``{"$scalar": dtype, "hex": bytes}`` (the exact
  bytes, so the value and its numpy type come back);
- scipy CSC/CSR matrices as ``{"$sparse": format, "shape", "data", "indices", "indptr"}``;
- an instance of a class registered with :func:`stored_type` as
  ``{"$object": name, "state": ...}``, its state being what its ``to_plain()`` returns and
  ``cls.from_plain(state)`` rebuilding it.

Nothing else is written (:class:`TypeError` naming where in the value), and reading names a
class only through the registry: a file cannot make the reader import or call anything else.
"""

from __future__ import annotations

from typing import Any, Callable

import jax
import numpy as np

_STORED: dict[str, type] = {}
_SPARSE = {"csc": "csc_matrix", "csr": "csr_matrix"}
_SCALAR_KINDS = "biufc"


class PlainDataError(ValueError):
    """A stored structure that is not one :func:`to_plain` writes (damaged or tampered)."""


def stored_type(name: str) -> Callable[[type], type]:
    """Class decorator: instances of the class may be stored under ``name``.

    The class defines ``to_plain(self) -> dict`` (its state as values :func:`to_plain`
    stores) and a classmethod ``from_plain(cls, state: dict)`` that rebuilds the instance
    exactly (a resumed run must go on bit-identically).  Registering another class under a
    name already taken is an error.
    """
    def register(cls: type) -> type:
        if not (callable(getattr(cls, "to_plain", None)) and callable(getattr(cls, "from_plain", None))):
            raise TypeError(f"{cls.__qualname__} needs to_plain() and from_plain() to be stored")
        known = _STORED.get(name)
        if known is not None and known.__qualname__ != cls.__qualname__:
            raise TypeError(f"stored type name {name!r} is taken by {known.__qualname__}")
        _STORED[name] = cls
        return cls

    return register


def stored_types() -> tuple[str, ...]:
    """The names of the registered classes, sorted."""
    return tuple(sorted(_STORED))


def to_plain(value: Any, arrays: dict[str, np.ndarray], where: str = "$"):
    """The JSON-able structure of ``value``; its arrays are added to ``arrays`` (module
    docstring).  :class:`TypeError` naming ``where`` for a value that cannot be stored."""
    if isinstance(value, np.generic):
        if value.dtype.kind not in _SCALAR_KINDS:
            raise TypeError(f"{where}: a numpy scalar of dtype {value.dtype} cannot be stored")
        return {"$scalar": value.dtype.str, "hex": value.tobytes().hex()}
    if type(value) in (bool, int, float, str) or value is None:
        return value
    if isinstance(value, (np.ndarray, jax.Array)):
        array = np.asarray(value)
        if array.dtype.hasobject:
            raise TypeError(f"{where}: an array of objects cannot be stored (it would need a pickle)")
        return {"$array": _array(array, arrays)}
    if type(value) is list:
        if value and isinstance(value[0], np.generic) and value[0].dtype.kind in _SCALAR_KINDS \
                and all(type(v) is type(value[0]) for v in value):
            return {"$scalars": _array(np.array(value), arrays)}
        return [to_plain(v, arrays, f"{where}[{i}]") for i, v in enumerate(value)]
    if type(value) is tuple:
        return {"$tuple": [to_plain(v, arrays, f"{where}[{i}]") for i, v in enumerate(value)]}
    if type(value) is dict:
        if all(isinstance(k, str) and not k.startswith("$") for k in value):
            return {k: to_plain(v, arrays, f"{where}.{k}") for k, v in value.items()}
        return {"$items": [[to_plain(k, arrays, f"{where}<key>"), to_plain(v, arrays, f"{where}[{k!r}]")]
                           for k, v in value.items()]}
    return _special_to_plain(value, arrays, where)


def _array(array: np.ndarray, arrays: dict) -> str:
    """The key of ``array``, added to ``arrays``."""
    key = f"a{len(arrays)}"
    arrays[key] = array
    return key


def _special_to_plain(value, arrays: dict, where: str):
    """A sparse matrix or a registered class's instance (:func:`to_plain`)."""
    for name, cls in _STORED.items():
        if type(value) is cls:
            state = value.to_plain()  # type: ignore[attr-defined]
            if type(state) is not dict:
                raise TypeError(f"{where}: {cls.__qualname__}.to_plain() must return a dict")
            return {"$object": name, "state": to_plain(state, arrays, f"{where}<{name}>")}
    fmt = str(getattr(value, "format", ""))
    if type(value).__name__ == _SPARSE.get(fmt) and type(value).__module__.startswith("scipy.sparse"):
        parts = ("data", "indices", "indptr")
        return {"$sparse": fmt, "shape": list(value.shape),
                **{part: to_plain(getattr(value, part), arrays, f"{where}.{part}") for part in parts}}
    raise TypeError(f"{where}: a {type(value).__module__}.{type(value).__qualname__} cannot be stored in a "
                    "checkpoint (plain data, numpy arrays and the registered types "
                    f"{', '.join(stored_types())} can)")


def from_plain(structure, arrays) -> Any:
    """The value :func:`to_plain` stored as ``structure`` with ``arrays`` (a mapping from key
    to array); :class:`PlainDataError` for anything :func:`to_plain` does not write."""
    if structure is None or type(structure) in (bool, int, float, str):
        return structure
    if type(structure) is list:
        return [from_plain(v, arrays) for v in structure]
    if type(structure) is not dict:
        raise PlainDataError(f"unexpected {type(structure).__name__} in the structure")
    markers = [k for k in structure if k.startswith("$")]
    if not markers:
        return {k: from_plain(v, arrays) for k, v in structure.items()}
    return _marked(markers[0], structure, arrays)


def _marked(marker: str, structure: dict, arrays):
    """The value of a ``{"$marker": ...}`` entry (:func:`from_plain`)."""
    content = structure[marker]
    if marker in ("$array", "$scalars"):
        if content not in arrays:
            raise PlainDataError(f"the structure refers to array {content!r}, which the file lacks")
        array = arrays[content]
        if marker == "$array":
            return array
        if array.ndim != 1 or array.dtype.kind not in _SCALAR_KINDS:
            raise PlainDataError(f"array {content!r} of dtype {array.dtype} cannot hold a list of scalars")
        return list(array)
    if marker == "$tuple":
        return tuple(from_plain(v, arrays) for v in content)
    if marker == "$items":
        return {_key(from_plain(k, arrays)): from_plain(v, arrays) for k, v in content}
    if marker == "$scalar":
        dtype = np.dtype(content)
        if dtype.kind not in _SCALAR_KINDS:
            raise PlainDataError(f"a numpy scalar of dtype {dtype} is not stored by jaxanm")
        return np.frombuffer(bytes.fromhex(structure["hex"]), dtype=dtype, count=1)[0]
    if marker == "$sparse":
        return _sparse(structure, arrays)
    if marker == "$object":
        cls = _STORED.get(content)
        if cls is None:
            raise PlainDataError(f"unknown stored type {content!r} (this jaxanm stores {', '.join(stored_types())})")
        state = from_plain(structure["state"], arrays)
        if type(state) is not dict:
            raise PlainDataError(f"the state of a stored {content} is not a dict")
        return cls.from_plain(state)  # type: ignore[attr-defined]
    raise PlainDataError(f"unknown entry {marker!r} in the structure")


def _key(key):
    """A dict key read back (a list, from a tuple key, is not hashable: refused)."""
    try:
        hash(key)
    except TypeError:
        raise PlainDataError(f"a dict key of type {type(key).__name__}") from None
    return key


def _sparse(structure: dict, arrays):
    """A scipy CSC/CSR matrix from its parts (:func:`from_plain`)."""
    import scipy.sparse

    fmt = structure["$sparse"]
    if fmt not in _SPARSE:
        raise PlainDataError(f"unknown sparse format {fmt!r}")
    parts = [from_plain(structure[part], arrays) for part in ("data", "indices", "indptr")]
    if not all(isinstance(p, np.ndarray) for p in parts):
        raise PlainDataError("a sparse matrix whose parts are not arrays")
    matrix = getattr(scipy.sparse, _SPARSE[fmt])(tuple(parts), shape=tuple(structure["shape"]))
    # the constructor may narrow the index dtype: keep the stored arrays as they were
    matrix.indices, matrix.indptr = parts[1], parts[2]
    return matrix
