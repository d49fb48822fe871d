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
from collections.abc import Iterator
from pathlib import Path

import jax
import numpy as np

from .errors import InputError

FORMAT_VERSION = 1


def to_host(tree):
    """The pytree with every array leaf as a numpy array (picklable, exact)."""
    return jax.tree_util.tree_map(lambda a: np.asarray(a) if hasattr(a, "shape") else a, tree)


@contextlib.contextmanager
def atomic_path(path, prefix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success move it onto ``path`` atomically.

    The temporary file (named ``prefix`` + random, default ``.<name>.`` + random + ``.tmp``) is
    created in the destination directory (so ``os.replace`` is an atomic rename on the same
    file system) and removed if the ``with`` block raises: a reader never sees a half-written
    file, and a failed write leaves the old one in place.  The one atomic write of jaxanm
    (checkpoints, and every output file: :mod:`jaxanm.fsw.io.output`, the sweeps).
    """
    path = Path(path)
    if prefix is None:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    else:
        fd, name = tempfile.mkstemp(dir=path.parent, prefix=prefix)
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_atomic(path, payload: dict) -> None:
    """Pickle ``payload`` to ``path`` atomically (:func:`atomic_path`), synced to disk first."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path, prefix=".ckpt-") as tmp:
        with open(tmp, "wb") as fh:
            pickle.dump({"format": FORMAT_VERSION, **payload}, fh, protocol=pickle.HIGHEST_PROTOCOL)
            fh.flush()
            os.fsync(fh.fileno())


def read(path) -> dict:
    """Load a checkpoint written by :func:`write_atomic`; checks the format version.

    Raises :class:`~jaxanm.errors.InputError` if the file is missing, is not a jaxanm
    checkpoint, or has another format version.
    """
    try:
        with open(path, "rb") as fh:
            payload = pickle.load(fh)
    except FileNotFoundError as exc:
        raise InputError(f"no checkpoint at {path}: nothing to resume (start the run without resume)") from exc
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, IndexError) as exc:
        raise InputError(f"{path} is not a readable jaxanm checkpoint ({type(exc).__name__}: {exc}); if another "
                         "jaxanm version wrote it (classes it stores may have moved), resume it with that "
                         "version, or start afresh") from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT_VERSION:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise InputError(f"checkpoint {path} has format {found!r}, this jaxanm reads {FORMAT_VERSION}; "
                         "resume it with the jaxanm version that wrote it, or start afresh")
    return payload


class Interrupted(KeyboardInterrupt):
    """Raised inside a run when SIGTERM arrives, so that the run can checkpoint and stop."""


class SignalGuard:
    """Defers SIGINT/SIGTERM while a run records an accepted step (see :func:`sigterm_as_interrupt`).

    Between :meth:`hold` and :meth:`release` a signal does not interrupt: it is remembered and
    raised by :meth:`release`, so an interruption never falls between accepting a step and
    recording it (the state written to a checkpoint is then always one consistent step).
    ``held`` is true inside such a block; a run that fails there (an exception from its own
    bookkeeping, not from a signal) must not write a checkpoint of a half-recorded step.
    """

    def __init__(self):
        self.held = False
        self.pending = None

    def hold(self) -> None:
        """Start a block in which signals are deferred."""
        self.held = True

    def release(self) -> None:
        """End the block; raise the interruption that arrived during it, if any."""
        self.held = False
        if self.pending is not None:
            exc, self.pending = self.pending, None
            raise exc

    def _handler(self, signum, frame):
        exc = Interrupted(f"received signal {signum}") if signum == signal.SIGTERM else KeyboardInterrupt()
        if self.held:
            self.pending = exc
            return
        raise exc


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Turn SIGTERM into :class:`Interrupted` for the duration of the block; yield a :class:`SignalGuard`.

    SIGINT keeps raising ``KeyboardInterrupt`` (its handler is replaced only if it is Python's
    default one), and both signals are deferred inside ``guard.hold() ... guard.release()``.
    Outside the main thread signals are left alone and the guard never defers.
    """
    guard = SignalGuard()
    try:
        previous_term = signal.signal(signal.SIGTERM, guard._handler)
    except ValueError:  # not in the main thread: leave signals alone
        yield guard
        return
    previous_int = signal.getsignal(signal.SIGINT)
    own_int = previous_int is signal.default_int_handler
    if own_int:
        signal.signal(signal.SIGINT, guard._handler)
    try:
        yield guard
    finally:
        signal.signal(signal.SIGTERM, previous_term)
        if own_int:
            signal.signal(signal.SIGINT, previous_int)
