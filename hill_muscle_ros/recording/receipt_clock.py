"""The sim time in force at a DDS receive instant, for a recorder on sim time.

A live recorder stamps each message's ``log_time`` with the time at which it
received the message. On the system clock DDS gives that instant itself (the
``received_timestamp`` of a take). On sim time (``use_sim_time``) the node's
clock only moves when its executor has handled a ``/clock`` message, so a
clock read when Python takes the message lags by the take period and by any
wait of the executor for a CPU; at a real-time factor of 10, 0.15 s of
wall-clock wait moved a batch of 136 messages 1.5 s of sim time later (a
recorder beside three other ROS tests on two cores).

:class:`ReceiptClock` instead keeps the ``/clock`` messages with their own DDS
receive instants. A message received at system time ``r`` gets the sim time of
the newest ``/clock`` message received at or before ``r``: what the node's clock
would have read at ``r`` had it handled every ``/clock`` message at once. The
remaining error is the DDS receive threads' own latency, the same as on the
system clock.

Pure Python: no rclpy.
"""
from __future__ import annotations

import bisect

from ..timebase import NS_PER_S

#: [s] how much ``/clock`` history is kept, on the receive instants' (system)
#: clock: a message can wait in a recorder's DDS queue for up to 10 s at 1 kHz
#: (its queue depth), so three times that.
HISTORY_S = 30.0


class ReceiptClock:
    """``/clock`` messages by their DDS receive instants; the sim time at any instant.

    :param history_s: [s] receive instants older than this before the newest
        are forgotten (the newest one before them is kept)
    :raises ValueError: if ``history_s`` is not positive
    """

    def __init__(self, history_s: float = HISTORY_S) -> None:
        if not history_s > 0.0:
            raise ValueError(f'`history_s` must be positive, got {history_s!r}')
        self._history_ns = round(history_s * NS_PER_S)
        self._received_ns: list[int] = []
        self._sim_ns: list[int] = []

    def __len__(self) -> int:
        return len(self._received_ns)

    def add(self, received_ns: int, sim_ns: int) -> None:
        """Keep one ``/clock`` message.

        :param received_ns: [ns] its DDS receive instant (system clock)
        :param sim_ns: [ns] the sim time it carries
        """
        # One writer's messages arrive in order; several /clock writers may
        # interleave, so insert in place rather than assume order.
        at = bisect.bisect_right(self._received_ns, received_ns)
        self._received_ns.insert(at, received_ns)
        self._sim_ns.insert(at, sim_ns)
        self._forget_before(self._received_ns[-1] - self._history_ns)

    def sim_ns_at(self, received_ns: int) -> int | None:
        """[ns] the sim time of the newest ``/clock`` message received at or
        before ``received_ns``; None if none was (or it was forgotten).

        :param received_ns: [ns] a DDS receive instant (system clock)
        """
        at = bisect.bisect_right(self._received_ns, received_ns)
        return self._sim_ns[at - 1] if at else None

    def _forget_before(self, oldest_ns: int) -> None:
        # Keep the newest entry before the cut: it is the sim time in force
        # at the cut. Trimmed in blocks, so the cost per message stays constant.
        cut = bisect.bisect_left(self._received_ns, oldest_ns) - 1
        if cut > 0 and cut * 2 >= len(self._received_ns):
            del self._received_ns[:cut]
            del self._sim_ns[:cut]
