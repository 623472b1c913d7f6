"""Test helpers: the limb's two builds of its kernels, and a look inside a plain run.

The limb's kernels (``hill_muscle_ros.model.limb.kernels``) run compiled or as
plain Python, as ``HILL_MUSCLE_ENGINE`` says; the tests compare the two runs
of the same functions (to rounding) and check the physics against the
independent oracle (``limb_reference``).
"""
from __future__ import annotations

import contextlib

import pytest

from hill_muscle_ros.model import engine
from hill_muscle_ros.model.limb import kernels

#: [rad], [rad/s], [N m], [m], [N]: agreement asked of the two builds: the
#: same functions, so rounding apart they give the same numbers.
TOL = 1e-9


@contextlib.contextmanager
def on_engine(value: str):
    """``HILL_MUSCLE_ENGINE=value`` inside the ``with``, as it was after it."""
    if value == engine.COMPILED:
        pytest.importorskip('numba')
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(engine.ENV_VAR, value)
        yield


def run_on(value: str, fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` with ``HILL_MUSCLE_ENGINE=value``."""
    with on_engine(value):
        return fn(*args, **kwargs)


def spy_quasi_static(monkeypatch, plant) -> list[str]:
    """The plain-Python engine, and a list of the ``fv_scaling`` of the muscle of
    each call of the kernels' quasi-static force (``muscle_kernels.quasi_force``,
    which :func:`kernels.forces` asks for a CE taken quasi-static): did a run of
    ``plant`` take a CE quasi-static, and which?"""
    calls = []
    original = kernels.quasi_force

    def spy(F, I, i, *args):
        calls.append(plant.muscles[i].params.fv_scaling)
        return original(F, I, i, *args)

    monkeypatch.setattr(kernels, 'quasi_force', spy)   # the plain functions' global
    monkeypatch.setenv(engine.ENV_VAR, engine.PYTHON)  # the spy sees the plain run only
    return calls
