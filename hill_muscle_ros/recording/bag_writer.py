"""A rosbag2 bag writer: MCAP storage, as rosbag2's ``mcap`` plugin (Jazzy) writes it.

What rosbag2 (``rosbag2_storage_mcap``, ``rosbag2_cpp``, Jazzy) puts in a bag,
and what this writer reproduces:

- a directory ``<name>/`` holding ``<name>_0.mcap`` and ``metadata.yaml``
  (``rosbag2_bagfile_information``, format version 9);
- the MCAP header profile ``ros2``, chunked, uncompressed by default;
- one schema per message type, named ``pkg/msg/Type``, encoding ``ros2msg``,
  whose data is the type's ``.msg`` file followed by every type it depends on,
  each after a line of 80 ``=`` and a ``MSG: pkg/Type`` line, depth-first in
  sorted order (``LocalMessageDefinitionSource::get_full_text``);
- one channel per topic, message encoding ``cdr``, with channel metadata
  ``offered_qos_profiles`` (the YAML list of the publishers' QoS, policies
  spelled as rmw strings) and ``topic_type_hash`` (RIHS01);
- messages with ``log_time`` = receive time, ``publish_time`` = send time
  and ``sequence`` = the publisher's sequence number (0 if unknown);
- at close, a metadata record named ``rosbag2`` whose ``serialized_metadata``
  is the bag metadata in YAML.

Message definitions are read from the ``.msg`` files that the installed ROS
packages ship in their ``share`` directories; nothing is pasted here. The MCAP
records themselves (header, schemas, channels, chunks, indexes, summary) are
written by the ``mcap`` library's :class:`mcap.writer.Writer`; this module
adds only the rosbag2 layer around it.

Why not ``rosbags.rosbag2.Writer`` (rosbags 0.11.9, with its MCAP storage)?
It was read and tried (the same 2.5 s of one 1 kHz topic as
``test_recording_bag.py``); for a live recorder it lacks:

- crash safety: its MCAP writer keeps the open chunk in memory until 1 MiB
  and has no public call to close one, so a recording killed (SIGKILL, power
  loss) after 2.5 s left a 0-byte file, nothing readable; here chunks close
  after :data:`CHUNK_DURATION_S` of log *or wall* time (a quiet topic still
  reaches the disk), 2000 of those 2500 messages survive
  (``test_closed_chunks_survive_a_crash``), and a failed write or close
  still leaves a ``metadata.yaml`` of what is on disk;
- a publish time apart from the log time (it writes one timestamp to both)
  and the publisher's sequence numbers (always 0): the recorder stores the
  header stamp and the sequence, from which lost messages are counted;
- the channel metadata ``topic_type_hash`` (only ``offered_qos_profiles``)
  and ``ros_distro: jazzy`` (it writes ``rosbags``);
- rosbag2's file name ``<name>_0.mcap`` (it writes ``<name>.mcap``), and
  an existing empty output directory (it refuses any existing path).

Reading is left to libraries: tests read every bag back with rosbags
(``Reader``, ``AnyReader``) and with ``mcap_ros2``, independent of this code.
"""
from __future__ import annotations

import json
import os
import re
import shutil
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

import yaml
from mcap.writer import CompressionType, Writer

from ..timebase import NS_PER_S

#: rosbag2 metadata format version written by ROS 2 Jazzy (QoS policies as strings,
#: ``offered_qos_profiles`` as a YAML list in ``metadata.yaml``).
ROSBAG2_METADATA_VERSION = 9
ROS_DISTRO = 'jazzy'
STORAGE_IDENTIFIER = 'mcap'
MCAP_PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
METADATA_RECORD_NAME = 'rosbag2'
METADATA_RECORD_KEY = 'serialized_metadata'
METADATA_FILE = 'metadata.yaml'
#: rosbag2 separates dependent definitions with a line of exactly 80 '='.
DEFINITION_SEPARATOR = '=' * 80 + '\n'
#: Longest span of data one chunk holds. A chunk reaches the disk only when
#: it is closed, so this bounds what a SIGKILL can lose.
CHUNK_DURATION_S = 1.0
#: rosbag2's MCAP default chunk size (768 KiB); the duration limit closes
#: chunks earlier at the rates this package records.
CHUNK_SIZE_BYTES = 768 * 1024
#: Refuse to start a recording with less free space than this.
MIN_FREE_BYTES = 16 * 1024 * 1024
#: Guards against a cyclic (broken) set of .msg files, as rosbag2 does.
MAX_DEFINITION_DEPTH = 50
#: The MCAP header's free-form writer name.
LIBRARY = 'hill_muscle_ros (mcap python writer)'

#: Field types of .msg files, as rosbag2 matches them ("foo_msgs/Bar" in "foo_msgs/Bar[] bar").
_MSG_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
_PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16',
    'int32', 'uint32', 'int64', 'uint64', 'string'})
_ROS_NAME = r'[a-zA-Z][a-zA-Z0-9_]*'
_TYPE_NAME = re.compile(rf'^({_ROS_NAME})/(?:({_ROS_NAME})/)?({_ROS_NAME})$')


class BagOutputError(RuntimeError):
    """The bag cannot be written where asked (exists, not writable, disk full)."""


# --------------------------------------------------------------------------- definitions

def share_directory(package: str) -> Path:
    """The ``share/<package>`` directory of an installed ROS package.

    Looks the package up in the ament index (``AMENT_PREFIX_PATH``) and, when
    it is not there, in this Python environment's prefix, where the ROS 2 wheels
    install their ``share`` tree and ament index.

    :raises LookupError: if the package is not installed
    """
    try:
        from ament_index_python.packages import get_package_share_directory
        return Path(get_package_share_directory(package))
    except (ImportError, LookupError, OSError, ValueError):
        pass
    prefix = Path(sys.prefix)
    marker = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / package
    if marker.exists() or (prefix / 'share' / package).is_dir():
        return prefix / 'share' / package
    raise LookupError(f'ROS package `{package}` is not installed (not on AMENT_PREFIX_PATH '
                      f'nor in {prefix / "share"})')


def split_type_name(type_name: str) -> tuple[str, str, str]:
    """``(package, namespace, name)`` of a ROS interface type name.

    :param type_name: ``pkg/msg/Type`` (or the short ``pkg/Type``, namespace ``msg``)
    :raises ValueError: naming the text if it is not a type name
    """
    match = _TYPE_NAME.match(type_name)
    if match is None:
        raise ValueError(f'`type_name` must look like `pkg/msg/Type` or `pkg/Type`, '
                         f'got {type_name!r}')
    package, namespace, name = match.groups()
    return package, namespace or 'msg', name


def read_msg_file(type_name: str) -> str:
    """The text of the type's own ``.msg`` file, as installed (without its dependencies).

    The same source :func:`message_definition` builds a bag's schema from.

    :param type_name: e.g. ``geometry_msgs/msg/WrenchStamped``
    :raises ValueError: if ``type_name`` is not a type name
    :raises LookupError: if the package or its ``.msg`` file is not installed
    """
    package, namespace, name = split_type_name(type_name)
    path = share_directory(package) / namespace / f'{name}.msg'
    try:
        return path.read_text(encoding='utf-8')
    except OSError as err:
        raise LookupError(f'no .msg definition for `{type_name}` at {path}: {err}') from None


def _msg_dependencies(text: str, package: str) -> list[str]:
    deps = set()
    for match in _MSG_FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVE_TYPES:
            continue
        deps.add(field_type if '/' in field_type else f'{package}/{field_type}')
    # std::set iteration order in rosbag2: byte-wise sorted.
    return sorted(deps)


def message_definition(type_name: str) -> str:
    """The complete ``ros2msg`` definition of a type, as rosbag2 stores it.

    :param type_name: e.g. ``geometry_msgs/msg/WrenchStamped``
    :return: the type's .msg text followed by each dependency, once, after
        ``====...`` and ``MSG: pkg/Type`` lines
    :raises LookupError: if a .msg file cannot be found
    """
    seen: set[str] = set()

    def append(name: str, depth: int) -> str:
        if depth <= 0:
            raise LookupError(f'reached max recursion depth resolving {type_name}')
        text = read_msg_file(name)
        result = text
        for dep in _msg_dependencies(text, split_type_name(name)[0]):
            if dep not in seen:
                seen.add(dep)
                result += '\n' + DEFINITION_SEPARATOR + f'MSG: {dep}\n'
                result += append(dep, depth - 1)
        return result

    return append(type_name, MAX_DEFINITION_DEPTH)


def type_description_hash(type_name: str) -> str:
    """The type's RIHS01 hash from the ``.json`` type description the package ships.

    :return: e.g. ``RIHS01_705ba9...``, or ``''`` if the package ships none
    """
    package, namespace, name = split_type_name(type_name)
    full = f'{package}/{namespace}/{name}'
    try:
        doc = json.loads((share_directory(package) / namespace / f'{name}.json')
                         .read_text(encoding='utf-8'))
    except (OSError, LookupError, ValueError):
        return ''
    for entry in doc.get('type_hashes', []):
        if entry.get('type_name') == full:
            return str(entry.get('hash_string', ''))
    return ''


# --------------------------------------------------------------------------- QoS

def _duration_dict(duration: Any) -> dict[str, int]:
    nanoseconds = int(getattr(duration, 'nanoseconds', duration))
    return {'sec': nanoseconds // NS_PER_S, 'nsec': nanoseconds % NS_PER_S}


def _policy_name(policy: Any) -> str:
    return policy.name.lower() if hasattr(policy, 'name') else str(policy).lower()


def qos_profile_dict(profile: Any) -> dict[str, Any]:
    """A QoS profile as rosbag2 (metadata version 9) serialises it.

    :param profile: an ``rclpy.qos.QoSProfile`` (e.g. from
        ``Node.get_publishers_info_by_topic``), or a mapping already in this form
    :return: a dict with keys in rosbag2's order; policies as rmw strings
        (``keep_last``, ``reliable``, ``volatile``, ``automatic``) and
        durations as ``{sec, nsec}``
    """
    if isinstance(profile, Mapping):
        return dict(profile)
    return {
        'history': _policy_name(profile.history),
        'depth': int(profile.depth),
        'reliability': _policy_name(profile.reliability),
        'durability': _policy_name(profile.durability),
        'deadline': _duration_dict(profile.deadline),
        'lifespan': _duration_dict(profile.lifespan),
        'liveliness': _policy_name(profile.liveliness),
        'liveliness_lease_duration': _duration_dict(profile.liveliness_lease_duration),
        'avoid_ros_namespace_conventions': bool(profile.avoid_ros_namespace_conventions),
    }


def _dump_yaml(data: Any) -> str:
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False).rstrip('\n')


def serialize_qos_profiles(profiles: Iterable[Any]) -> str:
    """The ``offered_qos_profiles`` channel metadata string (YAML list of profiles)."""
    return _dump_yaml([qos_profile_dict(p) for p in profiles])


# --------------------------------------------------------------------------- output

def prepare_output_dir(bag_dir: Path, *, min_free_bytes: int = MIN_FREE_BYTES) -> None:
    """Create the bag directory, or refuse with a clear reason.

    :raises BagOutputError: if it exists and is not empty (a bag is never
        overwritten), is not a directory, cannot be created or written, or
        the disk has less than ``min_free_bytes`` free
    """
    if bag_dir.exists():
        if not bag_dir.is_dir():
            raise BagOutputError(f'bag output {bag_dir} exists and is not a directory')
        if any(bag_dir.iterdir()):
            raise BagOutputError(f'bag output directory {bag_dir} exists and is not empty; '
                                 f'refusing to overwrite it; choose another directory')
    try:
        bag_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise BagOutputError(f'cannot create bag directory {bag_dir}: '
                             f'{err.strerror or err}') from None
    if not os.access(bag_dir, os.W_OK | os.X_OK):
        raise BagOutputError(f'bag directory {bag_dir} is not writable')
    free = shutil.disk_usage(bag_dir).free
    if free < min_free_bytes:
        raise BagOutputError(f'only {free} bytes free for {bag_dir}; need at least '
                             f'{min_free_bytes} to record')


@dataclass
class _Topic:
    name: str
    type: str
    channel_id: int
    offered_qos_profiles: list[dict[str, Any]]
    type_hash: str
    count: int = 0
    flushed_count: int = 0


@dataclass
class _TimeRange:
    start_ns: int | None = None
    end_ns: int | None = None

    def add(self, t_ns: int) -> None:
        self.start_ns = t_ns if self.start_ns is None else min(self.start_ns, t_ns)
        self.end_ns = t_ns if self.end_ns is None else max(self.end_ns, t_ns)


@dataclass
class _Chunk:
    first_log_ns: int | None = None
    opened_at_s: float = 0.0
    messages: int = 0
    per_topic: dict[str, int] = field(default_factory=dict)


class BagWriter:
    """Writes one rosbag2 bag: ``<bag_dir>/<name>_0.mcap`` and ``metadata.yaml``.

    Chunks close when they span ``chunk_duration_s`` of log time or of wall
    time, whichever comes first, so that after a crash everything but the last
    second can be read. :meth:`close` writes the summary, the ``rosbag2``
    metadata record and ``metadata.yaml``; it is safe to call twice.

    :param bag_dir: the bag directory; must not exist or be empty
    :param chunk_duration_s: [s] longest span of one chunk
    :param chunk_size_bytes: [B] largest chunk (uncompressed)
    :param custom_data: ``custom_data`` strings for ``metadata.yaml``
    :param wall_clock: [s] monotonic clock used for the wall-time chunk limit
    :raises BagOutputError: see :func:`prepare_output_dir`
    """

    def __init__(self, bag_dir: str | os.PathLike, *,
                 chunk_duration_s: float = CHUNK_DURATION_S,
                 chunk_size_bytes: int = CHUNK_SIZE_BYTES,
                 custom_data: Mapping[str, str] | None = None,
                 wall_clock: Callable[[], float] = time.monotonic,
                 min_free_bytes: int = MIN_FREE_BYTES) -> None:
        if not chunk_duration_s > 0:
            raise ValueError(f'`chunk_duration_s` must be positive, got {chunk_duration_s!r}')
        self.path = Path(bag_dir)
        prepare_output_dir(self.path, min_free_bytes=min_free_bytes)
        self.mcap_path = self.path / f'{self.path.name}_0.mcap'
        try:
            self._file = open(self.mcap_path, 'xb')
        except OSError as err:
            raise BagOutputError(f'cannot create {self.mcap_path}: {err.strerror or err}') from None
        self._chunk_duration_ns = int(round(chunk_duration_s * NS_PER_S))
        self._chunk_duration_s = chunk_duration_s
        self._wall_clock = wall_clock
        self._custom_data = dict(custom_data or {})
        self._writer = Writer(self._file, chunk_size=chunk_size_bytes,
                              compression=CompressionType.NONE)
        self._writer.start(profile=MCAP_PROFILE, library=LIBRARY)
        self._file.flush()
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[str, int] = {}
        self._times = _TimeRange()
        self._flushed_times = _TimeRange()
        self._chunk = _Chunk(opened_at_s=wall_clock())
        self.closed = False

    # ----------------------------------------------------------------- topics
    def add_topic(self, name: str, type_name: str, *,
                  offered_qos_profiles: Iterable[Any] = (),
                  type_hash: str | None = None,
                  definition: str | None = None) -> None:
        """Register a topic (a channel, and its type's schema the first time).

        :param name: the fully qualified topic name, e.g. ``/force``
        :param type_name: e.g. ``std_msgs/msg/Float64``
        :param offered_qos_profiles: the publishers' QoS (rclpy profiles or dicts)
        :param type_hash: RIHS01 hash; by default from the installed package
        :param definition: the complete .msg definition; by default from the
            installed packages (:func:`message_definition`)
        :raises ValueError: if the topic is already registered
        """
        if name in self._topics:
            raise ValueError(f'topic {name!r} is already in the bag')
        if type_name not in self._schema_ids:
            text = definition if definition is not None else message_definition(type_name)
            self._schema_ids[type_name] = self._writer.register_schema(
                name=type_name, encoding=SCHEMA_ENCODING, data=text.encode('utf-8'))
        qos = [qos_profile_dict(p) for p in offered_qos_profiles]
        type_hash = type_description_hash(type_name) if type_hash is None else type_hash
        channel_id = self._writer.register_channel(
            topic=name, message_encoding=MESSAGE_ENCODING,
            schema_id=self._schema_ids[type_name],
            metadata={'offered_qos_profiles': serialize_qos_profiles(qos),
                      'topic_type_hash': type_hash})
        self._topics[name] = _Topic(name, type_name, channel_id, qos, type_hash)

    def has_topic(self, name: str) -> bool:
        return name in self._topics

    @property
    def counts(self) -> dict[str, int]:
        """Messages handed to the writer, per topic."""
        return {t.name: t.count for t in self._topics.values()}

    @property
    def flushed_counts(self) -> dict[str, int]:
        """Messages in closed chunks (on disk), per topic."""
        return {t.name: t.flushed_count for t in self._topics.values()}

    # ----------------------------------------------------------------- writing
    def write(self, topic: str, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None, sequence: int = 0) -> None:
        """Append one serialized (CDR) message.

        :param topic: a registered topic
        :param data: the CDR bytes, exactly as received
        :param log_time_ns: [ns] receive time
        :param publish_time_ns: [ns] send time (header stamp); defaults to log time
        :param sequence: the publisher's sequence number, 0 if unknown
        :raises OSError: if the file cannot be written (the bag stays readable
            up to the last closed chunk)
        """
        info = self._topics[topic]
        if self._chunk.messages and self._chunk_due(log_time_ns):
            self.flush()
        if self._chunk.first_log_ns is None:
            self._chunk.first_log_ns = log_time_ns
        self._writer.add_message(
            channel_id=info.channel_id, log_time=log_time_ns, data=data,
            publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
            sequence=sequence)
        info.count += 1
        self._chunk.messages += 1
        self._chunk.per_topic[topic] = self._chunk.per_topic.get(topic, 0) + 1
        self._times.add(log_time_ns)

    def _chunk_due(self, log_time_ns: int) -> bool:
        first = self._chunk.first_log_ns
        return ((first is not None and log_time_ns - first >= self._chunk_duration_ns)
                or self._wall_clock() - self._chunk.opened_at_s >= self._chunk_duration_s)

    def flush_if_due(self) -> None:
        """Close the current chunk if it has been open for ``chunk_duration_s`` of wall time."""
        if self._chunk.messages and (self._wall_clock() - self._chunk.opened_at_s
                                     >= self._chunk_duration_s):
            self.flush()

    def flush(self) -> None:
        """Close the current chunk and push it to the operating system."""
        self._writer.flush()
        for name, n in self._chunk.per_topic.items():
            self._topics[name].flushed_count += n
        if self._chunk.messages:
            self._flushed_times.add(self._times.start_ns)
            self._flushed_times.add(self._times.end_ns)
        self._chunk = _Chunk(opened_at_s=self._wall_clock())

    # ----------------------------------------------------------------- closing
    def metadata(self, *, flushed_only: bool = False) -> dict[str, Any]:
        """The ``rosbag2_bagfile_information`` mapping for this bag."""
        counts = self.flushed_counts if flushed_only else self.counts
        times = self._flushed_times if flushed_only else self._times
        start = times.start_ns or 0
        duration = (times.end_ns - start) if times.end_ns is not None else 0
        total = sum(counts.values())
        return {
            'version': ROSBAG2_METADATA_VERSION,
            'storage_identifier': STORAGE_IDENTIFIER,
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': total,
            'topics_with_message_count': [
                {'topic_metadata': {
                    'name': t.name,
                    'type': t.type,
                    'serialization_format': MESSAGE_ENCODING,
                    'offered_qos_profiles': t.offered_qos_profiles,
                    'type_description_hash': t.type_hash},
                 'message_count': counts[t.name]}
                for t in self._topics.values()],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.mcap_path.name],
            'files': [{'path': self.mcap_path.name,
                       'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': duration},
                       'message_count': total}],
            'custom_data': self._custom_data or None,
            'ros_distro': ROS_DISTRO,
        }

    def write_metadata_yaml(self, *, flushed_only: bool = False) -> Path:
        """Write ``metadata.yaml`` atomically (temporary file, then rename)."""
        target = self.path / METADATA_FILE
        tmp = target.with_name(METADATA_FILE + '.tmp')
        tmp.write_text(_dump_yaml({'rosbag2_bagfile_information':
                                   self.metadata(flushed_only=flushed_only)}) + '\n',
                       encoding='utf-8')
        tmp.replace(target)
        return target

    def close(self) -> None:
        """Finish the MCAP file (summary, ``rosbag2`` record) and write ``metadata.yaml``.

        :raises OSError: if the file cannot be finished; ``metadata.yaml`` then
            describes only the chunks already on disk, and the file is closed
        """
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.add_metadata(METADATA_RECORD_NAME, {
                METADATA_RECORD_KEY: _dump_yaml(self.metadata())})
            self._writer.finish()
            self._file.flush()
            os.fsync(self._file.fileno())
        except OSError:
            self._close_file_quietly()
            self.write_metadata_yaml(flushed_only=True)
            raise
        self._file.close()
        self.write_metadata_yaml()

    def _close_file_quietly(self) -> None:
        try:
            self._file.close()
        except OSError:
            pass  # the buffer cannot reach the disk; what is there stays readable

    def __enter__(self) -> 'BagWriter':
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
