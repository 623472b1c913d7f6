"""``hill-muscle fit``: estimate muscle parameters from a recorded bag by least squares.

The recorded inputs (stimulation and MTU length) are replayed through the
model from rest, on the time grid of the recorded force, and the named
:class:`~hill_muscle_ros.model.params.MuscleParams` fields are moved by
:func:`scipy.optimize.least_squares` until the simulated force matches the
recorded one. The rest of the parameters stay as the start file gives them.

The pieces are kept apart, a module each, so that the limb is fitted the same
way: :mod:`.parameters` names what is fitted (:class:`FitParameter`);
:mod:`.recording` turns a bag into arrays (:func:`load_muscle_recording`);
:mod:`.replay` predicts the force of several parameter sets at once
(:class:`MuscleReplay`: its ``predict`` is all :func:`fit_parameters` asks of
a model); :mod:`.estimate` runs the optimiser, checks identifiability and
computes the standard errors (:func:`fit_parameters`); :mod:`.report` writes
the parameters file and the report; :mod:`.command` is the CLI glue
(:func:`cmd_fit`).

The limb (``--plant``): :func:`load_limb_recording` reads ``joint_states``
(the plant's joint by name) and each muscle's stimulation onto the joint
states' grid, :class:`LimbReplay` runs them through
:func:`~hill_muscle_ros.model.limb.simulate_limb` from the plant's initial
state, and :class:`PlantParameter` names what is fitted as the plant file
does (``joint.damping_n_m_s_per_rad``, ``quadriceps.f_iso_max_n``);
:func:`plant_file_text` writes the fitted values into the start plant file.

Live bags (``--edge-search``, :mod:`.edges`): the stimulation's stamps are the
recorder's receive times, some steps off the step the simulator acted on;
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
residual and the Jacobian together (``jac=``). The runs use
:class:`~hill_muscle_ros.model.muscle.Muscle`, as ``simulate`` does: muscles
with and without FES extensions run the same engine, compiled where numba is
(:meth:`MuscleReplay.compiled`). A limb run is far
dearer (the joint and every CE integrated together on sub-steps): a limb fit
takes the compiled limb once an evaluation's runs repay loading it
(BENCHMARKS.md, section 8).
"""
from .command import add_fit_parser, cmd_fit
from .edges import align_stimulation_edges, edge_search_runs, fit_with_aligned_edges
from .estimate import FitResult, ForceModel, check_identifiable, fit_parameters
from .parameters import (FitError, FitParameter, NotIdentifiableError, PlantParameter,
                         parse_fit_names, parse_plant_fit_names)
from .recording import (LimbRecording, MuscleRecording, load_limb_recording,
                        load_muscle_recording)
from .replay import LimbReplay, MuscleReplay, replay_runs
from .report import (REPORT_ANGLE_PNG, REPORT_MARKDOWN, REPORT_PNG, REPORT_YAML,
                     format_limb_report, format_report, params_file_text, plant_file_text)

__all__ = [
    'REPORT_ANGLE_PNG', 'REPORT_MARKDOWN', 'REPORT_PNG', 'REPORT_YAML', 'FitError',
    'FitParameter', 'FitResult', 'ForceModel', 'LimbRecording', 'LimbReplay',
    'MuscleRecording', 'MuscleReplay', 'NotIdentifiableError', 'PlantParameter',
    'add_fit_parser', 'align_stimulation_edges', 'check_identifiable', 'cmd_fit',
    'edge_search_runs', 'fit_parameters', 'fit_with_aligned_edges', 'format_limb_report',
    'format_report', 'load_limb_recording', 'load_muscle_recording', 'params_file_text',
    'parse_fit_names', 'parse_plant_fit_names', 'plant_file_text', 'replay_runs',
]
