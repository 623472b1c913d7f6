"""Claiming a DDS domain ID on this machine with a lock file.

Runs that start their own ROS graph (the demo, the test suite) each take a
domain no other run on the machine holds, so that their topics (and
``/clock``) never mix. The claim is an exclusive ``flock`` on a file in the
temporary directory; it lasts while the file stays open and ends with the
process, however it ends.
"""
from __future__ import annotations

import fcntl
import os
import tempfile
from pathlib import Path
from typing import IO, Iterable

#: A new lock file is readable by every user (less the umask): all a claim needs.
_LOCK_FILE_MODE = 0o644


def lock_free_domain(candidates: Iterable[int], pattern: str) -> tuple[int, IO] | None:
    """Lock the first domain of ``candidates`` that no other process holds.

    :param candidates: domain IDs, in the order to try them
    :param pattern: lock file name with one ``{}`` for the domain ID
    :return: the domain and its open lock file (close it to release the
        claim), or None if every candidate is held
    """
    for domain in candidates:
        path = Path(tempfile.gettempdir()) / pattern.format(domain)
        try:
            # Read-only, readable by all: ``flock`` needs no write access, so a
            # file another user's run left behind does not lock this user out.
            fd = os.open(path, os.O_RDONLY | os.O_CREAT, _LOCK_FILE_MODE)
        except OSError:
            continue   # not ours to read: count it as held
        lock = os.fdopen(fd, 'r')
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            lock.close()
            continue
        return domain, lock
    return None
