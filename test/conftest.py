"""Test-wide setup.

DDS isolation: every test run gets its own ROS_DOMAIN_ID and keeps discovery
on this host, so parallel runs (or a developer's live session) never cross-talk.
Subprocesses inherit these variables.
"""
import os
import random

from pathlib import Path

import pytest

#: Domain IDs 1..100 stay clear of 0 (the default most people use) and within
#: the range Fast DDS maps to valid UDP ports on Linux.
_DOMAIN_LOW, _DOMAIN_HIGH = 1, 100

REPO = Path(__file__).resolve().parents[1]
PROTOCOLS = REPO / 'config' / 'protocols'


def pytest_configure(config):
    if 'HILL_MUSCLE_TEST_DOMAIN' not in os.environ:
        domain = random.Random(os.getpid()).randint(_DOMAIN_LOW, _DOMAIN_HIGH)
        os.environ['HILL_MUSCLE_TEST_DOMAIN'] = str(domain)
    os.environ['ROS_DOMAIN_ID'] = os.environ['HILL_MUSCLE_TEST_DOMAIN']
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.pop('ROS_STATIC_PEERS', None)


@pytest.fixture(scope='session')
def protocol_paths():
    """Paths of the shipped protocols by their short name."""
    return {'I': PROTOCOLS / 'protocol_I.yaml', 'II': PROTOCOLS / 'protocol_II.yaml'}
