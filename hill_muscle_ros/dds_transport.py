"""Keep the package's nodes off Fast DDS's shared-memory transport (UDP only).

Why. Fast DDS 2.14 (the DDS of the Jazzy wheels) checks the listeners of a
shared-memory port the first time a participant sends to it, and when the
check cannot tell yet it sleeps a third of the port's health-check timeout:
1000 ms / 3 = 333 ms. That happens on the thread that has just received the
discovery data of a process joining the graph (a new reader to match), while
it holds its participant's send lock, which Fast DDS takes without a time limit
(it bounds it by a writer's ``max_blocking_time`` only in its strict real-time
build). Every publish of the process waits for that lock, so a 1 kHz
simulator stopped for 333 ms, now and then, whenever a tool such as
``ros2 topic pub`` or ``ros2 param get`` started: measured with a native
stack of the sleeping thread (``StatefulWriter::matched_reader_add`` ->
``SharedMemTransport::find_port`` -> ``open_port_internal`` -> ``nanosleep``)
while the simulator's ``publish('force')`` waited 332.6 ms (upstream issue
eProsima/Fast-DDS#6535). UDP loopback has no such check.

What. :func:`use_udp_transport` sets, in the environment of the calling
process and before ``rclpy.init``, what makes rmw_fastrtps create a UDPv4-only
participant with the discovery scope the user asked for:

- ``ROS_AUTOMATIC_DISCOVERY_RANGE`` unset or ``SUBNET``: Fast DDS's own
  ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``, and a profile (:func:`subnet_profile`)
  with only the reliable endpoints' timing below (the participant keeps Fast
  DDS's discovery).
- ``LOCALHOST`` (also the deprecated ``ROS_LOCALHOST_ONLY=1``, and a value rcl
  does not know, which rcl reads as localhost): rmw_fastrtps replaces the
  transports with shared memory plus UDP in this mode, so the node asks rmw
  for ``SYSTEM_DEFAULT`` (Fast DDS as configured) and hands Fast DDS a profile
  (:func:`localhost_profile`) with what rmw_fastrtps's localhost mode sets:
  no multicast, the unicast discovery port, 127.0.0.1 and the
  ``ROS_STATIC_PEERS`` as initial peers over 32 participant ports, on UDPv4;
  and a participant announcement every :data:`ANNOUNCEMENT_PERIOD_S` in
  place of Fast DDS's 3 s, and the reliable endpoints' timing below.
- ``OFF`` and ``SYSTEM_DEFAULT``: nothing (no other process to wait for, or
  Fast DDS exactly as the user configured it).

Nothing changes either if the user configures Fast DDS transports already
(:data:`USER_FASTDDS_SETTINGS`, or a ``DEFAULT_FASTRTPS_PROFILES.xml`` in the
working directory; a profile this module wrote, inherited from a parent
process that set itself up this way, is not the user's and is set up again),
under another RMW, or with
``HILL_MUSCLE_DDS_TRANSPORT=rmw``. Other processes (ros2cli, rviz) keep
their transports and reach the nodes over UDP.

Announcements. A participant that joins announces itself to every port of
the host at once; a node that has run for a while answers at once with its
own announcement, and the newcomer, still starting, often loses that answer
(Fast DDS 2.14, over UDP: measured with strace, the answer arrived 0.7 ms
after the newcomer's first announcement and nothing followed). It then learns
of the node only at the node's next periodic announcement: a tool, a probe or
a restarted node waited up to 3 s for nodes that were already there (a new
participant found a simulator that had run 3 s in a median 2.27 s, at most
2.71 s, in 12 tries; with the 0.5 s period a median 0.46 s, at most 0.75 s).
The cost is one small message per port and period (32 ports, about 470 bytes).

Heartbeats. A reliable reader learns that it missed a sample from a later
sample or from the writer's heartbeat. When UDP drops the tail of a burst
(a receive buffer that overflows while its process is busy), nothing follows
it, and the tail is repaired only after the writer's next periodic heartbeat:
Fast DDS's default period is 3 s. A fresh-clone test run saw the last 23 of
302 stamped length knots sent in one burst to a 10x-real-time simulator arrive
2.53 s late. Measured with a reader whose receive buffer was cut to 4 kB, 300
reliable messages sent in one burst, five bursts (``test_dds_transport``):
with the 3 s period they took 2.93-3.17 s to arrive whole; with 0.1 s,
0.17-0.32 s; with 10 ms (below), 0.04-0.10 s. Fast DDS sends periodic heartbeats only while a writer holds
samples some reader has not acknowledged, so an idle or fully acknowledged
writer sends nothing more.

Acknowledgements. A reader acknowledges samples only when a heartbeat asks,
and the writer adds one to its data only when its send buffer fills: on a
quiet link every acknowledgement waits for the next periodic heartbeat.
Measured on an idle machine, a sample published to a simulator that had
matched long before was acknowledged after 100.2-101.1 ms with the 0.1 s
period (5 tries), 2999-3001 ms with Fast DDS's 3 s (the default of the
unset range, 3 tries). The protocol player waits for acknowledgements to
start and to end (measured before: its handshake took 150 ms, 3 s with the range
unset, and its final zero went unacknowledged after 2 s). Hence
:data:`HEARTBEAT_PERIOD_S` of 10 ms, and 1 ms in place of Fast DDS's 5 ms
for a reader's answer to a heartbeat (:data:`HEARTBEAT_RESPONSE_DELAY_S`) and
a writer's answer to a negative acknowledgement
(:data:`NACK_RESPONSE_DELAY_S`): an acknowledgement then takes at most about
11 ms and a repair about 12 ms, under 20 ms. The cost, only while a writer
holds unacknowledged samples, is a heartbeat and its answer per 10 ms and
reader, against 1000 samples a second from the nodes' 1 kHz writers.

What it costs: shared memory saves copies of large messages; the package's
messages are a few hundred bytes. Reliability, history and every other QoS are
unchanged, so a reliable subscriber (the recorder) still receives every
message.

No rclpy here: the environment must be set before rclpy loads the RMW.
"""
from __future__ import annotations

import hashlib
import os
import socket
import tempfile
# html's escape with quote=False replaces &, < and > as xml.sax.saxutils.escape
# does, without its imports of urllib.request and http.client: about 20 ms of
# every node's start-up (python -X importtime).
from html import escape
from pathlib import Path
from typing import MutableMapping

#: Environment variable that chooses the nodes' DDS transport: one of :data:`TRANSPORTS`.
TRANSPORT_ENV = 'HILL_MUSCLE_DDS_TRANSPORT'
#: ``udp``: UDPv4 only (this module); ``rmw``: whatever rmw and Fast DDS choose
#: (shared memory and UDP on one host).
TRANSPORTS = ('udp', 'rmw')
DEFAULT_TRANSPORT = 'udp'

#: RMW implementations built on Fast DDS (the Jazzy default when none is set).
FASTDDS_RMWS = ('rmw_fastrtps_cpp', 'rmw_fastrtps_dynamic_cpp')
DEFAULT_RMW = 'rmw_fastrtps_cpp'
#: Variables with which a user configures Fast DDS's transports: left alone.
USER_FASTDDS_SETTINGS = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE',
                         'FASTDDS_BUILTIN_TRANSPORTS')
#: Fast DDS loads this file from the working directory unless
#: ``SKIP_DEFAULT_XML`` is ``1``: a user configuration too.
CWD_PROFILES_FILE = 'DEFAULT_FASTRTPS_PROFILES.xml'
SKIP_CWD_PROFILES_ENV = 'SKIP_DEFAULT_XML'

RANGE_ENV = 'ROS_AUTOMATIC_DISCOVERY_RANGE'
STATIC_PEERS_ENV = 'ROS_STATIC_PEERS'
LOCALHOST_ONLY_ENV = 'ROS_LOCALHOST_ONLY'
#: The values rcl reads; anything else is read as ``LOCALHOST``, and an empty
#: or unset variable as ``SUBNET`` (rcl's default).
RANGES = ('OFF', 'LOCALHOST', 'SUBNET', 'SYSTEM_DEFAULT')
#: rmw_fastrtps's UDP ``maxInitialPeersRange`` in localhost mode: participants
#: (roughly processes) per host that discovery reaches.
LOCALHOST_MAX_INITIAL_PEERS = 32
#: [s] period of the participant announcements in the localhost profile (Fast
#: DDS's default is 3 s): the longest a participant that missed a node's answer
#: to its own announcement waits to discover the node (module docstring).
ANNOUNCEMENT_PERIOD_S = 0.5
#: [s] period of a reliable writer's heartbeats in both profiles (Fast DDS's
#: default is 3 s): bounds how late a reader acknowledges a sample, and learns
#: of samples UDP lost at the end of a burst (module docstring).
HEARTBEAT_PERIOD_S = 0.01
#: [s] how long a reliable reader waits to answer a heartbeat (Fast DDS: 5 ms),
#: so that one answer covers a burst of heartbeats; part of every acknowledgement.
HEARTBEAT_RESPONSE_DELAY_S = 0.001
#: [s] how long a reliable writer waits to resend what a reader reported
#: missing (Fast DDS: 5 ms), so that one repair covers several readers; part
#: of every repair.
NACK_RESPONSE_DELAY_S = 0.001
#: Where the localhost profile's file goes when no directory is given.
PROFILE_FILE_PREFIX = 'hill_muscle_ros_fastdds_udp_'


def discovery_range(environ: MutableMapping[str, str]) -> str:
    """The discovery range rcl will use, from the environment as rcl reads it."""
    if environ.get(LOCALHOST_ONLY_ENV) == '1':
        return 'LOCALHOST'              # rcl: the deprecated variable still prevails
    value = environ.get(RANGE_ENV, '')
    if value == '':
        return 'SUBNET'
    return value if value in RANGES else 'LOCALHOST'


def static_peer_addresses(environ: MutableMapping[str, str]) -> list[str]:
    """IPv4 addresses of ``ROS_STATIC_PEERS`` (``;``-separated names or addresses).

    The first IPv4 address of each name, as rmw_fastrtps resolves them.

    :raises ValueError: naming the peer that does not resolve
    """
    addresses = []
    for peer in environ.get(STATIC_PEERS_ENV, '').split(';'):
        peer = peer.strip()
        if not peer:
            continue
        try:
            infos = socket.getaddrinfo(peer, None, family=socket.AF_INET)
        except OSError as err:
            raise ValueError(f'environment variable {STATIC_PEERS_ENV}: peer {peer!r} does not '
                             f'resolve to an IPv4 address ({err})') from None
        addresses.append(infos[0][4][0])
    return addresses


def _duration_xml(tag: str, seconds: float) -> str:
    """``<tag><sec>..</sec><nanosec>..</nanosec></tag>``: a Fast DDS XML duration."""
    sec, nanosec = divmod(round(seconds * 1e9), 1_000_000_000)
    return f'<{tag}><sec>{sec}</sec><nanosec>{nanosec}</nanosec></{tag}>'


def _endpoint_profiles() -> str:
    """The default data writer and data reader profiles of both profiles: the
    reliable endpoints' timing (module docstring, "Acknowledgements").
    rmw_fastrtps starts every endpoint from them and sets only the ROS QoS on
    top."""
    return f'''  <data_writer profile_name="hill_muscle_ros_writer" is_default_profile="true">
    <times>
      {_duration_xml('heartbeatPeriod', HEARTBEAT_PERIOD_S)}
      {_duration_xml('nackResponseDelay', NACK_RESPONSE_DELAY_S)}
    </times>
  </data_writer>
  <data_reader profile_name="hill_muscle_ros_reader" is_default_profile="true">
    <times>
      {_duration_xml('heartbeatResponseDelay', HEARTBEAT_RESPONSE_DELAY_S)}
    </times>
  </data_reader>
'''


def subnet_profile() -> str:
    """A Fast DDS XML profile for the unset or ``SUBNET`` range: the reliable
    endpoints' timing only (:func:`_endpoint_profiles`). No participant
    profile, so discovery is Fast DDS's own and ``FASTDDS_BUILTIN_TRANSPORTS``
    still chooses the transports (measured: with both set, a node maps no
    Fast DDS shared-memory segment)."""
    return f'''<?xml version="1.0" encoding="UTF-8" ?>
<!-- Written by hill_muscle_ros (dds_transport.py): the reliable endpoints'
     timing for the SUBNET discovery range. -->
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
{_endpoint_profiles()}</profiles>
'''


def localhost_profile(static_peers: list[str]) -> str:
    """A Fast DDS XML profile: rmw_fastrtps's localhost discovery, on UDPv4 only.

    The default participant profile: no multicast locator (a default unicast
    metatraffic locator instead), initial peers 127.0.0.1 and ``static_peers``,
    one UDPv4 transport with :data:`LOCALHOST_MAX_INITIAL_PEERS` in place of
    the built-in shared memory and UDP transports, an announcement every
    :data:`ANNOUNCEMENT_PERIOD_S`; and the default data writer and reader
    profiles of :func:`_endpoint_profiles`.

    :param static_peers: IPv4 addresses of ``ROS_STATIC_PEERS``
    """
    peers = ''.join(f'\n          <locator><udpv4><address>{escape(address, quote=False)}</address></udpv4>'
                    '</locator>' for address in static_peers)
    return f'''<?xml version="1.0" encoding="UTF-8" ?>
<!-- Written by hill_muscle_ros (dds_transport.py): rmw_fastrtps's
     ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST discovery, on UDPv4 only. -->
<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">
  <transport_descriptors>
    <transport_descriptor>
      <transport_id>hill_muscle_ros_udpv4</transport_id>
      <type>UDPv4</type>
      <maxInitialPeersRange>{LOCALHOST_MAX_INITIAL_PEERS}</maxInitialPeersRange>
    </transport_descriptor>
  </transport_descriptors>
  <participant profile_name="hill_muscle_ros_localhost_udpv4" is_default_profile="true">
    <rtps>
      <builtin>
        <discovery_config>
          {_duration_xml('leaseAnnouncement', ANNOUNCEMENT_PERIOD_S)}
        </discovery_config>
        <metatrafficUnicastLocatorList><locator/></metatrafficUnicastLocatorList>
        <initialPeersList>{peers}
          <locator><udpv4><address>127.0.0.1</address></udpv4></locator>
        </initialPeersList>
      </builtin>
      <userTransports><transport_id>hill_muscle_ros_udpv4</transport_id></userTransports>
      <useBuiltinTransports>false</useBuiltinTransports>
    </rtps>
  </participant>
{_endpoint_profiles()}</profiles>
'''


def write_profile(text: str, directory: Path | None = None) -> Path:
    """Write ``text`` to a file named by its hash (once) and return the path.

    Nodes starting together write the same bytes: each writes a private
    temporary file and renames it into place, so none reads a partial file.

    :param directory: default: ``$XDG_RUNTIME_DIR``, else the temporary directory
    """
    if directory is None:
        directory = Path(os.environ.get('XDG_RUNTIME_DIR') or tempfile.gettempdir())
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    path = Path(directory) / f'{PROFILE_FILE_PREFIX}{os.getuid()}_{digest}.xml'
    try:
        if path.stat().st_uid == os.getuid() and path.read_text() == text:
            return path
    except OSError:
        pass  # not there yet (or unreadable): write it
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=path.stem, suffix='.tmp')
    try:
        with os.fdopen(fd, 'w') as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def _is_own_profile(value: str) -> bool:
    """Whether a profiles-file variable names a profile :func:`write_profile`
    wrote: inherited from a process of the package (a test run or a launcher
    that set up its own participant this way), not a user's configuration, so
    it is set up again for this process's discovery range."""
    return Path(value).name.startswith(PROFILE_FILE_PREFIX)


def use_udp_transport(environ: MutableMapping[str, str] | None = None,
                      profile_dir: Path | None = None) -> str | None:
    """Set ``environ`` so that the next Fast DDS participant uses UDPv4 only.

    Call before ``rclpy.init``. See the module docstring for when and how.

    :param environ: the environment to change (default: ``os.environ``)
    :param profile_dir: where the profile is written (see :func:`write_profile`)
    :return: one line saying what was set and why, or ``None`` if nothing was
    :raises ValueError: on an unknown :data:`TRANSPORT_ENV` value or a
        ``ROS_STATIC_PEERS`` entry that does not resolve
    """
    if environ is None:
        environ = os.environ
    choice = environ.get(TRANSPORT_ENV, DEFAULT_TRANSPORT)
    if choice not in TRANSPORTS:
        raise ValueError(f'environment variable {TRANSPORT_ENV}={choice!r}: expected one of '
                         f'{", ".join(TRANSPORTS)}')
    user_settings = [name for name in USER_FASTDDS_SETTINGS
                     if environ.get(name) and not _is_own_profile(environ[name])]
    if environ.get(SKIP_CWD_PROFILES_ENV) != '1' and Path(CWD_PROFILES_FILE).is_file():
        user_settings.append(f'./{CWD_PROFILES_FILE}')
    scope = discovery_range(environ)
    if (choice != 'udp' or environ.get('RMW_IMPLEMENTATION', DEFAULT_RMW) not in FASTDDS_RMWS
            or user_settings or scope in ('OFF', 'SYSTEM_DEFAULT')):
        return None
    # The log line says the range in force and where it comes from, read before
    # the environment changes: rmw is handed SYSTEM_DEFAULT below, not the user.
    heading = f'DDS: discovery range {scope} ({_range_origin(environ)}) on UDPv4 only'
    why = (f'Fast DDS shared memory can hold every publish of this process for 333 ms '
           f'when another process joins ({TRANSPORT_ENV}=rmw keeps it)')
    if scope == 'SUBNET':
        environ['FASTDDS_BUILTIN_TRANSPORTS'] = 'UDPv4'
        # The endpoints' timing; replaces a profile of the package a parent
        # process set up for its own range (_is_own_profile).
        profile = write_profile(subnet_profile(), profile_dir)
        environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(profile)
        return (f'{heading} (FASTDDS_BUILTIN_TRANSPORTS=UDPv4, Fast DDS profile {profile}): '
                f'{why}')
    # rcl ignores the static peers under the deprecated ROS_LOCALHOST_ONLY=1.
    peers = [] if environ.get(LOCALHOST_ONLY_ENV) == '1' else static_peer_addresses(environ)
    profile = write_profile(localhost_profile(peers), profile_dir)
    environ.pop(LOCALHOST_ONLY_ENV, None)   # it would force rmw's localhost transports
    environ[RANGE_ENV] = 'SYSTEM_DEFAULT'
    environ['FASTRTPS_DEFAULT_PROFILES_FILE'] = str(profile)
    return f'{heading} (Fast DDS profile {profile}): {why}'


def _range_origin(environ: MutableMapping[str, str]) -> str:
    """Where :func:`discovery_range` took the range from, for the log line."""
    if environ.get(LOCALHOST_ONLY_ENV) == '1':
        return f'{LOCALHOST_ONLY_ENV}=1'
    value = environ.get(RANGE_ENV, '')
    if value == '':
        return f"{RANGE_ENV} unset: rcl's default"
    if value not in RANGES:
        return f'{RANGE_ENV}={value!r}, which rcl reads as LOCALHOST'
    return f'{RANGE_ENV}={value}'
