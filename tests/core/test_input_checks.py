"""core/input_checks.py: the one wording of whole-number, finite-number, boolean, choice and shape errors."""

from dataclasses import dataclass

import numpy as np
import pytest

from hupbench.core.errors import BadTypeError
from hupbench.core.input_checks import (check_bool, check_bool_fields, check_choice, check_int, check_interval,
                                        check_number, check_shape, is_number, is_whole)


@pytest.mark.parametrize("value,whole", [(3, True), (np.int64(3), True), (True, False), (np.bool_(True), False),
                                         (2.0, False), ("3", False), (None, False)])
def test_is_whole(value, whole):
    assert is_whole(value) is whole


@pytest.mark.parametrize("value,kwargs,message", [
    (0, dict(low=1), "workers must be a whole number >= 1, got 0"),
    (2.5, dict(low=1), "workers must be a whole number >= 1, got 2.5"),
    (True, dict(low=0), "workers must be a whole number >= 0, got True"),
    ("two", dict(), "workers must be a whole number, got 'two'"),
    (9, dict(low=1, high=8, hint=" (4 x the 2 CPU cores)"), "workers must be a whole number from 1 to 8 (4 x the 2 CPU cores), got 9"),
    (0, dict(low=1, optional=True), "workers must be a whole number >= 1 or null, got 0"),
    (11, dict(high=10), "workers must be a whole number <= 10, got 11"),
])
def test_check_int_refuses_naming_the_field(value, kwargs, message):
    with pytest.raises(ValueError) as info:
        check_int(value, "workers", **kwargs)
    assert str(info.value) == message


def test_check_int_accepts_and_returns_python_ints():
    assert check_int(np.int32(4), "n", 1, 4) == 4 and type(check_int(np.int32(4), "n")) is int
    assert check_int(None, "n", 1, optional=True) is None
    with pytest.raises(TypeError, match="n must be a whole number, got 1.5"):
        check_int(1.5, "n", error=BadTypeError)


@pytest.mark.parametrize("value,kwargs,message", [
    (float("nan"), dict(low=0.0, high=1.0, low_open=True), "lr must be a finite number in (0, 1], got nan"),
    (0.0, dict(low=0.0, low_open=True), "lr must be a finite number > 0, got 0.0"),
    (float("inf"), dict(), "lr must be a finite number, got inf"),
    (True, dict(), "lr must be a finite number, got True"),
    ("x", dict(low=0.0, optional=True), "lr must be a finite number >= 0 or null, got 'x'"),
])
def test_check_number_refuses_naming_the_field(value, kwargs, message):
    with pytest.raises(ValueError) as info:
        check_number(value, "lr", **kwargs)
    assert str(info.value) == message


def test_check_number_accepts_the_bounds():
    assert check_number(1, "lr", 0.0, 1.0, low_open=True) == 1.0 and check_number(0, "w", low=0.0) == 0.0


def test_check_shape_named_axes_take_one_size():
    points = np.zeros((5, 3))
    assert check_shape(points, ("N", 3), "points") is not None
    check_shape(np.zeros((4, 4)), ("N", "N"), "T")
    for array, shape, message in [(np.zeros((5, 2)), ("N", 3), "points must be (N, 3), got (5, 2)"),
                                  (np.zeros((4, 3)), ("N", "N"), "points must be (N, N), got (4, 3)"),
                                  (np.zeros(3), (3, 1), "points must be (3, 1), got (3,)"),
                                  (np.zeros((2, 3)), (6,), "points must be (6,), got (2, 3)")]:
        with pytest.raises(ValueError) as info:
            check_shape(array, shape, "points")
        assert str(info.value) == message


@pytest.mark.parametrize("value,number", [(3, True), (10**400, True), (2.5, True), (np.float32(1.5), True),
                                          (True, False), (float("nan"), False), (float("inf"), False), ("3", False),
                                          (None, False)])
def test_is_number(value, number):
    assert is_number(value) is number


@pytest.mark.parametrize("value", ["maybe", "true", 1, 0, None, 2.0])
def test_check_bool_refuses_what_is_not_a_boolean(value):
    with pytest.raises(ValueError) as info:
        check_bool(value, "train.progress")
    assert str(info.value) == f"train.progress must be true or false, got {value!r}"


def test_check_bool_accepts_python_and_numpy_booleans():
    assert check_bool(True, "x") is True and check_bool(np.bool_(False), "x") is False


def test_check_bool_fields_checks_every_field_annotated_bool():
    @dataclass
    class Node:
        count: int = 1
        progress: bool = True
        tensorboard: bool = False

    check_bool_fields(Node(count="not checked here"), "train.")
    with pytest.raises(ValueError, match=r"^train.tensorboard must be true or false, got 'maybe'$"):
        check_bool_fields(Node(tensorboard="maybe"), "train.")


@pytest.mark.parametrize("value,choices,message", [
    ("tpu", ("cpu", "cuda"), "device must be 'cpu' or 'cuda', got 'tpu'"),
    (True, (1, 2), "device must be 1 or 2, got True"),
    ("4", (4, 8), "device must be 4 or 8, got '4'"),
])
def test_check_choice_refuses_naming_the_choices(value, choices, message):
    with pytest.raises(ValueError) as info:
        check_choice(value, "device", choices)
    assert str(info.value) == message


def test_check_choice_returns_the_value():
    assert check_choice("cuda", "device", ("cpu", "cuda")) == "cuda" and check_choice(8, "stride", (4, 8)) == 8


@pytest.mark.parametrize("value,written", [((0.8, 0.35), "[0.8, 0.35]"), ([0.05, 0.8], "[0.05, 0.8]"),
                                           ([0.3], "[0.3]"), ([0.3, float("nan")], "[0.3, nan]"), (0.5, "0.5"),
                                           ("0.3, 0.5", "'0.3, 0.5'"), ([True, 0.5], "[True, 0.5]")])
def test_check_interval_refuses_naming_the_field(value, written):
    with pytest.raises(ValueError) as info:
        check_interval(value, "dataset.head.distance_m", 0.1, 10.0, unit="m")
    assert str(info.value) == ("dataset.head.distance_m must be two numbers [low, high], low <= high, "
                               f"from 0.1 to 10 m, got {written}")


def test_check_interval_returns_floats_and_accepts_its_bounds():
    assert check_interval([0.1, np.float32(10.0)], "x", 0.1, 10.0) == (0.1, 10.0)
    assert check_interval((2, 2), "x", 0, 5) == (2.0, 2.0)
