"""How many motor units a recruitment level recruits (doc/model.md section 2).

Units are always recruited in a fixed order (1..M) and de-recruited in
reverse, so the recruited set is a prefix of M = floor(N R + 0.5) units. The
memory of each unit's recruitment length and fitness lives in the engine's
unit pool (:mod:`hill_muscle_ros.model.muscle.kernels`), as segment stacks.
"""
from __future__ import annotations


def recruited_units(recruitment: float, n_units: int) -> int:
    """Number of recruited units M = floor(N R + 0.5) (doc/model.md section 2).

    :param recruitment: [-] recruitment R in [0, 1]
    :param n_units: [-] number of virtual units N
    :return: [-] M, in [0, N]
    """
    return int(n_units * recruitment + 0.5)
