"""Read a bag written by this package (live or offline) into NumPy arrays.

One reader serves the demo, the plots and the tests, whatever wrote the bag.
It decodes with ``mcap`` and ``mcap_ros2`` (the definitions stored in the
bag, no ROS installation needed) and tolerates a file that was never closed
(SIGKILL, power loss): every complete chunk is read, the rest is reported.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, SeekingReader
from mcap_ros2.decoder import DecoderFactory

from ..timebase import NS_PER_S
from .bag_writer import METADATA_FILE

#: Message types whose ``header.stamp`` is the publish time.
_STAMPED_FIELD = 'header'


@dataclass
class TopicData:
    """Every message of one topic, in file order.

    :param name: topic name, e.g. ``/force``
    :param type: message type, e.g. ``std_msgs/msg/Float64``
    :param log_time_ns: [ns] receive times (MCAP ``log_time``)
    :param publish_time_ns: [ns] publish times (header stamp where there is one)
    :param messages: the decoded messages (``mcap_ros2`` dynamic objects)
    :param sequence: the publisher's sequence numbers (0 where unknown)
    """

    name: str
    type: str
    log_time_ns: np.ndarray
    publish_time_ns: np.ndarray
    messages: list[Any] = field(repr=False)
    sequence: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64),
                                 repr=False)

    @property
    def count(self) -> int:
        return len(self.messages)

    def values(self) -> np.ndarray:
        """The scalar each message carries.

        ``std_msgs/Float64``: ``data``; ``WrenchStamped``: ``wrench.force.x``
        [N]; ``geometry_msgs/PointStamped`` (a length knot): ``point.x`` [m];
        ``sensor_msgs/JointState`` (the limb node's one joint): ``position[0]``
        [rad]; ``rosgraph_msgs/Clock``: the clock [s].
        """
        if self.type == 'std_msgs/msg/Float64':
            return np.array([m.data for m in self.messages], dtype=float)
        if self.type == 'geometry_msgs/msg/WrenchStamped':
            return np.array([m.wrench.force.x for m in self.messages], dtype=float)
        if self.type == 'geometry_msgs/msg/PointStamped':
            return np.array([m.point.x for m in self.messages], dtype=float)
        if self.type == 'sensor_msgs/msg/JointState':
            empty = next((k for k, m in enumerate(self.messages) if not len(m.position)), None)
            if empty is not None:
                raise ValueError(f'{self.name}: message {empty} has no position')
            return np.array([m.position[0] for m in self.messages], dtype=float)
        if self.type == 'rosgraph_msgs/msg/Clock':
            return np.array([m.clock.sec + m.clock.nanosec / NS_PER_S for m in self.messages],
                            dtype=float)
        raise ValueError(f'no scalar value defined for {self.type} (topic {self.name})')

    def stamps_ns(self) -> np.ndarray:
        """[ns] header stamps (publish time for messages without a header)."""
        if self.messages and hasattr(self.messages[0], _STAMPED_FIELD):
            return np.array([m.header.stamp.sec * NS_PER_S + m.header.stamp.nanosec
                             for m in self.messages], dtype=np.int64)
        return self.publish_time_ns


@dataclass
class Bag:
    """A bag read back: its topics, its ``metadata.yaml`` and whether it was closed.

    :param path: the bag directory
    :param metadata: ``rosbag2_bagfile_information`` from ``metadata.yaml``,
        or ``None`` if the recording never closed
    :param complete: the MCAP file has its summary (closed properly)
    :param problem: why reading stopped early, if it did
    """

    path: Path
    mcap_path: Path
    metadata: dict[str, Any] | None
    complete: bool
    topics: dict[str, TopicData]
    problem: str = ''

    def counts(self) -> dict[str, int]:
        """Messages per topic."""
        return {name: t.count for name, t in self.topics.items()}

    def topic(self, name: str) -> TopicData:
        """A topic by name.

        A relative name (``force``) finds ``/force``, or else the one topic
        of that name in any namespace (``/left/force``).
        """
        for key in (name, '/' + name.lstrip('/')):
            if key in self.topics:
                return self.topics[key]
        if not name.startswith('/'):
            matches = [t for n, t in self.topics.items() if n.endswith('/' + name)]
            if len(matches) == 1:
                return matches[0]
        raise KeyError(f'{self.path}: no single topic {name!r} '
                       f'(has {", ".join(self.topics)})')

    def has_topic(self, name: str) -> bool:
        try:
            self.topic(name)
        except KeyError:
            return False
        return True


def _mcap_file(bag_dir: Path, metadata: dict[str, Any] | None) -> Path:
    if metadata is not None:
        paths = metadata.get('relative_file_paths') or []
        if paths:
            return bag_dir / paths[0]
    found = sorted(bag_dir.glob('*.mcap'))
    if not found:
        raise FileNotFoundError(f'{bag_dir}: no metadata.yaml and no .mcap file: not a bag')
    return found[0]


def read_metadata(bag_dir: str | Path) -> dict[str, Any] | None:
    """``rosbag2_bagfile_information`` of a bag, or ``None`` without ``metadata.yaml``."""
    path = Path(bag_dir) / METADATA_FILE
    if not path.exists():
        return None
    doc = yaml.safe_load(path.read_text(encoding='utf-8'))
    return doc['rosbag2_bagfile_information']


def read_bag(bag_dir: str | Path, topics: list[str] | None = None) -> Bag:
    """Read a rosbag2 MCAP bag directory.

    :param bag_dir: the bag directory (with ``metadata.yaml`` and the ``.mcap``)
    :param topics: only these topics (default: all)
    :raises FileNotFoundError: if there is no bag there
    """
    bag_dir = Path(bag_dir)
    if not bag_dir.is_dir():
        raise FileNotFoundError(f'{bag_dir}: not a directory')
    metadata = read_metadata(bag_dir)
    mcap_path = _mcap_file(bag_dir, metadata)
    decoders = DecoderFactory()
    cache: dict[int, Any] = {}
    rows: dict[str, tuple[str, list, list, list, list]] = {}
    problem = ''
    with open(mcap_path, 'rb') as stream:
        complete = _has_summary(stream)
        stream.seek(0)
        reader = (SeekingReader(stream) if complete
                  else NonSeekingReader(stream, validate_crcs=True))
        try:
            for schema, channel, message in reader.iter_messages(topics=topics,
                                                                 log_time_order=False):
                decoder = cache.get(channel.id)
                if decoder is None:
                    decoder = decoders.decoder_for(channel.message_encoding, schema)
                    cache[channel.id] = decoder
                entry = rows.setdefault(channel.topic,
                                        (schema.name if schema else '', [], [], [], []))
                entry[1].append(message.log_time)
                entry[2].append(message.publish_time)
                entry[3].append(decoder(message.data))
                entry[4].append(message.sequence)
        except (McapError, EOFError, struct.error, ValueError) as err:
            if complete:
                raise
            # An unclosed file ends in a partial record: keep what came before it.
            problem = f'{type(err).__name__}: {err}'
    data = {name: TopicData(name, type_, np.asarray(log, dtype=np.int64),
                            np.asarray(pub, dtype=np.int64), msgs,
                            np.asarray(seq, dtype=np.int64))
            for name, (type_, log, pub, msgs, seq) in rows.items()}
    for entry in (metadata or {}).get('topics_with_message_count', []):
        meta = entry['topic_metadata']
        if meta['name'] not in data and (topics is None or meta['name'] in topics):
            empty = np.zeros(0, dtype=np.int64)
            data[meta['name']] = TopicData(meta['name'], meta['type'], empty, empty, [])
    return Bag(bag_dir, mcap_path, metadata, complete, data, problem)


def _has_summary(stream) -> bool:
    """The file ends with a footer pointing at a summary (it was closed)."""
    try:
        summary = SeekingReader(stream).get_summary()
    except (McapError, EOFError, struct.error, ValueError, OSError):
        return False
    return summary is not None
