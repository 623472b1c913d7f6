"""The QoS profiles of the package's topics, shared by the nodes and the recording code.

Below both :mod:`hill_muscle_ros.nodes` and :mod:`hill_muscle_ros.recording`:
the nodes publish and subscribe with these profiles, and an offline bag
declares the profiles the live publishers offer. Imports ``rclpy.qos`` only.
"""
from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

#: Depth of every subscription queue.
QUEUE_DEPTH = 10
#: Reliable, volatile, keep-last 10: what ``create_subscription(..., 10)`` gives.
RELIABLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=QUEUE_DEPTH,
                          reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE)
#: History a publisher keeps for reliable redelivery: 1 s of messages at 1 kHz.
#: With only 10, a subscriber that is descheduled for 10 ms (a recorder
#: writing a chunk on a busy machine) loses messages that DDS had to drop
#: before the subscriber acknowledged them; the cost is memory only.
OUTPUT_HISTORY_DEPTH = 1000
#: Reliable, volatile, keep-last 1000: every output of the package's nodes.
#: A reliable publisher also matches best-effort subscribers (such as the
#: sensor-data QoS), so every subscriber receives the outputs.
OUTPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=OUTPUT_HISTORY_DEPTH,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
