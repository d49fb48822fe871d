"""Fixtures that run once per test run, shared by the xdist workers."""

import dataclasses
import fcntl
import os
import pickle
import shutil
from pathlib import Path


def shared_once(tmp_path_factory, name: str, make):
    """``make(directory) -> result`` run once per test run, whichever xdist worker asks first, and
    a private copy for each worker that asks: ``(copy directory, result)``.

    A module-scoped fixture is made once *per worker*: an expensive one (a Dask sweep) then runs
    twice on two workers.  Here the first worker makes it under an exclusive lock in the run's
    shared temporary directory and pickles the result; the others wait on the lock and read it.
    Each worker gets its own copy of the directory (tests may write into it), and the result's
    paths into the shared directory are moved to the copy.
    """
    base = tmp_path_factory.getbasetemp()
    shared_root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    shared = shared_root / f"shared-{name}"
    with open(shared_root / f"shared-{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if not (shared / "result.pkl").is_file():
            build = shared_root / f"shared-{name}.build"
            shutil.rmtree(build, ignore_errors=True)
            build.mkdir()
            result = make(build)
            (build / "result.pkl").write_bytes(pickle.dumps((build, result)))
            build.rename(shared)
    made_in, result = pickle.loads((shared / "result.pkl").read_bytes())
    copy = tmp_path_factory.mktemp(name)
    shutil.copytree(shared, copy, dirs_exist_ok=True)

    def moved(value):
        if isinstance(value, Path) and value.is_relative_to(made_in):
            return copy / value.relative_to(made_in)
        return value

    if dataclasses.is_dataclass(result):
        result = dataclasses.replace(result, **{f.name: moved(getattr(result, f.name))
                                                for f in dataclasses.fields(result)})
    return copy, result
