"""Claiming a DDS domain ID on this machine with a lock file.

Runs that start their own ROS graph (the demo, the test suite) each take a
domain no other run on the machine holds, so that their topics (and
``/clock``) never mix. The claim is an exclusive ``flock`` on a file in the
temporary directory; it lasts while the file stays open and ends with the
process, however it ends.
"""
from __future__ import annotations

import fcntl
import tempfile
from pathlib import Path
from typing import IO, Iterable


def lock_free_domain(candidates: Iterable[int], pattern: str) -> tuple[int, IO] | None:
    """Lock the first domain of ``candidates`` that no other process holds.

    :param candidates: domain IDs, in the order to try them
    :param pattern: lock file name with one ``{}`` for the domain ID
    :return: the domain and its open lock file (close it to release the
        claim), or None if every candidate is held
    """
    for domain in candidates:
        lock = open(Path(tempfile.gettempdir()) / pattern.format(domain), 'w')
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        return domain, lock
    return None
