"""A node whose middleware teardown hangs after its work is saved still exits.

:class:`~hill_muscle_ros.nodes._process.TeardownGuard` is armed by every
node's exit path (``run_node`` and the recorder's ``main``) once the node's
last work is done. Run in a child process with the timeout shortened, as a
hung ``destroy_node`` would leave it.
"""
from __future__ import annotations

import subprocess
import sys
import time

#: [s] the shortened teardown timeout of the child process.
SHORT_TIMEOUT_S = 0.3
#: [s] what the guarded code would block for without the guard.
HANG_S = 60.0
#: [s] the child's deadline: Python and rclpy start-up, the timeout, the exit.
CHILD_DEADLINE_S = 30.0


def run_child(body: str, status: int) -> tuple[subprocess.CompletedProcess, float]:
    code = ('import time\n'
            'import hill_muscle_ros.nodes._process as c\n'
            f'c.TEARDOWN_TIMEOUT_S = {SHORT_TIMEOUT_S}\n'
            f'guard = c.TeardownGuard({status})\n'
            f'{body}\n'
            'print("after the teardown", flush=True)\n')
    start = time.monotonic()
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=CHILD_DEADLINE_S)
    return done, time.monotonic() - start


def test_hung_teardown_exits_with_the_nodes_status_and_says_where_it_hung():
    done, elapsed_s = run_child(f'time.sleep({HANG_S})', status=3)
    assert done.returncode == 3, done.stderr
    assert elapsed_s < HANG_S
    assert 'did not finish in 0.3 s' in done.stderr
    # The hung call's line: the fifth of the child's program.
    assert 'File "<string>", line 5 in <module>' in done.stderr
    assert 'after the teardown' not in done.stdout


def test_teardown_that_finishes_is_not_cut_short():
    done, _ = run_child(f'guard.stop()\ntime.sleep({3 * SHORT_TIMEOUT_S})', status=3)
    assert done.returncode == 0, done.stderr
    assert 'after the teardown' in done.stdout
    assert 'did not finish' not in done.stderr
