"""The flat state of one limb, as the kernels of :mod:`.kernels` take it.

:class:`LimbArrays` builds a limb's arrays from its plant and sets them to
rest, calls the kernels' one entry point (:func:`.kernels.limb_entry`) on
them, and turns a failed call's status into the error the limb raises.
Whichever build of the kernels runs (compiled or plain Python,
:func:`~hill_muscle_ros.model.engine.kernels`), it works on these arrays.
"""
from __future__ import annotations

import numpy as np

from ..muscle import state as muscle_state
from ..muscle.state import DELAY_FULL, S_DL, S_L, FesBundle, ScratchPool
from ..muscle import DL_MT_LIMIT_M
from ..params import PULSED_MODEL
from .kernels import (DL_OUT_OF_RANGE, L_COM, L_DAMPING, L_EQUILIBRIUM, L_GRAVITY,
                      L_INERTIA, L_MASS, L_MUSCLES, L_OMEGA, L_PER_MUSCLE, L_STIFFNESS, L_T,
                      L_TAU, L_THETA, M_ARM, M_REF, M_SIGN, N_W, dl_mt, muscle_slot)
from .plant import MUSCLE_COLUMNS, LimbPlant, stretch_message

#: [-] entries of an outputs row before the muscles' (t, theta, omega), each
#: muscle then :data:`~.plant.MUSCLE_COLUMNS`' (limb_record writes them).
ROW_JOINT = 3


def row_length(n_muscles: int, n_activations: int = 0) -> int:
    """[-] entries of an outputs row of a limb of ``n_muscles`` muscles whose
    pulsed muscles have ``n_activations`` channels in all
    (:func:`activation_count`): their a_c close the row."""
    return ROW_JOINT + len(MUSCLE_COLUMNS) * n_muscles + n_activations


def activation_count(plant: LimbPlant) -> int:
    """[-] the channels of the plant's pulsed (``ding2003``) muscles, in all."""
    return sum(m.params.n_channels for m in plant.muscles
               if m.params.activation_model == PULSED_MODEL)


def no_pulses() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pulse arrays of a run without pulses: (instants, (2, 0) muscle and
    channel, commands)."""
    return np.zeros(0), np.zeros((2, 0), dtype=np.int64), np.zeros(0)


def pulse_arrays(pulses) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernels' pulse arrays from ``(instant [s], muscle, 0-based channel, u)``
    rows in time order."""
    if not pulses:
        return no_pulses()
    pt = np.array([p[0] for p in pulses], dtype=float)
    pi = np.ascontiguousarray(np.array([[p[1] for p in pulses], [p[2] for p in pulses]],
                                       dtype=np.int64))
    pu = np.array([p[3] for p in pulses], dtype=float)
    return pt, pi, pu


class LimbArrays:
    """The flat state of a limb: its muscles'
    :class:`~hill_muscle_ros.model.muscle.state.FesBundle`, the joint array ``L``,
    the stage scratch ``W`` and the timeline ``TT``/``TI``; new, the limb is at
    rest (:meth:`reset`).

    :param plant: the joint and its muscles
    :param dt_s: [s] the step the delay lines are sized for
    :param pool: where a run's arrays come from and go back to (:meth:`give_back`),
        or None for arrays of their own
    """

    def __init__(self, plant: LimbPlant, dt_s: float, pool: ScratchPool | None = None) -> None:
        self.plant = plant
        self.nm = nm = len(plant.muscles)
        self.n_activations = activation_count(plant)
        self._pool = pool
        #: The pulses the next call of the kernels takes (:func:`pulse_arrays`).
        self.pulses = no_pulses()
        self.bundle = FesBundle([m.params for m in plant.muscles], dt_s, pool)
        self.L = np.zeros(L_MUSCLES + L_PER_MUSCLE * max(nm, 1))
        j = plant.joint
        self.L[[L_INERTIA, L_MASS, L_GRAVITY, L_COM, L_STIFFNESS, L_EQUILIBRIUM,
                L_DAMPING]] = (j.inertia_kg_m2, j.mass_kg, j.gravity_m_per_s2,
                               j.com_distance_m, j.stiffness_n_m_per_rad, j.equilibrium_rad,
                               j.damping_n_m_s_per_rad)
        for i, m in enumerate(plant.muscles):
            slot = muscle_slot(i)
            self.L[slot + M_SIGN] = m.sign
            self.L[slot + M_ARM] = m.moment_arm_m
            self.L[slot + M_REF] = m.reference_angle_rad
        self.W = np.zeros((N_W, max(nm, 1)))
        self._size_timeline()
        self.L[L_THETA] = plant.joint.initial_angle_rad
        self._place_ces()   # the new bundle is at rest already

    def _size_timeline(self) -> None:
        total = sum(int(self.bundle.I[i * muscle_state.N_HDR + muscle_state.H_CAPEV])
                    for i in range(self.nm))
        # limb_step writes a step's timeline (entries 0 .. n_events - 1) before
        # it reads it: a handed-back one needs no zeros.
        empty = np.zeros if self._pool is None else self._pool.empty
        self.TT = empty((max(total, 1),))
        self.TI = empty((2, max(total, 1)), dtype=np.int64)

    def give_back(self) -> None:
        """Hand the run's large arrays back to the pool; these arrays are not
        used after this."""
        if self._pool is not None:
            self._pool.give_back(self.bundle.F, self.bundle.I, self.TT, self.TI)

    def reset(self) -> None:
        """theta = theta_0, omega = 0, t = 0, each CE at l_rest + dl_MT(theta_0),
        nothing recruited, no command given."""
        self.L[L_THETA] = self.plant.joint.initial_angle_rad
        self.L[L_OMEGA] = self.L[L_T] = self.L[L_TAU] = 0.0
        for i in range(self.nm):
            self.bundle.reset(i)
        self._place_ces()

    def _place_ces(self) -> None:
        """Each CE at l_rest + dl_MT(theta)."""
        for i, m in enumerate(self.plant.muscles):
            fs = self.bundle.view(i, 'fs')
            fs[S_DL] = dl = dl_mt(self.L, i, self.L[L_THETA])
            fs[S_L] = m.params.l_rest_m + dl

    def ensure_delay(self, dt_s: float) -> None:
        """Room in the delay lines and the timeline for steps of ``dt_s`` [s]."""
        cap = self.bundle.cap
        self.bundle.ensure_delay(dt_s)
        if self.bundle.cap != cap:
            self._size_timeline()

    def entry(self, kernels, mode: int, u: np.ndarray, tau: np.ndarray, dt_s: float,
              n_steps: int, target_rad: float, acc: np.ndarray, rows: np.ndarray) -> int:
        """:func:`.kernels.limb_entry` of ``kernels`` on these arrays (its parameters).

        :param kernels: the kernels' build that runs (:func:`.engine.kernels`)
        :param mode: what to do, one of :data:`.kernels.MODE_RUN` ... ``MODE_RECORD``
        :return: the kernel's status
        """
        b = self.bundle
        pt, pi, pu = self.pulses
        return kernels.limb_entry(b.F, b.I, self.L, self.W, self.TT, self.TI, self.nm, mode,
                                  u, tau, dt_s, DL_MT_LIMIT_M, n_steps, target_rad, acc, rows,
                                  pt, pi, pu)

    def error(self, status: int) -> Exception:
        """The error of a kernel's failed ``status``: the ValueError naming the
        muscle stretched beyond ±:data:`~hill_muscle_ros.model.muscle.DL_MT_LIMIT_M`
        now, or a RuntimeError for a delay line that overflowed (its capacity
        bounds the commands pending: never for valid parameters)."""
        if status == DELAY_FULL:
            return RuntimeError('a muscle\'s delay line overflowed')
        i = status - DL_OUT_OF_RANGE
        theta = float(self.L[L_THETA])
        return ValueError(stretch_message(self.plant.muscles[i].name,
                                          dl_mt(self.L, i, theta), theta))


#: The arrays of the offline runs (:func:`~.simulate.run_rows`), each thread
#: its own: one run's, reused by the next of the same layout.
SCRATCH = ScratchPool()
