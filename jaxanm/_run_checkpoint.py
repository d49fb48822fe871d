"""The checkpoint of a :func:`jaxanm.integrate` run: what it stores, its version, and the
writer the loop calls (a do-nothing one when the run has no checkpoint path).

A run checkpoint is a dict written by :func:`jaxanm.checkpoint.write_atomic` (which adds the
file ``format``).  Version :data:`VERSION` holds:

- ``version``: :data:`VERSION`; ``fingerprint``: the run's size, span, step, solver,
  controller and time scheme (a checkpoint resumes only the run it was written by);
- ``k``, ``t``, ``x``: the last accepted step (:class:`LoopState`); ``params``: the leaves of
  its parameters (host arrays, in ``jax.tree_util`` order: the tree itself is the one the
  resumed run is given, so any pytree of parameters can be stored as plain data);
- ``ts``, ``xs``, ``ps`` (each saved step's parameter leaves), ``observed`` (lists): what the
  run kept so far;
- ``controller``: what the step-size controller stores of its state
  (:meth:`~jaxanm.StepController.to_checkpoint`); ``kstar_dt``;
- ``scheme``: the time scheme's history (:class:`~jaxanm.TimeScheme`: numpy arrays and floats,
  stored as they are, so a resumed multistep or Runge-Kutta run goes on bit-identically);
- ``solver``: what the step solver stores of its state (the matrix of its K*, refactorised on
  resume: the same factors, so a resumed run is bit-identical);
- ``stats``: the :class:`~jaxanm.Stats` so far;
- ``host_state``: the snapshot of the caller's ``host_state`` pair, or None.
"""

from __future__ import annotations

from typing import Callable, NamedTuple

import jax

from ._loop_state import Kept, Log, LoopState
from .checkpoint import read, to_host, write_atomic
from .errors import InputError

VERSION = 4
"""The run checkpoint version this jaxanm writes and reads (1: before the loop's record; 2:
before the time schemes; 3: parameters stored as their tree)."""


def to_checkpoint(state: LoopState, *, fingerprint: dict, stats, solver: object, controller: object,
                  host_state: object) -> dict:
    """The checkpoint of a run in ``state`` (module docstring): ``solver`` and ``controller``
    are what the solver and the controller store of their states, ``host_state`` the caller's
    snapshot."""
    kept = state.kept
    return {
        "version": VERSION, "fingerprint": fingerprint,
        "k": state.k, "t": state.t, "x": state.x, "params": _leaves(state.params),
        "ts": kept.ts.tolist(), "xs": kept.xs.tolist(),
        "ps": None if kept.ps is None else [_leaves(p) for p in kept.ps.tolist()],
        "observed": None if kept.observed is None else {key: log.tolist() for key, log in kept.observed.items()},
        "controller": controller, "kstar_dt": state.kstar_dt, "scheme": state.scheme_state, "solver": solver,
        "stats": stats,
        "host_state": host_state,
    }


def _leaves(params) -> list:
    """The leaves of a parameter pytree, on the host."""
    return jax.tree_util.tree_leaves(to_host(params))


def from_checkpoint(payload: dict, start: LoopState, path=None) -> LoopState:
    """The record a checkpoint (at ``path``) stores, over ``start`` (the record a fresh run
    starts from, whose solver and controller states are then restored from
    ``payload["solver"]`` and ``payload["controller"]`` by the loop); ``params`` on the host,
    in the tree of ``start.params``."""
    tree = jax.tree_util.tree_structure(start.params)

    def params(leaves):
        if len(leaves) != tree.num_leaves:
            raise InputError(f"checkpoint {path} stores parameters of {len(leaves)} arrays, this run's have "
                             f"{tree.num_leaves}: resume with the parameters it was started with, or start afresh")
        return jax.tree_util.tree_unflatten(tree, leaves)

    observed = payload["observed"]
    ps = None if payload["ps"] is None else Log.of([params(p) for p in payload["ps"]])
    kept = Kept(Log.of(payload["ts"]), Log.of(payload["xs"]), ps,
                None if observed is None else {key: Log.of(v) for key, v in observed.items()})
    return start._replace(k=payload["k"], t=payload["t"], x=payload["x"], params=params(payload["params"]),
                          kstar_dt=payload["kstar_dt"], scheme_state=payload["scheme"], kept=kept)


def load(path, fingerprint: dict | None = None) -> dict:
    """The run checkpoint at ``path``, of this :data:`VERSION`; with ``fingerprint``, only if it
    was written by the same run (:class:`~jaxanm.InputError` naming the file otherwise)."""
    payload = read(path)
    if payload.get("version") != VERSION:
        raise InputError(f"checkpoint {path} holds a run state of version {payload.get('version', 1)!r}; this jaxanm "
                         f"reads version {VERSION}: resume it with the jaxanm version that wrote it, or start afresh")
    if fingerprint is not None and payload["fingerprint"] != fingerprint:
        raise InputError(
            f"checkpoint {path} belongs to another run ({payload['fingerprint']}), not to this one "
            f"({fingerprint}); use a fresh output directory or the same settings"
        )
    return payload


def stored_host_state(path):
    """The host state a checkpoint of :func:`jaxanm.integrate` stores (the ``get()`` of its
    ``host_state`` pair at the last checkpointed step), or None if the run kept none.

    Raises :class:`~jaxanm.InputError` when ``path`` is no checkpoint of this version.
    """
    return load(path).get("host_state")


class Checkpoints(NamedTuple):
    """Where and when a run writes its checkpoints: ``path`` (None: never, and nothing to
    resume), every ``every`` steps (0: only at the end, on interruption and on failure),
    ``resume`` from it if it exists, the caller's ``host_state`` ``(get, set)`` pair or None,
    and the run's ``fingerprint``."""

    path: object
    every: int
    resume: bool
    host_state: tuple | None
    fingerprint: dict

    def due(self, k: int) -> bool:
        """Whether a checkpoint is written after step ``k``."""
        return bool(self.every) and k % self.every == 0

    def resumable(self, exists: Callable) -> bool:
        """Whether the run continues from a checkpoint (``exists(path)``: it is there)."""
        return self.resume and self.path is not None and exists(self.path)

    def load(self) -> dict:
        """The checkpoint to resume from; the caller's host state restored from it."""
        payload = load(self.path, self.fingerprint)
        if self.host_state is not None:
            if payload["host_state"] is None:
                raise InputError(f"checkpoint {self.path} holds no host state, but this run needs one; "
                                 "it was written by another kind of run: start afresh")
            self.host_state[1](payload["host_state"])
        return payload

    def write(self, state: LoopState, stats_now: Callable, solver: object, controller: object) -> None:
        """Write the checkpoint of ``state`` (nothing without a path); ``stats_now()`` gives the
        statistics, closed at the time of writing."""
        if self.path is None:
            return
        host = None if self.host_state is None else self.host_state[0]()
        write_atomic(self.path, to_checkpoint(state, fingerprint=self.fingerprint, stats=stats_now(), solver=solver,
                                              controller=controller, host_state=host))


