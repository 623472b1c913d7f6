"""The simulator keeps stepping while command-line tools come and go.

What must hold: with the simulator at 1 kHz, the force controller closing the
loop around it (a force target set) and a daemon-like participant polling the
graph, 20 short-lived processes shaped like ros2cli's commands join and leave
the graph a few at a time, and the simulator's tick never pauses for
:data:`MAX_TICK_GAP_S` or more. The gap is the simulator's own statistic (the
longest steady-clock interval between two ticks, in its exit statistics).

Each tool process is a new DDS participant doing what ``ros2 topic echo``,
``ros2 topic pub --once`` and ``ros2 param list`` / ``get`` do: ros2cli's
node (no parameter services of its own, the type description service on), a
subscription to ``force`` until a message arrives, a publisher on
``force_target`` that waits for a matching subscription and publishes once,
and the ListParameters and GetParameters services of both nodes. A tool that
cannot do all of it fails the test, so the churn really happened.

Why it could fail: on Fast DDS's shared-memory transport, each process that
joined could hold every publish of the simulator for 333 ms
(:mod:`hill_muscle_ros.dds_transport` tells how; measured with the real
ros2cli: 265 to 335 ms gaps, "steps due after a stall" warnings, and the
controller starved of force feedback).

The tools run at :data:`TOOL_NICENESS`: each spends about a CPU-second
starting Python and rclpy, and that is a load on the machine, not what their
participants do to the simulator over DDS, which is what is tested here.

A run is repeated only when an independent watcher measured that the machine,
not the simulator, made the gap: :data:`_RUN_QUEUE_WATCHER` is a separate
process that reads, every millisecond, the kernel's account of the simulator's
tick thread (``/proc/<pid>/task/<tid>/schedstat``: time on a CPU, time
runnable but waiting for one). On 2 cores shared with other jobs a thread
that has work to do waits its fair turn behind every busy process, unlike a
process that only sleeps and wakes (``stall_watch``), which saw nothing while
the simulator waited for a CPU 161 ms of a 190 ms gap and computed the other
30 ms (measured). A run is repeated when the ready thread was kept from a CPU
for the bound or longer during the gap and was not blocked (waiting in a call
or on a lock, as in the shared-memory stall) for the bound or longer; the
measurement is printed, and a run without such a wait fails at once.
"""
from __future__ import annotations

import itertools
import os
import re
import sys
import time

import pytest
from std_msgs.msg import Float64

from ros_helpers import DEFAULT_TIMEOUT_S, Probe, ProcessGroup, node_command

pytestmark = [pytest.mark.ros, pytest.mark.slow]

_RUNS = itertools.count()

RATE_HZ = 1000.0
#: [s] the bound on the simulator's longest interval between two ticks: 20
#: steps, far below the 333 ms a joining process could cause and above the
#: few ms of scheduling jitter a busy 2-core machine adds.
MAX_TICK_GAP_S = 0.02
#: Tool processes per run, and how many of them run at once at most.
TOOLS = 20
TOOLS_AT_ONCE = 3
#: [N] the force target the test and the tools publish; the loop is closed
#: once the force passes :data:`LOOP_CLOSED_N` (only stimulation gets it there).
TARGET_N = 5.0
LOOP_CLOSED_N = 1.0
#: Niceness of the tool and daemon processes (see the module docstring).
TOOL_NICENESS = 10
#: [s] the run-queue watcher's sampling period.
WATCH_PERIOD_S = 0.001
#: Runs in all, at most, when each failed one had an external stall measured.
MAX_ATTEMPTS = 3
#: [s] poll period of the daemon-like participant (ros2cli's daemon answers
#: every ``ros2`` command from its graph cache).
DAEMON_POLL_S = 0.1

_STATS_RE = re.compile(r'longest gap between ticks ([\d.]+) ms \(ended at steady time '
                       r'([\d.]+) s\)')

#: The run-queue watcher: argv = pid, tid, period [s], output file. Writes
#: ``<time.monotonic_ns()> <run delay ns>`` lines (the second field of
#: schedstat: time spent runnable on a run queue) until the thread is gone.
_RUN_QUEUE_WATCHER = r'''
import os, sys, time
pid, tid, period_s, path = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
fd = os.open(f'/proc/{pid}/task/{tid}/schedstat', os.O_RDONLY)
with open(path, 'w') as out:
    while True:
        try:
            fields = os.pread(fd, 128, 0).split()
        except OSError:
            break
        if not fields:
            break
        out.write(f'{time.monotonic_ns()} {int(fields[1])} {int(fields[0])}\n')
        time.sleep(period_s)
'''

#: A ros2cli-like command as a new process: argv = namespace, index, target [N], rate [Hz].
_TOOL = r'''
import sys, time
import rclpy
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Float64

ns, index, target, rate_hz = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
deadline = time.monotonic() + float(sys.argv[5])
rclpy.init()
# ros2cli's DirectNode.
node = rclpy.create_node(
    f'_ros2cli_churn_{index}', start_parameter_services=False,
    parameter_overrides=[Parameter('use_sim_time', value=False),
                         Parameter('start_type_description_service', value=True)],
    automatically_declare_parameters_from_overrides=True)

def spin_until(condition, what):
    while not condition():
        if time.monotonic() > deadline:
            sys.exit(f'tool {index}: timed out waiting for {what}')
        rclpy.spin_once(node, timeout_sec=0.05)

forces = []
node.create_subscription(Float64, f'{ns}/force', lambda m: forces.append(m.data), 10)
pub = node.create_publisher(Float64, f'{ns}/force_target', 10)
# ros2 topic pub --once: wait for a matching subscription, publish once.
spin_until(lambda: pub.get_subscription_count() > 0, 'a force_target subscription')
pub.publish(Float64(data=target))
spin_until(lambda: forces, 'a force message')
for name in (f'{ns}/simulator', f'{ns}/force_controller'):
    client = AsyncParameterClient(node, name)
    spin_until(client.services_are_ready, f'the parameter services of {name}')
    listed = client.list_parameters()
    spin_until(listed.done, f'ListParameters of {name}')
    if 'rate_hz' not in listed.result().result.names:
        sys.exit(f'tool {index}: {name} lists no rate_hz')
    got = client.get_parameters(['rate_hz'])
    spin_until(got.done, f'GetParameters of {name}')
    print(f'{name} rate_hz {got.result().values[0].double_value}', flush=True)
    if name.endswith('/simulator') and got.result().values[0].double_value != rate_hz:
        sys.exit(f'tool {index}: {name} rate_hz is {got.result().values[0]}, not {rate_hz}')
node.destroy_node()
rclpy.shutdown()
'''

#: A participant like ros2cli's daemon: it polls the graph until stopped.
_DAEMON = r'''
import sys, time
import rclpy
from rclpy.executors import ExternalShutdownException
rclpy.init()
node = rclpy.create_node('_ros2cli_daemon_churn', start_parameter_services=False)
polls = 0
try:
    while rclpy.ok():
        node.get_node_names_and_namespaces()
        node.get_topic_names_and_types()
        polls += 1
        rclpy.spin_once(node, timeout_sec=float(sys.argv[1]))
except (KeyboardInterrupt, ExternalShutdownException):
    pass
print(f'{polls} graph polls', flush=True)
'''


def _lower_priority():
    os.nice(TOOL_NICENESS)


def _run_tools(procs, probe, ns, watch):
    """Start :data:`TOOLS` tool processes, at most :data:`TOOLS_AT_ONCE` at a time.

    :return: [s] wall time from the first start to the last exit
    """
    start_s = time.monotonic()
    pending = list(range(TOOLS))
    running = []
    while pending or running:
        for tool in [t for t in running if t.returncode is not None]:
            running.remove(tool)
            assert tool.returncode == 0, tool.describe()
        while pending and len(running) < TOOLS_AT_ONCE:
            index = pending.pop(0)
            running.append(procs.start(f'tool{index}', [
                sys.executable, '-c', _TOOL, ns, str(index), repr(TARGET_N), repr(RATE_HZ),
                repr(DEFAULT_TIMEOUT_S)], preexec_fn=_lower_priority))
        # Spinning keeps the probe's own force subscription drained meanwhile.
        probe.spin_once()
        for proc in watch:
            assert proc.returncode is None, proc.describe()
        assert time.monotonic() - start_s < TOOLS * DEFAULT_TIMEOUT_S, 'tools never finished'
    return time.monotonic() - start_s


def _one_run(tmp_path):
    """One simulator lifetime with the tools churning; its longest tick gap."""
    ns = f'/churn_{os.getpid()}_{next(_RUNS)}'
    tmp_path.mkdir()
    with ProcessGroup(tmp_path) as procs, Probe('churn_probe') as probe:
        sim = procs.start('simulator', node_command('simulator', ns=ns,
                                                    params={'rate_hz': RATE_HZ}))
        # The tick runs in run_node's spin, on the main thread: tid = pid.
        waits_path = tmp_path / 'run_queue_waits.txt'
        watcher = procs.start('run_queue_watcher', [
            sys.executable, '-c', _RUN_QUEUE_WATCHER, str(sim.pid), str(sim.pid),
            repr(WATCH_PERIOD_S), str(waits_path)])
        ctl = procs.start('controller', node_command('force_controller', ns=ns))
        force = probe.record(f'{ns}/force', Float64)
        probe.publish_when_matched(f'{ns}/force_target', Float64(data=TARGET_N),
                                   procs=[sim, ctl])
        probe.wait_for_value(force, lambda f: f > LOOP_CLOSED_N, 'the loop closed',
                             procs=[sim, ctl])
        daemon = procs.start('daemon', [sys.executable, '-c', _DAEMON, repr(DAEMON_POLL_S)],
                             preexec_fn=_lower_priority)
        tools_s = _run_tools(procs, probe, ns, watch=[sim, ctl, daemon])
        assert sim.stop() == 0, sim.describe()
        assert watcher.wait() == 0, watcher.describe()   # it ends with the thread
        log = sim.output()
    match = _STATS_RE.search(log)
    assert match is not None, f'no exit statistics in the simulator log:\n{log[-3000:]}'
    samples = [tuple(int(v) for v in line.split())
               for line in waits_path.read_text().splitlines()]
    return {'gap_s': float(match.group(1)) / 1e3, 'gap_end_s': float(match.group(2)),
            'tools_s': tools_s, 'samples': samples}


def gap_breakdown(samples, start_s, end_s):
    """How the tick thread spent ``[start_s, end_s]``, from the watcher's samples.

    Between the samples just before the start and just after the end the
    thread either ran, waited for a CPU, or was blocked (sleeping or waiting
    in a call). The span may exceed the interval by the sampling period (more
    under load): the wait is counted as the least and the blocked time as the
    most the interval can hold.

    :param samples: ``(time ns, cumulative run-queue wait ns, cumulative CPU ns)``
    :return: [s] ``(waited for a CPU at least, blocked at most, span of the samples)``;
        ``(0.0, inf, inf)`` without samples on both sides
    """
    before = [s for s in samples if s[0] <= start_s * 1e9]
    after = [s for s in samples if s[0] >= end_s * 1e9]
    if not (before and after):
        return 0.0, float('inf'), float('inf')
    (t0, w0, c0), (t1, w1, c1) = before[-1], after[0]
    span_s = (t1 - t0) / 1e9
    outside_s = span_s - (end_s - start_s)
    waited_s = (w1 - w0) / 1e9
    blocked_s = span_s - waited_s - (c1 - c0) / 1e9
    return max(0.0, waited_s - outside_s), max(0.0, blocked_s), span_s


def test_simulator_tick_never_pauses_while_cli_tools_join_and_leave(tmp_path):
    for attempt in range(1, MAX_ATTEMPTS + 1):
        run = _one_run(tmp_path / f'attempt{attempt}')
        gap_s, end_s = run['gap_s'], run['gap_end_s']
        waited_s, blocked_s, span_s = gap_breakdown(run['samples'], end_s - gap_s, end_s)
        print(f'\nMEASURED run {attempt}: longest gap between simulator ticks '
              f'{gap_s * 1e3:.1f} ms (bound {MAX_TICK_GAP_S * 1e3:.0f} ms); in it the tick '
              f'thread waited for a CPU at least {waited_s * 1e3:.1f} ms and was blocked at '
              f'most {blocked_s * 1e3:.1f} ms (watcher samples {span_s * 1e3:.1f} ms apart); '
              f'{TOOLS} tools in {run["tools_s"]:.1f} s')
        if gap_s < MAX_TICK_GAP_S:
            return
        # The machine spoiled the run if it withheld a CPU from the ready thread
        # for the bound or longer; a thread blocked that long (in a call, on a
        # lock) stalled by itself, whatever the machine did.
        if blocked_s >= MAX_TICK_GAP_S or waited_s < MAX_TICK_GAP_S:
            pytest.fail(f'the simulator did not tick for {gap_s * 1e3:.1f} ms (bound '
                        f'{MAX_TICK_GAP_S * 1e3:.0f} ms): blocked up to {blocked_s * 1e3:.1f} ms '
                        f'of it, and kept from a CPU only {waited_s * 1e3:.1f} ms')
        print(f'REPEATED run {attempt} of {MAX_ATTEMPTS}: the machine kept the ready tick thread '
              f'from a CPU {waited_s * 1e3:.1f} ms of the {gap_s * 1e3:.1f} ms gap')
    pytest.fail(f'all {MAX_ATTEMPTS} runs had a gap over {MAX_TICK_GAP_S * 1e3:.0f} ms, each '
                'with the simulator kept from a CPU for longer than that')
