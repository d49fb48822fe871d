"""The host hooks of a run of :func:`jaxanm.integrate`: what an ``after_step`` hook may return
(:class:`Remap`), and the do-nothing hooks a run without them gets."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Remap(NamedTuple):
    """Returned by an ``after_step`` hook that changed the discretisation (e.g. moved points and
    rebuilt stencils): the new ``params`` and the accepted state mapped onto them.

    The next step starts its homotopy (or Newton iteration) from ``x`` and takes ``x`` as its
    old state, so a remapping that preserves the fields (``x`` such that the new operators
    reproduce the values the old ones gave) leaves only the physical change in the next
    residual.  ``x`` must keep the shape of the state.  ``history=False`` says the remap broke
    the continuity of what a :class:`~jaxanm.StepController` measures (e.g. a re-seeded
    cloud): the next step is then taken without a local error estimate.
    """

    params: object
    x: np.ndarray
    history: bool = True


def same_params(t, x, params):
    """The ``after_step`` of a run without one: the params unchanged."""
    return params


def no_callback(t, x, stats) -> None:
    """The ``callback`` of a run without one."""
