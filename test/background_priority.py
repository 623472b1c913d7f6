"""Run a command at the lowest CPU priority a user may give their own processes.

``python test/background_priority.py CMD [ARG...]``: nice 19, in a session of
its own, whose autogroup is at nice 19 too; then ``exec`` of the command.

Why. ``make test`` runs the offline tests beside the ROS tests, which run
nodes in real time, and the offline ones must only take the CPU the others
leave idle. ``nice -n 19`` alone does not do that on Linux with autogroups
(``CONFIG_SCHED_AUTOGROUP``, on in Debian's and Ubuntu's kernels): the
scheduler shares the CPUs between sessions' autogroups first and applies nice
only within one. Each node a ROS test starts runs in a session of its own,
so a niced offline run in make's session weighed as much as each node; with
it beside them, the ROS run took 233 s against 208 s alone, and a player
waited 0.61 s for a CPU. An autogroup's nice may be raised by its owner, as a
process's may (``sched(7)``, "The autogroup feature"); without autogroups
(the file is missing), or where the kernel refuses, plain nice is what there is.

The new session no longer gets a terminal's Ctrl-C: whoever starts this
passes a stop signal on (the Makefile's ``trap``).
"""
from __future__ import annotations

import errno
import os
import sys
import time

#: The lowest priority: the largest nice value.
NICENESS = 19
#: The calling session's autogroup (sched(7)).
AUTOGROUP = '/proc/self/autogroup'
#: The kernel takes at most one unprivileged autogroup change per 100 ms on
#: the whole machine (EAGAIN otherwise): a few tries, a little over that apart.
AUTOGROUP_TRIES = 5
AUTOGROUP_RETRY_S = 0.11


def lower_autogroup(niceness: int = NICENESS) -> str | None:
    """Set this session's autogroup to ``niceness``; return why not, or None.

    :param niceness: the autogroup's nice value, at least its present one
    """
    for _ in range(AUTOGROUP_TRIES):
        try:
            with open(AUTOGROUP, 'w') as group:
                group.write(str(niceness))
            return None
        except FileNotFoundError:
            return 'no autogroups in this kernel'
        except OSError as err:
            if err.errno != errno.EAGAIN:
                return f'{AUTOGROUP}: {err.strerror}'
            time.sleep(AUTOGROUP_RETRY_S)
    return f'{AUTOGROUP}: busy after {AUTOGROUP_TRIES} tries'


def main(argv: list[str]) -> None:
    if not argv:
        sys.exit(f'usage: {sys.argv[0]} CMD [ARG...]')
    os.setsid()   # a session, so an autogroup, of its own
    why_not = lower_autogroup()
    if why_not is not None:
        print(f'background_priority: plain nice only ({why_not})', file=sys.stderr)
    os.nice(NICENESS)
    os.execvp(argv[0], argv)


if __name__ == '__main__':
    main(sys.argv[1:])
