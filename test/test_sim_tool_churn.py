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
ros2cli: gaps of 326 to 336 ms, and 661 ms for two checks in a row, "steps due after a stall" warnings, and the
controller starved of force feedback).

The tools run at :data:`TOOL_NICENESS` (their autogroup too), two at a time. A
fresh interpreter spends about a CPU-second importing Python, numpy and rclpy
before its participant exists, and that is a load on the machine, not what a
participant does to the simulator over DDS, which is what is tested here. So
one launcher process (:data:`_LAUNCHER`) imports rclpy once, without
initialising it, and forks each tool from there: every tool is still a process
of its own that creates its own context and DDS participant
(``rclpy.init``), joins the graph, does its work and leaves. Measured on the
shared machine (load about 4): 20 fresh interpreters took 41.6 s, 20 forked
tools 8.3 and 9.6 s.

A run is repeated only when an independent watcher measured that the machine,
not the simulator, made the gap: :data:`_THREAD_WATCHER` is a separate process
that reads, every millisecond, the kernel's account of the simulator's tick
thread (``/proc/<pid>/task/<tid>/schedstat`` and ``stat``): time on a CPU,
time ready but waiting for one, and its state (waiting for the disk, ``D``,
when a page of its code or data that the kernel's memory reclaim evicted is
read back; ready, ``R``, but counted as neither running nor waiting when the
virtual machine's host takes the CPU away). On 2 cores shared with other jobs a thread that has work to do
waits its turn behind every busy process, unlike a process that only sleeps
and wakes (``stall_watch``), which saw nothing while the simulator was kept
from a CPU 161 ms of a 190 ms gap (measured). A run is repeated when, during the
gap, the machine held the thread up for the bound or longer (or for all that
the gap exceeds the bound by) and the thread was not blocked by itself
(asleep, waiting in a call or on a lock, as in the shared-memory stall) for
the bound or longer; the measurement is printed, and any other run over the
bound fails at once.
"""
from __future__ import annotations

import itertools
import os
import re
import sys
import time

import pytest
from std_msgs.msg import Float64

from background_priority import lower_autogroup
from ros_helpers import DEFAULT_TIMEOUT_S, Probe, ProcessGroup, node_command
from stall_watch import report_repeat

_RUNS = itertools.count()

RATE_HZ = 1000.0
#: [s] the bound on the simulator's longest interval between two ticks: 20
#: steps, far below the 333 ms a joining process could cause and above the
#: few ms of scheduling jitter a busy 2-core machine adds.
MAX_TICK_GAP_S = 0.02
#: Tool processes per run, and how many of them run at once at most.
TOOLS = 20
TOOLS_AT_ONCE = 2
#: [N] the force target the test and the tools publish; the loop is closed
#: once the force passes :data:`LOOP_CLOSED_N` (only stimulation gets it there).
TARGET_N = 5.0
LOOP_CLOSED_N = 1.0
#: Niceness of the tool and daemon processes (see the module docstring).
TOOL_NICENESS = 10
#: [s] the thread watcher's sampling period.
WATCH_PERIOD_S = 0.001
#: [s] a watcher interval longer than this means the machine held the watcher
#: up too (it only sleeps for WATCH_PERIOD_S; a few ms of wake-up latency are
#: common on a busy 2-core machine).
WATCHER_LATE_S = 0.005
#: Runs in all, at most, when each failed one had an external stall measured.
MAX_ATTEMPTS = 3
#: [s] the longest a tool may take to leave once its work is done: far above
#: the 0.1-0.5 s a participant's teardown takes here. A tool still tearing
#: down then is deadlocked in Fast DDS (seen once, with four pytest workers on
#: the machine: the tool's main thread spinning in ``set_listener`` inside
#: ``destroy_participant`` while a discovery thread waited in
#: ``onWriterDiscovery`` for a mutex the main thread held; gdb stacks): the
#: launcher kills it and the test names it.
TEARDOWN_LIMIT_S = 5.0
#: [s] how often the launcher looks at its tools.
LAUNCHER_POLL_S = 0.05
#: [s] poll period of the daemon-like participant (ros2cli's daemon answers
#: every ``ros2`` command from its graph cache).
DAEMON_POLL_S = 0.1

_STATS_RE = re.compile(r'longest gap between ticks ([\d.]+) ms \(ended at steady time '
                       r'([\d.]+) s\)')

#: The thread watcher: argv = pid, tid, period [s], output file. Writes
#: ``<time.monotonic_ns()> <run-queue wait ns> <CPU ns> <state> [<tid>:<state>:<CPU ns> ...]``
#: lines (the kernel's schedstat of the thread, and its state letter from stat:
#: ``D`` in an uninterruptible wait such as a page-in from disk) until the
#: thread is gone. The run-queue wait is kept for whoever reads the file after a
#: failure; :func:`gap_breakdown` goes by the states, which also see the host. While the thread sleeps without having run since the last
#: sample (possibly waiting for another of its process's threads), the other
#: threads' states and CPU times follow.
_THREAD_WATCHER = r'''
import os, sys, time
pid, tid, period_s, path = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
task_dir = f'/proc/{pid}/task'
schedstat = os.open(f'{task_dir}/{tid}/schedstat', os.O_RDONLY)
stat = os.open(f'{task_dir}/{tid}/stat', os.O_RDONLY)
others = {}
def other_threads():
    for other in os.listdir(task_dir):
        if other != tid and other not in others:
            try:
                others[other] = (os.open(f'{task_dir}/{other}/stat', os.O_RDONLY),
                                 os.open(f'{task_dir}/{other}/schedstat', os.O_RDONLY))
            except OSError:
                pass
    fields = []
    for other, (stat_fd, schedstat_fd) in others.items():
        try:
            state = os.pread(stat_fd, 512, 0).rsplit(b')', 1)[1].split()[0].decode()
            fields.append(f'{other}:{state}:{int(os.pread(schedstat_fd, 128, 0).split()[0])}')
        except (OSError, ValueError, IndexError):
            pass
    return ' '.join(fields)
last_cpu = None
with open(path, 'w') as out:
    while True:
        try:
            cpu_ns, wait_ns = os.pread(schedstat, 128, 0).split()[:2]
            state = os.pread(stat, 512, 0).rsplit(b')', 1)[1].split()[0].decode()
        except (OSError, ValueError, IndexError):
            break
        extra = other_threads() if state == 'S' and cpu_ns == last_cpu else ''
        last_cpu = cpu_ns
        out.write(f'{time.monotonic_ns()} {int(wait_ns)} {int(cpu_ns)} {state} {extra}\n')
        time.sleep(period_s)
'''

#: A ros2cli-like command, run in a forked process: argv = namespace, index,
#: force target [N], the simulator's rate_hz [Hz], deadline [s]. Exits non-zero
#: if any step fails.
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
print('TEARDOWN', flush=True)   # the work is done: the launcher times the rest
node.destroy_node()
rclpy.shutdown()
'''

#: The launcher: argv = tool count, tools at once, log directory, teardown
#: limit [s], poll period [s], then the tool's argv after the index. Imports what the tools import (rclpy, not
#: initialised: no context, no participant, no thread of rclpy's yet), then forks
#: the tools, at most ``tools at once`` alive, each writing ``tool<i>.log``, and
#: prints ``EXIT <index> <status>`` as each ends. A tool still alive the teardown
#: limit after it printed ``TEARDOWN`` is killed, with ``STUCK <index> <s>``
#: (:data:`TEARDOWN_LIMIT_S`). Exits 0 once all have ended.
_LAUNCHER = r'''
import os, sys, time, traceback
import rclpy
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Float64
import signal
code = compile(sys.argv[1], 'tool', 'exec')
tools, at_once, log_dir, teardown_s = int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], float(sys.argv[5])
poll_s, tool_args = float(sys.argv[6]), sys.argv[7:]

def run_tool(index):
    fd = os.open(os.path.join(log_dir, f'tool{index}.log'), os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    sys.argv = ['tool', tool_args[0], str(index), *tool_args[1:]]
    status = 0
    try:
        exec(code, {'__name__': '__main__'})
    except SystemExit as stop:
        if isinstance(stop.code, int):
            status = stop.code
        elif stop.code is not None:
            print(stop.code, file=sys.stderr)
            status = 1
    except BaseException:
        traceback.print_exc()
        status = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)

def tearing_down(index):
    try:
        with open(os.path.join(log_dir, f'tool{index}.log'), errors='replace') as log:
            return 'TEARDOWN' in log.read()
    except FileNotFoundError:   # the tool has not opened its log yet
        return False

running = {}
teardown_seen = {}
next_index = 0
while next_index < tools or running:
    while next_index < tools and len(running) < at_once:
        sys.stdout.flush()
        pid = os.fork()
        if pid == 0:
            run_tool(next_index)
        running[pid] = next_index
        next_index += 1
    pid, status = os.waitpid(-1, os.WNOHANG)
    if pid:
        print(f'EXIT {running.pop(pid)} {os.waitstatus_to_exitcode(status)}', flush=True)
        teardown_seen.pop(pid, None)
        continue
    now = time.monotonic()
    for pid, index in running.items():
        if pid not in teardown_seen and tearing_down(index):
            teardown_seen[pid] = now
        elif pid in teardown_seen and now - teardown_seen[pid] > teardown_s:
            os.kill(pid, signal.SIGKILL)
            print(f'STUCK {index} {now - teardown_seen[pid]:.1f}', flush=True)
            teardown_seen[pid] = float('inf')   # killed once; its EXIT follows
    time.sleep(poll_s)
'''

#: A participant like ros2cli's daemon: it polls the graph until stopped.
_DAEMON = r'''
import sys
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
    # Each process starts in a session of its own, so in an autogroup of its own,
    # and the kernel shares the CPUs between autogroups before nice counts within
    # one: without this, three starting tools weighed as much as three simulators.
    # A user who is not root may raise it too, but the kernel takes one such
    # change per 100 ms on the whole machine: the launcher's, a few ms after the
    # daemon's, failed with EAGAIN, and a plain user's tools weighed as much as
    # the simulator (the claim was STALLED in 9 runs of 9, the tick thread kept
    # from a CPU 19-37 ms). lower_autogroup waits its turn. Where there are no
    # autogroups, or the kernel refuses, the process's own nice is what there is.
    why_not = lower_autogroup(TOOL_NICENESS)
    if why_not is not None:
        os.write(2, f'tool priority: plain nice only ({why_not})\n'.encode())


def _run_tools(procs, ns, watch):
    """Run :data:`TOOLS` tools from the launcher, at most :data:`TOOLS_AT_ONCE` at a time.

    :param watch: processes that must stay up meanwhile
    :return: [s] wall time from the launcher's start to its exit
    """
    start_s = time.monotonic()
    launcher = procs.start('launcher', [
        sys.executable, '-c', _LAUNCHER, _TOOL, str(TOOLS), str(TOOLS_AT_ONCE),
        str(procs.log_dir), repr(TEARDOWN_LIMIT_S), repr(LAUNCHER_POLL_S),
        ns, repr(TARGET_N), repr(RATE_HZ), repr(DEFAULT_TIMEOUT_S)],
        preexec_fn=_lower_priority)
    procs.wait_until(lambda: launcher.returncode is not None, 'the tools to finish',
                     timeout_s=TOOLS * DEFAULT_TIMEOUT_S, watch=watch)
    tools_s = time.monotonic() - start_s
    lines = launcher.output().splitlines()
    stuck = [line.split()[1:] for line in lines if line.startswith('STUCK ')]
    for index, waited in stuck:
        print(f'\nMEASURED: tool {index} had done its work but was still in its participant '
              f'teardown {waited} s later: killed. That is the deadlock of Fast DDS 2.14 / '
              f'rmw_fastrtps (destroy_participant holds a lock and spins until an in-flight '
              f'onWriterDiscovery ends, which waits for that lock), in the tool, not in the '
              f'simulator; its exit counts as the end of its work.')
    exits = {index: ('0' if any(index == s[0] for s in stuck) else status)
             for index, status in (line.split()[1:] for line in lines
                                   if line.startswith('EXIT '))}
    failed = {index: status for index, status in exits.items() if status != '0'}
    logs = '\n'.join(f'--- tool{index} (exit {status}):\n'
                     f'{(procs.log_dir / f"tool{index}.log").read_text()[-1000:]}'
                     for index, status in failed.items())
    assert launcher.returncode == 0 and len(exits) == TOOLS and not failed, \
        f'{launcher.describe()}\n{logs}'
    return tools_s


def _one_run(tmp_path):
    """One simulator lifetime with the tools churning; its longest tick gap."""
    ns = f'/churn_{os.getpid()}_{next(_RUNS)}'
    tmp_path.mkdir()
    with ProcessGroup(tmp_path) as procs:
        sim = procs.start('simulator', node_command('simulator', ns=ns,
                                                    params={'rate_hz': RATE_HZ}))
        # The tick runs in run_node's spin, on the main thread: tid = pid.
        samples_path = tmp_path / 'tick_thread.txt'
        watcher = procs.start('thread_watcher', [
            sys.executable, '-c', _THREAD_WATCHER, str(sim.pid), str(sim.pid),
            repr(WATCH_PERIOD_S), str(samples_path)])
        ctl = procs.start('controller', node_command('force_controller', ns=ns))
        with Probe('churn_probe') as probe:
            force = probe.record(f'{ns}/force', Float64)
            probe.publish_when_matched(f'{ns}/force_target', Float64(data=TARGET_N),
                                       procs=[sim, ctl])
            probe.wait_for_value(force, lambda f: f > LOOP_CLOSED_N, 'the loop closed',
                                 procs=[sim, ctl])
        # The probe has left: its executor would take a CPU's share at 1 kHz.
        daemon = procs.start('daemon', [sys.executable, '-c', _DAEMON, repr(DAEMON_POLL_S)],
                             preexec_fn=_lower_priority)
        tools_s = _run_tools(procs, ns, watch=[sim, ctl, daemon])
        assert sim.stop() == 0, sim.describe()
        assert watcher.wait() == 0, watcher.describe()   # it ends with the thread
        log = sim.output()
    match = _STATS_RE.search(log)
    assert match is not None, f'no exit statistics in the simulator log:\n{log[-3000:]}'
    samples = []
    for line in samples_path.read_text().splitlines():
        t_ns, wait_ns, cpu_ns, state, *rest = line.split()
        others = {tid: (other_state, int(cpu)) for tid, other_state, cpu
                  in (field.split(':') for field in rest)}
        samples.append((int(t_ns), int(wait_ns), int(cpu_ns), state, others))
    return {'gap_s': float(match.group(1)) / 1e3, 'gap_end_s': float(match.group(2)),
            'tools_s': tools_s, 'samples': samples}


def gap_breakdown(samples, start_s, end_s, late_s=WATCHER_LATE_S):
    """How the tick thread spent ``[start_s, end_s]``, from the watcher's samples.

    Between the samples just before the start and just after the end, each
    sample interval counts by the thread's state at its start:

    - ready (``R``): running, waiting for a CPU, or with its virtual CPU taken
      away by the host; all but its CPU time is the machine's. (The kernel's
      run-queue wait alone misses the host's share, and counts a wait only
      when the thread gets a CPU, hence the states.)
    - waiting for the disk (``D``: a page that the kernel's memory reclaim had
      evicted, read back in): the machine's.
    - asleep (``S``): between ticks, or waiting in a call or on a lock: the
      simulator's own, unless another of its threads (the timer thread, or
      the holder of the lock) was ready then and did not run: that much is
      the machine's (from the other threads' samples at both ends).

    An interval longer than ``late_s`` means the machine held the watcher
    itself up: the excess counts as the machine's. The samples cover the
    interval and up to a period more (more under load): the machine's share
    is counted as the least the interval can hold, the blocked time as the
    most.

    :param samples: ``(time ns, cumulative run-queue wait ns, cumulative CPU ns,
        state, {other tid: (state, cumulative CPU ns)})``, the last possibly empty
    :param late_s: [s] the longest interval the watcher's own sleep explains
    :return: [s] ``(held up by the machine at least, blocked by itself at most,
        span of the samples)``; ``(0.0, inf, inf)`` without samples on both sides
    """
    first = [k for k, s in enumerate(samples) if s[0] <= start_s * 1e9]
    last = [k for k, s in enumerate(samples) if s[0] >= end_s * 1e9]
    if not (first and last):
        return 0.0, float('inf'), float('inf')
    inside = samples[first[-1]:last[0] + 1]
    late_ns = round(late_s * 1e9)
    blocked_ns = held_ns = machine_ns = 0
    for (t0, _, _, state, others0), (t1, _, _, _, others1) in zip(inside, inside[1:]):
        machine_ns += max(0, t1 - t0 - late_ns)
        watched_ns = min(t1 - t0, late_ns)
        if state != 'S':
            held_ns += watched_ns
            continue
        # The longest another thread was ready but did not run.
        idle_ns = max((watched_ns - (others1[tid][1] - cpu) for tid, (other_state, cpu)
                       in others0.items() if other_state == 'R' and tid in others1),
                      default=0)
        machine_ns += min(watched_ns, max(0, idle_ns))
        blocked_ns += watched_ns - min(watched_ns, max(0, idle_ns))
    machine_ns += max(0, held_ns - (inside[-1][2] - inside[0][2]))
    span_s = (inside[-1][0] - inside[0][0]) / 1e9
    outside_s = span_s - (end_s - start_s)
    return max(0.0, machine_ns / 1e9 - outside_s), blocked_ns / 1e9, span_s


def test_gap_breakdown_tells_the_machine_from_the_simulator():
    ms = 1_000_000
    # Samples every ms from 0 to 100 ms but none from 80 to 92 ms (the watcher
    # was held up: 12 ms, 7 over WATCHER_LATE_S); a gap from 10.5 to 95.5 ms
    # in which the thread waits 30 ms for a CPU (20 to 50 ms), runs 5 ms,
    # waits 10 ms for the disk (60 to 70 ms), is ready 5 ms more without a
    # CPU (70 to 75 ms), and sleeps otherwise; from 10 to 14 ms its timer
    # thread (tid 7) is ready but gets no CPU, from 14 to 16 ms it runs.
    samples = []
    wait = cpu = 0
    for t in range(0, 101):
        state = 'D' if 60 <= t < 70 else 'R' if 20 <= t < 55 or 70 <= t < 75 else 'S'
        others = {'7': ('R' if 10 <= t < 16 else 'S', max(0, min(t, 16) - 14) * ms)}
        if not 80 < t < 92:
            samples.append((t * ms, wait, cpu, state, others if state == 'S' else {}))
        wait += ms if 20 <= t < 50 else 0
        cpu += ms if 50 <= t < 55 else 0
    machine_s, blocked_s, span_s = gap_breakdown(samples, 0.0105, 0.0955)
    assert span_s == pytest.approx(0.086)      # the samples at 10 and 96 ms
    outside_s = 0.086 - 0.085
    assert machine_s == pytest.approx(0.004 + 0.030 + 0.010 + 0.005 + 0.007 - outside_s)
    # Asleep 14-20, 55-60, 75-80, 5 ms of 80-92 and 92-96 ms.
    assert blocked_s == pytest.approx(0.006 + 0.005 + 0.005 + 0.005 + 0.004)
    # Without samples on both sides nothing is known: nothing is excused.
    assert gap_breakdown(samples, 0.050, 0.2) == (0.0, float('inf'), float('inf'))


@pytest.mark.ros
@pytest.mark.slow
# Its own judge of stalls: the tick thread's own wait (gap_breakdown), not
# the tools', which this test starts to load the machine.
@pytest.mark.realtime(judges_stalls=True)
def test_simulator_tick_never_pauses_while_cli_tools_join_and_leave(tmp_path, realtime_claim):
    for attempt in range(1, MAX_ATTEMPTS + 1):
        run = _one_run(tmp_path / f'attempt{attempt}')
        gap_s, end_s = run['gap_s'], run['gap_end_s']
        machine_s, blocked_s, span_s = gap_breakdown(run['samples'], end_s - gap_s, end_s)
        print(f'\nMEASURED run {attempt}: longest gap between simulator ticks '
              f'{gap_s * 1e3:.1f} ms (bound {MAX_TICK_GAP_S * 1e3:.0f} ms); in it the tick '
              f'thread was kept from a CPU or waited for the disk at least '
              f'{machine_s * 1e3:.1f} ms, and was blocked otherwise at most '
              f'{blocked_s * 1e3:.1f} ms (watched over {span_s * 1e3:.1f} ms); {TOOLS} tools '
              f'in {run["tools_s"]:.1f} s')
        realtime_claim('simulator tick gap while CLI tools come and go',
                       f'{gap_s * 1e3:.1f} ms', f'< {MAX_TICK_GAP_S * 1e3:.0f} ms')
        if gap_s < MAX_TICK_GAP_S:
            return
        # The machine spoiled the run if it held the thread up for the bound or
        # longer, or for all the gap exceeds the bound by; a thread blocked for
        # the bound by itself (in a call, on a lock) stalled, whatever the
        # machine did.
        if blocked_s >= MAX_TICK_GAP_S or (machine_s < MAX_TICK_GAP_S
                                           and gap_s - machine_s >= MAX_TICK_GAP_S):
            pytest.fail(f'the simulator did not tick for {gap_s * 1e3:.1f} ms (bound '
                        f'{MAX_TICK_GAP_S * 1e3:.0f} ms): blocked up to {blocked_s * 1e3:.1f} ms '
                        f'of it by itself, held up by the machine only {machine_s * 1e3:.1f} ms')
        report_repeat(f'REPEATED run {attempt} of {MAX_ATTEMPTS}: the machine held the tick '
                      f'thread up {machine_s * 1e3:.1f} ms of the {gap_s * 1e3:.1f} ms gap')
    # Every run measured the machine, not the simulator: not judged (STALLED).
    pytest.skip(f'STALLED: all {MAX_ATTEMPTS} runs had a gap over '
                f'{MAX_TICK_GAP_S * 1e3:.0f} ms, each with the tick thread held up by the '
                'machine (CPU or disk) for longer than that')
