"""Muscles on a chosen build of the one engine (test helper).

:class:`~hill_muscle_ros.model.muscle.Muscle` runs the kernels of
model/muscle/kernels.py compiled by numba or as the very same plain Python
functions (:func:`hill_muscle_ros.model.engine.kernels`); these helpers make one
on each build.
"""
from hill_muscle_ros.model import Muscle, MuscleParams, engine
from hill_muscle_ros.model.muscle import pool as muscle_pool, state as muscle_state
from hill_muscle_ros.model.units import UnitLayout


def plain(params: MuscleParams | None = None) -> Muscle:
    """A muscle on the plain Python functions."""
    return Muscle(params, build=engine.PYTHON)


def compiled(params: MuscleParams | None = None) -> Muscle:
    """A muscle on numba's build of the same functions."""
    return Muscle(params, build=engine.COMPILED)


class KernelPool:
    """The unit pool of the engine's kernels (model/muscle/kernels.py), one muscle of
    a bundle, driven as the tests drive the naive model (plain Python build)."""

    def __init__(self, p: MuscleParams):
        self.bundle = muscle_state.FesBundle([p])
        self.layout = UnitLayout(p)

    def update(self, m, x, t):
        muscle_pool.pool_update(self.bundle.F, self.bundle.I, 0, m, x, t)

    def advance_to(self, t):
        muscle_pool.pool_advance_to(self.bundle.F, self.bundle.I, 0, t)

    def eff_f_iso(self, x, t):
        return muscle_pool.pool_eff_f_iso(self.bundle.F, self.bundle.I, 0, x, t)

    def mean_fitness(self, t):
        return muscle_pool.pool_mean_fitness(self.bundle.F, self.bundle.I, 0, t)

    def fitness_profile(self, t):
        self.bundle.view(0, 'fs')[muscle_state.S_T] = t   # the profile is read at the state's t
        return muscle_state.fitness_profile(self.bundle, 0)
