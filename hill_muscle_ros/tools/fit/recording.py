"""Reading a bag for a fit: its inputs and measurements on one uniform time grid.

:func:`load_muscle_recording` reads a single muscle's stimulation, MTU length
and force (the grid is the force's), :func:`load_limb_recording` a limb's
stimulation per muscle, external torque and joint angle (the grid is the joint
states'). Each input holds its last message (zero before the first), as the
nodes hold them; a ``length_command_stamped`` knot track is linear between its
stamps.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ...model.limb import TORQUE_LIMIT_N_M, LimbPlant
from ...model.muscle import DL_MT_LIMIT_M
from ...timebase import NS_PER_S
from .parameters import FitError

#: Default topics, each list in order of preference: the first with messages is used.
PULSE_WIDTH_TOPIC = 'pulse_width'
RECRUITMENT_TOPIC = 'recruitment'
#: Stamped knots first: their stamps are the instants the length is to be reached.
LENGTH_TOPICS = ('length_command_stamped', 'length_command')
#: The wrench first: its header stamp is the simulated time of the step.
FORCE_TOPICS = ('wrench', 'force')
#: Message type of the knot track (``point.x`` at ``header.stamp``).
POINT_STAMPED = 'geometry_msgs/msg/PointStamped'


@dataclass(frozen=True)
class MuscleRecording:
    """A single muscle's recorded inputs and force, on one uniform time grid.

    :param bag: the bag directory
    :param rate_hz: [Hz] 1 / dt of the grid (the force's median sample spacing)
    :param t0_ns: [ns] the grid's first instant, in the bag's stamp clock
    :param stimulation: per grid instant, the pulse width [s] or recruitment [-] held then
    :param stimulation_kind: ``pulse_width`` or ``recruitment``
    :param dl_mt_m: [m] per grid instant, the MTU length change
    :param sample_index: grid index of each measured force sample used
    :param force_n: [N] the measured force at those samples
    :param topics: the topics read, by role (``stimulation``, ``length``, ``force``)
    """

    bag: Path
    rate_hz: float
    t0_ns: int
    stimulation: np.ndarray
    stimulation_kind: str
    dl_mt_m: np.ndarray
    sample_index: np.ndarray
    force_n: np.ndarray
    topics: dict[str, str]

    @property
    def t_s(self) -> np.ndarray:
        """[s] the grid, from 0 at its first instant."""
        return np.arange(len(self.dl_mt_m)) / self.rate_hz

    @property
    def sample_t_s(self) -> np.ndarray:
        """[s] the times of the measured force samples on the grid."""
        return self.sample_index / self.rate_hz


def _pick_topic(bag, candidates: Sequence[str], role: str, option: str):
    """The first candidate topic with messages, or a FitError naming them all."""
    for name in candidates:
        if bag.has_topic(name) and bag.topic(name).count:
            return bag.topic(name)
    listed = ' or '.join(f'`{c}`' for c in candidates)
    counts = ', '.join(f'{n} ({c})' for n, c in bag.counts().items()) or 'no topics'
    raise FitError(f'{bag.path}: no messages on {listed} ({role}; {option} names another '
                   f'topic); the bag has: {counts}')


def _span(stamps_ns: np.ndarray, origin_ns: int) -> str:
    return (f't = {(stamps_ns[0] - origin_ns) / NS_PER_S:.3f}..'
            f'{(stamps_ns[-1] - origin_ns) / NS_PER_S:.3f} s')


def _held(stamps_ns: np.ndarray, values: np.ndarray, grid_ns: np.ndarray) -> np.ndarray:
    """The last value at or before each grid instant; 0 (rest) before the first."""
    idx = np.searchsorted(stamps_ns, grid_ns, side='right') - 1
    return np.where(idx >= 0, values[np.maximum(idx, 0)], 0.0)


def load_muscle_recording(bag_dir: str | Path, *, pulse_width_topic: str | None = None,
                          recruitment_topic: str | None = None,
                          length_topic: str | None = None,
                          force_topic: str | None = None,
                          lead_s: float = 0.0) -> MuscleRecording:
    """Read a bag's stimulation, length and force onto one time grid.

    Without topic options, the stimulation is ``pulse_width`` or else
    ``recruitment``, the length ``length_command_stamped`` or else
    ``length_command``, the force ``wrench`` or else ``force`` (each the first
    with messages; relative names find the topic in any one namespace).

    :param lead_s: [s] start the grid this much earlier (the inputs at rest there),
        so that the first stimulation change can be moved earlier than its stamp
        (:func:`align_stimulation_edges`)
    :raises FitError: naming the bag and the topic if a topic is missing, a value
        is out of range, or the inputs and the force do not overlap in time
    """
    from ...recording.reader import read_bag   # mcap: imported only when reading a bag
    bag_dir = Path(bag_dir)
    try:
        bag = read_bag(bag_dir)
    except (FileNotFoundError, OSError, ValueError) as err:
        raise FitError(f'{bag_dir}: cannot read the bag: {err}') from None
    if pulse_width_topic is not None and recruitment_topic is not None:
        raise FitError('give --pulse-width-topic or --recruitment-topic, not both')
    if pulse_width_topic is not None:
        stim = _pick_topic(bag, [pulse_width_topic], 'the stimulation', '--pulse-width-topic')
        kind = 'pulse_width'
    elif recruitment_topic is not None:
        stim = _pick_topic(bag, [recruitment_topic], 'the stimulation', '--recruitment-topic')
        kind = 'recruitment'
    else:
        stim = _pick_topic(bag, [PULSE_WIDTH_TOPIC, RECRUITMENT_TOPIC], 'the stimulation',
                           '--pulse-width-topic or --recruitment-topic')
        kind = 'pulse_width' if stim.name.endswith(PULSE_WIDTH_TOPIC) else 'recruitment'
    length = _pick_topic(bag, [length_topic] if length_topic else LENGTH_TOPICS,
                         'the MTU length', '--length-topic')
    force = _pick_topic(bag, [force_topic] if force_topic else FORCE_TOPICS,
                        'the measured force', '--force-topic')
    try:
        stim_v, length_v, force_v = stim.values(), length.values(), force.values()
    except ValueError as err:
        raise FitError(f'{bag_dir}: {err}') from None
    stim_t, length_t, force_t = stim.stamps_ns(), length.stamps_ns(), force.stamps_ns()
    for topic, t in ((stim, stim_t), (length, length_t), (force, force_t)):
        if np.any(np.diff(t) < 0):
            raise FitError(f'{bag_dir}: the stamps of `{topic.name}` go back in time')
    _check_values(bag_dir, stim.name, kind, stim_v)
    bad = ~(np.abs(length_v) <= DL_MT_LIMIT_M)
    if bad.any():
        raise FitError(f'{bag_dir}: `{length.name}` must be within ±{DL_MT_LIMIT_M:g} m of '
                       f'rest, got {length_v[bad][0]!r}')
    keep = np.isfinite(force_v)
    force_t, force_v = force_t[keep], force_v[keep]
    if len(force_t) < 2:
        raise FitError(f'{bag_dir}: `{force.name}` has {len(force_t)} finite samples: '
                       'too few to fit')
    origin = int(force_t[0])
    for topic, t in ((stim, stim_t), (length, length_t)):
        if t[0] > force_t[-1] or t[-1] < force_t[0]:
            raise FitError(f'{bag_dir}: the messages on `{topic.name}` ({_span(t, origin)}) '
                           f'and the force on `{force.name}` ({_span(force_t, origin)}) do '
                           'not overlap in time')
    dt_ns = float(np.median(np.diff(force_t)))
    if not dt_ns > 0:
        raise FitError(f'{bag_dir}: the samples of `{force.name}` share one stamp')
    # The muscle is at rest where every input has started; the grid starts at
    # the force sample at or just before that instant.
    start_ns = max(int(stim_t[0]), int(length_t[0])) - round(lead_s * NS_PER_S)
    first = max(int(np.searchsorted(force_t, start_ns, side='right')) - 1, 0)
    force_t, force_v = force_t[first:], force_v[first:]
    t0 = int(force_t[0])
    sample_index = np.rint((force_t - t0) / dt_ns).astype(np.int64)
    if np.any(np.diff(sample_index) <= 0):
        raise FitError(f'{bag_dir}: the samples of `{force.name}` are not on a uniform '
                       'time grid (two fall on one step)')
    grid_ns = t0 + np.rint(np.arange(sample_index[-1] + 1) * dt_ns).astype(np.int64)
    if length.type == POINT_STAMPED:
        # A knot track: linear between the instants its stamps name, the ends held.
        dl = np.interp(grid_ns.astype(float), length_t.astype(float), length_v)
    else:
        dl = _held(length_t, length_v, grid_ns)
    return MuscleRecording(bag_dir, NS_PER_S / dt_ns, t0, _held(stim_t, stim_v, grid_ns),
                           kind, dl, sample_index, force_v,
                           {'stimulation': stim.name, 'length': length.name,
                            'force': force.name})


def _check_values(bag_dir: Path, topic: str, kind: str, values: np.ndarray) -> None:
    if kind == 'recruitment':
        bad = ~((values >= 0.0) & (values <= 1.0))
        what = 'in [0, 1]'
    else:
        bad = ~((values >= 0.0) & np.isfinite(values))
        what = 'finite and non-negative (seconds)'
    if bad.any():
        raise FitError(f'{bag_dir}: `{topic}` must be {what}, got {values[bad][0]!r}')


#: Default topics of a limb bag, as the limb node names them: the joint angle,
#: each muscle's stimulation (``{muscle}`` stands for its name; pulse width
#: first, else recruitment, the first with messages) and the external torque.
JOINT_STATES_TOPIC = 'joint_states'
LIMB_PULSE_WIDTH_TOPIC = '{muscle}/pulse_width'
LIMB_RECRUITMENT_TOPIC = '{muscle}/recruitment'
EXTERNAL_TORQUE_TOPIC = 'external_torque'
MUSCLE_PLACEHOLDER = '{muscle}'
JOINT_STATE = 'sensor_msgs/msg/JointState'


@dataclass(frozen=True)
class LimbRecording:
    """A limb's recorded stimulation and joint angle, on one uniform time grid.

    :param bag: the bag directory
    :param rate_hz: [Hz] 1 / dt of the grid (the joint states' median sample spacing)
    :param t0_ns: [ns] the grid's first instant (the first joint state), in the bag's
        stamp clock
    :param joint: the joint's name in ``joint_states``
    :param stimulation: per muscle name, the pulse width [s] or recruitment [-] held at
        each grid instant
    :param stimulation_kind: per muscle name, ``pulse_width`` or ``recruitment``
    :param external_torque_n_m: [N m] the external torque held at each grid instant
    :param sample_index: grid index of each joint state used
    :param angle_rad: [rad] the recorded joint angle at those samples
    :param topics: the topics read, by role (``joint_states``, ``external_torque``,
        and each muscle's name); ``external_torque`` is ``None`` if the bag has none
    """

    bag: Path
    rate_hz: float
    t0_ns: int
    joint: str
    stimulation: dict
    stimulation_kind: dict
    external_torque_n_m: np.ndarray
    sample_index: np.ndarray
    angle_rad: np.ndarray
    topics: dict

    @property
    def sample_t_s(self) -> np.ndarray:
        """[s] the times of the joint states on the grid."""
        return self.sample_index / self.rate_hz


def _topic_for(template: str, muscle: str) -> str:
    return template.replace(MUSCLE_PLACEHOLDER, muscle)


def load_limb_recording(bag_dir: str | Path, plant: LimbPlant, *,
                        joint_states_topic: str | None = None,
                        pulse_width_topic: str | None = None,
                        recruitment_topic: str | None = None,
                        external_torque_topic: str | None = None) -> LimbRecording:
    """Read a limb bag's stimulation and joint angle onto one time grid.

    The grid is that of ``joint_states`` (the joint named as in the plant); the
    limb is taken to be at its initial state at the first joint state. Each
    muscle's stimulation is ``<muscle>/pulse_width`` or else
    ``<muscle>/recruitment``, the external torque ``external_torque`` (0 if the
    bag has none), each held from its message on, as the limb node holds them.
    Topic templates name ``{muscle}`` for the muscle's name.

    :raises FitError: naming the bag and the topic if a topic is missing or a
        muscle's stimulation does not overlap the joint states in time
    """
    from ...recording.reader import read_bag
    bag_dir = Path(bag_dir)
    try:
        bag = read_bag(bag_dir)
    except (FileNotFoundError, OSError, ValueError) as err:
        raise FitError(f'{bag_dir}: cannot read the bag: {err}') from None
    if pulse_width_topic is not None and recruitment_topic is not None:
        raise FitError('give --pulse-width-topic or --recruitment-topic, not both')
    for option, template in (('--pulse-width-topic', pulse_width_topic),
                             ('--recruitment-topic', recruitment_topic)):
        if (template is not None and MUSCLE_PLACEHOLDER not in template
                and len(plant.muscles) > 1):
            raise FitError(f'{option} {template!r}: with {len(plant.muscles)} muscles the '
                           f'topic must contain {MUSCLE_PLACEHOLDER} for the muscle\'s name')
    states = _pick_topic(bag, [joint_states_topic or JOINT_STATES_TOPIC], 'the joint angle',
                         '--joint-states-topic')
    if states.type != JOINT_STATE:
        raise FitError(f'{bag_dir}: `{states.name}` carries {states.type}, not {JOINT_STATE}')
    joint = plant.joint.name
    angle = np.empty(states.count)
    for k, msg in enumerate(states.messages):
        names = list(msg.name)
        if joint not in names:
            raise FitError(f'{bag_dir}: message {k} on `{states.name}` has no joint '
                           f'`{joint}` (the plant\'s joint.name); it names: '
                           f'{", ".join(names) or "none"}')
        i = names.index(joint)
        if i >= len(msg.position):
            raise FitError(f'{bag_dir}: message {k} on `{states.name}` has no position '
                           f'for `{joint}`')
        angle[k] = msg.position[i]
    states_t = states.stamps_ns()
    if np.any(np.diff(states_t) < 0):
        raise FitError(f'{bag_dir}: the stamps of `{states.name}` go back in time')
    keep = np.isfinite(angle)
    states_t, angle = states_t[keep], angle[keep]
    if len(states_t) < 2:
        raise FitError(f'{bag_dir}: `{states.name}` has {len(states_t)} finite joint '
                       'angles: too few to fit')
    dt_ns = float(np.median(np.diff(states_t)))
    if not dt_ns > 0:
        raise FitError(f'{bag_dir}: the samples of `{states.name}` share one stamp')
    t0 = int(states_t[0])
    sample_index = np.rint((states_t - t0) / dt_ns).astype(np.int64)
    if np.any(np.diff(sample_index) <= 0):
        raise FitError(f'{bag_dir}: the samples of `{states.name}` are not on a uniform '
                       'time grid (two fall on one step)')
    grid_ns = t0 + np.rint(np.arange(sample_index[-1] + 1) * dt_ns).astype(np.int64)

    stimulation, kinds, topics = {}, {}, {'joint_states': states.name}
    for m in plant.muscles:
        if pulse_width_topic is not None:
            candidates = [(_topic_for(pulse_width_topic, m.name), 'pulse_width')]
        elif recruitment_topic is not None:
            candidates = [(_topic_for(recruitment_topic, m.name), 'recruitment')]
        else:
            candidates = [(_topic_for(LIMB_PULSE_WIDTH_TOPIC, m.name), 'pulse_width'),
                          (_topic_for(LIMB_RECRUITMENT_TOPIC, m.name), 'recruitment')]
        found = [(bag.topic(c), k) for c, k in candidates
                 if bag.has_topic(c) and bag.topic(c).count]
        if not found:   # the message names every candidate and what the bag has
            _pick_topic(bag, [c for c, _ in candidates], f"{m.name}'s stimulation",
                        '--pulse-width-topic or --recruitment-topic')
        stim, kind = found[0]
        try:
            values = stim.values()
        except ValueError as err:
            raise FitError(f'{bag_dir}: {err}') from None
        _check_values(bag_dir, stim.name, kind, values)
        t = stim.stamps_ns()
        if t[0] > states_t[-1] or t[-1] < states_t[0]:
            raise FitError(f'{bag_dir}: the messages on `{stim.name}` ({_span(t, t0)}) and '
                           f'the joint states on `{states.name}` ({_span(states_t, t0)}) do '
                           'not overlap in time')
        stimulation[m.name] = _held(t, values, grid_ns)
        kinds[m.name] = kind
        topics[m.name] = stim.name
    tau_name = external_torque_topic or EXTERNAL_TORQUE_TOPIC
    if bag.has_topic(tau_name) and bag.topic(tau_name).count:
        tau = bag.topic(tau_name)
        try:
            tau_v = tau.values()
        except ValueError as err:
            raise FitError(f'{bag_dir}: {err}') from None
        bad = ~(np.abs(tau_v) <= TORQUE_LIMIT_N_M)
        if bad.any():
            raise FitError(f'{bag_dir}: `{tau.name}` must be within ±{TORQUE_LIMIT_N_M:g} '
                           f'N m, got {tau_v[bad][0]!r}')
        torque = _held(tau.stamps_ns(), tau_v, grid_ns)
        topics['external_torque'] = tau.name
    elif external_torque_topic is not None:
        # Named by the user: its absence is an error, not a zero torque.
        _pick_topic(bag, [external_torque_topic], 'the external torque',
                    '--external-torque-topic')
    else:
        torque = np.zeros(len(grid_ns))
        topics['external_torque'] = None
    return LimbRecording(bag_dir, NS_PER_S / dt_ns, t0, joint, stimulation, kinds, torque,
                         sample_index, angle, topics)
