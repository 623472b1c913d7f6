"""Checking a node's input messages: a throttled warning per topic for rejected input."""
from __future__ import annotations

import time

#: [s] at most one bad-input warning per topic in this period.
BAD_INPUT_THROTTLE_S = 1.0


class BadInputWarner:
    """A warning per topic, at most once per ``period_s``, counting the rest.

    rclpy's ``throttle_duration_sec`` throttles per call site, so one helper
    line would let one noisy topic hide another; this keys on the topic.

    :param logger: the node's logger
    :param period_s: [s] shortest interval between two warnings of one topic
    """

    def __init__(self, logger, period_s: float = BAD_INPUT_THROTTLE_S) -> None:
        self._logger = logger
        self._period_s = period_s
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        #: Rejected inputs per topic, logged or not (reported on /diagnostics).
        self.counts: dict[str, int] = {}

    @property
    def total(self) -> int:
        """Rejected inputs on every topic."""
        return sum(self.counts.values())

    def warn(self, topic: str, message: str) -> bool:
        """Count a rejected input on ``topic``; log ``message`` unless one was
        logged less than a period ago.

        :return: whether it was logged
        """
        self.counts[topic] = self.counts.get(topic, 0) + 1
        now = time.monotonic()
        last = self._last.get(topic)
        if last is not None and now - last < self._period_s:
            self._suppressed[topic] = self._suppressed.get(topic, 0) + 1
            return False
        skipped = self._suppressed.pop(topic, 0)
        suffix = f' ({skipped} more since the last warning)' if skipped else ''
        self._logger.warning(message + suffix)
        self._last[topic] = now
        return True
