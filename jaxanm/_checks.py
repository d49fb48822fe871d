"""Checks of scalar inputs: one function per kind of value, each raising an error that names the field.

Every option of a solver, a controller, a grid file or a calibration is checked by one of
these before any computation, so that a bad value gets one message shape everywhere::

    ANM.order must be an integer >= 2, got 1.5
    StepController.rtol must be a number in (0, 1), got 2.0; e.g. rtol=1e-4

``field`` is the name the user wrote (``"ANM.order"``, ``"q"``, ``"sweep.toml: rtol"``), ``hint``
an optional fix appended after a semicolon, and ``error`` the class raised: :class:`InputError`,
or a subclass a module owns (a scene's ``SceneError``, a grid's ``GridError``).  Each check
returns the value as the plain Python type it checked (``int``, ``float``, ``bool``, ``str``).

``bool`` is not an integer or a number here (``True`` for an order is a mistake, not 1), while
numpy scalars (``np.int64``, ``np.float64``) are.  Checks of arrays (finite entries, shapes)
stay with the code that owns the array: their messages name rows and counts, not one value.
"""

from __future__ import annotations

import math
from collections.abc import Collection
from typing import NoReturn

import numpy as np

from .errors import InputError, did_you_mean

__all__ = ["choice", "flag", "integer", "positive", "real"]

_INTEGERS = (int, np.integer)
_REALS = (int, float, np.integer, np.floating)
_BOOLS = (bool, np.bool_)


def _fail(error: type[InputError], field: str, what: str, value, hint: str, note: str = "") -> NoReturn:
    """Raise ``error("<field> must be <what>, got <value>[ (<note>)][; <hint>]")``."""
    raise error(f"{field} must be {what}, got {value!r}" + (f" ({note})" if note else "")
                + (f"; {hint}" if hint else ""))


def integer(field: str, value, minimum: int | None = None, maximum: int | None = None, *,
            hint: str = "", error: type[InputError] = InputError) -> int:
    """``value`` as an ``int`` if it is an integer (not a bool) within ``[minimum, maximum]``
    (each bound optional), else ``error`` naming ``field``: "must be an integer >= 2"."""
    if minimum is not None and maximum is not None:
        what = f"an integer from {minimum} to {maximum}"
    elif minimum is not None:
        what = f"an integer >= {minimum}"
    elif maximum is not None:
        what = f"an integer <= {maximum}"
    else:
        what = "an integer"
    if (not isinstance(value, _INTEGERS) or isinstance(value, _BOOLS)
            or (minimum is not None and value < minimum) or (maximum is not None and value > maximum)):
        _fail(error, field, what, value, hint)
    return int(value)


def _interval(low: float | None, high: float | None, open_low: bool, open_high: bool) -> str:
    """The allowed range in words: ``in (0, 1]``, ``> 0``, ``<= 5``, or ``""`` (any)."""
    if low is not None and high is not None:
        return f"in {'(' if open_low else '['}{low:g}, {high:g}{')' if open_high else ']'}"
    if low is not None:
        return f"{'>' if open_low else '>='} {low:g}"
    if high is not None:
        return f"{'<' if open_high else '<='} {high:g}"
    return ""


def real(field: str, value, low: float | None = None, high: float | None = None, *, open_low: bool = False,
         open_high: bool = False, finite: bool = True, hint: str = "",
         error: type[InputError] = InputError) -> float:
    """``value`` as a ``float`` if it is a real number (an int or float, not a bool) within the
    bounds, else ``error`` naming ``field``: "must be a number in (0, 1)".

    ``low`` and ``high`` are each optional and closed unless ``open_low`` / ``open_high``.
    NaN is never accepted; infinities only with ``finite=False`` (and then only inside the
    bounds: ``low=1, finite=False`` accepts ``inf``).
    """
    interval = _interval(low, high, open_low, open_high)
    what = "a " + ("finite " if finite and not interval else "") + "number" + (f" {interval}" if interval else "")
    if not isinstance(value, _REALS) or isinstance(value, _BOOLS):
        _fail(error, field, what, value, hint)
    number = float(value)
    if (math.isnan(number) or (finite and math.isinf(number))
            or (low is not None and (number <= low if open_low else number < low))
            or (high is not None and (number >= high if open_high else number > high))):
        _fail(error, field, what, value, hint)
    return number


def positive(field: str, value, *, hint: str = "", error: type[InputError] = InputError) -> float:
    """``value`` as a ``float`` if it is a finite number > 0 (:func:`real` with an open lower bound 0)."""
    return real(field, value, 0.0, open_low=True, hint=hint, error=error)


def flag(field: str, value, *, hint: str = "", error: type[InputError] = InputError) -> bool:
    """``value`` as a ``bool`` if it is True or False (``np.bool_`` too; not 0 or 1), else
    ``error`` naming ``field``."""
    if not isinstance(value, _BOOLS):
        _fail(error, field, "True or False", value, hint)
    return bool(value)


def choice(field: str, value, choices: Collection[str], *, hint: str = "",
           error: type[InputError] = InputError) -> str:
    """``value`` if it is one of the strings ``choices``, else ``error`` naming ``field``, the
    choices and the closest of them to a misspelt ``value``."""
    if not (isinstance(value, str) and value in choices):
        close = did_you_mean(value, choices) if isinstance(value, str) else ""
        what = "one of " + ", ".join(repr(c) for c in choices)
        _fail(error, field, what, value, hint, note=close)
    return value
