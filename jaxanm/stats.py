"""Run statistics: counters, the a_max history and the wall-time split.

Every statistics class of the package (:class:`Stats`, :class:`jaxanm.ida.IDAStats`,
:class:`jaxanm.sensitivity.SensitivityStats`) is a :class:`Counters`: the same names for the
same things (``wall_time_s`` the total, ``wall_time`` its split, whose ``REMAINDER`` key takes
what the named timers did not account for).  Who writes them is fixed: work counters (factorisations,
residual and Jacobian evaluations, solves, their times) only through :mod:`jaxanm._problem`,
step counters by the time loop, a branch's by the walk of the path follower
(``tests/test_code_layout.py`` holds the rule).
"""

from __future__ import annotations

import contextlib
import dataclasses
import time

from ._plain import stored_type

TIMER_KEYS = ("jacobian", "factorize", "series", "solve", "other")


class Counters:
    """The shared base of the statistics classes: the total wall time ``wall_time_s`` and its
    split ``wall_time`` (a dict of timer names to seconds, ``REMAINDER`` the key that
    :meth:`close` gives the time the others did not account for)."""

    REMAINDER: str = "other"
    wall_time_s: float
    wall_time: dict

    @contextlib.contextmanager
    def timer(self, key: str):
        """Accumulate the wall time of the ``with`` block under ``wall_time[key]``."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self.wall_time[key] += time.perf_counter() - start

    def close(self, total_s: float) -> None:
        """Set the total wall time; ``wall_time[REMAINDER]`` gets what the named timers did not
        account for."""
        self.wall_time_s = total_s
        named = sum(v for k, v in self.wall_time.items() if k != self.REMAINDER)
        self.wall_time[self.REMAINDER] = max(total_s - named, 0.0)


@stored_type("Stats")
@dataclasses.dataclass
class Stats(Counters):
    """Statistics of one :func:`jaxanm.integrate` run.

    Counters are totals over the run.  ``series_orders`` counts evaluations of the jet
    series (one per order and per series); ``residual_evaluations`` counts plain residual
    evaluations (series evaluations excluded).  ``solves`` counts the right-hand sides solved
    with a factorised K* (each a forward and a backward triangular sweep).  ``resumes`` counts continuations from a
    checkpoint (each re-factorises the stored K* once, not counted in ``factorizations``).
    ``pade_accepted`` counts the ANM series accepted through their Padé approximant
    (``ANM(pade=True)``).  ``amax`` holds, for ANM, the validity range of the accepted series
    of each time step (for one accepted through its Padé approximant, the approximant's range)
    and ``orders`` the order of that series (the maximum order unless the ANM is
    order-adaptive); ``residual_norm`` the max-norm of the step residual at each accepted
    state.  With a step controller (:class:`jaxanm.StepController`), ``step_sizes`` holds the
    size of each accepted step and ``rejected_steps`` counts the steps its error test refused
    (``dt_halvings`` counts the solver failures).  ``wall_time`` splits ``wall_time_s`` into
    ``jacobian``, ``factorize``, ``series``, ``solve`` (triangular solves) and ``other``.
    """

    factorizations: int = 0
    jacobian_evaluations: int = 0
    time_steps: int = 0
    series_orders: int = 0
    residual_evaluations: int = 0
    newton_iterations: int = 0
    solves: int = 0
    substeps: int = 0
    pade_accepted: int = 0
    dt_halvings: int = 0
    rejected_steps: int = 0
    resumes: int = 0
    amax: list = dataclasses.field(default_factory=list)
    orders: list = dataclasses.field(default_factory=list)
    residual_norm: list = dataclasses.field(default_factory=list)
    step_sizes: list = dataclasses.field(default_factory=list)
    wall_time_s: float = 0.0
    wall_time: dict = dataclasses.field(default_factory=lambda: dict.fromkeys(TIMER_KEYS, 0.0))

    def as_dict(self) -> dict:
        """Plain-Python dictionary (JSON-serialisable) of every field."""
        d = dataclasses.asdict(self)
        d["amax"] = [float(a) for a in self.amax]
        d["residual_norm"] = [float(r) for r in self.residual_norm]
        d["step_sizes"] = [float(h) for h in self.step_sizes]
        return d

    def to_plain(self) -> dict:
        """Every field as it is (how a checkpoint stores the statistics; :meth:`from_plain`)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_plain(cls, state: dict) -> Stats:
        """The statistics :meth:`to_plain` gave."""
        return cls(**state)

    def summary(self) -> dict:
        """The headline numbers (no per-step lists), for printing side by side."""
        d = self.as_dict()
        del d["amax"], d["residual_norm"], d["orders"], d["step_sizes"]
        d["wall_time"] = {k: round(v, 4) for k, v in self.wall_time.items()}
        return d
