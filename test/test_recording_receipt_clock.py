"""The sim time in force at a DDS receive instant (:class:`ReceiptClock`).

What must hold: a receive instant gets the sim time of the newest ``/clock``
message received at or before it, none before the first, whatever order the
``/clock`` messages are added in; forgetting old history never changes the
answer for an instant inside it.
"""
from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hill_muscle_ros.recording.receipt_clock import ReceiptClock
from hill_muscle_ros.timebase import NS_PER_S


def reference_sim_ns(clocks: list[tuple[int, int]], received_ns: int) -> int | None:
    """Brute force: among the (receive instant, sim time) pairs received at or
    before ``received_ns``, the latest; of equal instants, the one added last."""
    best = None
    for r, sim in clocks:
        if r <= received_ns and (best is None or r >= best[0]):
            best = (r, sim)
    return None if best is None else best[1]


def test_an_instant_before_the_first_clock_message_has_no_sim_time():
    clock = ReceiptClock()
    assert clock.sim_ns_at(5) is None
    clock.add(10, 1 * NS_PER_S)
    assert clock.sim_ns_at(9) is None


def test_an_instant_gets_the_newest_clock_received_at_or_before_it():
    clock = ReceiptClock()
    clock.add(10, 1 * NS_PER_S)
    clock.add(20, 2 * NS_PER_S)
    assert [clock.sim_ns_at(r) for r in (10, 15, 19, 20, 10**6)] == \
        [1 * NS_PER_S, 1 * NS_PER_S, 1 * NS_PER_S, 2 * NS_PER_S, 2 * NS_PER_S]


@given(st.lists(st.tuples(st.integers(0, 1000), st.integers(0, 10**12)), max_size=40),
       st.lists(st.integers(-5, 1005), min_size=1, max_size=20))
def test_any_order_of_clock_messages_gives_the_brute_force_answer(clocks, instants):
    clock = ReceiptClock()
    for r, sim in clocks:
        clock.add(r, sim)
    assert [clock.sim_ns_at(r) for r in instants] == \
        [reference_sim_ns(clocks, r) for r in instants]


def test_forgetting_keeps_the_answer_for_every_instant_inside_the_history():
    history_s = 1.0
    clock = ReceiptClock(history_s)
    period_ns = NS_PER_S // 100
    clocks = [(k * period_ns, k * 7) for k in range(1000)]   # 10 s of receive instants
    for r, sim in clocks:
        clock.add(r, sim)
    newest_ns = clocks[-1][0]
    assert len(clock) < 3 * history_s * NS_PER_S / period_ns   # old ones are forgotten
    for r in range(newest_ns - round(history_s * NS_PER_S), newest_ns + period_ns,
                   period_ns // 3):
        assert clock.sim_ns_at(r) == reference_sim_ns(clocks, r)


@pytest.mark.parametrize('history_s', [0.0, -1.0, float('nan')])
def test_a_history_that_is_not_positive_is_refused_by_name(history_s):
    with pytest.raises(ValueError, match=r'`history_s` must be positive, got'):
        ReceiptClock(history_s)
