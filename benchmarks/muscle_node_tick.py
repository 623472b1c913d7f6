"""The simulator node's work per step: ``Muscle.step`` on the plain and the compiled build.

The simulator node (``hill_muscle_ros/nodes/simulator.py``) steps its muscle
once per model step inside its timer callback. This times that call, one step
at a time as the node makes it, on the knee quadriceps preset
(``config/fes_quadriceps.yaml``, 1 kHz) for the one
:class:`~hill_muscle_ros.model.muscle.Muscle` on each build of its kernels:
the very same functions as plain Python (``build='python'``, where numba is
missing) and compiled by numba (``build='compiled'``, what the node loads):
pulse widths stepping up through the recruitment curve for
:data:`STEPS_EACH` steps, then 0 (the release) for as many; and the compiled
muscle's loading in this process. Not part of ``make bench``; its printed
numbers are quoted in the node's docstring.

Run: ``.venv/bin/python benchmarks/muscle_node_tick.py``
"""
from __future__ import annotations

import time

import numpy as np

from hill_muscle_ros.model import Muscle, engine
from hill_muscle_ros.model.stimulus import command_from_pulse_width
from hill_muscle_ros.params_file import load_muscle_params
from hill_muscle_ros.resources import config_dir

#: [-] steps stimulated, then as many released
STEPS_EACH = 1000
#: [-] the pulse width as a fraction of pw_max_s over the stimulated steps:
#: four levels of STEPS_EACH / 4 steps each
PW_FRACTIONS = (0.25, 0.5, 0.75, 1.0)
#: [s] the node's default step (rate_hz 1000)
DT_S = 1e-3
#: [us/s]
US_PER_S = 1e6


def commands(params) -> list[float]:
    """[-] the command of each step: the pulse widths through the curve, then 0."""
    per_level = STEPS_EACH // len(PW_FRACTIONS)
    stim = [command_from_pulse_width(f * params.pw_max_s, params)
            for f in PW_FRACTIONS for _ in range(per_level)]
    return stim + [0.0] * STEPS_EACH


def time_steps(muscle, u: list[float]) -> np.ndarray:
    """[us] the wall time of each step."""
    per = []
    for r in u:
        t0 = time.perf_counter()
        muscle.step(r, 0.0, DT_S)
        per.append(time.perf_counter() - t0)
    return np.array(per) * US_PER_S


def main() -> None:
    params = load_muscle_params(config_dir() / 'fes_quadriceps.yaml')[0]
    u = commands(params)
    t0 = time.perf_counter()
    compiled = Muscle(params, build=engine.COMPILED)
    load_s = time.perf_counter() - t0
    for muscle in (Muscle(params, build=engine.PYTHON), compiled):
        a = time_steps(muscle, u)
        print(f'{muscle.build} (Muscle, build={muscle.build!r}): per step median '
              f'{np.median(a):.1f} us, mean {a.mean():.1f} us, p99 '
              f'{np.percentile(a, 99):.1f} us, max {a.max():.0f} us; mean stimulated '
              f'{a[:STEPS_EACH].mean():.1f} us, released {a[STEPS_EACH:].mean():.1f} us')
    print(f'loading the compiled muscle in this process: {load_s:.2f} s')


if __name__ == '__main__':
    main()
