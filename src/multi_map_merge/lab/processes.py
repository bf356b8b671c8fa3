"""Processes, ports and roscores of the benchmarks and tests: one helper for them all
(``bench/accuracy`` and its SLAM runs, ``bench/live_gap.py``, ``bench/peer.py``,
``lab/loopback_cluster.py``, ``test/ros/rostest_helpers.py``).

Every process is started in a session of its own (:func:`start_group`), so that stopping it
stops what it started too (roscore's master and rosout, roslaunch's nodes): :func:`stop_group`
sends SIGINT to the group (ROS tools shut down cleanly on it), then SIGKILL to whatever is left
after a grace period. :class:`Processes` keeps the processes a run started so that all of them are
stopped on its exit, also on Ctrl-C. Ports: :func:`port_free` and :func:`free_port` (a port of a
range not handed out before in this process: threads start roscores at once).
:class:`Roscore` is a master of our own on a free port, a context manager.

No ROS at import; ``rosgraph`` is imported by :class:`Roscore` only.
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import threading
import time
from typing import Any, Dict, Iterable, List, Optional, Tuple


def exit_code(status: int) -> int:
    """A ``wait`` status as Popen's returncode: the exit code, or -N for signal N."""
    if os.WIFEXITED(status):
        return os.WEXITSTATUS(status)
    if os.WIFSIGNALED(status):
        return -os.WTERMSIG(status)
    return -1


def signal_group(p: subprocess.Popen, sig: int) -> None:
    """``sig`` to ``p``'s process group (its session: :func:`start_group`); a group already gone
    is no error."""
    try:
        os.killpg(p.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def reap(p: subprocess.Popen, block: bool) -> Optional[Tuple[int, Any]]:
    """(exit code, rusage or None) once ``p`` has ended, None while it runs. ``wait4`` gives the
    process's own CPU time (its rusage); a process reaped before gives no rusage."""
    if p.returncode is not None:
        return p.returncode, None
    try:
        pid, status, ru = os.wait4(p.pid, 0 if block else os.WNOHANG)
    except ChildProcessError:
        p.returncode = p.returncode if p.returncode is not None else -1
        return p.returncode, None
    if pid == 0:
        return None
    p.returncode = exit_code(status)
    return p.returncode, ru


def start_group(cmd: List[str], log_path: str, env: Optional[Dict[str, str]] = None,
                cwd: Optional[str] = None, append: bool = True) -> subprocess.Popen:
    """``cmd`` in a session of its own (stopped as a group), its stdout and stderr into
    ``log_path`` (appended, or truncated with ``append`` False), no stdin; in ``cwd``, by
    default the log's directory (MRPT's aligner writes debug images into its working one)."""
    with open(log_path, 'ab' if append else 'wb') as log:
        return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                env=env, start_new_session=True,
                                cwd=cwd or os.path.dirname(os.path.abspath(log_path)))


def stop_group(p: Optional[subprocess.Popen], grace: float = 10.0, first: int = signal.SIGINT) -> Optional[int]:
    """Stop ``p`` and its group: ``first`` (SIGINT: roscore and roslaunch stop their children)
    to the group, SIGKILL to what is left of it after ``grace`` s (also once its leader ended:
    a child may linger). Returns its exit code (None for no process)."""
    if p is None:
        return None
    if p.returncode is None:
        signal_group(p, first)
        end = time.time() + grace
        while time.time() < end and reap(p, False) is None:
            time.sleep(0.1)
    signal_group(p, signal.SIGKILL)
    reap(p, True)
    return p.returncode


class Processes:
    """The processes a run started (:meth:`start`), stopped at its end by :meth:`stop_all`, which
    also refuses new ones from then on (worker threads may still try)."""

    def __init__(self) -> None:
        self._procs: List[subprocess.Popen] = []
        self._lock = threading.Lock()
        self.stopping = threading.Event()

    def start(self, cmd: List[str], log_path: str, env: Optional[Dict[str, str]] = None,
              cwd: Optional[str] = None) -> subprocess.Popen:
        if self.stopping.is_set():
            raise RuntimeError('stopping')
        p = start_group(cmd, log_path, env, cwd)
        with self._lock:
            self._procs.append(p)
        return p

    def stop(self, p: subprocess.Popen, grace: float = 10.0) -> None:
        stop_group(p, grace)
        with self._lock:
            if p in self._procs:
                self._procs.remove(p)

    def stop_all(self, grace: float = 5.0) -> None:
        self.stopping.set()
        with self._lock:
            procs = list(reversed(self._procs))
        for p in procs:
            self.stop(p, grace)

    def run_timed(self, cmd: List[str], log_path: str, env: Optional[Dict[str, str]],
                  timeout: float) -> Dict[str, Any]:
        """Run ``cmd`` to its end (or ``timeout`` s, or until :meth:`stop_all`), then stop what
        is left of its group: {'rc', 'wall_s', 'cpu_s' (its own, from wait4), 'timed_out'}."""
        t0 = time.time()
        p = self.start(cmd, log_path, env)
        rc, ru, timed_out = None, None, False
        while True:
            r = reap(p, False)
            if r is not None:
                rc, ru = r
                break
            if time.time() - t0 > timeout or self.stopping.is_set():
                timed_out = not self.stopping.is_set()
                break
            time.sleep(0.2)
        self.stop(p, grace=5.0)
        if rc is None:
            rc = p.returncode if p.returncode is not None else -1
        cpu = (ru.ru_utime + ru.ru_stime) if ru is not None else None
        return {'rc': rc, 'wall_s': round(time.time() - t0, 1), 'cpu_s': None if cpu is None else round(cpu, 1),
                'timed_out': timed_out}


# ------------------------------------------------------------------------------ ports

_given: set = set()
_given_lock = threading.Lock()


def port_free(port: int, host: str = '127.0.0.1') -> bool:
    """Nothing bound to ``port`` on ``host`` nor listening there."""
    with socket.socket() as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex((host, port)) != 0


def free_port(ports: Optional[Iterable[int]] = None) -> int:
    """A free port of ``ports`` (default: one the system picks) not handed out before by this
    process and not given back (:func:`release_port`). RuntimeError when none is free."""
    with _given_lock:
        if ports is None:
            with socket.socket() as s:
                s.bind(('127.0.0.1', 0))
                port = int(s.getsockname()[1])
            _given.add(port)
            return port
        tried = []
        for port in ports:
            tried.append(port)
            if port not in _given and port_free(port):
                _given.add(port)
                return port
    raise RuntimeError('no free port in %s-%s' % (tried[0], tried[-1]) if tried else 'no port to try')


def release_port(port: Optional[int]) -> None:
    """``port`` may be handed out again by :func:`free_port`."""
    with _given_lock:
        _given.discard(port)


# ------------------------------------------------------------------------------ roscore

def ros_env(base: Dict[str, str], port: int, ros_home: str) -> Dict[str, str]:
    """``base`` with a master of our own on the loopback at ``port`` (works where the machine's
    hostname does not resolve), ROS_HOME and its logs under ``ros_home``."""
    env = dict(base, ROS_MASTER_URI='http://127.0.0.1:%d' % port, ROS_IP='127.0.0.1', ROS_HOME=ros_home,
               ROS_LOG_DIR=os.path.join(ros_home, 'log'))
    env.pop('ROS_HOSTNAME', None)
    return env


class Roscore:
    """A roscore of our own on the first free port from ``base`` (within ``span`` ports), its
    output into ``log_path``; a context manager: ``env`` is the environment of its clients,
    ``master`` a ``rosgraph.Master`` on it. ``procs``: the :class:`Processes` it is started in
    (stopped with them), default a set of its own."""

    def __init__(self, base: int, log_path: str, ros_home: str, env: Optional[Dict[str, str]] = None,
                 procs: Optional[Processes] = None, span: int = 100, timeout: float = 60.0):
        self.base, self.span, self.log_path, self.ros_home = base, span, log_path, ros_home
        self.base_env = dict(os.environ if env is None else env)
        self.procs = procs or Processes()
        self.timeout = timeout
        self.port: Optional[int] = None
        self.proc: Optional[subprocess.Popen] = None

    def __enter__(self) -> 'Roscore':
        self.port = free_port(range(self.base, self.base + self.span))
        self.uri = 'http://127.0.0.1:%d' % self.port
        self.env = ros_env(self.base_env, self.port, self.ros_home)
        self.proc = self.procs.start(['roscore', '-p', str(self.port)], self.log_path, self.env)
        import rosgraph
        master = rosgraph.Master('/bench', master_uri=self.uri)
        end = time.time() + self.timeout
        while True:
            try:
                master.getPid()
                break
            except Exception:                    # noqa: BLE001 (not up yet: any error of the call)
                if time.time() > end or self.proc.poll() is not None:
                    self.__exit__(None, None, None)
                    raise RuntimeError('roscore did not start on port %d (see %s)'
                                       % (self.port, self.log_path)) from None
                time.sleep(0.3)
        self.master = master
        return self

    def set_params(self, params: Dict[str, Any]) -> None:
        for k, v in params.items():
            self.master.setParam(k, v)

    def __exit__(self, *exc) -> None:
        if self.proc is not None:
            self.procs.stop(self.proc)
        release_port(self.port)
