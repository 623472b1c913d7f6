"""Test-wide setup.

DDS isolation: every test run gets its own ROS_DOMAIN_ID and keeps discovery
on this host, so parallel runs (or a developer's live session) never cross-talk.
The domain is claimed with an exclusive lock file held for the whole run, so
two concurrent runs on one machine never draw the same one. Subprocesses
inherit these variables.
"""
import os
import random
from pathlib import Path

import pytest

from hill_muscle_ros.domain_lock import lock_free_domain
from stall_watch import StallWatcher

#: Domain IDs 1..100 stay clear of 0 (the default most people use), of the
#: demo's 101..199, and within the range Fast DDS maps to valid UDP ports.
_DOMAIN_LOW, _DOMAIN_HIGH = 1, 100
_LOCK_PATTERN = 'hill_muscle_ros_test_domain_{}.lock'

REPO = Path(__file__).resolve().parents[1]
PROTOCOLS = REPO / 'config' / 'protocols'

#: The open lock file of the claimed domain; the lock lasts while it is open.
_domain_lock = None


def _claim_domain() -> int:
    """Lock and return a domain ID no other test run on this machine holds."""
    global _domain_lock
    candidates = list(range(_DOMAIN_LOW, _DOMAIN_HIGH + 1))
    random.Random(os.getpid()).shuffle(candidates)
    claimed = lock_free_domain(candidates, _LOCK_PATTERN)
    if claimed is not None:
        domain, _domain_lock = claimed
        return domain
    raise RuntimeError(f'every ROS_DOMAIN_ID in {_DOMAIN_LOW}..{_DOMAIN_HIGH} is held by '
                       f'another test run')


def pytest_configure(config):
    if 'HILL_MUSCLE_TEST_DOMAIN' not in os.environ:
        os.environ['HILL_MUSCLE_TEST_DOMAIN'] = str(_claim_domain())
    os.environ['ROS_DOMAIN_ID'] = os.environ['HILL_MUSCLE_TEST_DOMAIN']
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_STATIC_PEERS', None)


@pytest.fixture(scope='session')
def stall_watcher():
    """One :class:`~stall_watch.StallWatcher` for the whole run: the only
    evidence on which a test may repeat a timing measurement."""
    with StallWatcher() as watcher:
        yield watcher


@pytest.fixture(scope='session')
def protocol_paths():
    """Paths of the shipped protocols by their short name."""
    return {'I': PROTOCOLS / 'protocol_I.yaml', 'II': PROTOCOLS / 'protocol_II.yaml'}
