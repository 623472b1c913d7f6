"""The stimulation watchdog of the simulator and limb nodes, without ROS.

A node holds the last stimulation it received. If the controller goes quiet
(it crashed, its network went), the held stimulation would go on for ever;
so after ``input_timeout_s`` of *simulated* time with no input message it
drops to 0, until the next message. The nodes call :func:`watchdog_trips`
before each step, on their own simulated clock; the tests drive that clock.
"""

#: [s] default ``input_timeout_s`` of the simulator and limb nodes.
DEFAULT_INPUT_TIMEOUT_S = 0.5
#: [s] 0 disables the watchdog; an hour is longer than any FES session gap.
INPUT_TIMEOUT_RANGE_S = (0.0, 3600.0)


def watchdog_trips(now_s: float, last_input_s: float, timeout_s: float,
                   stimulating: bool) -> bool:
    """Whether the held stimulation must drop to 0 before the step at ``now_s``.

    :param now_s: [s] the node's simulated time at the start of the step
    :param last_input_s: [s] simulated time at which the last input arrived
    :param timeout_s: [s] ``input_timeout_s``; 0 turns the watchdog off
    :param stimulating: whether the held stimulation is above 0 (a muscle at
        rest has nothing to drop, so a quiet controller is no fault then)
    :return: True once more than ``timeout_s`` has passed since the last input
    """
    return timeout_s > 0.0 and stimulating and now_s - last_input_s > timeout_s
