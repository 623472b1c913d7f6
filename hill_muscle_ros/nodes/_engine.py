"""Loading the model a node steps: compiled or Python (ROS side only, no model logic).

:func:`load_engine` loads and logs it at start-up (the limb node, the
simulator node); :func:`load_muscle` and :func:`rebuild_muscle` are the
simulator's muscle at start-up and after a live parameter change.
"""
from __future__ import annotations

import time
from typing import Any, Callable

from ..model import Muscle, MuscleParams
from ..model import engine as engines
from ..model.muscle import kernels as muscle_kernels


#: [s] about how long the compiled kernels take to compile when numba's cache
#: has no copy (BENCHMARKS.md, "The limb and the FES muscle, compiled"), for the log.
COLD_COMPILE_S = 30.0


def load_engine(what: str, make_compiled: Callable[[], Any], make_python: Callable[[], Any],
                loaded: Callable[[], bool], logger: Any) -> Any:
    """The model a node steps: compiled when :func:`~hill_muscle_ros.model.engine.choice`
    says so, else Python; logs which, and how long loading took.

    Call it in the node's ``__init__`` before any publisher, subscription,
    service or timer: a compile (about :data:`COLD_COMPILE_S`) then happens
    before the node can be seen as started, never in a callback. A compiled
    model that cannot be loaded (numba missing, a compile error, a bad
    ``HILL_MUSCLE_ENGINE``) is not a reason to stop: the Python model computes
    the same steps (to 1e-9), so the node warns and runs it.

    :param what: the model's name in the log lines, e.g. ``limb``
    :param make_compiled: builds the compiled model (loading its kernels)
    :param make_python: builds the Python model
    :param loaded: whether the compiled kernels are loaded in this process already
    :param logger: the node's logger
    """
    try:
        wanted = engines.choice()
    except (ValueError, ImportError) as err:
        logger.warning(f'{err}: the {what} runs on the Python engine')
        return make_python()
    if wanted != engines.COMPILED:
        why = (f'{engines.ENV_VAR}={engines.PYTHON}' if engines.requested() == engines.PYTHON
               else 'numba cannot be imported')
        logger.info(f'{what} engine: python ({why})')
        return make_python()
    if not loaded():
        logger.info(f'loading the compiled {what}; if numba has no cached copy (the first '
                    'start after an install or an edit of the model) it compiles it once, '
                    f'about {COLD_COMPILE_S:g} s, and caches it for later starts')
    started_s = time.monotonic()
    compiled_before_s = engines.compile_seconds()
    try:
        model = make_compiled()
    except Exception as err:   # noqa: BLE001 -- any failure of numba: the Python model works
        logger.warning(f'the compiled {what} failed to load ({type(err).__name__}: {err}): '
                       f'the {what} runs on the Python engine')
        return make_python()
    took_s = time.monotonic() - started_s
    compiled_s = engines.compile_seconds() - compiled_before_s
    how = (f'compiled in {compiled_s:.1f} s (cached for later starts)' if compiled_s > 0.0
           else 'from numba\'s cache')
    logger.info(f'{what} engine: compiled, loaded in {took_s:.2f} s, {how}')
    return model


def load_muscle(params: MuscleParams, logger) -> Muscle:
    """The muscle the node steps, made at start-up; logs which build runs it
    (compiled or plain Python, as :func:`~hill_muscle_ros.model.engine.choice`
    says; :func:`._engine.load_engine`).

    :param params: the muscle's parameters
    :param logger: the node's logger
    """
    return load_engine('muscle',
                       lambda: with_read_outs_loaded(Muscle(params, build=engines.COMPILED)),
                       lambda: Muscle(params, build=engines.PYTHON), muscle_kernels.loaded,
                       logger)


def with_read_outs_loaded(muscle: Muscle) -> Muscle:
    """``muscle``, after one call of each read-out the node makes outside its
    steps: ``outputs`` (/diagnostics) and ``activation`` (the ``activation``
    topic). Their kernels have no signature given in advance, so numba loads
    each from its cache on the first call: 5-12 ms, which the first
    /diagnostics report of a ding2003 simulator spent inside a callback (11.5
    ms, its longest tick gap under a 1 kHz stimulation stream). Here it is
    start-up.
    """
    muscle.outputs()
    muscle.activation   # noqa: B018 -- read for its kernel's first call
    return muscle


def rebuild_muscle(params: MuscleParams, compiled: bool, logger) -> Muscle:
    """The muscle remade after a live parameter change, inside a callback.

    On the compiled build only if the node's muscle was compiled until now
    (``compiled``: the kernels are loaded, so this compiles nothing); else on
    the plain Python functions. A compiled muscle that fails to build falls
    back to Python, with a warning.

    :param params: the new parameters
    :param compiled: whether the node's muscle was compiled until now
    :param logger: the node's logger
    """
    if compiled and muscle_kernels.loaded():
        try:
            return Muscle(params, build=engines.COMPILED)
        except Exception as err:   # noqa: BLE001 -- the Python build computes the same steps
            logger.warning(f'the compiled muscle failed to build ({type(err).__name__}: '
                           f'{err}): the muscle runs on the Python engine')
    return Muscle(params, build=engines.PYTHON)
