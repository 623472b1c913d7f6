"""The stimulation watchdog on a clock the test drives (no DDS): the node's
step loop checks :func:`watchdog_trips` before each step of 1 / rate_hz."""
import pytest

from hill_muscle_ros.watchdog import watchdog_trips

RATE_HZ = 1000
DT_S = 1.0 / RATE_HZ
#: [s] the nodes' default ``input_timeout_s``.
TIMEOUT_S = 0.5


def first_trip_step(last_input_s: float, timeout_s: float, stimulating: bool = True,
                    steps: int = 2 * RATE_HZ) -> int | None:
    """The first step, counted from t = 0, before which the watchdog trips."""
    for k in range(steps):
        if watchdog_trips(k * DT_S, last_input_s, timeout_s, stimulating):
            return k
    return None


def test_a_quiet_input_trips_at_the_first_step_past_the_timeout():
    # The last input at t = 0: the steps up to 0.5 s keep it; the next drops it.
    assert first_trip_step(0.0, TIMEOUT_S) == round(TIMEOUT_S * RATE_HZ) + 1


def test_the_timeout_counts_from_the_last_input_not_the_first():
    assert first_trip_step(0.7, TIMEOUT_S) == round((0.7 + TIMEOUT_S) * RATE_HZ) + 1


@pytest.mark.parametrize('gap_s', [0.1, 0.25, 0.499])
def test_inputs_closer_than_the_timeout_never_trip(gap_s):
    last_input_s, k = 0.0, 0
    while k * DT_S < 10.0:
        now_s = k * DT_S
        if now_s - last_input_s >= gap_s:
            last_input_s = now_s       # the next message arrives
        assert not watchdog_trips(now_s, last_input_s, TIMEOUT_S, True), now_s
        k += 1


def test_a_muscle_at_rest_has_nothing_to_drop():
    assert first_trip_step(0.0, TIMEOUT_S, stimulating=False) is None


def test_a_zero_timeout_turns_the_watchdog_off():
    assert first_trip_step(0.0, 0.0) is None
