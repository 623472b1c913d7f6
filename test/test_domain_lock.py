"""Claiming a ROS domain with a lock file (``hill_muscle_ros.domain_lock``):
the demo and every test run take a domain no other run on the machine holds."""
import os
import shutil
import subprocess
import tempfile

import pytest

from hill_muscle_ros import domain_lock
from hill_muscle_ros.domain_lock import lock_free_domain

PATTERN = 'hill_muscle_ros_test_lock_{}.lock'
#: The uid of ``nobody``: another user than the one who left the lock files.
NOBODY_UID = 65534
#: Claims a domain of 7 or 8 in the temporary directory and prints it: the
#: module is loaded from its file, with the standard library only (nobody may
#: not enter root's home, where this venv's interpreter may live).
CLAIM = ('import importlib.util\n'
         f'spec = importlib.util.spec_from_file_location("domain_lock", {domain_lock.__file__!r})\n'
         'module = importlib.util.module_from_spec(spec)\n'
         'spec.loader.exec_module(module)\n'
         f'print(module.lock_free_domain([7, 8], {PATTERN!r})[0])')
#: An interpreter every user may run, for the claim made as nobody.
SYSTEM_PYTHON = shutil.which('python3', path='/usr/bin:/bin')


@pytest.fixture
def shared_tmp(monkeypatch):
    """A temporary directory every user may write, like /tmp (sticky bit)."""
    folder = tempfile.mkdtemp(prefix='hill_muscle_ros_lock_test_', dir='/tmp')
    os.chmod(folder, 0o1777)
    monkeypatch.setenv('TMPDIR', folder)
    monkeypatch.setattr(tempfile, 'tempdir', folder)
    yield folder
    shutil.rmtree(folder)


def test_a_held_domain_is_skipped_and_released_when_its_file_closes(shared_tmp):
    first = lock_free_domain([3, 4], PATTERN)
    second = lock_free_domain([3, 4], PATTERN)
    assert (first[0], second[0]) == (3, 4)
    assert lock_free_domain([3, 4], PATTERN) is None
    first[1].close()
    assert lock_free_domain([3, 4], PATTERN)[0] == 3


def test_a_lock_file_another_user_left_behind_can_still_be_claimed(shared_tmp):
    # Another user's run made the file of domain 7 and ended; its mode lets
    # this user read it, not write it.
    path = os.path.join(shared_tmp, PATTERN.format(7))
    with open(path, 'w'):
        pass
    os.chmod(path, 0o444)
    if os.geteuid() == 0:
        # root may write any file: the claim is made as nobody instead.
        if SYSTEM_PYTHON is None:
            pytest.skip('as root, the claim as nobody needs /usr/bin/python3')
        result = subprocess.run([SYSTEM_PYTHON, '-c', CLAIM], capture_output=True, text=True,
                                env={**os.environ, 'TMPDIR': shared_tmp},
                                user=NOBODY_UID, timeout=60)
        assert result.returncode == 0, result.stderr
        assert result.stdout.strip() == '7'
    else:
        assert lock_free_domain([7, 8], PATTERN)[0] == 7
