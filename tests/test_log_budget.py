"""The log budget: a line a client can repeat is logged up to the budget per window, the rest
counted and reported once, nothing lost or counted twice (a fake clock: no sleeping)."""

from hypothesis import given, settings
from hypothesis import strategies as st
import pytest

from hystbench.log_budget import LogBudget


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_the_budget_logs_its_lines_then_counts_and_reports_the_rest_when_the_next_window_opens():
    clock = Clock()
    budget = LogBudget(3, 1.0, clock=clock)
    turns = [budget.admit() for _ in range(5)]
    assert [t.log for t in turns] == [True, True, True, False, False]
    assert [t.last for t in turns] == [False, False, True, False, False]  # the third says the rest are counted
    assert all(t.held == 0 for t in turns)
    clock.t = 0.999
    assert not budget.admit().log  # still the first window
    clock.t = 1.5
    turn = budget.admit()
    assert turn.log and turn.held == 3 and budget.take_held() == 0


def test_what_was_held_at_the_end_is_handed_over_once():
    budget = LogBudget(1, 1.0, clock=Clock())
    budget.admit(), budget.admit(), budget.admit()
    assert budget.take_held() == 2 and budget.take_held() == 0


def test_a_line_that_must_be_logged_is_logged_beyond_the_budget_and_not_counted_as_held():
    clock = Clock()
    budget = LogBudget(1, 1.0, clock=clock)
    assert budget.admit().log
    assert budget.admit(always=True).log
    assert not budget.admit().log
    clock.t = 2.0
    assert budget.admit().held == 1


@pytest.mark.parametrize("per_window, window_s", [(0, 1.0), (3, 0.0), (3, float("nan"))])
def test_a_budget_of_nothing_is_refused(per_window, window_s):
    with pytest.raises(ValueError, match="per_window >= 1 and window_s > 0"):
        LogBudget(per_window, window_s)


@settings(max_examples=200, deadline=None)
@given(per_window=st.integers(1, 5), steps=st.lists(st.floats(0.0, 2.0), max_size=60))
def test_every_occurrence_is_either_logged_or_reported_held_once(per_window, steps):
    """Logged one by one, or in one of the counts: the sum is every occurrence; and no window
    logs more than its budget."""
    clock = Clock()
    budget = LogBudget(per_window, 1.0, clock=clock)
    logged = held = 0
    per_window_logged: dict[float, int] = {}
    start = None
    for dt in steps:
        clock.t += dt
        turn = budget.admit()
        if start is None or clock.t - start >= 1.0:
            start = clock.t
        logged += turn.log
        held += turn.held
        per_window_logged[start] = per_window_logged.get(start, 0) + turn.log
    held += budget.take_held()
    assert logged + held == len(steps)
    assert all(n <= per_window for n in per_window_logged.values())
