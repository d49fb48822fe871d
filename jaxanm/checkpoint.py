"""Checkpoints of a run: atomic writes, resumable state, and signal-safe interruption.

A checkpoint holds everything a run needs to continue exactly where it stopped: the step
index, time, state, parameters, what was saved so far, the statistics, and the matrix of the
current K* (re-factorised on resume, so the continued run is bit-identical to an
uninterrupted one).  It is written to a temporary file in the same directory and moved into
place with ``os.replace``, so a crash never leaves a half-written checkpoint.

The file (format :data:`FORMAT_VERSION`) is an uncompressed ``.npz`` archive and cannot run
code when read:

- entry ``checkpoint.json`` (:data:`STRUCTURE_KEY`): UTF-8 JSON text, stored as a ``uint8``
  array, ``{"kind": "jaxanm checkpoint", "format": 2, "payload": ...}``;
- entries ``a0``, ``a1``, ...: the payload's numpy arrays, read with ``allow_pickle=False``.

The payload is plain data (JSON values, lists, tuples, dicts), arrays and numpy scalars, scipy
CSC/CSR matrices, and instances of the few classes registered with :func:`stored_type` (each
stored by its own ``to_plain`` / ``from_plain``: :class:`~jaxanm.Stats`,
:class:`~jaxanm.mls.NeighbourList`, the FSW refit and start report); the encoding is that of
:mod:`jaxanm._plain`.  A file that is missing, truncated, altered, of another format or kind,
names an unregistered class, or is a pickle written by an older jaxanm (format 1) is refused
with an :class:`~jaxanm.InputError` naming it and the way on.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import tempfile
import zipfile
from collections.abc import Callable, Iterator
from pathlib import Path

import jax
import numpy as np

from ._plain import PlainDataError, from_plain, stored_type, stored_types, to_plain
from .errors import InputError, RunInterrupted

__all__ = ["FORMAT_VERSION", "Interrupted", "SignalGuard", "atomic_path", "read", "sigterm_as_interrupt",
           "stored_type", "stored_types", "to_host", "write_atomic"]

FORMAT_VERSION = 2
"""The checkpoint file format this jaxanm writes and reads (1: a pickle, no longer read)."""
KIND = "jaxanm checkpoint"
"""The header's ``kind``: what marks a file as a jaxanm checkpoint."""
STRUCTURE_KEY = "checkpoint.json"
"""The archive entry holding the header (UTF-8 JSON as bytes)."""


def to_host(tree):
    """The pytree with every array leaf as a numpy array (storable, exact)."""
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
    """Write ``payload`` to ``path`` atomically (:func:`atomic_path`), synced to disk first.

    The file is an ``.npz`` (module docstring): the payload's arrays, and its structure as
    JSON with the format version.  :class:`TypeError` naming the entry if the payload holds
    something other than plain data, arrays and the registered types.
    """
    path = Path(path)
    arrays: dict[str, np.ndarray] = {}
    header = {"kind": KIND, "format": FORMAT_VERSION, "payload": to_plain(payload, arrays)}
    text = json.dumps(header, separators=(",", ":"))
    arrays[STRUCTURE_KEY] = np.frombuffer(text.encode("utf-8"), dtype=np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    # numpy's stub would match the ** dict against savez's keyword allow_pickle; every key is an array's
    save: Callable[..., None] = np.savez
    with atomic_path(path, prefix=".ckpt-") as tmp:
        with open(tmp, "wb") as fh:
            save(fh, allow_pickle=False, **arrays)
            fh.flush()
            os.fsync(fh.fileno())


def read(path) -> dict:
    """Load a checkpoint written by :func:`write_atomic`, without running any code from it.

    Returns the payload with ``"format"`` (:data:`FORMAT_VERSION`) added.  Raises
    :class:`~jaxanm.errors.InputError` naming the file if it is missing, truncated, damaged or
    not a jaxanm checkpoint (arrays are read with ``allow_pickle=False``, classes only through
    the registry of stored types), has another format version, or is a pickle written by an
    older jaxanm (never unpickled).
    """
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except FileNotFoundError as exc:
        raise InputError(f"no checkpoint at {path}: nothing to resume (start the run without resume)") from exc
    if magic[:1] == b"\x80":
        raise InputError(f"{path} is a checkpoint in the pickle format of an older jaxanm version (format 1); this "
                         "jaxanm reads only its own format, which cannot run code: finish that run with the jaxanm "
                         "version that wrote it, or start afresh")
    header = _header(path, magic)
    found = header.get("format")
    if found != FORMAT_VERSION:
        raise InputError(f"checkpoint {path} has format {found!r}, this jaxanm reads {FORMAT_VERSION}; "
                         "resume it with the jaxanm version that wrote it, or start afresh")
    return {"format": FORMAT_VERSION, **header["payload"]}


def _header(path, magic: bytes) -> dict:
    """The decoded header of the checkpoint at ``path`` (:func:`read`)."""
    try:
        if magic != b"PK\x03\x04":
            raise PlainDataError("not an npz archive")
        with np.load(path, allow_pickle=False) as archive:
            arrays = {key: archive[key] for key in archive.files}
        header = json.loads(arrays.pop(STRUCTURE_KEY).tobytes().decode("utf-8"))
        if not isinstance(header, dict) or header.get("kind") != KIND:
            raise PlainDataError("no jaxanm checkpoint header")
        if header.get("format") == FORMAT_VERSION:
            header["payload"] = from_plain(header["payload"], arrays)
            if not isinstance(header["payload"], dict):
                raise PlainDataError("the payload is not a dict")
    except (PlainDataError, OSError, EOFError, KeyError, TypeError, ValueError, RecursionError,
            zipfile.BadZipFile) as exc:
        raise InputError(f"{path} is not a readable jaxanm checkpoint ({type(exc).__name__}: {exc}); it is truncated, "
                         "damaged or no checkpoint: start the run afresh, or resume from an intact copy") from exc
    return header


class Interrupted(RunInterrupted):
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
