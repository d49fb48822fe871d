"""The checkpoint file format: arrays in an npz read with ``allow_pickle=False`` and the
structure as JSON, so that reading a checkpoint never runs code from it.  Every stored type
comes back exactly; pickles, unknown types, damaged files and another format are refused
with an InputError naming the file.  (Resuming bit-identically is tested end to end in
test_checkpoint.py, test_cli.py, test_fsw_rezone.py and test_fsw_start.py.)"""

from __future__ import annotations

import json
import pickle
import re
import zipfile

import numpy as np
import pytest
import scipy.sparse

import jaxanm
import jaxanm.fsw  # noqa: F401  (registers the FSW types)
from jaxanm import cli
from jaxanm.checkpoint import FORMAT_VERSION, STRUCTURE_KEY, read, stored_types, write_atomic
from jaxanm.fsw.discretisation import Refit
from jaxanm.fsw.start import StartReport
from jaxanm.internal import sparse_lu
from jaxanm.mls import NeighbourList

MARKS: list = []
"""Appended to by :func:`_mark`: it stays empty unless a test file got unpickled."""


def _mark():
    MARKS.append("unpickled")
    return "ran"


class _Payload:
    """Unpickling this calls :func:`_mark` (what a malicious pickle would do, harmlessly)."""

    def __reduce__(self):
        return (_mark, ())


def _same(a, b) -> bool:
    """``a`` and ``b`` equal with the same types all the way down (arrays: dtype and bits)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()
    if isinstance(a, np.generic):
        return a.dtype == b.dtype and a.tobytes() == b.tobytes()
    if scipy.sparse.issparse(a):
        return a.shape == b.shape and all(_same(getattr(a, p), getattr(b, p)) for p in ("data", "indices", "indptr"))
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, float) and np.isnan(a):
        return bool(np.isnan(b))
    if hasattr(a, "to_plain"):
        return _same(a.to_plain(), b.to_plain())
    return a == b


def _matrix(n=6):
    rng = np.random.default_rng(0)
    return (scipy.sparse.random(n, n, density=0.3, random_state=rng) + 4.0 * scipy.sparse.eye(n)).tocsc()


def _registered_examples() -> dict:
    """A populated instance of every registered type, by its stored name."""
    stats = jaxanm.Stats(factorizations=3, time_steps=2, amax=[np.float64(0.25), 0.5], orders=[5, 7],
                         step_sizes=[1e-3, 2e-3], wall_time_s=1.5)
    neighbours = NeighbourList(skin=0.05)
    points = np.random.default_rng(1).uniform(size=(40, 2))
    neighbours.query(points, np.full(40, 0.2), None)
    refit = Refit(refresh=5)
    refit.matrix, refit.iterations, refit.factorizations = _matrix(), [0, 3, 2], 1
    report = StartReport(iterations=2, step_lengths=[1.0, 0.5], residual_norms=[1.0, 1e-3, 1e-9], stats=stats,
                         path=[(1.0, 0.0, 3), (2.0, 0.5, 2)])
    return {"Stats": stats, "mls.NeighbourList": neighbours, "fsw.Refit": refit, "fsw.StartReport": report}


def test_every_registered_type_and_plain_value_round_trips_exactly(tmp_path):
    examples = _registered_examples()
    assert set(examples) == set(stored_types())  # a new stored type needs its example here
    plain = {
        "none": None, "flag": True, "int": 2**70, "float": 0.1, "inf": float("inf"), "nan": float("nan"),
        "text": "é", "list": [1, [2.5, "x"]], "tuple": (1, (2.0, None)), "empty": ((), [], {}),
        "odd keys": {1: "int", (2, "a"): "tuple", "$dollar": "escaped", 2.5: None},
        "scalars": [np.float64(1 / 3), np.float32(0.1), np.int64(-7), np.int32(3), np.bool_(True),
                    np.complex128(1 - 2j), np.uint8(255)],
        "history": [np.float64(1 / 3), np.float64(-0.0), np.float64(np.nan)],  # one type: stored as one array
        "mixed": [np.float64(1.5), 1.5],
        "arrays": [np.arange(6.0).reshape(2, 3) / 7, np.arange(4, dtype=np.int32), np.array(2.0),
                   np.zeros((0, 3)), np.array([1 + 1j]), np.array([True, False])],
        "sparse": [_matrix(), _matrix().tocsr(), scipy.sparse.csc_matrix((3, 3))],
        "objects": examples,
    }
    path = tmp_path / "c.ckpt"
    write_atomic(path, plain)
    back = read(path)
    assert back.pop("format") == FORMAT_VERSION
    assert _same(back, plain)
    # what they do afterwards, too: the refit's factors are remade from the stored matrix
    # (the same factors: its solves are bit-identical), the neighbour list gives the same stencils
    restored = back["objects"]
    b = np.arange(6.0)
    assert restored["fsw.Refit"]._lu.solve(b).tobytes() == sparse_lu(examples["fsw.Refit"].matrix).solve(b).tobytes()
    points = np.random.default_rng(1).uniform(size=(40, 2)) * 1.001
    for x, y in zip(restored["mls.NeighbourList"].query(points, np.full(40, 0.2), None),
                    examples["mls.NeighbourList"].query(points, np.full(40, 0.2), None)):
        assert _same(x, y)


def test_the_file_is_an_npz_of_plain_arrays_and_json(tmp_path):
    path = tmp_path / "c.ckpt"
    write_atomic(path, {"x": np.ones(3), "stats": jaxanm.Stats(), "probe": [np.float64(1.0), np.float64(2.0)]})
    with np.load(path, allow_pickle=False) as archive:
        assert sorted(archive.files) == ["a0", "a1", STRUCTURE_KEY]
        header = json.loads(archive[STRUCTURE_KEY].tobytes())
        assert archive["a1"].tolist() == [1.0, 2.0]
    assert header["kind"] == "jaxanm checkpoint" and header["format"] == FORMAT_VERSION
    assert header["payload"]["x"] == {"$array": "a0"} and header["payload"]["stats"]["$object"] == "Stats"
    assert header["payload"]["probe"] == {"$scalars": "a1"}  # a history of numpy scalars: one array


def test_what_cannot_be_stored_is_refused_when_writing(tmp_path):
    path = tmp_path / "c.ckpt"
    with pytest.raises(TypeError, match=r"\$\.host\.hook: a builtins.function cannot be stored"):
        write_atomic(path, {"host": {"hook": lambda: 0}})
    with pytest.raises(TypeError, match=r"\$\.a: an array of objects"):
        write_atomic(path, {"a": np.array([None, 1], dtype=object)})
    assert not path.exists()


def _forge(path, payload: dict, arrays: dict | None = None, fmt=FORMAT_VERSION):
    """A checkpoint file with a hand-made header and arrays (np.savez may pickle objects)."""
    header = {"kind": "jaxanm checkpoint", "format": fmt, "payload": payload}
    with open(path, "wb") as fh:
        np.savez(fh, **{STRUCTURE_KEY: np.frombuffer(json.dumps(header).encode(), np.uint8)}, **(arrays or {}))


@pytest.mark.parametrize("payload, arrays, expected", [
    ({"x": {"$array": "a0"}}, {"a0": np.array([_Payload()], dtype=object)}, "Object arrays cannot be loaded"),
    ({"x": {"$object": "os.system", "state": {}}}, None, "unknown stored type 'os.system'"),
    ({"x": {"$eval": "print(1)"}}, None, "unknown entry '$eval'"),
    ({"x": {"$array": "a7"}}, None, "refers to array 'a7'"),
    ({"x": {"$scalar": "|O", "hex": "00"}}, None, "dtype object"),
])
def test_a_pickle_or_an_unknown_type_inside_the_file_is_refused(tmp_path, payload, arrays, expected):
    path = tmp_path / "c.ckpt"
    _forge(path, payload, arrays)
    with pytest.raises(jaxanm.InputError, match=re.escape(f"{path} is not a readable jaxanm checkpoint")) as info:
        read(path)
    assert expected in str(info.value) and "start the run afresh" in str(info.value)
    assert MARKS == []  # nothing was unpickled


def test_another_format_version_is_refused(tmp_path):
    path = tmp_path / "c.ckpt"
    _forge(path, {"version": 9}, fmt=FORMAT_VERSION + 1)
    with pytest.raises(jaxanm.InputError, match=f"has format {FORMAT_VERSION + 1}, this jaxanm reads {FORMAT_VERSION}"):
        read(path)


def _written(tmp_path):
    path = tmp_path / "c.ckpt"
    write_atomic(path, {"x": np.linspace(0.0, 1.0, 500), "stats": jaxanm.Stats(time_steps=4)})
    return path, path.read_bytes()


def test_a_truncated_file_is_refused_naming_it_and_the_way_on(tmp_path):
    path, data = _written(tmp_path)
    for size in (len(data) // 2, len(data) - 10, 3):
        path.write_bytes(data[:size])
        with pytest.raises(jaxanm.InputError) as info:
            read(path)
        message = str(info.value)
        assert f"{path} is not a readable jaxanm checkpoint" in message
        assert "truncated, damaged or no checkpoint: start the run afresh" in message


def test_an_altered_array_is_refused(tmp_path):
    """The archive's CRC-32 of each entry catches a changed byte of the stored arrays."""
    path, data = _written(tmp_path)
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo("a0.npy")
    at = info.header_offset + 30 + len(info.filename) + len(info.extra) + 200  # inside the array's data
    path.write_bytes(data[:at] + bytes([data[at] ^ 1]) + data[at + 1:])
    with pytest.raises(jaxanm.InputError, match="Bad CRC-32"):
        read(path)


def test_a_pickle_checkpoint_of_an_older_version_is_refused_unopened(tmp_path, capsys):
    path = tmp_path / "run.ckpt"
    with open(path, "wb") as fh:  # what jaxanm wrote before: one pickle of the payload
        pickle.dump({"format": 1, "version": 3, "hook": _Payload()}, fh, protocol=pickle.HIGHEST_PROTOCOL)
    expected = f"{path} is a checkpoint in the pickle format of an older jaxanm version"
    with pytest.raises(jaxanm.InputError, match=re.escape(expected)):
        read(path)
    with pytest.raises(jaxanm.InputError, match="finish that run with the jaxanm version that wrote it"):
        jaxanm.stored_host_state(path)
    # the command line: an output directory holding an old checkpoint.pkl
    path.rename(tmp_path / cli.OLD_CHECKPOINT_NAME)
    assert cli.main(["run", "--resume", str(tmp_path), "--no-progress"]) == 2
    assert "checkpoint.pkl is a pickle checkpoint of an older jaxanm version" in capsys.readouterr().err
    assert MARKS == []


def test_parameters_are_stored_as_leaves_and_resumed_in_the_runs_tree(tmp_path):
    """The parameters are stored as their leaves (plain arrays, whatever the pytree) and put
    back into the tree of the parameters the resumed run is given; a tree with another number
    of leaves is refused, naming the file."""
    from model_problems import heat_1d

    residual, x0, params = heat_1d(4)
    path = tmp_path / "run.ckpt"
    kw = dict(t0=0.0, t1=0.05, dt=1e-2, solver=jaxanm.Newton(), checkpoint=path)
    jaxanm.integrate(residual, x0, params, saveat=jaxanm.SaveAt(steps=2, params=True), **kw)
    stored = read(path)
    leaves = [np.asarray(params["c"]), np.asarray(params["r"])]  # jax.tree_util order (sorted keys), on the host
    assert _same(stored["params"], leaves)
    assert len(stored["ps"]) == 4 and all(_same(p, leaves) for p in stored["ps"])
    with pytest.raises(jaxanm.InputError, match=re.escape(f"checkpoint {path} stores parameters of 2 arrays, "
                                                          "this run's have 3")):
        jaxanm.integrate(residual, x0, {**params, "extra": np.float64(0.0)}, resume=True, **kw)


def test_the_package_never_unpickles():
    """No module of jaxanm loads a pickle or lets numpy do so: every file it reads is data."""
    from pathlib import Path

    package = Path(jaxanm.__file__).parent
    offenders = [f"{path.relative_to(package.parent)}:{n}" for path in sorted(package.rglob("*.py"))
                 for n, line in enumerate(path.read_text().splitlines(), 1)
                 if re.search(r"pickle\.(load|loads|Unpickler)\b|allow_pickle\s*=\s*True|import (cloud|dill)", line)]
    assert not offenders, "unpickling at " + ", ".join(offenders)
