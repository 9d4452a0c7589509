"""The one deadline helper (issue 11): a wait's time is fixed when it starts, ``None`` waits forever,
time left is never negative, and a cap bounds each step.  A hand-turned clock, no sleeps."""

import math

import pytest
from hypothesis import given, strategies as st

from hystbench.deadline import Deadline


class Clock:
    """A clock that moves only when told to."""

    def __init__(self, t: float = 1000.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> None:
        self.t += dt


def test_time_left_counts_down_from_the_start_and_then_it_is_expired():
    clock = Clock()
    d = Deadline(2.0, clock=clock)
    assert d.left() == 2.0 and not d.expired and d.elapsed == 0.0
    clock.advance(0.5)
    assert d.left() == 1.5 and not d.expired and d.elapsed == 0.5
    clock.advance(1.5)
    assert d.left() == 0.0 and d.expired
    clock.advance(3.0)
    assert d.left() == 0.0 and d.expired and d.elapsed == 5.0  # never negative: a blocking call's argument


def test_none_never_expires_and_waits_forever_unless_capped():
    clock = Clock()
    d = Deadline(None, clock=clock)
    clock.advance(1e9)
    assert d.forever and not d.expired and d.left() is None  # cond.wait(None): until woken
    assert d.left(0.05) == 0.05  # a loop that looks again in short steps
    assert d.elapsed == 1e9


def test_a_cap_bounds_each_step_and_the_last_step_is_what_is_left():
    clock = Clock()
    d = Deadline(0.12, clock=clock)
    steps = []
    while not d.expired:
        steps.append(d.left(0.05))
        clock.advance(steps[-1])  # a read that used its whole timeout
    assert steps == pytest.approx([0.05, 0.05, 0.02])


@pytest.mark.parametrize("seconds", [0.0, -1.0])
def test_zero_or_negative_is_a_non_blocking_look(seconds):
    d = Deadline(seconds, clock=Clock())
    assert d.expired and d.left() == 0.0 and d.left(0.05) == 0.0


def test_nan_is_refused_naming_the_parameter():
    with pytest.raises(ValueError, match="seconds"):
        Deadline(math.nan)


def test_the_real_clock_is_the_default():
    d = Deadline(3600.0)
    assert not d.expired and 0 < d.left() <= 3600.0


@given(seconds=st.floats(0, 1e6), moves=st.lists(st.floats(0, 1e5), max_size=20))
def test_left_plus_elapsed_is_the_timeout_until_it_expires(seconds, moves):
    clock = Clock(0.0)
    d = Deadline(seconds, clock=clock)
    for dt in moves:
        clock.advance(dt)
        assert d.left() == max(0.0, seconds - clock.t)
        assert d.expired == (clock.t >= seconds)
