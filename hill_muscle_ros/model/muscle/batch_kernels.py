"""The FES muscles of a :class:`~hill_muscle_ros.model.batch.MuscleBatch`, stepped compiled.

A batch on the compiled engine keeps its muscles with FES features on in one
:class:`~hill_muscle_ros.model.muscle.state.FesBundle` (muscle j of the bundle
is batch muscle ``index[j]``) and steps them all in one call of
:func:`step_all`, each exactly as the NumPy engine's
:class:`~hill_muscle_ros.model.muscle.Muscle` does it: the command
given now (``set_recruitment``), then ``step`` (which gives it again at the
same instant: no change) and the outputs. :func:`give_all` is
``set_recruitment`` alone, with the state the batch copies afterwards, and
:func:`outputs_all` the outputs now.

A muscle whose delay line is full is left unchanged and marked not done;
the caller grows the delay lines and calls again for those muscles
(:meth:`FesBundle.ensure_delay
<hill_muscle_ros.model.muscle.state.FesBundle.ensure_delay>`).
"""
from __future__ import annotations

import sys
import types

import numpy as np

from .. import equations, memory, stimulus, units
from . import kernels, pool, state
from .kernels import give_command, muscle_advance, muscle_outputs
from .pool import pool_mean_fitness
from .state import H_FS, H_IP, H_JS, I_MULTI, J_NREC, OK, S_CMD, S_DL, S_L, S_MU, S_R, S_T, hdr

#: Columns of a muscle's row of :data:`.state.N_OUT` entries in
#: MuscleOutputs' order (as the kernels' outputs): those ``MuscleBatch``
#: copies from the state, which :func:`give_all` fills.
(ROW_RECRUITMENT, ROW_N_RECRUITED, ROW_DL_MT, ROW_L_CE, ROW_V_CE, ROW_EFF_F_ISO,
 ROW_COMMAND, ROW_MEAN_FITNESS) = 1, 2, 3, 4, 5, 9, 10, 11


def read_state(F, I, j, row):
    """Muscle ``j``'s state as Muscle's attributes give it, into ``row``
    (the ROW_* columns): what MuscleBatch copies after a command."""
    fs, js, ip = hdr(I, j, H_FS), hdr(I, j, H_JS), hdr(I, j, H_IP)
    row[ROW_RECRUITMENT] = F[fs + S_R]
    row[ROW_N_RECRUITED] = I[js + J_NREC]
    row[ROW_DL_MT] = F[fs + S_DL]
    row[ROW_L_CE] = F[fs + S_L]
    row[ROW_COMMAND] = F[fs + S_CMD]
    row[ROW_MEAN_FITNESS] = (pool_mean_fitness(F, I, j, F[fs + S_T]) if I[ip + I_MULTI]
                             else F[fs + S_MU])


def give_all(F, I, r, index, done, state):
    """Give each muscle j not ``done`` the command ``r[index[j]]`` now
    (Muscle.set_recruitment), then its state into ``state[j]``; ``done[j]``
    becomes True, or stays False if its delay line is full (nothing changed)."""
    for j in range(index.shape[0]):
        if done[j]:
            continue
        if give_command(F, I, j, r[index[j]]):
            read_state(F, I, j, state[j])
            done[j] = True


def step_all(F, I, r, dl1, dt, index, done, out):
    """One step of each muscle j not ``done``, as the NumPy engine takes it:
    command ``r[index[j]]`` given now, then Muscle.step(r, dl1[index[j]], dt)
    and its outputs into ``out[j]``; ``done[j]`` as in :func:`give_all`."""
    for j in range(index.shape[0]):
        if done[j]:
            continue
        b = index[j]
        # A full delay line refuses the first command, changing nothing; the
        # step gives the same command at the same instant again, which never
        # queues a second one.
        if give_command(F, I, j, r[b]) and muscle_advance(F, I, j, r[b], dl1[b], dt) == OK:
            muscle_outputs(F, I, j, out[j])
            done[j] = True


def outputs_all(F, I, out):
    """Every muscle's outputs now (Muscle.outputs) into ``out[j]``."""
    for j in range(out.shape[0]):
        muscle_outputs(F, I, j, out[j])


#: What :func:`batch_entry` does: :func:`give_all`, :func:`step_all`, :func:`outputs_all`.
MODE_GIVE, MODE_STEP, MODE_OUTPUTS = range(3)


def batch_entry(F, I, mode, r, dl1, dt, index, done, out):
    """The compiled batch's one entry point: ``mode`` (MODE_*) chooses the function,
    which takes the arguments it names (``out`` is give_all's ``state``).

    One entry rather than one per function, because numba links the whole FES
    muscle into every compiled function that calls it and optimises it again
    there: each entry point more cost seconds of a cold compile.
    """
    if mode == MODE_GIVE:
        give_all(F, I, r, index, done, out)
    elif mode == MODE_STEP:
        step_all(F, I, r, dl1, dt, index, done, out)
    else:
        outputs_all(F, I, out)


# -- compiling ------------------------------------------------------------------------------

_KERNELS = ('read_state', 'give_all', 'step_all', 'outputs_all', 'batch_entry')
#: The modules whose code the kernels inline: their digest names the cache entries.
_DIGEST_OF = (equations, stimulus, memory, units, state, pool, kernels)
#: The functions of :mod:`.kernels` called here, bound to their compiled versions.
_CALLED = ('give_command', 'hdr', 'muscle_advance', 'muscle_outputs', 'pool_mean_fitness')
_compiled = None


def compiled() -> types.SimpleNamespace:
    """The numba-compiled :func:`batch_entry`, calling :func:`.kernels.compiled`'s
    muscle, and ``give_all``, ``step_all`` and ``outputs_all`` with their own
    arguments, each one call of it.

    :raises ImportError: if numba cannot be imported
    """
    global _compiled
    if _compiled is not None:
        return _compiled
    from .. import engine
    scope = kernels.scope_calling(globals(), _CALLED)
    # Everything but the entry is compiled into it by numba's own inlining: no
    # compiled function of its own holding the muscle's code again.
    leaf = {'error_model': 'numpy', 'inline': 'always'}
    options = {name: leaf for name in _KERNELS}
    options['batch_entry'] = {'error_model': 'numpy'}

    def signature(numba):
        f8, i8, b1 = numba.float64, numba.int64, numba.boolean
        c1, i1 = f8[::1], i8[::1]
        return numba.void(c1, i1, i8, c1, c1, f8, i1, b1[::1], f8[:, ::1])

    built = engine.compile_functions(
        scope, _KERNELS, digest_of=_DIGEST_OF + (sys.modules[__name__],),
        signatures={'batch_entry': signature}, options=options)
    entry = built.batch_entry
    # outputs_all's stand-ins for the arguments it does not take.
    no_r, no_index, no_done = np.zeros(0), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)

    # The functions with their own arguments, for MuscleBatch.
    def give_all_(F, I, r, index, done, state):
        entry(F, I, MODE_GIVE, r, r, 0.0, index, done, state)

    def step_all_(F, I, r, dl1, dt, index, done, out):
        entry(F, I, MODE_STEP, r, dl1, dt, index, done, out)

    def outputs_all_(F, I, out):
        entry(F, I, MODE_OUTPUTS, no_r, no_r, 0.0, no_index, no_done, out)

    _compiled = types.SimpleNamespace(numba=built.numba, batch_entry=entry,
                                      give_all=give_all_, step_all=step_all_,
                                      outputs_all=outputs_all_)
    return _compiled
