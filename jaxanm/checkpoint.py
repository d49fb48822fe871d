"""Checkpoints of a run: atomic writes, resumable state, and signal-safe interruption.

A checkpoint is one pickle file holding everything a run needs to continue exactly where it
stopped: the step index, time, state, parameters, what was saved so far, the statistics, and
the matrix of the current K* (re-factorised on resume, so the continued run is bit-identical
to an uninterrupted one).  It is written to a temporary file in the same directory and moved
into place with ``os.replace``, so a crash never leaves a half-written checkpoint.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import tempfile

import jax
import numpy as np

FORMAT_VERSION = 1


def to_host(tree):
    """The pytree with every array leaf as a numpy array (picklable, exact)."""
    return jax.tree_util.tree_map(lambda a: np.asarray(a) if hasattr(a, "shape") else a, tree)


def write_atomic(path, payload: dict) -> None:
    """Pickle ``payload`` to ``path`` atomically (temporary file + ``os.replace``)."""
    path = os.fspath(path)
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=".ckpt-", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            pickle.dump({"format": FORMAT_VERSION, **payload}, fh, protocol=pickle.HIGHEST_PROTOCOL)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def read(path) -> dict:
    """Load a checkpoint written by :func:`write_atomic`; checks the format version."""
    with open(path, "rb") as fh:
        payload = pickle.load(fh)
    if payload.get("format") != FORMAT_VERSION:
        raise ValueError(f"checkpoint {path} has format {payload.get('format')!r}, this jaxanm reads {FORMAT_VERSION}")
    return payload


class Interrupted(KeyboardInterrupt):
    """Raised inside a run when SIGTERM arrives, so that the run can checkpoint and stop."""


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Turn SIGTERM into :class:`Interrupted` for the duration of the block (main thread only)."""
    try:
        previous = signal.signal(signal.SIGTERM, _raise_interrupted)
    except ValueError:  # not in the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _raise_interrupted(signum, frame):
    raise Interrupted(f"received signal {signum}")
