"""Build the compiled kernels that the nodes load, in a process of its own (test helper).

``python test/kernel_builder.py MARKER``: compiles the FES muscle's and the
limb's kernels (``fes_kernels.compiled()``, ``limb_kernels.compiled()``) into
numba's disk cache, or loads them from it, then writes ``MARKER`` (JSON:
``ok``, ``compile_s`` the seconds numba spent compiling, ``wall_s``, ``error``
the traceback's tail if it failed). The marker is written whatever happens, by
a rename, so a reader never sees half of it.

``conftest.py`` starts it at the beginning of a run, in a session of its own at
the weakest priority, so that the tests that need no compiled kernel run while
it compiles; a test whose nodes load the kernels waits for the marker first
(:func:`wait_for_kernels`).
"""
from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path

#: Characters of the builder's traceback kept in the marker.
ERROR_CHARS = 3000
#: [s] poll period while waiting for the marker.
POLL_S = 0.1


def build(marker: Path) -> None:
    """Compile (or load) the kernels and write ``marker``."""
    started = time.monotonic()
    result = {'ok': False, 'compile_s': 0.0, 'wall_s': 0.0, 'error': ''}
    try:
        from hill_muscle_ros.model import engine, fes_kernels, limb_kernels
        fes_kernels.compiled()   # the simulator node's FES muscle (compiled_muscle)
        limb_kernels.compiled()  # the limb node
        result.update(ok=True, compile_s=engine.compile_seconds())
    except BaseException:   # noqa: B036 - whatever it is, the waiting tests must hear of it
        result['error'] = traceback.format_exc()[-ERROR_CHARS:]
    finally:
        result['wall_s'] = time.monotonic() - started
        partial = marker.with_name(marker.name + '.partial')
        partial.write_text(json.dumps(result), encoding='utf-8')
        os.replace(partial, marker)


def read_marker(marker: Path) -> dict | None:
    """The builder's result, or ``None`` while it is not written yet."""
    try:
        return json.loads(marker.read_text(encoding='utf-8'))
    except FileNotFoundError:
        return None


def wait_for_kernels(marker: Path, timeout_s: float) -> dict:
    """Wait until the builder has written ``marker``; return its result.

    :raises TimeoutError: if it has not after ``timeout_s``
    """
    deadline = time.monotonic() + timeout_s
    while (result := read_marker(marker)) is None:
        if time.monotonic() > deadline:
            raise TimeoutError(f'the kernel builder wrote no {marker} within {timeout_s:g} s')
        time.sleep(POLL_S)
    return result


if __name__ == '__main__':
    build(Path(sys.argv[1]))
