"""The integration step of every engine: at most :data:`MAX_SUBSTEP_S`, whatever the output rate.

The rate a user asks for (``simulate --rate``, a node's ``rate_hz``) sets how
often results are reported and inputs sampled; it is not the integrator's
step. An output step of dt is integrated as n = ceil(dt / :data:`MAX_SUBSTEP_S`)
equal substeps of dt / n, with the inputs of the output step held over all of
them (the recruitment command, the pulse width, the external torque) and the
MTU length ramping linearly across the whole output step, as it does within
one step. So any output rate gives the same force at the same instants, to the
accuracy of the 1 ms step; at 1 kHz and above n = 1 and nothing changes.

The engines take their substeps in their own loops: a run over a whole
protocol is handed the substeps' inputs (:func:`substep_inputs`) and its
outputs read at the output instants (:func:`output_rows`); a single step
(the nodes' tick) runs n substeps of its engine (:func:`substeps_for`,
:func:`length_ramp`).
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

#: [s] Longest step any engine integrates at once. 1 ms is the paper's 1 kHz,
#: the step at which the references are checked: the RK4 step of the paper's
#: muscle stays within 0.01 N of a ``solve_ivp`` reference at rtol 1e-10 there
#: (muscle.py). A longer step is inaccurate before it is unstable: RK4 is
#: stable on the real axis up to h lambda = 2.785, lambda the CE's relaxation
#: rate k_SE d FV_inv / d f_SE, at most k_SE b (a + F0) / a^2 shortening and
#: k_SE 2 b' (F0 + a') / a'^2 at the eccentric plateau's edge: 330 /s for the
#: paper's muscle (F0 = 45 N, k_SE = 10 kN/m), a stability limit of 8.4 ms,
#: yet Protocol II's force at 1 s is 9.58 N at a 100 ms step instead of 18.6 N.
#: A stiffer tendon needs less than 1 ms: the FES muscle and the limb cut each
#: substep further by their own relaxation rates (equations.RK4_MAX_H_LAMBDA).
MAX_SUBSTEP_S = 1.0e-3


def substeps_for(dt_s: float) -> int:
    """[-] substeps of an output step ``dt_s``: n = ceil(dt / :data:`MAX_SUBSTEP_S`), at least 1.

    :param dt_s: [s] output step (dt), positive and finite
    :return: [-] n; 1 for any dt <= 1 ms (rates of 1 kHz and above)
    """
    return max(1, math.ceil(dt_s / MAX_SUBSTEP_S))


def length_ramp(dl_start_m: float, dl_end_m: float, n: int) -> list[float]:
    """[m] dl_MT at the end of each of ``n`` substeps of a linear ramp.

    The last is ``dl_end_m`` itself, so the output step ends exactly where it
    would unsplit.

    :param dl_start_m: [m] dl_MT at the start of the output step
    :param dl_end_m: [m] dl_MT at its end
    :param n: [-] substeps, >= 1
    """
    change = dl_end_m - dl_start_m
    return [dl_start_m + change * (j / n) for j in range(1, n)] + [dl_end_m]


def substep_inputs(r: np.ndarray, dl_mt_m: np.ndarray,
                   n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The inputs of a run's substeps from its samples, in the engines' ``run`` form.

    Sample k's command holds over the n substeps of output step k; the next
    sample's command is given at the end of its last substep only (as
    ``r_end`` of an unsplit run); dl_MT ramps linearly from sample k to
    sample k + 1. With n = 1 these are ``r[:-1]``, ``dl_mt_m[1:]``, ``r[1:]``.

    :param r: [-] (S,) command (recruitment) at each sample
    :param dl_mt_m: [m] (S,) dl_MT at each sample
    :param n: [-] substeps per output step, >= 1
    :return: ([-] command at each substep's start, [m] dl_MT at its end, [-]
        command given at its end), each of (S - 1) n entries
    """
    r = np.asarray(r, dtype=float)
    dl = np.asarray(dl_mt_m, dtype=float)
    if n == 1:
        return r[:-1], dl[1:], r[1:]
    r_start = np.repeat(r[:-1], n)
    r_end = r_start.copy()
    r_end[n - 1::n] = r[1:]
    fraction = np.arange(1, n + 1) / n
    dl_end = (dl[:-1, None] + (dl[1:] - dl[:-1])[:, None] * fraction).ravel()
    dl_end[n - 1::n] = dl[1:]   # each output step ends exactly at its sample
    return r_start, dl_end, r_end


def output_rows(n: int, steps: int) -> slice:
    """The substeps whose ends are output instants: every n-th, the last of each step.

    :param n: [-] substeps per output step
    :param steps: [-] output steps
    :return: a slice of the substeps' outputs, ``steps`` long
    """
    return slice(n - 1, n * steps, n)


def repeat_rows(values: Sequence, n: int) -> np.ndarray:
    """Sample-held inputs (commands, torques) on the substeps' grid: each row of
    ``values`` but the last n times, then the last once.

    :param values: (S, ...) inputs at the samples
    :param n: [-] substeps per output step
    :return: ((S - 1) n + 1, ...) inputs at the substeps' starts, and the last sample
    """
    values = np.asarray(values, dtype=float)
    return np.concatenate([np.repeat(values[:-1], n, axis=0), values[-1:]])
