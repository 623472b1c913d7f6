"""The peers of the benchmark, driven with Protocol II's inputs at a 1 ms step.

Each ``*_runner`` returns a function that replays the whole input sequence
once from a fresh state and returns the last force, so the driver can time
it like the package's own runs. Both peers are bench-only dependencies
(requirements-bench.txt); an ImportError is reported, never faked.
"""
from __future__ import annotations

from typing import Callable, Sequence

#: [N] maximal isometric force given to the peers, the paper's f_iso_max.
F_MAX_N = 45.0
#: [m] MTU length at rest used for MuJoCo's joint transmission; the muscle's
#: length range is placed around it so that force-length is near its plateau.
MUJOCO_REST_LENGTH_M = 0.15

MJCF = f"""
<mujoco model="hill_muscle_bench">
  <option timestep="0.001" gravity="0 0 0"/>
  <worldbody>
    <body name="insertion">
      <joint name="mtu" type="slide" axis="1 0 0" limited="false"/>
      <geom type="sphere" size="0.01" mass="0.1"/>
    </body>
  </worldbody>
  <actuator>
    <muscle name="muscle" joint="mtu" force="{F_MAX_N}" lengthrange="0.1 0.2"
            range="0.75 1.05"/>
  </actuator>
</mujoco>
"""


def mujoco_runner(recruitment: Sequence[float], dl_mt_m: Sequence[float],
                  dt_s: float) -> Callable[[], float]:
    """MuJoCo's muscle actuator with the MTU length driven kinematically.

    Every step sets the slide joint's position and velocity from the
    protocol, the control to R, and calls ``mj_step`` at ``dt_s``.
    """
    import mujoco

    model = mujoco.MjModel.from_xml_string(MJCF)
    model.opt.timestep = dt_s
    data = mujoco.MjData(model)
    n = len(dl_mt_m)

    def run() -> float:
        mujoco.mj_resetData(model, data)
        qpos, qvel, ctrl, force = data.qpos, data.qvel, data.ctrl, data.actuator_force
        step = mujoco.mj_step
        dl_prev = dl_mt_m[0]
        f = 0.0
        for k in range(1, n):
            dl = dl_mt_m[k]
            qpos[0] = MUJOCO_REST_LENGTH_M + dl
            qvel[0] = (dl - dl_prev) / dt_s
            ctrl[0] = recruitment[k - 1]
            step(model, data)
            f = force[0]
            dl_prev = dl
        return -f   # MuJoCo reports a muscle's pull as negative force

    return run


def pymuscle_runner(recruitment: Sequence[float], n_units: int,
                    dt_s: float) -> Callable[[], float]:
    """pymuscle's Potvin-Fuglevand motor-unit pool (the README's example
    muscle) with ``n_units`` units, excited with R times its maximal
    excitation. It has no length input, so only R drives it.
    """
    from pymuscle import PotvinFuglevandMuscle

    def run() -> float:
        muscle = PotvinFuglevandMuscle(n_units)
        scale = muscle.max_excitation
        f = 0.0
        for r in recruitment[:-1]:
            f = muscle.step(r * scale, dt_s)
        return float(f)

    return run
