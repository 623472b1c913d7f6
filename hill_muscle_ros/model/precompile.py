"""Every compiled kernel set of the model, compiled (or loaded) ahead of use.

numba compiles each kernel set the first time a process needs it and keeps
it in its disk cache (:mod:`.engine`); after that a process loads it in about
a second. The first use pays the compile: 28 s for the limb node's first
start in a clean clone, longer than a launch file or a test waits for a node.
:func:`compile_kernel_set` builds one set; ``hill-muscle compile`` builds them
all, several processes at once, so that no node and no run compiles later:
after an install, in a container's build, and before the test suite
(``make test``), as ``compileall`` writes the bytecode.
"""
from __future__ import annotations

import importlib
import time

from . import engine

#: The kernel sets, by name: the module and the function that builds it (or
#: loads it from the cache). Together they are every function numba compiles
#: for the package (a clean clone's test suite compiles nothing beyond them).
KERNEL_SETS = {
    'muscle': ('muscle.kernels', 'compiled'),         # Muscle: simulate, the simulator node
    'limb': ('limb.kernels', 'compiled'),             # Limb: the limb node, simulate_limb
    'batch': ('muscle.batch_kernels', 'compiled'),    # MuscleBatch: sweeps, the gym
}

#: The kernel sets in the groups that build in one process each, in order:
#: the limb's and the FES batch's kernels call the FES muscle's, which a
#: process compiles (or loads) once for all three. Measured in a clean clone,
#: one process after the other (cold cache): the FES muscle 12.9 s, the limb
#: 10.3 s, the FES batch 0.9 s.
KERNEL_GROUPS = (('muscle', 'limb', 'batch'),)


def compile_kernel_group(names) -> list[tuple[str, float, float]]:
    """Build the kernel sets ``names`` in this process, in order.

    :param names: keys of :data:`KERNEL_SETS`
    :return: for each set: (name, [s] wall time, [s] of it compiling)
    """
    return [(name, *compile_kernel_set(name)) for name in names]


def compile_kernel_set(name: str) -> tuple[float, float]:
    """Build the kernel set ``name`` of :data:`KERNEL_SETS` in this process.

    :param name: a key of :data:`KERNEL_SETS`
    :return: ([s] wall time of the whole build, [s] of it in numba's compiler;
        0 when everything came from the cache)
    :raises ValueError: if ``name`` is not a kernel set
    :raises ImportError: if numba cannot be imported
    """
    if name not in KERNEL_SETS:
        raise ValueError(f'`name` must be one of {", ".join(KERNEL_SETS)}, got {name!r}')
    module_name, function = KERNEL_SETS[name]
    engine.import_numba()
    module = importlib.import_module(f'{__package__}.{module_name}')
    compiling_before = engine.compile_seconds()
    start = time.perf_counter()
    getattr(module, function)()
    return time.perf_counter() - start, engine.compile_seconds() - compiling_before
