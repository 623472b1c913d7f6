"""``hill-muscle fit``: estimate muscle parameters from a recorded bag by least squares.

The recorded inputs (stimulation and MTU length) are replayed through the
model from rest, on the time grid of the recorded force, and the named
:class:`~hill_muscle_ros.model.params.MuscleParams` fields are moved by
:func:`scipy.optimize.least_squares` until the simulated force matches the
recorded one. The rest of the parameters stay as the start file gives them.

The pieces are kept apart so that the limb is fitted the same way:
:func:`load_muscle_recording` turns a bag into arrays, :class:`MuscleReplay`
predicts the force of several parameter sets at once (its ``predict`` is all
:func:`fit_parameters` asks of a model), and :func:`fit_parameters` runs the
optimiser, checks identifiability and computes the standard errors. The CLI
glue (:func:`cmd_fit`) writes the parameters file and the report.

The limb (``--plant``): :func:`load_limb_recording` reads ``joint_states``
(the plant's joint by name) and each muscle's stimulation onto the joint
states' grid, :class:`LimbReplay` runs them through
:func:`~hill_muscle_ros.model.limb.simulate_limb` from the plant's initial
state, and :class:`PlantParameter` names what is fitted as the plant file
does (``joint.damping_n_m_s_per_rad``, ``quadriceps.f_iso_max_n``);
:func:`plant_file_text` writes the fitted values into the start plant file.

Live bags (``--edge-search``): the stimulation's stamps are the recorder's
receive times, some steps off the step the simulator acted on;
:func:`fit_with_aligned_edges` moves each change to the step that best explains
the force and fits again.

Replaying: the force samples define the grid (step dt = their median
spacing). The stimulation holds its last message (zero before the first),
as the simulator node does; a plain ``length_command`` holds too and the step
ramps linearly to it, a ``length_command_stamped`` knot track is linear
between its stamps. Each step holds the command of its start and the force
sample is taken at its end, as in the simulator node: a bag written by
``simulate --bag`` is reproduced to the last bit by its own parameters,
except for the sample at which the stimulation drops to zero, which
``simulate`` shows released one sample earlier (its final zero message does
not count: no sample follows it). The muscle is taken to be at rest at the
first instant where every input and the force have a message.

Cost: each evaluation runs the nominal parameters and one forward-difference
perturbation per fitted parameter (K = n + 1 runs) and hands scipy the
residual and the Jacobian together (``jac=``). The runs use the scalar hot
loop of :class:`~hill_muscle_ros.model.muscle.Muscle`, the one ``simulate``
uses: on Protocol II at 1 kHz one run takes about 12 ms, where
:class:`~hill_muscle_ros.model.batch.MuscleBatch` takes about 0.5 s for K = 4
(its per-step NumPy overhead only pays off for hundreds of muscles). Muscles
with FES extensions on run :class:`~hill_muscle_ros.model.fes_muscle.FesMuscle`,
which is several times slower per step. Where the runs a fit expects repay
loading the compiled loop (:meth:`MuscleReplay.compiled`: an ``--edge-search``
replays the recording once per candidate move, hundreds of times), every run
of that fit takes it, with the same forces to about 1e-9 N. A limb run is far
dearer (the joint and every CE integrated together on sub-steps): a limb fit
takes the compiled limb once an evaluation's runs repay loading it
(BENCHMARKS.md, section 8).
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Protocol as TypingProtocol, Sequence

import numpy as np
import yaml

from ..model import Muscle, MuscleParams
from ..model.fes_muscle import FesMuscle
from ..model.limb import TORQUE_LIMIT_N_M, JointParams, LimbPlant, LimbProtocol, simulate_limb
from ..model.muscle import DL_MT_LIMIT_M, MuscleOutputs
from ..model.plant_fields import (GEOMETRY_FIELDS, JOINT_PART, PARAMS, PlantNameError,
                                 plant_field, plant_value, replaced_plant)
from ..model.protocol import Knots, commands_from_pulse_widths
from ..model.simulate import sample_times
from ..timebase import NS_PER_S
from .common import PROG, UserError, bounded_number

#: Default topics, each list in order of preference: the first with messages is used.
PULSE_WIDTH_TOPIC = 'pulse_width'
RECRUITMENT_TOPIC = 'recruitment'
#: Stamped knots first: their stamps are the instants the length is to be reached.
LENGTH_TOPICS = ('length_command_stamped', 'length_command')
#: The wrench first: its header stamp is the simulated time of the step.
FORCE_TOPICS = ('wrench', 'force')
#: Message type of the knot track (``point.x`` at ``header.stamp``).
POINT_STAMPED = 'geometry_msgs/msg/PointStamped'

#: Relative forward-difference step, as scipy's '2-point' scheme:
#: h = sqrt(eps) max(1, |x|) balances truncation and rounding error.
FD_RELATIVE_STEP = math.sqrt(np.finfo(float).eps)
#: A parameter whose relative sensitivity |dF/dx| |x| / |F| (norms over the
#: samples) is below this does not act on the force: the forward difference
#: itself carries a relative rounding error of about eps / FD_RELATIVE_STEP
#: = 1.5e-8, so anything within 100 times that is indistinguishable from zero.
MIN_RELATIVE_SENSITIVITY = 1e-6
#: Largest condition index s_max / s_k of the Jacobian with unit-length columns
#: accepted (Belsley, Kuh and Welsch 1980, Regression Diagnostics, ch. 3:
#: above 30 the columns are strongly, above 100 seriously, linearly
#: dependent). Above it J^T J is near-singular: the force determines a
#: combination of some parameters far better than each one, and their
#: standard errors are at least 100 times those of independent columns.
#: Protocol II gives 2.0 for f_iso_max_n, k_se_n_per_m and fv_a_n, and 139 for
#: the Riener fatigue constants tau_fatigue_s and fatigue_min of a 6 s run.
MAX_CONDITION_INDEX = 100.0
#: A parameter takes part in a near-singular direction when at least this
#: share of its estimate's variance comes from that direction (Belsley, Kuh
#: and Welsch's variance-decomposition proportion, their threshold).
VARIANCE_PROPORTION = 0.5
#: Tolerances of least_squares on the cost, the step and the gradient: far
#: below any force noise, yet above the simulation's rounding.
FIT_TOLERANCE = 1e-10
#: Most evaluations (each one K = n + 1 simulations).
MAX_EVALUATIONS = 100
#: Output file names in --report DIR.
REPORT_MARKDOWN = 'fit_report.md'
REPORT_YAML = 'fit_report.yaml'
REPORT_PNG = 'fit_force.png'


class FitError(ValueError):
    """A user error of a fit (bag, topic, parameter name): the message names it."""


class NotIdentifiableError(FitError):
    """The force does not determine some of the fitted parameters.

    :param names: the parameters concerned
    :param message: why, in words
    """

    def __init__(self, names: Sequence[str], message: str) -> None:
        super().__init__(message)
        self.names = tuple(names)


# --------------------------------------------------------------------------- parameters

@dataclass(frozen=True)
class FitParameter:
    """One fitted quantity: a float field of the parameters, or one entry of a
    per-fibre-type list (``tau_fatigue_s`` for a list of one, ``tau_fatigue_s[1]``).

    :param field: the dataclass field name
    :param index: the list entry, or ``None`` for a float field
    :param unit: the field's unit
    :param low: lower bound of the field's range
    :param high: upper bound of the field's range
    :param named_by_index: the user wrote ``field[i]`` (else a list of one: ``field``)
    """

    field: str
    index: int | None
    unit: str
    low: float
    high: float
    named_by_index: bool = False

    @property
    def name(self) -> str:
        """The name as the user writes it in ``--fit``."""
        return f'{self.field}[{self.index}]' if self.named_by_index else self.field

    def get(self, params: Any) -> float:
        value = getattr(params, self.field)
        return float(value if self.index is None else value[self.index])

    def set(self, params: Any, value: float) -> Any:
        """A copy of ``params`` with this quantity set (validated on construction)."""
        if self.index is None:
            return params.replace(**{self.field: float(value)})
        values = list(getattr(params, self.field))
        values[self.index] = float(value)
        return params.replace(**{self.field: tuple(values)})


def parse_fit_names(text: str, params: MuscleParams, prefix: str = '') -> list[FitParameter]:
    """The fitted quantities that ``--fit NAME[,NAME...]`` names.

    :param text: comma-separated field names, optionally ``name[i]`` for a list entry
    :param params: the start parameters (for list lengths)
    :param prefix: what the user wrote before these names (``quadriceps.`` on a
        limb), for the messages
    :raises FitError: naming an unknown, repeated or non-float name
    """
    fields = {f.name: f for f in dataclasses.fields(MuscleParams)}
    out: list[FitParameter] = []
    for raw in text.split(','):
        name = raw.strip()
        if not name:
            raise FitError(f'--fit: empty parameter name in {text!r}')
        field_name, index = name, None
        if name.endswith(']') and '[' in name:
            field_name, _, rest = name[:-1].partition('[')
            try:
                index = int(rest)
            except ValueError:
                raise FitError(f'--fit: `{prefix}{name}`: the index must be an integer') from None
        f = fields.get(field_name)
        if f is None:
            raise FitError(f'--fit: unknown parameter `{prefix}{name}` (fittable: '
                           f'{", ".join(fittable_names())})')
        spec = f.metadata
        if spec['choices'] is not None or f.type == 'int':
            raise FitError(f'--fit: `{prefix}{name}` cannot be fitted: it is not a real number '
                           f'({"a choice" if spec["choices"] else "an integer"})')
        is_list = f.type.startswith('tuple')
        if is_list:
            n = len(getattr(params, field_name))
            if index is None:
                if n != 1:
                    raise FitError(f'--fit: `{prefix}{name}` has {n} entries: name one, e.g. '
                                   f'`{prefix}{field_name}[0]`')
                index = 0
            elif not 0 <= index < n:
                raise FitError(f'--fit: `{prefix}{name}`: index out of range, the start '
                               f'parameters give {n} entries')
        elif index is not None:
            raise FitError(f'--fit: `{prefix}{name}`: `{field_name}` is not a list')
        param = FitParameter(field_name, index if is_list else None, spec['unit'],
                             float(spec['low']), float(spec['high']), name != field_name)
        if any(p.name == param.name for p in out):
            raise FitError(f'--fit: `{prefix}{param.name}` is named twice')
        out.append(param)
    return out


def fittable_names() -> list[str]:
    """Names of the fields that can be fitted (real numbers and lists of them)."""
    return [f.name for f in dataclasses.fields(MuscleParams)
            if f.metadata['choices'] is None and f.type != 'int']


# --------------------------------------------------------------------------- the bag

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
    from ..recording.reader import read_bag   # mcap: imported only when reading a bag
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


# --------------------------------------------------------------------------- replay

class ForceModel(TypingProtocol):
    """What :func:`fit_parameters` needs of a model: predictions for parameter sets."""

    def predict(self, params: Sequence[Any]) -> np.ndarray:
        """The predicted measurements, one row per parameter set."""


#: Evaluations a fit is expected to take, to judge its runs before it starts:
#: the three-parameter fit of Protocol II takes 6 (BENCHMARKS.md, section 8).
#: Only the choice of engine depends on it, never the result.
EXPECTED_EVALUATIONS = 6


def replay_runs(n_parameters: int) -> int:
    """[-] runs a fit of ``n_parameters`` is expected to ask a replay for: K = n + 1
    per evaluation, :data:`EXPECTED_EVALUATIONS` evaluations."""
    return (n_parameters + 1) * EXPECTED_EVALUATIONS


def candidate_moves(recording: 'MuscleRecording', max_shift_steps: int) -> int:
    """[-] moves :func:`align_stimulation_edges` tries at most: each stimulation
    change by every whole step within ±``max_shift_steps``."""
    return len(stimulation_edges(recording.stimulation)) * (2 * max_shift_steps + 1)


def edge_search_runs(recording: 'MuscleRecording', n_parameters: int,
                     max_shift_steps: int) -> int:
    """[-] runs of :func:`fit_with_aligned_edges` at most: per round a fit and one
    run per candidate move."""
    return MAX_ALIGN_ROUNDS * (replay_runs(n_parameters)
                               + candidate_moves(recording, max_shift_steps))


class MuscleReplay:
    """The recorded inputs replayed through the muscle, for any parameters.

    The runs take the compiled muscle (:func:`~hill_muscle_ros.model.kernels.run_compiled`,
    or the compiled FES muscle) where :func:`~hill_muscle_ros.model.engine.use_compiled`
    says ``runs`` runs of the recording repay loading it, or where it is
    loaded already: the same forces to about 1e-9 N (test_muscle_compiled,
    test_fes_compiled), one engine for every run of a fit.

    :param recording: the inputs and the force samples to predict
    :param runs: [-] runs the caller expects to ask for in all (:func:`replay_runs`);
        it chooses the engine only
    """

    def __init__(self, recording: MuscleRecording, runs: int = 1) -> None:
        self.recording = recording
        self.runs = runs
        self.dt_s = 1.0 / recording.rate_hz
        self._dl_end = recording.dl_mt_m[1:].tolist()

    def compiled(self, fes: bool) -> bool:
        """Whether the runs take the compiled engine (loading it here if they repay it).

        :param fes: the FES muscle's engine rather than the paper's loop
        """
        from ..model import engine, fes_kernels, kernels
        from ..model.simulate import FES_RUN_MIN_STEPS
        work = (len(self.recording.stimulation) - 1) * self.runs
        if fes:
            if not engine.use_compiled(work, FES_RUN_MIN_STEPS, fes_kernels.loaded()):
                return False
            fes_kernels.compiled()
            return True
        if not engine.use_compiled(work, kernels.RUN_MIN_STEPS, kernels.run_loaded()):
            return False
        kernels.compiled_run()
        return True

    def commands(self, params: MuscleParams) -> np.ndarray:
        """[-] the command u at each grid instant: the recruitment itself, or the
        pulse width through the muscle's recruitment curve."""
        if self.recording.stimulation_kind == 'recruitment':
            return self.recording.stimulation
        return commands_from_pulse_widths(self.recording.stimulation, params)

    def force(self, params: MuscleParams, fes: bool = False) -> np.ndarray:
        """[N] the force at every grid instant, from rest.

        :param fes: run the FES engine even if every FES extension is off
        """
        u = self.commands(params).tolist()
        muscle = FesMuscle(params) if fes else Muscle(params)
        muscle.set_recruitment(u[0])
        first = muscle.outputs()
        n_steps = len(u) - 1
        force = np.empty(n_steps + 1)
        force[0] = first.force_n
        # As the simulator node: a command acts from the step after it, so a
        # release to zero shows one sample later than in `simulate`'s own table.
        if self.compiled(fes):
            force[1:] = self._force_compiled(muscle, fes, u)
            return force
        columns = [[0.0] * n_steps for _ in first]
        muscle.run(u[:-1], self._dl_end, self.dt_s, columns=columns)
        force[1:] = columns[first._fields.index('force_n')]
        return force

    def _force_compiled(self, muscle: Muscle, fes: bool, u: list) -> np.ndarray:
        """[N] the force after each step, :meth:`force`'s loop on the compiled engine."""
        from ..model import fes_kernels, kernels
        if fes:
            # From rest: its first step gives u[0] at t = 0, all that
            # set_recruitment(u[0]) did to the reference before its first step.
            bundle = fes_kernels.FesBundle([muscle.params], dt_s=self.dt_s)
            rows = fes_kernels.run_muscle(bundle, 0, u[:-1], self._dl_end, self.dt_s,
                                          kernels=fes_kernels.compiled())
            return rows[:, MuscleOutputs._fields.index('force_n')]
        return kernels.run_compiled(muscle, u[:-1], self._dl_end, self.dt_s)[kernels.RUN_FORCE]

    def predict(self, params: Sequence[MuscleParams]) -> np.ndarray:
        """[N] the force at the recorded samples, one row per parameter set."""
        index = self.recording.sample_index
        # One engine for all: the paper's loop and the FES engine agree to about
        # 1e-9 N, not to the bit, and a forward difference across the two (an FES
        # constant moved off its default) would turn that into a false slope.
        fes = not all(p.fes_defaults for p in params)
        return np.array([self.force(p, fes)[index] for p in params])


def stimulation_edges(stimulation: np.ndarray) -> np.ndarray:
    """Grid indices where the held stimulation changes (the first step it acts on)."""
    return np.flatnonzero(stimulation[1:] != stimulation[:-1]) + 1


def _moved_edge(stimulation: np.ndarray, edge: int, shift: int) -> np.ndarray:
    """The stimulation with the change at ``edge`` moved by ``shift`` steps."""
    out = stimulation.copy()
    if shift > 0:
        out[edge:edge + shift] = stimulation[edge - 1]
    elif shift < 0:
        out[edge + shift:edge] = stimulation[edge]
    return out


def align_stimulation_edges(recording: MuscleRecording, params: MuscleParams,
                            max_shift_steps: int, runs: int | None = None,
                            ) -> tuple[MuscleRecording, list[int]]:
    """Each stimulation change moved to the step that best explains the force.

    A live recording stamps the stimulation with the recorder's receive time,
    while the simulator applied each message from the first step of its next
    tick: a change can act some steps before or after its stamp (measured: up
    to 13 ms on a loaded machine). With the force of the paper's model jumping
    at each change, one step off leaves a residual of the size of the jump and
    biases the fit. Each change, in order, is moved by the whole number of steps
    within ±``max_shift_steps`` (never past its neighbours) that gives the least
    sum of squared residuals with ``params``; a tie keeps the smallest move.

    :param runs: [-] runs the caller expects in all, for :class:`MuscleReplay`'s
        choice of engine (default: this search's own, one per candidate move)
    :return: the recording with the changes moved, and each change's move [steps]
    """
    stim = recording.stimulation
    edges = [int(c) for c in stimulation_edges(stim)]
    if runs is None:
        runs = candidate_moves(recording, max_shift_steps)
    shifts = []
    for j, edge in enumerate(edges):
        low = (edges[j - 1] + shifts[j - 1] + 1) if j else 1
        high = edges[j + 1] - 1 if j + 1 < len(edges) else len(stim) - 1
        best = None
        for shift in sorted(range(-max_shift_steps, max_shift_steps + 1), key=abs):
            if not low <= edge + shift <= high:
                continue
            moved = dataclasses.replace(recording, stimulation=_moved_edge(stim, edge, shift))
            residual = MuscleReplay(moved, runs).predict([params])[0] - recording.force_n
            sse = float(residual @ residual)
            if best is None or sse < best[0]:
                best = (sse, shift)
        shift = best[1] if best is not None else 0
        stim = _moved_edge(stim, edge, shift)
        shifts.append(shift)
    return dataclasses.replace(recording, stimulation=stim), shifts


#: Most rounds of fitting and aligning the stimulation changes: the moves settle
#: in one or two (a move found with the first estimates is rarely revised).
MAX_ALIGN_ROUNDS = 4


def fit_with_aligned_edges(recording: MuscleRecording, start: MuscleParams,
                           parameters: Sequence[FitParameter], max_shift_steps: int,
                           progress: Callable[[str], None] | None = None,
                           ) -> tuple['FitResult', MuscleRecording, list[int]]:
    """Fit, move the stimulation changes to the fitted model, and fit again from
    ``start``, until the moves stay the same (:func:`align_stimulation_edges`).

    :return: the last fit, the recording it used, and the moves [steps]
    """
    used = recording
    shifts = [0] * len(stimulation_edges(recording.stimulation))
    # Every run of the search judged together: one engine from the first run on.
    runs = edge_search_runs(recording, len(parameters), max_shift_steps)
    for _ in range(MAX_ALIGN_ROUNDS):
        result = fit_parameters(MuscleReplay(used, runs), recording.force_n, start,
                                parameters, progress=progress)
        fitted_with = (used, shifts)
        aligned, new_shifts = align_stimulation_edges(recording, result.params,
                                                      max_shift_steps, runs)
        if progress is not None:
            progress('stimulation changes moved by ' + (', '.join(
                f'{s * 1e3 / recording.rate_hz:+g} ms' for s in new_shifts) or 'nothing'))
        if new_shifts == shifts:
            break
        used, shifts = aligned, new_shifts
    return (result, *fitted_with)   # if the moves never settled: the last fit's


# --------------------------------------------------------------------------- fitting

@dataclass(frozen=True)
class FitResult:
    """The outcome of a fit.

    :param parameters: the fitted quantities
    :param start: the start parameters
    :param params: the fitted parameters (the rest unchanged)
    :param start_values: the fitted quantities' start values
    :param estimates: their estimates
    :param std_errors: their standard errors, sqrt(diag(sigma^2 (J^T J)^-1))
    :param correlation: the correlation matrix of the estimates
    :param rms_n: [N] residual RMS at the estimate (in the measured quantity's
        unit: [rad] for a joint angle)
    :param start_rms_n: [N] residual RMS at the start (as ``rms_n``)
    :param n_samples: number of samples fitted
    :param n_evaluations: evaluations of residual and Jacobian together
    :param message: the optimiser's reason to stop
    :param fitted: the prediction at the samples, at the estimate
    """

    parameters: tuple[FitParameter, ...]
    start: Any
    params: Any
    start_values: np.ndarray
    estimates: np.ndarray
    std_errors: np.ndarray
    correlation: np.ndarray
    rms_n: float
    start_rms_n: float
    n_samples: int
    n_evaluations: int
    message: str
    fitted: np.ndarray


def _perturbed(parameters: Sequence[FitParameter], start: Any,
               x: np.ndarray) -> tuple[list[Any], np.ndarray]:
    """The parameter sets of one evaluation: x itself, then x with each entry moved
    by its forward-difference step (backwards at an upper bound), and the steps."""
    base = start
    for p, v in zip(parameters, x):
        base = p.set(base, v)
    sets, steps = [base], np.empty(len(x))
    for j, p in enumerate(parameters):
        h = FD_RELATIVE_STEP * max(1.0, abs(x[j]))
        moved = x[j] + h if x[j] + h <= p.high else x[j] - h
        steps[j] = moved - x[j]   # the step actually taken, after rounding
        sets.append(p.set(base, moved))
    return sets, steps


def _and(names: Sequence[str]) -> str:
    quoted = [f'`{n}`' for n in names]
    return quoted[0] if len(quoted) == 1 else ', '.join(quoted[:-1]) + ' and ' + quoted[-1]


def check_identifiable(parameters: Sequence[Any], x: np.ndarray,
                       jac: np.ndarray, force: np.ndarray, quantity: str = 'force') -> None:
    """Raise if the Jacobian shows fitted quantities the force does not determine.

    :param parameters: the fitted quantities (:class:`FitParameter` or :class:`PlantParameter`)
    :param x: the values at which ``jac`` was taken
    :param jac: [N per unit] d force / d x, one column per quantity
    :param force: [N] the predicted force there (its norm sets the scale)
    :param quantity: what is measured, in the messages (``force``, ``joint angle``)
    :raises NotIdentifiableError: naming the quantities, with the reason
    """
    norms = np.linalg.norm(jac, axis=0)
    scale = max(float(np.linalg.norm(force)), np.finfo(float).tiny)
    sensitivity = norms * np.maximum(np.abs(x), np.finfo(float).tiny) / scale
    dead = [p.name for p, s in zip(parameters, sensitivity) if not s >= MIN_RELATIVE_SENSITIVITY]
    if dead:
        listed = _and(dead)
        raise NotIdentifiableError(dead, f'not identifiable from this recording: {listed} '
                                         f'(the {quantity} does not depend on '
                                         f'{"it" if len(dead) == 1 else "them"})')
    if len(parameters) < 2:
        return
    _, sv, vt = np.linalg.svd(jac / norms, full_matrices=False)
    weak = sv * MAX_CONDITION_INDEX < sv[0]
    if weak.any():
        # Variance-decomposition proportions: the share of each estimate's
        # variance sum_k v_jk^2 / s_k^2 that each singular direction k carries.
        phi = (vt.T / sv) ** 2
        share = phi[:, weak].max(axis=1) / phi.sum(axis=1)
        names = [p.name for p, w in zip(parameters, share) if w >= VARIANCE_PROPORTION]
        listed = _and(names)
        raise NotIdentifiableError(names, f'not identifiable from this recording: {listed} '
                                          f'(J^T J is near-singular: the {quantity} determines '
                                          'only a combination of them; fit fewer of them or use '
                                          'a recording that separates them)')


def fit_parameters(model: ForceModel, measured: np.ndarray, start: Any,
                   parameters: Sequence[Any],
                   progress: Callable[[str], None] | None = None, *,
                   quantity: str = 'force', unit: str = 'N') -> FitResult:
    """Least-squares estimate of ``parameters``, the rest of ``start`` held.

    Each evaluation predicts K = n + 1 parameter sets at once: the residual at
    x and the forward-difference Jacobian columns, handed to
    :func:`scipy.optimize.least_squares` (trust region reflective, within the
    fields' ranges) as ``fun`` and ``jac``.

    :param model: predicts the measurements for parameter sets (:class:`MuscleReplay`)
    :param measured: the measurements, in the order ``model.predict`` returns them
    :param start: the start parameters (their ``replace`` makes the others)
    :param parameters: the quantities to fit
    :param progress: called with one line per evaluation (cost, RMS)
    :param quantity: what ``measured`` is, in the messages (``force``, ``joint angle``)
    :param unit: its unit, in the progress lines
    :raises NotIdentifiableError: at the start or at the estimate
    :raises FitError: if a parameter set on the way is invalid
    """
    from scipy.optimize import least_squares
    parameters = tuple(parameters)
    n = len(parameters)
    m = len(measured)
    if m <= n:
        raise FitError(f'{m} {quantity} samples for {n} parameters: too few to fit')
    x0 = np.array([p.get(start) for p in parameters])
    cache: dict[str, Any] = {}

    def evaluate(x: np.ndarray) -> None:
        if cache.get('x') is not None and np.array_equal(cache['x'], x):
            return
        try:
            sets, steps = _perturbed(parameters, start, x)
        except ValueError as err:
            raise FitError(f'the fit reached invalid parameters: {err}') from None
        forces = model.predict(sets)
        residual = forces[0] - measured
        cache.update(x=x.copy(), residual=residual, force=forces[0],
                     jac=(forces[1:] - forces[0]).T / steps)
        cache['n'] = cache.get('n', 0) + 1
        if progress is not None:
            cost = 0.5 * float(residual @ residual)
            progress(f'evaluation {cache["n"]:3d}: cost {cost:.6g} {unit}^2, RMS '
                     f'{math.sqrt(2.0 * cost / m):.6g} {unit}  ' + ', '.join(
                         f'{p.name}={v:.8g}' for p, v in zip(parameters, x)))

    def fun(x: np.ndarray) -> np.ndarray:
        evaluate(x)
        return cache['residual']

    def jac(x: np.ndarray) -> np.ndarray:
        evaluate(x)
        return cache['jac']

    evaluate(x0)
    start_rms = float(np.sqrt(np.mean(cache['residual'] ** 2)))
    check_identifiable(parameters, x0, cache['jac'], cache['force'], quantity)
    lower = np.array([p.low for p in parameters])
    upper = np.array([p.high for p in parameters])
    result = least_squares(fun, x0, jac=jac, bounds=(lower, upper), method='trf',
                           x_scale='jac', ftol=FIT_TOLERANCE, xtol=FIT_TOLERANCE,
                           gtol=FIT_TOLERANCE, max_nfev=MAX_EVALUATIONS)
    x = result.x
    evaluate(x)
    J, residual = cache['jac'], cache['residual']
    check_identifiable(parameters, x, J, cache['force'], quantity)
    # sigma^2 (J^T J)^-1 through the column-normalised J: same result, better conditioned.
    norms = np.linalg.norm(J, axis=0)
    inv = np.linalg.inv((J / norms).T @ (J / norms)) / np.outer(norms, norms)
    sigma2 = float(residual @ residual) / (m - n)
    cov = sigma2 * inv
    d = np.sqrt(np.diag(inv))
    fitted = start
    for p, v in zip(parameters, x):
        fitted = p.set(fitted, v)
    return FitResult(parameters, start, fitted, x0, x.copy(), np.sqrt(np.diag(cov)),
                     inv / np.outer(d, d), float(np.sqrt(np.mean(residual ** 2))),
                     start_rms, m, cache['n'], str(result.message), cache['force'])


# --------------------------------------------------------------------------- the limb

#: Default topics of a limb bag, as the limb node names them: the joint angle,
#: each muscle's stimulation (``{muscle}`` stands for its name; pulse width
#: first, else recruitment, the first with messages) and the external torque.
JOINT_STATES_TOPIC = 'joint_states'
LIMB_PULSE_WIDTH_TOPIC = '{muscle}/pulse_width'
LIMB_RECRUITMENT_TOPIC = '{muscle}/recruitment'
EXTERNAL_TORQUE_TOPIC = 'external_torque'
MUSCLE_PLACEHOLDER = '{muscle}'
JOINT_STATE = 'sensor_msgs/msg/JointState'
REPORT_ANGLE_PNG = 'fit_angle.png'


@dataclass(frozen=True)
class PlantParameter:
    """One fitted quantity of a limb plant, named as the plant file's ROS parameter
    (``joint.damping_n_m_s_per_rad``, ``quadriceps.f_iso_max_n``,
    ``quadriceps.moment_arm_m``, ``quadriceps.tau_fatigue_s[1]``).

    :param part: ``joint`` or the muscle's name
    :param inner: the field within :class:`~hill_muscle_ros.model.limb.JointParams`,
        :class:`~hill_muscle_ros.model.limb.LimbMuscle` (its geometry) or the
        muscle's :class:`~hill_muscle_ros.model.params.MuscleParams`
    :param where: ``joint``, ``geometry`` or ``params``
        (:mod:`~hill_muscle_ros.model.plant_fields`)
    """

    part: str
    inner: FitParameter
    where: str

    @property
    def name(self) -> str:
        """The name as the user writes it in ``--fit``."""
        return f'{self.part}.{self.inner.name}'

    @property
    def path(self) -> str:
        """The plant field's dotted name (a list's, without the entry)."""
        return f'{self.part}.{self.inner.field}'

    @property
    def field(self) -> str:
        return self.inner.field

    @property
    def unit(self) -> str:
        return self.inner.unit

    @property
    def low(self) -> float:
        return self.inner.low

    @property
    def high(self) -> float:
        return self.inner.high

    def get(self, plant: LimbPlant) -> float:
        value = plant_value(plant, self.path)
        return float(value if self.inner.index is None else value[self.inner.index])

    def set(self, plant: LimbPlant, value: float) -> LimbPlant:
        """A copy of ``plant`` with this quantity set (validated on construction)."""
        new: float | tuple[float, ...] = float(value)
        if self.inner.index is not None:
            values = list(plant_value(plant, self.path))
            values[self.inner.index] = float(value)
            new = tuple(values)
        return replaced_plant(plant, {self.path: new})


def plant_fittable_names(plant: LimbPlant) -> list[str]:
    """The patterns of fittable names of ``plant`` (for the messages)."""
    joint = [f.name for f in dataclasses.fields(JointParams) if f.name != 'name']
    return ([f'{JOINT_PART}.{{{",".join(joint)}}}']
            + [f'{m.name}.{{{",".join(GEOMETRY_FIELDS)}}} or {m.name}.<muscle parameter>'
               for m in plant.muscles])


def parse_plant_fit_names(text: str, plant: LimbPlant) -> list[PlantParameter]:
    """The fitted quantities of a limb that ``--fit NAME[,NAME...]`` names.

    Each name is ``<part>.<field>``, the plant file's parameter name: ``joint.``
    and a field of the joint, or a muscle's name and ``moment_arm_m``,
    ``reference_angle_rad`` or one of its muscle parameters (a list entry as
    ``quadriceps.tau_fatigue_s[1]``).

    :raises FitError: naming an unknown, repeated or non-real name
    """
    out: list[PlantParameter] = []
    for raw in text.split(','):
        name = raw.strip()
        if not name:
            raise FitError(f'--fit: empty parameter name in {text!r}')
        path, bracket, _ = name.partition('[')   # a list entry names the list's field
        try:
            where = plant_field(path, plant)
        except PlantNameError as err:
            raise FitError(f'--fit: {err}') from None
        if where.where == PARAMS:
            muscle = next(m for m in plant.muscles if m.name == where.part)
            [inner] = parse_fit_names(name.partition('.')[2], muscle.params,
                                      prefix=f'{where.part}.')
        elif bracket:
            raise FitError(f'--fit: `{name}`: `{where.field}` is not a list')
        else:
            inner = FitParameter(where.field, None, where.unit, where.low, where.high)
        param = PlantParameter(where.part, inner, where.where)
        if any(p.name == param.name for p in out):
            raise FitError(f'--fit: `{param.name}` is named twice')
        out.append(param)
    return out


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
    from ..recording.reader import read_bag
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


def _held_knots(values: np.ndarray, t_s: np.ndarray) -> Knots:
    """Knots that give ``values[k]`` at ``t_s[k]`` and hold it to the next instant:
    a repeated time at each change is a step (the later knot wins there)."""
    change = np.flatnonzero(values[1:] != values[:-1]) + 1
    times = np.concatenate(([t_s[0]], np.repeat(t_s[change], 2), [t_s[-1]]))
    held = np.empty(2 * len(change))
    held[0::2], held[1::2] = values[change - 1], values[change]
    return Knots(times, np.concatenate(([values[0]], held, [values[-1]])))


#: A worker process's replay: (protocol, rate [Hz], sample indices), set once by
#: :func:`_limb_worker_init` so that each task sends only its plant.
_LIMB_WORKER: tuple | None = None


def _limb_worker_init(protocol: LimbProtocol, rate_hz: float, index: np.ndarray) -> None:
    global _LIMB_WORKER
    _LIMB_WORKER = (protocol, rate_hz, index)


def _limb_worker_angle(plant: LimbPlant) -> np.ndarray:
    protocol, rate_hz, index = _LIMB_WORKER
    return simulate_limb(plant, protocol, rate_hz)['theta_rad'][index]


class LimbReplay:
    """The recorded stimulation replayed through the limb
    (:func:`~hill_muscle_ros.model.limb.simulate_limb`), for any plant.

    The recording becomes a limb protocol on the grid's instants: each step holds
    the stimulation and torque of its start, as the limb node does, and the angle
    of step k is the state after it, as ``joint_states`` shows it.

    With ``jobs`` > 1 the plants of one :meth:`predict` (an evaluation's n + 1)
    run in that many worker processes (forked once, kept until :meth:`close`);
    each run is the same computation, so the angles are identical to one process's.

    :param recording: the inputs and the joint angles to predict
    :param jobs: worker processes, >= 1
    """

    def __init__(self, recording: LimbRecording, jobs: int = 1) -> None:
        if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
            raise ValueError(f'`jobs` must be a positive integer, got {jobs!r}')
        self.jobs = jobs
        self._pool = None
        self.recording = recording
        n = len(recording.external_torque_n_m)
        t = sample_times((n - 1) / recording.rate_hz, recording.rate_hz)
        stimulation = {
            name: ('recruitment' if recording.stimulation_kind[name] == 'recruitment'
                   else 'pulse_width_s', _held_knots(values, t))
            for name, values in recording.stimulation.items()}
        self.protocol = LimbProtocol(f'recording {recording.bag}', float(t[-1]), stimulation,
                                     _held_knots(recording.external_torque_n_m, t))

    def angle(self, plant: LimbPlant) -> np.ndarray:
        """[rad] the joint angle at every grid instant, from the plant's initial state."""
        return simulate_limb(plant, self.protocol, self.recording.rate_hz)['theta_rad']

    def predict(self, plants: Sequence[LimbPlant]) -> np.ndarray:
        """[rad] the joint angle at the recorded samples, one row per plant."""
        from ..model import engine, limb_kernels
        index = self.recording.sample_index
        # One run of a short recording is below the compiled limb's threshold,
        # an evaluation's n + 1 runs together often not: judged on them, the
        # limb is loaded here, so every later run takes it (forked workers too).
        steps = len(self.recording.external_torque_n_m) - 1
        work = steps * sum(len(p.muscles) for p in plants)
        if engine.use_compiled(work, limb_kernels.RUN_MIN_MUSCLE_STEPS, limb_kernels.loaded()):
            limb_kernels.compiled()
        try:
            if self.jobs > 1 and len(plants) > 1:
                return np.array(list(self._workers().map(_limb_worker_angle, plants)))
            return np.array([self.angle(p)[index] for p in plants])
        except ValueError as err:   # a muscle driven beyond its length range
            raise FitError(f'the fit reached a plant the recording drives out of range: '
                           f'{err}') from None

    def _workers(self):
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor
            # fork: the workers start with the recording in memory, nothing to import.
            self._pool = ProcessPoolExecutor(
                self.jobs, mp_context=multiprocessing.get_context('fork'),
                initializer=_limb_worker_init,
                initargs=(self.protocol, self.recording.rate_hz, self.recording.sample_index))
        return self._pool

    def close(self) -> None:
        """Stop the worker processes, if any."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def __enter__(self) -> 'LimbReplay':
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


# --------------------------------------------------------------------------- outputs

def _yaml_value(value: Any) -> str:
    """A parameter value as one line of YAML, floats with a point (ROS types them)."""
    if isinstance(value, tuple):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    if isinstance(value, float):
        return repr(value)   # shortest round-trip form, always with '.' or 'e'
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()


def params_file_text(result: FitResult, node_settings: dict[str, Any], source: str) -> str:
    """The fitted parameters as a ROS 2 parameters file (``/**: ros__parameters:``)."""
    fitted = {p.field for p in result.parameters}
    errors = {p.name: (v, se) for p, v, se in zip(result.parameters, result.estimates,
                                                   result.std_errors)}
    lines = [f'# Muscle parameters fitted by `hill-muscle fit` to {source}.',
             '# Load with:  hill-muscle simulate --params THIS_FILE ...',
             '# or:         ros2 run hill_muscle_ros simulator --ros-args --params-file THIS_FILE',
             '/**:', '  ros__parameters:']
    for f in dataclasses.fields(MuscleParams):
        value = getattr(result.params, f.name)
        line = f'    {f.name}: {_yaml_value(value)}'
        if f.name in fitted:
            notes = [f'{name} fitted, std error {se:.3g} {f.metadata["unit"]}'
                     for name, (_, se) in errors.items()
                     if name == f.name or name.startswith(f.name + '[')]
            line += '  # ' + '; '.join(notes)
        lines.append(line)
    for key, value in node_settings.items():
        lines.append(f'    {key}: {_yaml_value(value)}')
    return '\n'.join(lines) + '\n'


def format_report(result: FitResult, recording: MuscleRecording, start_source: str,
                  shifts: Sequence[int] | None = None, edge_search_s: float = 0.0) -> str:
    """The fit in words and tables (Markdown; also what stdout shows).

    :param shifts: [steps] the moves of the stimulation changes, if they were searched
    :param edge_search_s: [s] the search window, ±
    """
    r = recording
    names = [p.name for p in result.parameters]
    lines = [f'# Fit of {", ".join(names)}', '',
             f'- bag: {r.bag}',
             f'- force: `{r.topics["force"]}`, {result.n_samples} samples at '
             f'{r.rate_hz:g} Hz over {r.sample_t_s[-1] - r.sample_t_s[0]:.3f} s',
             f'- inputs: `{r.topics["stimulation"]}` ({r.stimulation_kind}), '
             f'`{r.topics["length"]}`'] + ([
                 f'- stimulation changes moved by '
                 f'{", ".join(f"{s * 1e3 / r.rate_hz:+g}" for s in shifts) or "nothing"} ms '
                 f'(searched within ±{edge_search_s:g} s of their stamps)']
                 if shifts is not None else []) + [
             f'- start: {start_source}',
             f'- least squares: {result.n_evaluations} evaluations; {result.message}',
             f'- residual RMS: {result.rms_n:.6g} N (at the start: {result.start_rms_n:.6g} N)',
             ''] + _estimate_lines(result) + [
        '', 'Standard errors: sigma^2 (J^T J)^-1 at the estimate, sigma^2 = the sum of '
            'squared residuals / (samples - parameters); they assume independent '
            'force errors of equal variance.']
    return '\n'.join(lines)


def _estimate_lines(result: FitResult) -> list[str]:
    """The estimates with their standard errors, and their correlations (Markdown)."""
    names = [p.name for p in result.parameters]
    width = max(len(n) for n in names + ['parameter'])
    lines = [f'| {"parameter":<{width}} | {"start":>12} | {"estimate":>14} | '
             f'{"std error":>10} | unit |',
             f'|{"-" * (width + 2)}|{"-" * 14}|{"-" * 16}|{"-" * 12}|------|']
    for p, x0, x, se in zip(result.parameters, result.start_values, result.estimates,
                            result.std_errors):
        lines.append(f'| {p.name:<{width}} | {x0:12.6g} | {x:14.8g} | {se:10.3g} | '
                     f'{p.unit} |')
    col = max([12] + [len(n) for n in names])   # 12: the muscle's names fit
    lines += ['', 'Correlation of the estimates:', '',
              '| ' + ' | '.join([' ' * width] + [f'{n:>{col}}' for n in names]) + ' |',
              '|' + '|'.join(['-' * (width + 2)] + ['-' * (col + 2)] * len(names)) + '|']
    for name, row in zip(names, result.correlation):
        lines.append('| ' + ' | '.join([f'{name:<{width}}'] + [f'{c:{col}.4f}' for c in row])
                     + ' |')
    return lines


def _estimates_data(result: FitResult) -> dict[str, Any]:
    """The estimates, their standard errors and correlations as plain data,
    the part of ``fit_report.yaml`` that a muscle's and a limb's fit share."""
    return {
        'parameters': {p.name: {'unit': p.unit, 'start': float(x0), 'estimate': float(x),
                                'std_error': float(se)}
                       for p, x0, x, se in zip(result.parameters, result.start_values,
                                               result.estimates, result.std_errors)},
        'correlation': {'names': [p.name for p in result.parameters],
                        'matrix': [[float(c) for c in row] for row in result.correlation]},
    }


def report_data(result: FitResult, recording: MuscleRecording) -> dict[str, Any]:
    """The report as plain data (for ``fit_report.yaml``)."""
    return {
        'bag': str(recording.bag), 'topics': dict(recording.topics),
        'rate_hz': float(recording.rate_hz), 'n_samples': result.n_samples,
        'n_evaluations': result.n_evaluations, 'message': result.message,
        'residual_rms_n': result.rms_n, 'start_residual_rms_n': result.start_rms_n,
        **_estimates_data(result),
    }


def _plot_measured_and_fitted(path: Path, result: FitResult, t_s: np.ndarray,
                              measured: np.ndarray, measured_label: str,
                              quantity: str, unit: str) -> None:
    """PNG of a measured signal and the fitted model's, and their difference.

    :param measured_label: what was measured, for the legend (the topic)
    :param quantity: its name on the axis (``force``, ``joint angle``)
    :param unit: its unit (``N``, ``rad``)
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (ax_m, ax_r) = plt.subplots(2, 1, sharex=True, figsize=(8, 6),
                                     gridspec_kw={'height_ratios': [3, 1]})
    ax_m.plot(t_s, measured, color='0.6', lw=2, label=f'measured ({measured_label})')
    ax_m.plot(t_s, result.fitted, color='C0', lw=1, label='fitted model')
    ax_m.set_ylabel(f'{quantity} [{unit}]')
    ax_m.set_title(f'hill-muscle fit: {", ".join(p.name for p in result.parameters)}')
    ax_m.legend(loc='best')
    ax_r.plot(t_s, measured - result.fitted, color='C3', lw=0.8)
    ax_r.set_ylabel(f'measured - fitted [{unit}]')
    ax_r.set_xlabel('time [s]')
    for ax in (ax_m, ax_r):
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_fit(path: Path, result: FitResult, recording: MuscleRecording) -> None:
    """PNG of the measured and the fitted force, and their difference."""
    _plot_measured_and_fitted(path, result, recording.sample_t_s, recording.force_n,
                              recording.topics['force'], 'force', 'N')


# --------------------------------------------------------------------------- limb outputs

def _plant_sections(root: Any) -> list[Any]:
    """The ``ros__parameters`` mapping nodes of the sections the limb node reads."""
    sections = []
    if not isinstance(root, yaml.MappingNode):
        return sections
    for key, value in root.value:
        name = str(key.value)
        if name != '/**' and name.rstrip('/').split('/')[-1] != 'limb':
            continue
        if isinstance(value, yaml.MappingNode):
            sections += [v for k, v in value.value
                         if k.value == 'ros__parameters' and isinstance(v, yaml.MappingNode)]
    return sections


def _lookup(mapping: Any, key: str) -> Any:
    return next((v for k, v in mapping.value if k.value == key), None)


def _value_nodes(section: Any, p: PlantParameter) -> list[Any]:
    """The YAML scalar nodes of ``section`` that hold ``p`` (nested or dotted)."""
    nodes = []
    part = _lookup(section, p.part)
    candidates = [_lookup(section, f'{p.part}.{p.field}')]
    if isinstance(part, yaml.MappingNode):
        candidates.append(_lookup(part, p.field))
    for node in candidates:
        if p.inner.index is not None and isinstance(node, yaml.SequenceNode):
            node = node.value[p.inner.index] if p.inner.index < len(node.value) else None
        if isinstance(node, yaml.ScalarNode):
            nodes.append(node)
    return nodes


def plant_file_text(text: str, result: FitResult, source: str) -> str | None:
    """The plant file ``text`` with the fitted values written in place.

    Every other byte stays as it was (comments included); a fitted value's own
    line comment becomes its standard error and start value. A value the file
    does not give (a default) is added as a line of its own in the muscle's or
    the joint's section, or as a dotted name. A header comment names the fit.

    :return: the new text, or ``None`` if the file's layout (flow style) has no
        place for a missing value
    """
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    sections = _plant_sections(root)
    if not sections:
        return None
    edits: list[tuple[int, int, str]] = []   # (start, end, replacement) character spans
    lines_at = text.splitlines(keepends=True)
    for p, x0, x, se in zip(result.parameters, result.start_values, result.estimates,
                            result.std_errors):
        note = (f'# fitted by hill-muscle fit: std error {se:.3g} {p.unit} '
                f'(was {_yaml_value(float(x0))})')
        nodes = [n for s in sections for n in _value_nodes(s, p)]
        for node in nodes:
            start, end = node.start_mark.index, node.end_mark.index
            line = lines_at[node.end_mark.line]
            rest = line[node.end_mark.column:]
            if not rest.strip() or (node.style is None and rest.strip().startswith('#')):
                # A block value: its line comment becomes the fit's note.
                end += len(rest.rstrip('\r\n'))
                edits.append((start, end, f'{_yaml_value(float(x))}  {note}'))
            else:
                edits.append((start, end, _yaml_value(float(x))))
        if nodes:
            continue
        # Not in the file: a new line in the last section the node reads.
        section = sections[-1]
        part = _lookup(section, p.part)
        # A list entry brings the whole list (the rest of it as the start gave it).
        fitted = (p.get(result.params) if p.inner.index is None
                  else plant_value(result.params, p.path))
        if isinstance(part, yaml.MappingNode) and part.value and not part.flow_style:
            target, key = part, p.field
        elif section.value and not section.flow_style:
            target, key = section, f'{p.part}.{p.field}'
        else:
            return None
        first = target.value[0][0].start_mark
        line_start = first.index - first.column
        edits.append((line_start, line_start,
                      f'{" " * first.column}{key}: {_yaml_value(fitted)}  {note}\n'))
    for start, end, new in sorted(edits, reverse=True):
        text = text[:start] + new + text[end:]
    names = ', '.join(p.name for p in result.parameters)
    return (f'# {names} fitted by `hill-muscle fit` to {source}; every other value is the '
            'start file\'s.\n' + text)


def format_limb_report(result: FitResult, recording: LimbRecording, start_source: str) -> str:
    """The limb fit in words and tables (Markdown; also what stdout shows)."""
    r = recording
    inputs = ', '.join(f'`{r.topics[name]}` ({r.stimulation_kind[name]})'
                       for name in r.stimulation)
    torque = (f'`{r.topics["external_torque"]}`' if r.topics['external_torque']
              else 'none in the bag (0 N m)')
    lines = [f'# Fit of {", ".join(p.name for p in result.parameters)}', '',
             f'- bag: {r.bag}',
             f'- joint angle: `{r.topics["joint_states"]}` (`{r.joint}`), {result.n_samples} '
             f'samples at {r.rate_hz:g} Hz over {r.sample_t_s[-1] - r.sample_t_s[0]:.3f} s',
             f'- stimulation: {inputs}; external torque: {torque}',
             f'- start: {start_source}',
             f'- least squares: {result.n_evaluations} evaluations; {result.message}',
             f'- residual RMS: {result.rms_n:.6g} rad (at the start: {result.start_rms_n:.6g} '
             'rad)', ''] + _estimate_lines(result) + [
        '', 'Standard errors: sigma^2 (J^T J)^-1 at the estimate, sigma^2 = the sum of '
            'squared residuals / (samples - parameters); they assume independent '
            'angle errors of equal variance.']
    return '\n'.join(lines)


def limb_report_data(result: FitResult, recording: LimbRecording) -> dict[str, Any]:
    """The limb fit's report as plain data (for ``fit_report.yaml``)."""
    return {
        'bag': str(recording.bag), 'topics': dict(recording.topics),
        'joint': recording.joint, 'rate_hz': float(recording.rate_hz),
        'n_samples': result.n_samples, 'n_evaluations': result.n_evaluations,
        'message': result.message, 'residual_rms_rad': result.rms_n,
        'start_residual_rms_rad': result.start_rms_n,
        **_estimates_data(result),
    }


def plot_limb_fit(path: Path, result: FitResult, recording: LimbRecording) -> None:
    """PNG of the measured and the fitted joint angle, and their difference."""
    _plot_measured_and_fitted(path, result, recording.sample_t_s, recording.angle_rad,
                              f'{recording.topics["joint_states"]}, {recording.joint}',
                              'joint angle', 'rad')


# --------------------------------------------------------------------------- CLI

def add_fit_parser(sub: argparse._SubParsersAction) -> None:
    """The ``fit`` subcommand's parser."""
    fit = sub.add_parser(
        'fit', help='estimate muscle or limb parameters from a recorded bag (least squares)',
        description='Replay the stimulation and length recorded in a rosbag2 MCAP bag '
                    'through the model and fit the named parameters to the recorded '
                    'force by least squares. Writes a parameters file that simulate and '
                    'the simulator node load, and reports each estimate with its standard '
                    'error and the correlations. With --plant, replay each muscle\'s '
                    'stimulation through the limb and fit to the recorded joint angle '
                    '(joint_states); names are then the plant file\'s parameter names, '
                    'joint.<field> or <muscle>.<field> (e.g. joint.damping_n_m_s_per_rad, '
                    'quadriceps.f_iso_max_n, quadriceps.moment_arm_m), and the output is '
                    'the plant file with the fitted values in place.',
        epilog='examples:\n'
               f'  {PROG} simulate --protocol II --params truth.yaml --bag run_bag\n'
               f'  {PROG} fit --bag run_bag --fit f_iso_max_n,k_se_n_per_m,fv_a_n '
               '--out fitted.yaml --report fit_report\n'
               f'  {PROG} fit --bag knee_bag --plant config/knee.yaml '
               '--fit quadriceps.f_iso_max_n,joint.damping_n_m_s_per_rad '
               '--out knee_fitted.yaml --report knee_fit',
        formatter_class=argparse.RawDescriptionHelpFormatter)
    fit.add_argument('--bag', required=True, type=Path, metavar='DIR',
                     help='the rosbag2 MCAP bag (a directory)')
    fit.add_argument('--fit', required=True, metavar='NAME[,NAME...]', dest='fit_names',
                     help='parameters to estimate, e.g. f_iso_max_n,k_se_n_per_m '
                          '(a list entry as tau_fatigue_s[0]); with --plant '
                          f'{JOINT_PART}.<field> or <muscle>.<field>, e.g. '
                          f'{JOINT_PART}.damping_n_m_s_per_rad,quadriceps.f_iso_max_n')
    fit.add_argument('--params', type=Path, metavar='YAML',
                     help='start values and every parameter not fitted (default: the '
                          "package's config/muscle.yaml)")
    fit.add_argument('--plant', type=Path, metavar='YAML',
                     help='fit a limb instead: the plant file (e.g. config/knee.yaml) gives '
                          'the start values and every parameter not fitted; --out is then '
                          'that file with the fitted values in place')
    fit.add_argument('--out', required=True, type=Path, metavar='YAML',
                     help='write the fitted parameters (or plant) file here')
    fit.add_argument('--report', type=Path, metavar='DIR',
                     help=f'also write {REPORT_MARKDOWN}, {REPORT_YAML} and {REPORT_PNG} '
                          f'({REPORT_ANGLE_PNG} with --plant) here')
    stim = fit.add_mutually_exclusive_group()
    stim.add_argument('--pulse-width-topic', metavar='TOPIC',
                      help=f'stimulation as pulse widths [s] (default: `{PULSE_WIDTH_TOPIC}`, '
                           f'else `{RECRUITMENT_TOPIC}`; with --plant `{LIMB_PULSE_WIDTH_TOPIC}`, '
                           f'else `{LIMB_RECRUITMENT_TOPIC}`, {MUSCLE_PLACEHOLDER} standing for '
                           "each muscle's name)")
    stim.add_argument('--recruitment-topic', metavar='TOPIC',
                      help='stimulation as recruitment [-] (with --plant, a topic with '
                           f'{MUSCLE_PLACEHOLDER})')
    fit.add_argument('--joint-states-topic', metavar='TOPIC',
                     help='with --plant: the joint angle, sensor_msgs/JointState position of '
                          f"the plant's joint.name (default: `{JOINT_STATES_TOPIC}`)")
    fit.add_argument('--external-torque-topic', metavar='TOPIC',
                     help='with --plant: the external torque [N m], Float64 (default: '
                          f'`{EXTERNAL_TORQUE_TOPIC}`, 0 if the bag has none)')
    fit.add_argument('--jobs', type=_jobs, metavar='N',
                     help='with --plant: run the n + 1 limb simulations of each evaluation '
                          'in N processes (default 1; more than the free CPUs does not help)')
    fit.add_argument('--edge-search', type=_edge_search, metavar='S',
                     help='single muscle, for live bags: move each change of the stimulation '
                          'by whole steps within +-S seconds of its stamp to where it best '
                          'explains the force, fitting again until the moves settle (a plain '
                          'stimulation topic reaches the simulator some ms off the '
                          "recorder's stamp; e.g. 0.03). Default: the stamps as they are")
    fit.add_argument('--length-topic', metavar='TOPIC',
                     help='MTU length change [m], Float64 or PointStamped knots (default: '
                          f'`{LENGTH_TOPICS[0]}`, else `{LENGTH_TOPICS[1]}`)')
    fit.add_argument('--force-topic', metavar='TOPIC',
                     help='measured force [N], Float64 or WrenchStamped force.x (default: '
                          f'`{FORCE_TOPICS[0]}`, else `{FORCE_TOPICS[1]}`)')


#: [s] Largest --edge-search: a second is far beyond any delivery delay, and the
#: search costs one replay per step of the window and change.
MAX_EDGE_SEARCH_S = 1.0


#: argparse type for ``--edge-search``: seconds in [0, MAX_EDGE_SEARCH_S].
_edge_search = bounded_number(float, low=0.0, high=MAX_EDGE_SEARCH_S, unit='s',
                              noun='a number of seconds')


#: Most --jobs: an evaluation runs n + 1 simulations, and a fit of more than a
#: few dozen parameters is not what this is for.
MAX_JOBS = 64


#: argparse type for ``--jobs``: an integer in [1, MAX_JOBS].
_jobs = bounded_number(int, low=1, high=MAX_JOBS)


#: Options of ``fit`` for one kind of plant only: (attribute, flag).
MUSCLE_FIT_OPTIONS = (('params', '--params'), ('length_topic', '--length-topic'),
                      ('force_topic', '--force-topic'), ('edge_search', '--edge-search'))
LIMB_FIT_OPTIONS = (('joint_states_topic', '--joint-states-topic'),
                    ('external_torque_topic', '--external-torque-topic'), ('jobs', '--jobs'))


def cmd_fit(args: argparse.Namespace) -> int:
    """Run ``hill-muscle fit``; user errors raise
    :class:`~hill_muscle_ros.tools.common.UserError`."""
    from .. import resources
    from ..params_file import load_muscle_params
    if args.plant is not None:
        given = [flag for attr, flag in MUSCLE_FIT_OPTIONS if getattr(args, attr) is not None]
        if given:
            raise UserError(f'{given[0]} applies to the single muscle, not to a limb '
                            '(--plant): the plant file gives every start value')
        return _cmd_fit_limb(args)
    given = [flag for attr, flag in LIMB_FIT_OPTIONS if getattr(args, attr) is not None]
    if given:
        raise UserError(f'{given[0]} applies to a limb: give --plant PLANT.yaml')
    params_path = args.params if args.params is not None else resources.default_params_file()
    try:
        start, node_settings = load_muscle_params(params_path)
        parameters = parse_fit_names(args.fit_names, start)
        edge_search_s = args.edge_search or 0.0
        recording = load_muscle_recording(
            args.bag, pulse_width_topic=args.pulse_width_topic,
            recruitment_topic=args.recruitment_topic, length_topic=args.length_topic,
            force_topic=args.force_topic, lead_s=edge_search_s)
        runs = (edge_search_runs(recording, len(parameters),
                                 round(edge_search_s * recording.rate_hz))
                if edge_search_s > 0.0 else replay_runs(len(parameters)))
        compiled = MuscleReplay(recording, runs).compiled(not start.fes_defaults)
        print(f'fitting {", ".join(p.name for p in parameters)} to '
              f'{recording.topics["force"]} ({len(recording.force_n)} samples at '
              f'{recording.rate_hz:g} Hz); each evaluation runs {len(parameters) + 1} '
              f'simulations, {"compiled" if compiled else "in Python"}', file=sys.stderr)
        progress = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
        shifts = None
        if edge_search_s > 0.0:
            result, recording, shifts = fit_with_aligned_edges(
                recording, start, parameters, round(edge_search_s * recording.rate_hz),
                progress)
        else:
            result = fit_parameters(MuscleReplay(recording, runs), recording.force_n, start,
                                    parameters, progress=progress)
    except ValueError as err:   # FitError, and the params file's own errors
        raise UserError(str(err)) from None
    report = format_report(result, recording, str(params_path), shifts, edge_search_s)
    return _write_outputs(args, params_file_text(result, node_settings, str(args.bag)), report,
                          lambda: report_data(result, recording), REPORT_PNG,
                          lambda path: plot_fit(path, result, recording))


def _cmd_fit_limb(args: argparse.Namespace) -> int:
    """``hill-muscle fit --plant``: the limb's parameters from its joint angle."""
    from ..params_file import load_plant
    try:
        start, _ = load_plant(args.plant)
        start_text = args.plant.read_text(encoding='utf-8')
        parameters = parse_plant_fit_names(args.fit_names, start)
        recording = load_limb_recording(
            args.bag, start, joint_states_topic=args.joint_states_topic,
            pulse_width_topic=args.pulse_width_topic,
            recruitment_topic=args.recruitment_topic,
            external_torque_topic=args.external_torque_topic)
        print(f'fitting {", ".join(p.name for p in parameters)} to the angle of '
              f'`{recording.joint}` on {recording.topics["joint_states"]} '
              f'({len(recording.angle_rad)} samples at {recording.rate_hz:g} Hz); each '
              f'evaluation runs {len(parameters) + 1} limb simulations', file=sys.stderr)
        with LimbReplay(recording, jobs=args.jobs or 1) as replay:
            result = fit_parameters(
                replay, recording.angle_rad, start, parameters,
                progress=lambda line: print(line, file=sys.stderr, flush=True),
                quantity='joint angle', unit='rad')
    except (OSError, UnicodeDecodeError) as err:
        raise UserError(f'{args.plant}: cannot read the plant file: {err}') from None
    except ValueError as err:   # FitError, and the plant file's own errors
        raise UserError(str(err)) from None
    report = format_limb_report(result, recording, str(args.plant))
    text = plant_file_text(start_text, result, str(args.bag))
    if text is None or _plant_of(text) != result.params:
        raise UserError(f'{args.plant}: cannot write the fitted values into this file\'s '
                        'layout (block-style `ros__parameters` with the muscles\' and the '
                        'joint\'s sections needed)')
    return _write_outputs(args, text, report, lambda: limb_report_data(result, recording),
                          REPORT_ANGLE_PNG, lambda path: plot_limb_fit(path, result, recording))


def _write_outputs(args: argparse.Namespace, out_text: str, report: str,
                   data: Callable[[], dict[str, Any]], png: str,
                   plot: Callable[[Path], None]) -> int:
    """Write ``--out`` and, with ``--report``, the report's Markdown, YAML and plot
    (file name ``png``); print the report and what was written.

    :param data: the report's YAML data (made only with ``--report``)
    :param plot: draws the plot into the path it is given
    """
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(out_text, encoding='utf-8')
        if args.report is not None:
            args.report.mkdir(parents=True, exist_ok=True)
            (args.report / REPORT_MARKDOWN).write_text(report + '\n', encoding='utf-8')
            (args.report / REPORT_YAML).write_text(
                yaml.safe_dump(data(), sort_keys=False), encoding='utf-8')
            plot(args.report / png)
    except OSError as err:
        raise UserError(f'{err.filename}: cannot write: {err.strerror or err}') from None
    print(report)
    print(f'wrote {args.out}')
    if args.report is not None:
        print(f'wrote {args.report / REPORT_MARKDOWN}, {args.report / REPORT_YAML}, '
              f'{args.report / png}')
    return 0


def _plant_of(text: str) -> LimbPlant | None:
    """The plant a plant file's text gives, as the limb CLI loads it (``None`` if it
    does not load): the written file is checked against the fitted plant."""
    import tempfile
    from ..params_file import load_plant
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'plant.yaml'
        path.write_text(text, encoding='utf-8')
        try:
            return load_plant(path)[0]
        except ValueError:
            return None
