"""What the parts of ``make accuracy`` share (bench/accuracy.py and its modules): the worlds, the
team, the SLAMs and their settings, the run's arguments (``ARGS``, set by accuracy.main) and
peers, its printed lines, its processes and roscores (through ``multi_map_merge.lab.processes``,
the benchmarks' one helper for them) and its scheduler of heavy steps."""
from __future__ import annotations

import heapq
import os
import sys
import threading
import time
import traceback
from typing import Any, Callable, Dict, List, Optional, Tuple

from accuracy_summary import Invalid

from multi_map_merge.lab import processes
from multi_map_merge.lab.worlds import AWS_SMALL_HOUSE_FILES

# one thread each for Open3D's ICP and OpenCV: the two job slots are the CPU budget
os.environ.setdefault('OMP_NUM_THREADS', '1')

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
SHARED = os.path.abspath(os.path.join(REPO, '..', 'shared'))

WORLDS = {
    # written into --work by main() (a map drawn by our code has no file of its own)
    'home': ('', "the project's own home (lab/home.py, 119 m2 of free floor)"),
    'house': (os.path.join(SHARED, 'data', AWS_SMALL_HOUSE_FILES[0]),
              'AWS small house (../shared/data/aws/small_house/map.yaml, about 160 m2)'),
    'intel': (os.path.join(SHARED, 'data', 'ground_truth', 'intel_gt.yaml'),
              'Intel lab (../shared/data/ground_truth/intel_gt.yaml, 28x28 m)'),
}
TEAM = ['tb3_0', 'tb3_1', 'tb3_2', 'tb3_3']
SINGLE = 'single'
# the SLAMs a run can map with (--slam; default rbpf): the replayer (every scan of a bag, the
# same flags), the node name its private parameters are under, the settings for the Turtlebot3s,
# its cache directory under --work, the name printed
SLAMS: Dict[str, Dict[str, str]] = {
    'rbpf': {'package': 'multi_map_merge', 'replay': 'rbpf_slam_replay', 'node': 'rbpf_slam',
             'config': os.path.join(REPO, 'config', 'rbpf_lds02.yaml'), 'cache': 'rbpf_slam',
             'label': 'rbpf_slam'},
    'gmapping': {'package': 'gmapping', 'replay': 'slam_gmapping_replay', 'node': 'slam_gmapping',
                 'config': os.path.join(REPO, 'config', 'gmapping_lds02.yaml'), 'cache': 'gmapping',
                 'label': 'gmapping'},
}
DEFAULT_SLAM = 'rbpf'
# the files whose code makes the bags (a change remakes them)
SIM_SOURCES = [os.path.join(REPO, 'src', 'multi_map_merge', p) for p in
               ('lab/simulate.py', 'lab/robot_bags.py', 'lab/drives.py', 'ros/replay.py', 'lab/home.py',
                'lab/worlds.py')]
# (the gmapping maps are keyed by what the bags hold, not by these: bags remade alike keep them)
BAG_ARGS = ['--robots', '4', '--sensors-only']
MRPT_TOOL = os.path.join(HERE, 'mrpt_merge.py')      # MRPT's aligner, the project's own driver
MEXPLORE_TOOL = os.path.join(HERE, 'peer.py')        # m-explore's node, where installed
NICENESS = 10   # of this process and so of everything it starts (they inherit it)
# the address space each SLAM run may take (GiB; SLAM_MEMORY_GB, 0: no limit): the machine is shared,
# and a run whose particles' grids outgrow it fails alone (INVALID, naming the limit) instead of
# waking the kernel's OOM killer
SLAM_MEMORY_GB = float(os.environ.get('SLAM_MEMORY_GB', '4'))
PY = '/usr/bin/python3' if os.path.exists('/usr/bin/python3') else sys.executable

_print_lock = threading.Lock()
_out_lines: List[str] = []


def say(*lines: str) -> None:
    """Print lines at once (worker threads print too) and keep them for accuracy.txt."""
    with _print_lock:
        for ln in lines:
            print(ln, flush=True)
            _out_lines.append(ln)


def stamp() -> str:
    return time.strftime('%H:%M:%S')


# the run's state: set by accuracy.main (bend_sweep.main sets ARGS too)
ARGS: Any = None
PEERS: Dict[str, Optional[str]] = {}
T_START = time.time()


def _no_results() -> None:
    """WRITE_RESULTS before accuracy.main sets it (bend_sweep writes its own)."""


WRITE_RESULTS: Callable[[], Any] = _no_results     # accuracy.write_results once main runs


# ------------------------------------------------------------------------------ processes

PROCS = processes.Processes()      # everything the run starts, stopped on its exit


def child_env(**extra: str) -> Dict[str, str]:
    env = dict(os.environ)
    env['PATH'] = '/usr/bin:/bin:' + env.get('PATH', '')
    env['PYTHONPATH'] = os.path.join(REPO, 'src') + (':' + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
    env['PYTHONUNBUFFERED'] = '1'
    env.setdefault('ROS_IP', '127.0.0.1')
    env.pop('ROS_HOSTNAME', None)
    env.update(extra)
    return env


def run_timed(cmd: List[str], log_path: str, env: Dict[str, str], timeout: float) -> Dict[str, Any]:
    """Run ``cmd`` to its end (or ``timeout`` s): exit code, wall and CPU seconds
    (``processes.Processes.run_timed``)."""
    return PROCS.run_timed(cmd, log_path, env, timeout)


def stop_all() -> None:
    PROCS.stop_all()


class Roscore(processes.Roscore):
    """A roscore of our own on a free port of ``base``..``base`` + 99, stopped with the run."""

    def __init__(self, base: int, log_path: str, ros_home: str):
        super().__init__(base, log_path, ros_home, env=child_env(), procs=PROCS)


# ------------------------------------------------------------------------------ scheduling

def slam_job(case: Any, robot: str, slam: str, left: Dict[str, int], then: Callable[[], None]) -> Callable[[], None]:
    """A scheduler job: ``case.gmapping(robot)``, ``case``'s SLAM run for one robot. A run that
    fails leaves that robot's map INVALID with why (``case.gm[robot]``, under ``case.lock``); the
    last of the case's ``left['n']`` SLAM jobs to end calls ``then`` (not while the run stops)."""
    def job() -> None:
        try:
            case.gmapping(robot)
        except Exception as e:                # noqa: BLE001 (the case says INVALID and why)
            if not PROCS.stopping.is_set():
                traceback.print_exc()
            with case.lock:
                case.gm[robot] = {'invalid': '%s run failed: %s: %s' % (SLAMS[slam]['label'], type(e).__name__, e)}
        with case.lock:
            left['n'] -= 1
            last = left['n'] == 0
        if last and not PROCS.stopping.is_set():
            then()
    return job


class Scheduler:
    """At most ``jobs`` jobs at a time, the ready one of the earliest condition first."""

    def __init__(self) -> None:
        self.cv = threading.Condition()
        self.ready: List[Tuple[Tuple[int, int], int, Callable[[], None]]] = []
        self.pending = 0
        self.seq = 0

    def submit(self, prio: Tuple[int, int], fn: Callable[[], None]) -> None:
        with self.cv:
            heapq.heappush(self.ready, (prio, self.seq, fn))
            self.seq += 1
            self.pending += 1
            self.cv.notify()

    def _worker(self) -> None:
        while True:
            with self.cv:
                while not self.ready and self.pending > 0:
                    self.cv.wait(1.0)
                if self.pending == 0 or PROCS.stopping.is_set():
                    return
                _, _, fn = heapq.heappop(self.ready)
            try:
                fn()
            except Exception:                     # noqa: BLE001 (each job records its own failure)
                if not PROCS.stopping.is_set():
                    traceback.print_exc()
            finally:
                with self.cv:
                    self.pending -= 1
                    self.cv.notify_all()

    def run(self, jobs: int) -> None:
        threads = [threading.Thread(target=self._worker, daemon=True) for _ in range(jobs)]
        for t in threads:
            t.start()
        while any(t.is_alive() for t in threads):
            for t in threads:
                t.join(0.5)




def _json_default(o):
    if isinstance(o, Invalid):
        return {'invalid': o.reason}
    try:
        import numpy as np
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
    except ImportError:
        pass
    return str(o)
