"""``test/background_priority.py``: the offline run of ``make test`` at the lowest
priority a user may give, also across autogroups."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import background_priority

WRAPPER = Path(__file__).with_name('background_priority.py')
#: Prints the child's nice value, whether it leads a session of its own, and
#: its autogroup line (or nothing without autogroups).
PROBE = ('import os\n'
         'group = open("/proc/self/autogroup").read().strip() '
         'if os.path.exists("/proc/self/autogroup") else ""\n'
         'print(os.nice(0), os.getsid(0) == os.getpid(), group, sep="|")\n')


def run_wrapped() -> tuple[list[str], str]:
    """The probe's fields, and what the wrapper said on stderr."""
    out = subprocess.run([sys.executable, str(WRAPPER), sys.executable, '-c', PROBE],
                         capture_output=True, text=True, timeout=30, check=True)
    return out.stdout.strip().split('|'), out.stderr


def test_the_command_runs_at_nice_19_in_a_session_of_its_own():
    (nice, own_session, _), _ = run_wrapped()
    assert int(nice) == background_priority.NICENESS
    assert own_session == 'True'


@pytest.mark.skipif(not os.path.exists(background_priority.AUTOGROUP),
                    reason='this kernel has no autogroups')
def test_its_autogroup_is_at_nice_19_too_or_it_says_why_not():
    """Else the scheduler weighs the whole session as much as any other,
    whatever the nice of its processes. A kernel may refuse a user the
    change: the run then goes on with plain nice, and says so."""
    (*_, group), said = run_wrapped()
    if 'plain nice only' in said:
        assert background_priority.AUTOGROUP in said, said
    else:
        assert group.endswith(f'nice {background_priority.NICENESS}'), group


def test_without_a_command_it_says_how_to_call_it():
    out = subprocess.run([sys.executable, str(WRAPPER)], capture_output=True, text=True,
                         timeout=30)
    assert out.returncode != 0 and 'usage:' in out.stderr
