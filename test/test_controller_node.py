"""The force controller node on its own, over real DDS: what it publishes when
feedback is missing or stops, on shutdown, and how it treats its parameters.

The probe plays the simulator (it publishes ``force``) so that each claim can
be checked without the muscle in the loop.

Every test's controller starts at once, when the module's first test asks (a
pool, :func:`pool`, to share the start-up time), each in a namespace of its own
and with the parameters its test needs; a test stops its controller when it is
done with it.
"""
from __future__ import annotations

import contextlib
import itertools
import os
import signal

import pytest
from rclpy.duration import Duration
from std_msgs.msg import Float64

from hill_muscle_ros.control import ControllerParams, ForceController
from hill_muscle_ros.model import MuscleParams
from ros_helpers import Probe, ProcessGroup, node_command

pytestmark = pytest.mark.ros

_RUNS = itertools.count()
DEFAULTS = ControllerParams()
#: [N] a target the controller must stimulate for.
TARGET_N = 10.0


def unique_namespace() -> str:
    """Unique even if another test run drew the same ROS_DOMAIN_ID."""
    return f'/ctrl_{os.getpid()}_{next(_RUNS)}'


def _wait_target_acknowledged(probe, ns, proc) -> None:
    """Spin until the controller has acknowledged every target the probe sent."""
    target_pub = probe.publisher(f'{ns}/force_target', Float64)
    probe.spin_until(lambda: target_pub.wait_for_all_acked(Duration(seconds=0)),
                     'the controller to acknowledge the target', procs=[proc])


#: [s] ``feedback_timeout_s`` of the wind-up test: the probe's 5 ms feedback
#: timer runs only while the test process gets a CPU, and a workers run's
#: first minute (four workers collecting, two compiling processes) stalled it
#: past the default 0.5 s, so the controller rightly held zero. That test is
#: about the target, not the timeout (which has tests of its own below).
WIND_UP_FEEDBACK_TIMEOUT_S = 30.0
#: [s] the controller's feedback timeout in the plant-stall test: the
#: probe's silence is PLANT_STALL_S plus however long the test process then
#: waits for a CPU, so the default 0.5 s left a margin of only 0.2 s for that.
STALL_TEST_FEEDBACK_TIMEOUT_S = 2.0
#: Controllers of the tests that take a :func:`ctrl`, one each.
CTRL_NAMES = ('stale_feedback', 'feedback_returns', 'SIGINT', 'SIGTERM')
#: The pool: a controller per test (or fixture), with the parameters it needs.
POOL = {
    'no_feedback': {},
    'wind_up': {'feedback_timeout_s': WIND_UP_FEEDBACK_TIMEOUT_S},
    'stale_target': {'target_timeout_s': 0.3},
    'plant_stall': {'feedback_timeout_s': STALL_TEST_FEEDBACK_TIMEOUT_S},
    **{name: {} for name in CTRL_NAMES},
    'params': {},
}


@pytest.fixture(scope='module')
def pool(tmp_path_factory):
    """Every controller of :data:`POOL`, started at once, and the probe:
    ``probe``, and per name its ``ns`` and ``proc``."""
    with ProcessGroup(tmp_path_factory.mktemp('controllers')) as procs, \
            Probe('ctrl_probe') as probe:
        ctrls = {}
        for name, params in POOL.items():
            ns = unique_namespace()
            ctrls[name] = {'ns': ns, 'proc': procs.start(name, node_command(
                'force_controller', ns=ns, params=params or None))}
        yield {'probe': probe, **ctrls}


@contextlib.contextmanager
def taken(pool, name):
    """The pool's controller ``name``, which nothing has talked to yet:
    ``(probe, ns, proc)``; stopped (SIGINT, reaped by the pool) after the
    test, so that it loads the machine no longer."""
    assert not pool[name].get('taken'), f'the controller {name} was taken before'
    pool[name]['taken'] = True
    proc = pool[name]['proc']
    try:
        yield pool['probe'], pool[name]['ns'], proc
    finally:
        if proc.returncode is None:
            proc.send_signal(signal.SIGINT)


@contextlib.contextmanager
def stimulating_controller(pool, name):
    """The pool's controller ``name``, stimulating against a fake force of 0 N."""
    with taken(pool, name) as (probe, ns, proc):
        pw = probe.record(f'{ns}/pulse_width', Float64)
        probe.publish_when_matched(f'{ns}/force_target', Float64(data=TARGET_N), procs=[proc])
        force_pub = probe.publisher(f'{ns}/force', Float64)
        probe.spin_until(lambda: force_pub.get_subscription_count() > 0,
                         'controller subscribed to force', procs=[proc])
        # The one force sample below allows feedback_timeout_s of stimulation,
        # on two conditions. The controller has the target already: a force
        # heard first is used up while it waits for the target, and then it
        # holds zero until a newer sample (a fresh-clone run: "stimulating"
        # logged, only zeros sent). And its pulse_width writer has matched the
        # probe, as its zeros arriving show.
        _wait_target_acknowledged(probe, ns, proc)
        probe.wait_for_messages(pw, procs=[proc])
        force_pub.publish(Float64(data=0.0))
        probe.wait_for_value(pw, lambda v: v > 0.0, 'stimulation', procs=[proc])
        yield {'ns': ns, 'proc': proc, 'probe': probe, 'pw': pw, 'force_pub': force_pub}


@pytest.fixture
def ctrl(pool):
    """A :func:`stimulating_controller` of its own (the next of
    :data:`CTRL_NAMES` nothing has taken), for a test that takes it through
    feedback timeouts or stops it."""
    name = next(name for name in CTRL_NAMES if not pool[name].get('taken'))
    with stimulating_controller(pool, name) as ctrl:
        yield ctrl


@pytest.fixture(scope='module')
def params_ctrl(pool):
    """One :func:`stimulating_controller` for the tests of run-time parameters:
    each reads the parameters before and after its own change."""
    with stimulating_controller(pool, 'params') as ctrl:
        yield ctrl


@pytest.fixture(scope='module')
def target_without_feedback(pool):
    """A controller that is sent a target and never a force: the pulse widths it
    published from the start, those from the target's sending on, and those
    from its acknowledgement on (at least :data:`PERIODS_BEFORE_TARGET` of them)."""
    with taken(pool, 'no_feedback') as (probe, ns, proc):
        pw = probe.record(f'{ns}/pulse_width', Float64)
        probe.publish_when_matched(f'{ns}/force_target', Float64(data=TARGET_N), procs=[proc])
        sent = pw.mark()
        probe.wait_for_messages(pw, 20, mark=sent, procs=[proc])
        _wait_target_acknowledged(probe, ns, proc)
        acked = pw.mark()
        probe.wait_for_messages(pw, PERIODS_BEFORE_TARGET, mark=acked, procs=[proc])
        return {'all': pw.data_since(0), 'since_sent': pw.data_since(sent),
                'since_acked': pw.data_since(acked)}


def test_without_force_feedback_the_controller_publishes_zero(target_without_feedback):
    since_sent = target_without_feedback['since_sent']
    assert len(since_sent) >= 20
    assert set(since_sent) == {0.0}


#: [s] how long a publisher may wait for its subscribers' acknowledgements.
ACK_TIMEOUT_S = 30.0
#: Controller periods of force feedback heard before the target arrives: at
#: 100 Hz, 0.5 s, far more than the reference model's 60 ms time constant,
#: so a controller that acted on a made-up 0 N target would have wound up.
PERIODS_BEFORE_TARGET = 50


def test_force_heard_before_the_target_neither_stimulates_nor_winds_up(pool):
    """The DDS race: feedback reaches the controller before the first target.

    The probe plays a muscle that holds exactly the target, so once the target
    is known the error is zero and the pulse width must be exactly the
    feedforward. A controller that ran on a default target of 0 N while only
    the force was known would wind its integral down and settle elsewhere.
    """
    expected_pw = ForceController(ControllerParams(), MuscleParams()).feedforward(
        TARGET_N, TARGET_N)
    with taken(pool, 'wind_up') as (probe, ns, proc):
        pw = probe.record(f'{ns}/pulse_width', Float64)
        force_pub = probe.publisher(f'{ns}/force', Float64)
        target_pub = probe.publisher(f'{ns}/force_target', Float64)
        probe.spin_until(lambda: (force_pub.get_subscription_count() > 0
                                  and target_pub.get_subscription_count() > 0
                                  and pw.messages),
                         'discovery both ways', procs=[proc])
        feedback = probe.node.create_timer(
            0.005, lambda: force_pub.publish(Float64(data=TARGET_N)))
        probe.spin_until(lambda: force_pub.wait_for_all_acked(Duration(seconds=0)),
                         'the controller to acknowledge the force', procs=[proc])
        # Pulse widths published after the acknowledgement were computed with the force known.
        heard = pw.mark()
        probe.wait_for_messages(pw, PERIODS_BEFORE_TARGET, mark=heard, procs=[proc])
        before_target = pw.data_since(0)
        target_pub.publish(Float64(data=TARGET_N))
        probe.wait_for_value(pw, lambda v: v > 0.0, 'stimulation', mark=len(pw.messages),
                             procs=[proc])
        mark = pw.mark()
        probe.wait_for_messages(pw, PERIODS_BEFORE_TARGET, mark=mark, procs=[proc])
        feedback.cancel()
        after = pw.data_since(mark)

    assert set(before_target) == {0.0}
    assert set(after) == {expected_pw}


def test_target_without_force_feedback_never_stimulates(target_without_feedback):
    assert len(target_without_feedback['since_acked']) >= PERIODS_BEFORE_TARGET
    assert set(target_without_feedback['all']) == {0.0}


def test_a_stale_target_stops_stimulation_when_target_timeout_is_set(pool):
    with taken(pool, 'stale_target') as (probe, ns, proc):
        pw = probe.record(f'{ns}/pulse_width', Float64)
        force_pub = probe.publisher(f'{ns}/force', Float64)
        probe.spin_until(lambda: force_pub.get_subscription_count() > 0,
                         'controller subscribed to force', procs=[proc])
        feedback = probe.node.create_timer(0.005, lambda: force_pub.publish(Float64(data=0.0)))
        probe.publish_when_matched(f'{ns}/force_target', Float64(data=TARGET_N), procs=[proc])
        on = probe.wait_for_value(pw, lambda v: v > 0.0, 'stimulation', procs=[proc])
        off = probe.wait_for_value(pw, lambda v: v == 0.0, 'zero after the target expired',
                                   mark=on, procs=[proc])
        feedback.cancel()
        # Feedback kept coming: only the target's age can have stopped it.
        probe.spin_until(lambda: 'target_timeout_s' in proc.output(), 'the warning',
                         procs=[proc])
        assert off > on


#: [s] a plant stall shorter than the feedback timeout, as long as the
#: simulator stalls that a loop must ride through.
PLANT_STALL_S = 0.3
#: [s] read on after the zero of a stopped controller, for anything it sent later
AFTER_EXIT_S = 0.5
#: Pulse widths at the end of the stall that must all be the held one: the
#: first one or two of the stall were still computed from the last samples.
HELD_PERIODS = 20


def test_a_plant_stall_shorter_than_the_feedback_timeout_holds_the_pulse_width(pool):
    """No dropout and no integration on an old error while the force is briefly late."""
    with taken(pool, 'plant_stall') as (probe, ns, proc):
        pw = probe.record(f'{ns}/pulse_width', Float64)
        force_pub = probe.publisher(f'{ns}/force', Float64)
        probe.spin_until(lambda: force_pub.get_subscription_count() > 0,
                         'controller subscribed to force', procs=[proc])
        # A muscle stuck below the target: the integral moves every period it is fed.
        feedback = probe.node.create_timer(
            0.001, lambda: force_pub.publish(Float64(data=TARGET_N / 2)))
        probe.publish_when_matched(f'{ns}/force_target', Float64(data=TARGET_N), procs=[proc])
        probe.wait_for_value(pw, lambda v: v > 0.0, 'stimulation', procs=[proc])
        feedback.cancel()
        stall = pw.mark()
        probe.spin_for(PLANT_STALL_S)  # the stimulus: the plant says nothing this long
        during = pw.data_since(stall)
        feedback = probe.node.create_timer(
            0.001, lambda: force_pub.publish(Float64(data=TARGET_N / 2)))
        back = pw.mark()
        probe.wait_for_messages(pw, 5, mark=back, procs=[proc])
        feedback.cancel()
        after = pw.data_since(back)

    assert len(during) > HELD_PERIODS
    assert all(v > 0.0 for v in during + after)
    assert len(set(during[-HELD_PERIODS:])) == 1


def test_stale_force_feedback_stops_stimulation_with_a_warning(ctrl):
    probe, pw, proc = ctrl['probe'], ctrl['pw'], ctrl['proc']
    # No more force messages: after feedback_timeout_s the output must be 0.
    probe.wait_for_value(pw, lambda v: v == 0.0, 'zero after feedback stops',
                         mark=pw.mark(), procs=[proc])
    # The stale-feedback warning, not the start-up line "no force feedback received yet".
    probe.spin_until(lambda: 'for more than' in proc.output()
                     and '(feedback_timeout_s): stimulation stopped' in proc.output(),
                     'the warning', procs=[proc])


def test_stimulation_resumes_when_feedback_returns(ctrl):
    probe, pw, proc = ctrl['probe'], ctrl['pw'], ctrl['proc']
    probe.wait_for_value(pw, lambda v: v == 0.0, 'zero after feedback stops',
                         mark=pw.mark(), procs=[proc])
    mark = pw.mark()
    ctrl['force_pub'].publish(Float64(data=0.0))
    probe.wait_for_value(pw, lambda v: v > 0.0, 'stimulation again', mark=mark, procs=[proc])


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_stop_signal_publishes_zero_stimulation_last(ctrl, sig):
    probe, pw, proc = ctrl['probe'], ctrl['pw'], ctrl['proc']
    keep_fresh = probe.node.create_timer(
        0.02, lambda: ctrl['force_pub'].publish(Float64(data=0.0)))
    probe.wait_for_value(pw, lambda v: v > 0.0, 'stimulation', mark=pw.mark(), procs=[proc])
    signalled = pw.mark()
    proc.popen.send_signal(sig)
    probe.spin_until(lambda: proc.returncode is not None, 'the controller to exit')
    keep_fresh.cancel()
    # The exit says nothing of what the probe has taken yet (it may lag on a
    # busy machine): wait for the zero, then read on for anything sent after it.
    probe.wait_for_value(pw, lambda v: v == 0.0, 'the zero stimulation', mark=signalled)
    probe.spin_for(AFTER_EXIT_S)
    assert pw.messages[-1].data == 0.0


@pytest.mark.parametrize('name, bad', [('kp_s_per_n', -1.0), ('rate_hz', 50.0),
                                       ('pw_max_s', 0.0), ('ki_s_per_n_s', float('nan'))])
def test_bad_parameter_at_run_time_is_rejected_by_name_and_nothing_changes(params_ctrl, name,
                                                                          bad):
    probe, proc = params_ctrl['probe'], params_ctrl['proc']
    node = f'{params_ctrl["ns"]}/force_controller'
    names = [f for f in ControllerParams.__dataclass_fields__]
    before = probe.get_parameters(node, names, procs=[proc])
    (result,) = probe.set_parameters(node, {name: bad}, procs=[proc])
    assert not result.successful
    assert name in result.reason
    assert probe.get_parameters(node, names, procs=[proc]) == before
    assert proc.returncode is None


def test_good_parameter_at_run_time_is_applied(params_ctrl):
    probe, proc = params_ctrl['probe'], params_ctrl['proc']
    node = f'{params_ctrl["ns"]}/force_controller'
    (result,) = probe.set_parameters(node, {'kp_s_per_n': 1e-5}, procs=[proc])
    assert result.successful
    assert probe.get_parameters(node, ['kp_s_per_n'], procs=[proc]) == {'kp_s_per_n': 1e-5}
