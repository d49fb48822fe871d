"""The checks of scalar inputs (``jaxanm._checks``): what each accepts, what it refuses, and the
one message shape every refusal has ("<field> must be <what>, got <value>[; <hint>]")."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jaxanm import InputError
from jaxanm._checks import choice, flag, integer, positive, real


class OwnError(InputError):
    """A module's own error class (as a scene's SceneError)."""


@pytest.mark.parametrize("value", [2, 7, np.int64(3), np.int32(2)])
def test_integer_accepts_integers_at_or_above_the_minimum(value):
    out = integer("ANM.order", value, 2)
    assert out == int(value) and type(out) is int


@pytest.mark.parametrize("value", [1, 1.5, 2.0, True, np.bool_(True), "3", None, np.float64(3.0)])
def test_integer_refuses_non_integers_bools_and_values_below_the_minimum(value):
    with pytest.raises(InputError) as info:
        integer("ANM.order", value, 2)
    assert str(info.value) == f"ANM.order must be an integer >= 2, got {value!r}"


def test_integer_names_both_bounds_and_appends_the_hint():
    with pytest.raises(InputError, match=r"^max_order must be an integer from 1 to 5, got 6; BDF orders$"):
        integer("max_order", 6, 1, 5, hint="BDF orders")
    with pytest.raises(InputError, match=r"^k must be an integer <= 3, got 4$"):
        integer("k", 4, maximum=3)
    assert integer("k", -10) == -10


@pytest.mark.parametrize(("kwargs", "inside", "outside", "words"), [
    ({"low": 0, "high": 1, "open_low": True, "open_high": True}, [1e-300, 0.5, 1 - 1e-16], [0, 1, -1], "in (0, 1)"),
    ({"low": 0, "high": 1}, [0, 1, 0.5], [-1e-300, 1 + 1e-15], "in [0, 1]"),
    ({"low": 1}, [1, 2.5, 1e300], [0.999], ">= 1"),
    ({"low": 0, "open_low": True}, [1e-300], [0, -1.0], "> 0"),
    ({"high": 5, "open_high": True}, [-1e300, 4.9], [5, 6], "< 5"),
    ({}, [-1e300, 0, 1e300], [], "a finite number"),
])
def test_real_bounds_open_and_closed(kwargs, inside, outside, words):
    for value in inside:
        assert real("x", value, **kwargs) == float(value)
    for value in outside:
        with pytest.raises(InputError) as info:
            real("x", value, **kwargs)
        assert words in str(info.value) and str(info.value).endswith(f"got {value!r}")


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf, True, "0.1", None, np.array([0.1])])
def test_real_refuses_nan_infinities_bools_and_non_numbers(value):
    with pytest.raises(InputError, match="x must be a number in"):
        real("x", value, 0, 1)


def test_real_accepts_infinity_only_when_asked_and_inside_the_bounds():
    assert real("dt_max", math.inf, 0, open_low=True, finite=False) == math.inf
    with pytest.raises(InputError):
        real("dt_max", -math.inf, 0, open_low=True, finite=False)
    with pytest.raises(InputError):
        real("dt_max", math.nan, finite=False)


def test_positive_is_an_open_lower_bound_at_zero():
    assert positive("dt", np.float32(0.5)) == 0.5
    with pytest.raises(InputError, match=r"^dt must be a number > 0, got 0$"):
        positive("dt", 0)


@pytest.mark.parametrize("value", [True, False, np.bool_(False)])
def test_flag_accepts_bools(value):
    assert flag("ANM.pade", value) is bool(value)


@pytest.mark.parametrize("value", [0, 1, "yes", None])
def test_flag_refuses_everything_else(value):
    with pytest.raises(InputError, match=r"^ANM.pade must be True or False, got "):
        flag("ANM.pade", value)


def test_choice_names_the_choices_and_the_closest_one():
    assert choice("jacobian", "sparse", ("dense", "sparse", "auto")) == "sparse"
    with pytest.raises(InputError) as info:
        choice("jacobian", "sprase", ("dense", "sparse", "auto"), hint="or a pattern")
    assert str(info.value) == ("jacobian must be one of 'dense', 'sparse', 'auto', got 'sprase' "
                               "(did you mean 'sparse'?); or a pattern")
    with pytest.raises(InputError, match=r"got 3$"):
        choice("jacobian", 3, ("dense",))


def test_a_module_raises_its_own_error_class():
    for check, args in [(integer, (0, 1)), (real, (2.0, 0, 1)), (positive, (-1,)), (flag, (1,)),
                        (choice, ("a", ("b",)))]:
        with pytest.raises(OwnError):
            check("field", *args, error=OwnError)


@pytest.mark.parametrize(("option", "message"), [
    ({"polish_tol": 1e-2}, r"polish_tol must be a number in \(0, 0.001\), got 0.01"),
    ({"max_polish": 0}, "max_polish must be an integer >= 1, got 0"),
    ({"max_refine": 2.0}, "max_refine must be an integer >= 1, got 2.0"),
    ({"tangents": 1}, "tangents must be True or False, got 1"),
])
def test_sensitivity_options_are_checked_before_any_computation(option, message):
    from jaxanm import ForwardSensitivity

    with pytest.raises(InputError, match=message):
        ForwardSensitivity(lambda x, x_old, t, dt, p: x, {"k": 1.0}, {"k": 1.0}, lambda t, x, p: {"x": x}, **option)
