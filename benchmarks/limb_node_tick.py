"""The limb node's work per step: one ``Limb.step`` on either build of the kernels.

The limb node (``hill_muscle_ros/nodes/limb.py``) steps its limb once per model
step inside its timer callback. This times that call, one step at a time as
the node makes it, on the knee preset (``config/knee.yaml``, 1 kHz) for
:class:`~hill_muscle_ros.model.limb.Limb` on the plain Python functions of its
kernels and on their numba build: a held 0.3
quadriceps command for :data:`STEPS_EACH` steps, then 0 (the release) for as
many; and the compiled limb's loading in this process. Not part of ``make
bench``; its printed numbers are quoted in the node's docstring.

Run: ``.venv/bin/python benchmarks/limb_node_tick.py``
"""
from __future__ import annotations

import time

import numpy as np

from hill_muscle_ros.model import engine
from hill_muscle_ros.model.limb import Limb
from hill_muscle_ros.params_file import load_plant
from hill_muscle_ros.resources import config_dir

#: [-] steps with the quadriceps stimulated, then as many released
STEPS_EACH = 1000
#: [-] the quadriceps' command while stimulated (the hamstrings' stays 0)
COMMAND = 0.3
#: [s] the node's default step (rate_hz 1000)
DT_S = 1e-3
#: [us/s]
US_PER_S = 1e6


def time_steps(limb) -> np.ndarray:
    """[us] the wall time of each step."""
    per = []
    for k in range(2 * STEPS_EACH):
        u = [COMMAND, 0.0] if k < STEPS_EACH else [0.0, 0.0]
        t0 = time.perf_counter()
        limb.step(u, 0.0, DT_S)
        per.append(time.perf_counter() - t0)
    return np.array(per) * US_PER_S


def main() -> None:
    plant = load_plant(config_dir() / 'knee.yaml')[0]
    t0 = time.perf_counter()
    compiled = Limb(plant, build=engine.COMPILED)
    load_s = time.perf_counter() - t0
    for name, limb in (('python', Limb(plant, build=engine.PYTHON)), ('compiled', compiled)):
        a = time_steps(limb)
        print(f'{name}: per step median {np.median(a):.1f} us, mean {a.mean():.1f} us, '
              f'p99 {np.percentile(a, 99):.1f} us, max {a.max():.0f} us; mean stimulated '
              f'{a[:STEPS_EACH].mean():.1f} us, released {a[STEPS_EACH:].mean():.1f} us')
    print(f'loading the compiled limb in this process: {load_s:.2f} s')


if __name__ == '__main__':
    main()
