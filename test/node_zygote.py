"""Node processes forked from a Python that has already imported them (a zygote).

A node started from its console script spends about a second before it runs:
the interpreter, rclpy, numpy and the package import, and the simulator and
the limb load their numba kernels from the disk cache (0.5-2 CPU-s each,
measured with ``/proc/<pid>/stat``). The ROS tests start about 200 nodes, so
that start-up was half of their CPU time. Here one server per pytest process
imports every node module of the package and loads the kernels once; each
node is then a ``fork`` of it that sets the test's environment, arguments,
log file and session, and calls the console script's own function (from the
package's entry points, as the script does). Nothing of ROS is initialised
before the fork: ``rclpy.init``, the DDS participant and every thread are the
child's own, and the child sees only the environment the test gave it.

What stays an ``exec`` of the real console script (:func:`forkable` says no):
a command that is not one of the package's node scripts in this venv (the
``hill-muscle`` CLI, a colcon install, ``python -m``), a start with a
``preexec_fn``, an environment that differs from the server's in a variable
read while the modules import (``NUMBA_*``, ``PYTHON*``, ``LD_*``, ``OMP_*``),
and every start when ``HILL_MUSCLE_TEST_FORK=0``.

:class:`ForkedPopen` stands in for the ``subprocess.Popen`` of
:class:`hill_muscle_ros.supervisor.Process`: ``pid``, ``poll``, ``wait`` and
``send_signal``. The child is the server's, not the test's, so its exit
status comes over the connection that asked for it: the server reaps its
children on ``SIGCHLD`` and writes each status to its connection.

Run as a program, this file is the server: ``node_zygote.py SOCKET``.
"""
from __future__ import annotations

import atexit
import ctypes
import gc
import importlib
import importlib.metadata
import io
import json
import os
import select
import selectors
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import traceback
from pathlib import Path

#: The distribution whose console scripts are forked.
DISTRIBUTION = 'hill_muscle_ros'
#: The package of the node modules: only their scripts are forked.
NODE_PACKAGE = 'hill_muscle_ros.nodes.'
#: Set to ``0`` to start every node from its console script.
ENV_SWITCH = 'HILL_MUSCLE_TEST_FORK'
#: Variables read while Python and the pre-imported modules load: a child
#: that needs other values than the server's is started by ``exec``.
IMPORT_TIME_PREFIXES = ('NUMBA_', 'PYTHON', 'LD_', 'OMP_')
#: The kernel sets the nodes step (:data:`hill_muscle_ros.model.precompile.KERNEL_SETS`).
NODE_KERNEL_SETS = ('muscle', 'limb')
#: [s] bound on the server's start: imports, and the kernels from numba's cache.
START_TIMEOUT_S = 120.0
#: prctl option that sends a signal to a process when its parent dies (Linux).
_PR_SET_PDEATHSIG = 1
#: The line the server writes once it listens.
READY = 'ready'


def node_scripts() -> dict[str, str]:
    """The package's node console scripts: name -> ``module:function``."""
    eps = importlib.metadata.distribution(DISTRIBUTION).entry_points
    return {ep.name: ep.value for ep in eps
            if ep.group == 'console_scripts' and ep.value.startswith(NODE_PACKAGE)}


# --------------------------------------------------------------------------- server

def _preload() -> dict[str, str]:
    """Import every node module and load the nodes' kernels; return the scripts."""
    scripts = node_scripts()
    for target in scripts.values():
        importlib.import_module(target.partition(':')[0])
    from hill_muscle_ros.model import engine, precompile
    if engine.choice() == engine.COMPILED:
        for name in NODE_KERNEL_SETS:
            precompile.compile_kernel_set(name)
    # What is loaded now is every child's, for good: frozen, no child's
    # collections walk it, nor copy its pages by touching their headers.
    gc.collect()
    gc.freeze()
    return scripts


def _exit_code(err: SystemExit) -> int:
    """The status Python exits with for ``SystemExit(err.code)``."""
    if err.code is None:
        return 0
    if isinstance(err.code, int):
        return err.code
    print(err.code, file=sys.stderr)
    return 1


def _run_child(request: dict, target: str) -> None:
    """In the forked child: become the node process the request describes; never returns."""
    code = 1
    try:
        signal.set_wakeup_fd(-1)
        for sig in (signal.SIGCHLD, signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_DFL)
        os.setsid()   # its own session and process group, as Popen(start_new_session=True)
        try:
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
        except (OSError, AttributeError):
            pass
        log = os.open(request['log'], os.O_WRONLY | os.O_APPEND)
        devnull = os.open(os.devnull, os.O_RDONLY)
        os.dup2(devnull, 0)
        os.dup2(log, 1)
        os.dup2(log, 2)
        os.close(log)
        os.close(devnull)
        sys.stdout = io.TextIOWrapper(io.FileIO(1, 'w', closefd=False), write_through=True)
        sys.stderr = io.TextIOWrapper(io.FileIO(2, 'w', closefd=False), write_through=True)
        os.environ.clear()
        os.environ.update(request['env'])
        sys.argv = list(request['argv'])
        module_name, _, function = target.partition(':')
        main = getattr(importlib.import_module(module_name), function)
        try:
            result = main()
            code = 0 if result is None else (result if isinstance(result, int) else 1)
        except SystemExit as err:
            code = _exit_code(err)
        except KeyboardInterrupt:
            # As the interpreter does: the traceback, then death by SIGINT.
            traceback.print_exc()
            code = -signal.SIGINT
        for thread in threading.enumerate():
            if thread is not threading.current_thread() and not thread.daemon:
                thread.join()
        atexit._run_exitfuncs()
    except BaseException:  # noqa: BLE001 -- the child must never return into the server
        traceback.print_exc()
    finally:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        if code < 0:
            os.kill(os.getpid(), -code)
        os._exit(code & 0xFF)


def serve(path: str) -> None:
    """Listen on the Unix socket ``path``; fork a node per request; report exits.

    A request is one JSON line ``{"argv": [...], "env": {...}, "log": path}``;
    the reply is the child's pid, then, when it has exited, its status as
    ``subprocess.Popen.returncode`` gives it (negative: the signal). The
    server ends when its stdin closes (the test process is gone).
    """
    scripts = _preload()
    wake_r, wake_w = os.pipe()
    os.set_blocking(wake_w, False)
    signal.set_wakeup_fd(wake_w)
    signal.signal(signal.SIGCHLD, lambda *_: None)
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(16)
    children: dict[int, socket.socket] = {}
    selector = selectors.DefaultSelector()
    selector.register(listener, selectors.EVENT_READ, 'listener')
    selector.register(wake_r, selectors.EVENT_READ, 'child')
    selector.register(sys.stdin, selectors.EVENT_READ, 'stdin')
    print(READY, flush=True)
    while True:
        for key, _ in selector.select():
            if key.data == 'stdin':
                if not sys.stdin.buffer.read1(4096):
                    return
            elif key.data == 'child':
                os.read(wake_r, 4096)
                while children:
                    pid, status = os.waitpid(-1, os.WNOHANG)
                    if pid == 0:
                        break
                    conn = children.pop(pid, None)
                    if conn is not None:
                        try:
                            conn.sendall(f'{os.waitstatus_to_exitcode(status)}\n'.encode())
                        except OSError:
                            pass   # the test stopped listening
                        conn.close()
            else:
                conn, _ = listener.accept()
                with conn.makefile('rb') as lines:
                    request = json.loads(lines.readline())
                target = scripts[Path(request['argv'][0]).name]
                pid = os.fork()
                if pid == 0:
                    selector.close()
                    listener.close()
                    for other in children.values():
                        other.close()
                    conn.close()
                    os.close(wake_r)
                    os.close(wake_w)
                    _run_child(request, target)
                children[pid] = conn
                conn.sendall(f'{pid}\n'.encode())


# --------------------------------------------------------------------------- client

class ForkedPopen:
    """The part of ``subprocess.Popen`` that :class:`hill_muscle_ros.supervisor.Process`
    uses, for a node the server forked.

    :param args: the command line, for messages
    :param conn: the connection the server writes the exit status to
    :param pid: the child's process id
    """

    def __init__(self, args: list[str], conn: socket.socket, pid: int,
                 received: bytes = b'') -> None:
        self.args = args
        self.pid = pid
        self.returncode: int | None = None
        self._conn = conn
        self._received = received

    def _collect(self, timeout_s: float | None) -> None:
        if self.returncode is not None:
            return
        data = self._received
        if not data:
            ready, _, _ = select.select([self._conn], [], [], timeout_s)
            if not ready:
                return
        while not data.endswith(b'\n'):
            chunk = self._conn.recv(64)
            if not chunk:
                break
            data += chunk
        self._conn.close()
        # A server that died without a status cannot say; the child died with it
        # (PR_SET_PDEATHSIG), so report that signal.
        self.returncode = int(data) if data.strip() else -signal.SIGTERM

    def poll(self) -> int | None:
        self._collect(0.0)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        self._collect(timeout)
        if self.returncode is None:
            raise subprocess.TimeoutExpired(self.args, timeout)
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            try:
                os.kill(self.pid, sig)
            except ProcessLookupError:
                pass


class Zygote:
    """The server of this process, started at the first :meth:`start`."""

    def __init__(self) -> None:
        self._server: subprocess.Popen | None = None
        self._dir: tempfile.TemporaryDirectory | None = None
        self._env: dict[str, str] = {}
        self._scripts: dict[str, str] | None = None

    def forkable(self, cmd, env: dict[str, str], preexec_fn) -> bool:
        """Whether ``cmd`` with ``env`` can be a fork of the server (module docstring)."""
        if os.environ.get(ENV_SWITCH, '1') == '0' or preexec_fn is not None or not cmd:
            return False
        if self._scripts is None:
            self._scripts = node_scripts()
        script = Path(cmd[0])
        if script.parent != Path(sys.executable).parent or script.name not in self._scripts:
            return False
        from hill_muscle_ros.supervisor import ros_environment
        base = self._env or ros_environment()
        changed = {k for k in set(env) | set(base) if env.get(k) != base.get(k)}
        return not any(k.startswith(IMPORT_TIME_PREFIXES) for k in changed)

    def _ensure(self) -> None:
        if self._server is not None and self._server.poll() is None:
            return
        self._dir = tempfile.TemporaryDirectory(prefix='hill_muscle_zygote_')
        self._socket = os.path.join(self._dir.name, 'zygote.sock')
        # The test run's own node environment, whatever the first start asks:
        # a first start with an unusual variable must not set every later one's.
        from hill_muscle_ros.supervisor import _child_setup, ros_environment
        self._env = ros_environment()
        self._server = subprocess.Popen(
            [sys.executable, __file__, self._socket], env=self._env, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, start_new_session=True, preexec_fn=_child_setup(None))
        ready, _, _ = select.select([self._server.stdout], [], [], START_TIMEOUT_S)
        line = self._server.stdout.readline().decode().strip() if ready else ''
        if line != READY:
            self._server.kill()
            raise RuntimeError(f'the node zygote did not start within {START_TIMEOUT_S:g} s '
                               f'(said {line!r}); HILL_MUSCLE_TEST_FORK=0 starts nodes '
                               'from their scripts')
        atexit.register(self.close)

    def start(self, cmd: list[str], env: dict[str, str], log_path: Path) -> ForkedPopen:
        """Fork the node ``cmd`` with ``env``, its output appended to ``log_path``."""
        self._ensure()
        conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        conn.connect(self._socket)
        conn.sendall(json.dumps({'argv': list(cmd), 'env': env,
                                 'log': str(log_path)}).encode() + b'\n')
        received = b''
        while b'\n' not in received:
            chunk = conn.recv(64)
            if not chunk:
                raise RuntimeError(f'the node zygote closed the connection starting {cmd}')
            received += chunk
        pid, _, rest = received.partition(b'\n')
        return ForkedPopen(list(cmd), conn, int(pid), rest)

    def close(self) -> None:
        """Stop the server (its stdin closes); its children get SIGTERM with it."""
        if self._server is not None:
            self._server.stdin.close()
            try:
                self._server.wait(timeout=10.0)
            except subprocess.TimeoutExpired:
                self._server.kill()
                self._server.wait()
            self._server = None
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None


#: The server of this test process.
ZYGOTE = Zygote()


if __name__ == '__main__':
    serve(sys.argv[1])
