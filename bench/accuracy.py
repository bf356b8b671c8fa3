#!/usr/bin/env python3
"""The paper's experiment as a benchmark: four Turtlebot3s merged vs one robot alone (Table 1's
Fitness), over several seeds and worlds, every map made by a real SLAM: rbpf_slam (ours, over
MRPT's Rao-Blackwellized particle filter, the algorithm gmapping implements) or gmapping.

    python3 bench/accuracy.py [--seeds 5] [--first-seed 1] [--worlds home,intel] [--quick]
                              [--slam rbpf|gmapping] [--work /tmp/mmm_accuracy] [--jobs 2] [--port 12500]

For every world and seed:

1. ``make_robot_bags --world W --seed S --robots 4 --sensors-only``: four Burgers (LDS-02) that
   start together and explore different regions (``team.bag``: scans, odometry and their TF
   only) and one robot exploring it all alone (``team_single.bag``), with the truth file;
2. one SLAM run per robot, team robots and the lone robot: ``--slam rbpf`` (the default):
   ``rbpf_slam_replay --bag_filename BAG --scan_topic /tb3_k/scan --seed S`` (built by ``make
   build`` into the workspace) with config/rbpf_lds02.yaml (the Turtlebot3 LDS-02 settings under
   gmapping's names) as ``/rbpf_slam/...``; ``--slam gmapping``: ``slam_gmapping_replay``, the same
   flags, with config/gmapping_lds02.yaml as ``/slam_gmapping/...``, where ROS has gmapping
   (elsewhere every row says INVALID and why). Either with the robot's frames
   (``tb3_k/base_footprint``, ``tb3_k/odom``, ``tb3_k/map``). The replayer reads the bag itself and
   drops no scan; each run has its own roscore on a free port (from ``--port``) and, when the bag
   is read, saves its latched last ``/map`` (``scripts/save_map``) through ``--on_done``. Printed
   per robot: the scans in its bag, the scans the SLAM processed (its ``update frame`` lines) and
   its CPU seconds;
3. scored against the world's ground truth (``lab/evaluate.py``: the paper's Fitness, Open3D ICP
   at 0.10 m): the single robot's map, our ``merge_maps`` on the four final maps, each robot's map
   alone (mean), the **rigid bound** (every robot's map placed at its own map's best fit to the
   truth and composited as ``merge_maps`` composites: what a merge that places every robot
   perfectly, rigidly, could reach), and m-explore's and MRPT's merges of the same four maps.
   MRPT: ``bench/mrpt_merge.py`` (its CGridMapAligner through the project's own driver, built
   on first use); its transforms composited the same way, so that only the placements differ
   between the merge rows; robots it did not merge are left out, and how many it merged is
   printed. m-explore: where its node is installed (ros-noetic-multirobot-map-merge;
   ``bench/peer.py``), its own merged /map (known_init_poses false, the last one 10 s after its
   first) scored as it is (it publishes no placements); elsewhere its row is INVALID: not installed.

Every map is scored from its frame's known start pose (the reference robot's, for a merge) and
from ``best_fit_score``'s eight headings; the best Fitness is kept (a distorted map's ICP from
one coarse pose can stop in a worse local optimum).

Then, per world, the mean and the worst over the seeds; the last line printed is::

    accuracy: N seeds x W worlds; merged mean M, single mean S, own maps mean O, rigid bound mean B; \
worst loss to the rigid bound L

(one line; ``L`` = the largest rigid bound - merged over all seeds and worlds).

A row whose condition was not created (the SLAM missing, a robot's SLAM processed nothing or
saved no map, a peer absent or failed, a merge that failed) says INVALID and why, not a number;
a mean over it is INVALID too.

Bags and SLAM maps are cached under ``--work``: the bags (``bags/WORLD-sSEED-BAGKEY``) keyed
by world, seed, the arguments and the simulator's files; each robot's map
(``rbpf_slam/WORLD-sSEED-content-SHA1``, gmapping's in ``gmapping/...``) by what its bag holds
(``content.json`` beside the bags: a digest of their messages, not of their files;
``bag_content_digest``), the robot, the SLAM, its config and its binary: one SLAM's map is never
taken for the other's. Bags remade alike by changed sources find the maps already made, and so do
gmapping results of the earlier scheme, keyed by the bag key (``resolve_gmapping``: copied, never
deleted). The JSON keeps gmapping's key names for the SLAM's runs (``gmapping``,
``gmapping_cpu_s_sum``, ...); ``args.slam`` says which SLAM made them.
A rerun only merges and scores again (about a minute). It runs at nice 10 (it renices itself; whatever it starts
inherits that), at most ``--jobs`` (2) heavy steps at a time. Everything it starts is stopped on exit, also on Ctrl-C.

The worlds: ``home``, the project's own home (lab/home.py, written into ``--work``), ``house``,
the AWS small house read in place from ../shared/data, ``intel``, the Intel lab of ../shared/data.

Writes bench/results/accuracy.{json,md,txt} (``--quick``: 1 seed, the home only, into
accuracy_quick.*; ``--slam gmapping``: accuracy_gmapping.*, accuracy_quick_gmapping.*). Run it
with Debian's /usr/bin/python3 and the workspace sourced (``make accuracy`` does both).
"""
from __future__ import annotations

import argparse
import hashlib
import heapq
import json
import math
import os
import re
import shlex
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from typing import Any, Callable, Dict, List, Optional, Tuple

# one thread each for Open3D's ICP and OpenCV: the two job slots are the CPU budget
os.environ.setdefault('OMP_NUM_THREADS', '1')

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
SHARED = os.path.abspath(os.path.join(REPO, '..', 'shared'))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(REPO, 'src'))

from accuracy_summary import (  # noqa: E402
    BEND_TOLERANCE,
    ROW_NAMES,
    ROWS,
    STARTS_TOLERANCE,
    Invalid,
    aggregate,
    bend_decision,
    fmt,
    group_reasons,
    is_valid,
    loss,
    markdown,
    mean,
    secs,
    summary_line,
    timeline_lines,
    to_json,
)
from bend_summary import OFF  # noqa: E402

from multi_map_merge.lab.home import write_home_map  # noqa: E402
from multi_map_merge.lab.worlds import AWS_SMALL_HOUSE_FILES  # noqa: E402

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


# ------------------------------------------------------------------------------ processes

_procs: List[subprocess.Popen] = []
_procs_lock = threading.Lock()
_stopping = threading.Event()


def child_env(**extra: str) -> Dict[str, str]:
    env = dict(os.environ)
    env['PATH'] = '/usr/bin:/bin:' + env.get('PATH', '')
    env['PYTHONPATH'] = os.path.join(REPO, 'src') + (':' + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
    env['PYTHONUNBUFFERED'] = '1'
    env.setdefault('ROS_IP', '127.0.0.1')
    env.pop('ROS_HOSTNAME', None)
    env.update(extra)
    return env


def spawn(cmd: List[str], log_path: str, env: Dict[str, str]) -> subprocess.Popen:
    """Start ``cmd`` in a session of its own (stopped as a group), output to ``log_path``, in the
    log's directory (MRPT's aligner writes debug images into its working directory)."""
    if _stopping.is_set():
        raise RuntimeError('stopping')
    with open(log_path, 'ab') as log:
        p = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                             env=env, start_new_session=True, cwd=os.path.dirname(os.path.abspath(log_path)))
    with _procs_lock:
        _procs.append(p)
    return p


def _exitcode(status: int) -> int:
    if os.WIFEXITED(status):
        return os.WEXITSTATUS(status)
    if os.WIFSIGNALED(status):
        return -os.WTERMSIG(status)
    return -1


def _killpg(p: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(p.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def _reap(p: subprocess.Popen, block: bool) -> Optional[Tuple[int, Any]]:
    """(exit code, rusage) once ``p`` has ended, None while it runs (wait4: its CPU time)."""
    if p.returncode is not None:
        return p.returncode, None
    try:
        pid, status, ru = os.wait4(p.pid, 0 if block else os.WNOHANG)
    except ChildProcessError:
        p.returncode = p.returncode if p.returncode is not None else -1
        return p.returncode, None
    if pid == 0:
        return None
    p.returncode = _exitcode(status)
    return p.returncode, ru


def stop(p: subprocess.Popen, grace: float = 10.0) -> None:
    """SIGINT to the process group (roscore stops its children), then SIGKILL; forget it."""
    _killpg(p, signal.SIGINT)
    end = time.time() + grace
    while time.time() < end and _reap(p, False) is None:
        time.sleep(0.1)
    _killpg(p, signal.SIGKILL)   # also what is left of the group once its leader ended
    _reap(p, True)
    with _procs_lock:
        if p in _procs:
            _procs.remove(p)


def stop_all() -> None:
    _stopping.set()
    with _procs_lock:
        procs = list(reversed(_procs))
    for p in procs:
        stop(p, grace=5.0)


def run_timed(cmd: List[str], log_path: str, env: Dict[str, str], timeout: float) -> Dict[str, Any]:
    """Run ``cmd`` to its end (or ``timeout`` s): exit code, wall and CPU seconds."""
    t0 = time.time()
    p = spawn(cmd, log_path, env)
    rc, ru, timed_out = None, None, False
    while True:
        r = _reap(p, False)
        if r is not None:
            rc, ru = r
            break
        if time.time() - t0 > timeout or _stopping.is_set():
            timed_out = not _stopping.is_set()
            break
        time.sleep(0.2)
    stop(p, grace=5.0)           # the rest of its group (and itself after a timeout)
    if rc is None:
        rc = p.returncode if p.returncode is not None else -1
    cpu = (ru.ru_utime + ru.ru_stime) if ru is not None else None
    return {'rc': rc, 'wall_s': round(time.time() - t0, 1), 'cpu_s': None if cpu is None else round(cpu, 1),
            'timed_out': timed_out}


# ------------------------------------------------------------------------------ roscore

_ports_lock = threading.Lock()
_ports_used: set = set()


def _port_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(('127.0.0.1', port))
        except OSError:
            return False
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex(('127.0.0.1', port)) != 0


class Roscore:
    """A roscore of our own on a free port from ``base``; a context manager."""

    def __init__(self, base: int, log_path: str, ros_home: str):
        self.base, self.log_path, self.ros_home = base, log_path, ros_home
        self.port = None
        self.proc = None

    def __enter__(self) -> 'Roscore':
        with _ports_lock:
            port = self.base
            while port in _ports_used or not _port_free(port):
                port += 1
            _ports_used.add(port)
        self.port = port
        self.uri = 'http://127.0.0.1:%d' % port
        self.env = child_env(ROS_MASTER_URI=self.uri, ROS_HOME=self.ros_home,
                             ROS_LOG_DIR=os.path.join(self.ros_home, 'log'))
        self.proc = spawn(['roscore', '-p', str(port)], self.log_path, self.env)
        import rosgraph
        master = rosgraph.Master('/accuracy', master_uri=self.uri)
        end = time.time() + 60
        while True:
            try:
                master.getPid()
                break
            except Exception:
                if time.time() > end or self.proc.poll() is not None:
                    self.__exit__(None, None, None)
                    raise RuntimeError('roscore did not start on port %d (see %s)' % (port, self.log_path)) from None
                time.sleep(0.3)
        self.master = master
        return self

    def set_params(self, params: Dict[str, Any]) -> None:
        for k, v in params.items():
            self.master.setParam(k, v)

    def __exit__(self, *exc) -> None:
        if self.proc is not None:
            stop(self.proc)
        with _ports_lock:
            _ports_used.discard(self.port)


# ------------------------------------------------------------------------------ cache keys

def file_digest(path: str) -> str:
    h = hashlib.sha1()
    with open(path, 'rb') as f:
        for chunk in iter(lambda: f.read(1 << 20), b''):
            h.update(chunk)
    return h.hexdigest()


def world_digest(yaml_path: str) -> str:
    import yaml
    with open(yaml_path) as f:
        meta = yaml.safe_load(f)
    img = meta['image'] if os.path.isabs(meta['image']) else os.path.join(os.path.dirname(yaml_path), meta['image'])
    return hashlib.sha1((file_digest(yaml_path) + file_digest(img)).encode()).hexdigest()


def key_of(doc: Dict[str, Any]) -> str:
    return hashlib.sha1(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:10]


def replay_binary(slam: str = DEFAULT_SLAM) -> Optional[str]:
    """The replayer of ``slam`` (SLAMS) that ROS finds: rbpf_slam_replay of our workspace
    (``make build``), or slam_gmapping_replay of a gmapping ROS has (an overlay or the system's);
    None when there is none."""
    s = SLAMS[slam]
    for p in os.environ.get('CMAKE_PREFIX_PATH', '').split(':') + ['/opt/ros/noetic']:
        exe = os.path.join(p, 'lib', s['package'], s['replay'])
        if p and os.access(exe, os.X_OK):
            return exe
    return None


def slam_missing(slam: str) -> str:
    """Why ``slam`` cannot run here (its replayer was not found): one line for an INVALID row."""
    if slam == 'gmapping':
        return ('gmapping missing: ROS here has no gmapping (no lib/gmapping/slam_gmapping_replay under '
                'CMAKE_PREFIX_PATH or /opt/ros/noetic; its source is gone and Debian has no package, '
                'issue 47): use --slam rbpf')
    return ('rbpf_slam missing: no lib/multi_map_merge/rbpf_slam_replay under CMAKE_PREFIX_PATH '
            '(make build builds it; source the workspace)')


def bag_scans(bag: str, topic: str) -> int:
    import rosbag
    with rosbag.Bag(bag) as b:
        info = b.get_type_and_topic_info().topics.get(topic)
    return int(info.message_count) if info is not None else 0


def read_json(path: str) -> Optional[Any]:
    """The JSON document in ``path``, None when it is absent or unreadable."""
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def write_json(path: str, doc: Any) -> None:
    """``doc`` into ``path`` at once (a file of this process and thread, then renamed): a reader
    sees the whole file or none."""
    tmp = '%s.tmp-%d-%d' % (path, os.getpid(), threading.get_ident())
    with open(tmp, 'w') as f:
        json.dump(doc, f, indent=1)
    os.replace(tmp, path)


def cached_bags(d: str) -> Optional[Dict[str, Any]]:
    """What ``make_bags_dir`` recorded of the bags in ``d`` (its ok.json), None when not made.
    ``make_bags_dir`` writes into a directory of its own and renames it to ``d`` only once the
    bags are made and ok.json is written, so a ``d`` whose bags are being written or whose make
    failed does not exist (or has no ok.json): None."""
    done = read_json(os.path.join(d, 'ok.json'))
    return done if isinstance(done, dict) else None


def make_bags_dir(d: str, doc: Dict[str, Any], cmd_for: Callable[[str], List[str]],
                  timeout: float = 3600) -> Dict[str, Any]:
    """Run ``make_robot_bags`` (``cmd_for(directory)``: its command writing team.bag there) into
    a directory of its own (``d``.tmp-XXXX: two runs making the same bags do not share one),
    record ``doc`` (args.json) and its times (ok.json), then rename it to ``d``: {'wall_s',
    'cpu_s'}. When another run made ``d`` meanwhile, its bags are kept and this copy dropped; an
    incomplete ``d`` (no ok.json) is set aside (``d``.incomplete-TIME), not deleted. Raises
    RuntimeError with the log's tail when it fails (its directory is left for the log)."""
    parent = os.path.dirname(d)
    os.makedirs(parent, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix=os.path.basename(d) + '.tmp-', dir=parent)
    os.chmod(tmp, 0o755)
    r = run_timed(cmd_for(tmp), os.path.join(tmp, 'make_robot_bags.log'), child_env(), timeout)
    if r['rc'] != 0 or not os.path.exists(os.path.join(tmp, 'team.truth.yaml')):
        with open(os.path.join(tmp, 'make_robot_bags.log')) as f:
            tail = f.read()[-600:]
        raise RuntimeError('make_robot_bags failed (exit %s, in %s): %s' % (r['rc'], tmp, tail))
    with open(os.path.join(tmp, 'args.json'), 'w') as f:
        json.dump(doc, f, indent=1)
    with open(os.path.join(tmp, 'ok.json'), 'w') as f:
        json.dump({'wall_s': r['wall_s'], 'cpu_s': r['cpu_s']}, f)
    if os.path.exists(d) and cached_bags(d) is None:
        os.replace(d, '%s.incomplete-%s' % (d, time.strftime('%Y%m%dT%H%M%S')))
    try:
        os.replace(tmp, d)
    except OSError:
        if cached_bags(d) is None:
            raise
        shutil.rmtree(tmp, ignore_errors=True)   # another run made these bags first: its copy is kept
    return r


# ------------------------------------------------------------------------------ a bag's content

CONTENT_FILE = 'content.json'
BAG_FILES = ('team.bag', 'team_single.bag')
_content_lock = threading.Lock()


def bag_content_digest(path: str) -> Dict[str, Any]:
    """The digest of what ``path`` (a bag) holds, not of its file: sha1 over every message, in the
    order ``read_messages`` gives them, of its topic, its receive time (ns), its type (name and
    md5) and its serialised bytes (``raw=True``: not deserialised). The file's own layout (chunk
    size, compression, index, when it was written) does not change it. {'sha1', 'messages',
    'seconds'} (the time the digest took)."""
    import rosbag
    t0 = time.time()
    h = hashlib.sha1()
    n = 0
    with rosbag.Bag(path) as b:
        for topic, raw, t in b.read_messages(raw=True):
            datatype, data, md5sum = raw[0], raw[1], raw[2]
            head = '%s\0%s\0%s\0' % (topic, datatype, md5sum)
            h.update(head.encode())
            h.update(struct.pack('<qQ', t.to_nsec(), len(data)))
            h.update(data)
            n += 1
    return {'sha1': h.hexdigest(), 'messages': n, 'seconds': round(time.time() - t0, 2)}


def _stat_of(path: str) -> List[int]:
    st = os.stat(path)
    return [st.st_size, st.st_mtime_ns]


def bag_contents(d: str, names: Tuple[str, ...] = BAG_FILES,
                 digest: Callable[[str], Dict[str, Any]] = bag_content_digest,
                 log: Optional[Callable[[str], None]] = None) -> Optional[Dict[str, Dict[str, Any]]]:
    """The content digests of the bags ``names`` of the bag directory ``d`` (``bag_content_digest``):
    {name: {'sha1', 'messages', 'seconds', 'stat'}}, kept in ``d``/content.json. A digest is made
    once per bag, when it is missing there or the bag's file changed since (its size and mtime,
    'stat'), and ``log`` is told how long it took. None for a directory whose bags are not
    complete (no ok.json: being made, or their make failed): its bags are not read."""
    if cached_bags(d) is None:
        return None
    with _content_lock:                    # one digest of a bag at a time, also across a condition's threads
        path = os.path.join(d, CONTENT_FILE)
        doc = read_json(path)
        doc = doc if isinstance(doc, dict) else {}
        made = []
        for name in names:
            bag = os.path.join(d, name)
            if not os.path.exists(bag):
                continue
            have = doc.get(name)
            if isinstance(have, dict) and have.get('sha1') and have.get('stat') == _stat_of(bag):
                continue
            got = dict(digest(bag))
            got['stat'] = _stat_of(bag)
            doc[name] = got
            made.append(name)
        if made:
            write_json(path, doc)
            if log is not None:
                log('bag contents digested (%s): %s' % (path, ', '.join(
                    '%s %d messages in %.1f s' % (n, doc[n].get('messages', -1), doc[n].get('seconds', float('nan')))
                    for n in made)))
        return {n: doc[n] for n in names if n in doc}


# ------------------------------------------------------------------------------ SLAM results by content
# (the functions keep gmapping's names: gmapping_dir, resolve_gmapping, run_gmapping's results)

GMAPPING_FILES = ('.yaml', '.pgm', '.log', '.core.log')


def slam_of(doc: Dict[str, Any]) -> str:
    """The SLAM a run's key document names; a document without 'slam' (written before rbpf_slam
    existed) is gmapping's."""
    return str(doc.get('slam', 'gmapping'))


def gmapping_dir(work: str, world: str, seed: int, content: str, slam: str = 'gmapping') -> str:
    """Where the runs of ``slam`` on a bag of this content (its sha1, ``bag_contents``) are kept:
    ``work``/CACHE/WORLD-sSEED-content-SHA1 (CACHE: ``gmapping`` or ``rbpf_slam``, SLAMS; SHA1 its
    first 12 hex digits; an old-scheme gmapping directory is named WORLD-sSEED-BAGKEY)."""
    return os.path.join(work, SLAMS[slam]['cache'], '%s-s%d-content-%s' % (world, seed, content[:12]))


def _same_run(args: Any, doc: Dict[str, Any]) -> bool:
    """``args`` (a result's key document) and ``doc`` name the same run but for its 'bag' (an
    old-scheme bag key there, a content digest here): the same SLAM (``slam_of``), robot, topic,
    seed, config and binary."""
    if not isinstance(args, dict):
        return False

    def run(d):
        out = {k: v for k, v in d.items() if k != 'bag'}
        out['slam'] = slam_of(d)
        return out
    return run(args) == run(doc)


def old_scheme_results(work: str, world: str, seed: int, robot: str, bag_file: str, content: str,
                       doc: Dict[str, Any], digest: Callable[[str], Dict[str, Any]] = bag_content_digest,
                       log: Optional[Callable[[str], None]] = None) -> List[Tuple[str, Dict[str, Any]]]:
    """The gmapping results of the OLD scheme (keyed by the bag key, the digest of the simulator's
    sources) that belong to this content: [(prefix, meta)], usable first. The rule: a result
    ``gmapping/WORLD-sSEED-BAGKEY/ROBOT.json`` whose key document's 'bag' is BAGKEY (the name of
    its directory), whose key is that document's, and whose run is this one but for the bag (robot,
    topic, seed, gmapping config and binary), was made from ``bags/WORLD-sSEED-BAGKEY/BAG_FILE``;
    it belongs to that bag's content (``bag_contents``: read only from a complete bag directory,
    digested once). A result whose bag directory is gone cannot be placed and is not used. Only
    gmapping has results of the old scheme (``doc``'s SLAM, ``slam_of``): for rbpf_slam, []."""
    if slam_of(doc) != 'gmapping':
        return []
    gm_root, bag_root = os.path.join(work, 'gmapping'), os.path.join(work, 'bags')
    if not os.path.isdir(gm_root):
        return []
    name_re = re.compile(r'^%s-s%d-([0-9a-f]{10})$' % (re.escape(world), seed))
    found = []
    for name in sorted(os.listdir(gm_root)):
        m = name_re.match(name)
        if not m:
            continue
        bag_key = m.group(1)
        prefix = os.path.join(gm_root, name, robot)
        meta = read_json(prefix + '.json')
        if not isinstance(meta, dict) or not isinstance(meta.get('args'), dict):
            continue
        args = meta['args']
        if args.get('bag') != bag_key or meta.get('key') != key_of(args) or not _same_run(args, doc):
            continue
        contents = bag_contents(os.path.join(bag_root, name), (bag_file,), digest, log)
        if not contents or contents.get(bag_file, {}).get('sha1') != content:
            continue
        found.append((prefix, meta))
    # a complete result first (a map saved), then the newest
    found.sort(key=lambda pm: (not pm[1].get('invalid') and os.path.exists(pm[0] + '.yaml'),
                               os.path.getmtime(pm[0] + '.json')), reverse=True)
    return found


def _set_aside(prefix: str, key: Any) -> None:
    """A stale result at ``prefix`` (another gmapping key: another config or binary) moved to
    ``stale-KEY/`` beside it rather than deleted."""
    aside = os.path.join(os.path.dirname(prefix), 'stale-%s' % key)
    os.makedirs(aside, exist_ok=True)
    for ext in ('.json',) + GMAPPING_FILES:
        if os.path.exists(prefix + ext):
            os.replace(prefix + ext, os.path.join(aside, os.path.basename(prefix) + ext))


def resolve_gmapping(work: str, world: str, seed: int, robot: str, bag_file: str, content: str,
                     doc: Dict[str, Any], digest: Callable[[str], Dict[str, Any]] = bag_content_digest,
                     log: Optional[Callable[[str], None]] = None) -> Tuple[str, Optional[Dict[str, Any]]]:
    """Where ``robot``'s SLAM run (gmapping's or rbpf_slam's: ``doc``'s 'slam', ``slam_of``) on the
    bag ``bag_file`` of this content (``doc``: its key document, 'bag' = ``content``) is kept, and
    its result when there is one: (prefix, meta or None: to be run). The key document names the
    SLAM and its binary, and each SLAM has a directory of its own: one SLAM's result is never
    taken for the other's. Looked for in the content's directory (``gmapping_dir``), then among the
    old scheme's results (``old_scheme_results``): one found there is copied into the content's
    directory with its key rewritten (the new key, 'migrated_from' naming where it came from), so
    that every bag directory of this content, the old-named ones and ones remade by new sources,
    finds this one result. Nothing is deleted: the old result stays where it was (a run of the old
    code still finds it) and a stale result in the content's directory is set aside."""
    key = key_of(doc)
    d = gmapping_dir(work, world, seed, content, slam_of(doc))
    os.makedirs(d, exist_ok=True)
    prefix = os.path.join(d, robot)
    meta = read_json(prefix + '.json')
    if isinstance(meta, dict) and meta.get('key') == key:
        meta.update(map=prefix + '.yaml', log=prefix + '.log', cached=True)
        return prefix, meta
    olds = old_scheme_results(work, world, seed, robot, bag_file, content, doc, digest, log)
    if os.path.exists(prefix + '.json'):
        _set_aside(prefix, meta.get('key') if isinstance(meta, dict) else 'unreadable')
    if not olds:
        return prefix, None
    old_prefix, old = olds[0]
    for ext in GMAPPING_FILES:
        if os.path.exists(old_prefix + ext):
            shutil.copy2(old_prefix + ext, prefix + ext)
    new = dict(old)
    new.pop('cached', None)
    new.update(key=key, args=doc, map=prefix + '.yaml', log=prefix + '.log',
               migrated_from={'meta': old_prefix + '.json', 'key': old.get('key'), 'bag_key': old['args'].get('bag')})
    write_json(prefix + '.json', new)        # last: its presence means the result is complete
    new['cached'] = True
    new['migrated_now'] = True
    return prefix, new


def run_gmapping(exe: str, bag: str, topic: str, name: str, seed: int, config: str, prefix: str,
                 head: Dict[str, Any], timeout: float, port: int, ros_home: str,
                 extra_params: Optional[Dict[str, Any]] = None, slam: str = 'gmapping',
                 snapshot_every: Optional[float] = None) -> Dict[str, Any]:
    """One real SLAM run: ``exe`` (``slam``'s replayer, SLAMS: rbpf_slam_replay or
    slam_gmapping_replay, the same flags) on ``topic`` of ``bag`` with the settings of ``config``
    (gmapping's parameter names; ``extra_params`` over it) under the node's name and ``name``'s
    frames, in a roscore of its own (a free port from ``port``), saving its last map to
    ``prefix``.yaml (``scripts/save_map``). Returns ``head`` + what it did (scans in the bag,
    processed, for rbpf_slam those without TF, exit code, times, map), with ``invalid`` naming why
    when it made no usable map; written to ``prefix``.json last (its presence means the run is
    complete)."""
    label, node = SLAMS[slam]['label'], SLAMS[slam]['node']
    for ext in ('.yaml', '.pgm', '.log', '.json', '.core.log'):
        if os.path.exists(prefix + ext):
            os.remove(prefix + ext)
    meta_path = prefix + '.json'
    scans = bag_scans(bag, topic)
    import yaml
    with open(config) as f:
        settings = dict(yaml.safe_load(f) or {})
    settings.update(extra_params or {})
    params = {'/%s/%s' % (node, k): v for k, v in settings.items()}
    params.update({'/%s/base_frame' % node: '%s/base_footprint' % name,
                   '/%s/odom_frame' % node: '%s/odom' % name,
                   '/%s/map_frame' % node: '%s/map' % name})
    on_done = ' '.join(shlex.quote(x) for x in [PY, os.path.join(REPO, 'scripts', 'save_map'),
                                                '-f', prefix, '--topic', '/map', '--timeout', '60'])
    cmd = [exe, '--bag_filename', bag, '--scan_topic', topic, '--seed', str(seed), '--on_done', on_done]
    snap_dir = prefix + '.snap'
    if os.path.isdir(snap_dir):
        shutil.rmtree(snap_dir)
    if snapshot_every:       # rbpf_slam_replay: the map every S s of bag time, into PREFIX.snap/
        os.makedirs(snap_dir)
        cmd += ['--snapshot_every', '%g' % snapshot_every,
                '--snapshot_prefix', os.path.join(snap_dir, os.path.basename(prefix))]
    prlimit = shutil.which('prlimit')
    if SLAM_MEMORY_GB > 0 and prlimit:
        cmd = [prlimit, '--as=%d' % int(SLAM_MEMORY_GB * (1 << 30)), '--'] + cmd
    with Roscore(port, prefix + '.core.log', ros_home) as core:
        core.set_params(params)
        r = run_timed(cmd, prefix + '.log', core.env, timeout)
    with open(prefix + '.log', errors='replace') as f:
        log = f.read()
    processed = len(re.findall(r'^update frame \d+', log, re.M))
    dropped = log.count('Dropping old scan')
    # rbpf_slam_replay's last line: R scans received, P processed, K without TF
    last = re.findall(r'^rbpf_slam_replay: (\d+) scans received, (\d+) processed, (\d+) without TF', log, re.M)
    meta = dict(head)
    if last:
        meta.update(received=int(last[-1][0]), without_tf=int(last[-1][2]))
    meta.update({'slam': slam, 'name': name, 'bag': bag, 'topic': topic,
                 'scans': scans, 'processed': processed, 'dropped': dropped, 'rc': r['rc'],
                 'wall_s': r['wall_s'], 'cpu_s': r['cpu_s'], 'map': prefix + '.yaml', 'log': prefix + '.log'})
    why = None
    # (MRPT's serialising of a particle's map fails an assertion when its buffer cannot grow)
    oom_sign = next((m for m in ('std::bad_alloc', 'CMemoryStream::resize') if m in log), None)
    out_of_memory = oom_sign is not None or r['rc'] == -9
    if out_of_memory:
        why = ('%s ran out of memory (exit %s: %s; its limit %s GiB, SLAM_MEMORY_GB) after %d of %d scans (%s)'
               % (label, r['rc'], oom_sign or 'killed', SLAM_MEMORY_GB, processed, scans, prefix + '.log'))
    elif r['timed_out']:
        why = '%s did not finish within %.0f s' % (label, timeout)
    elif processed == 0:
        why = '%s processed no scan of %d (%s)' % (label, scans, prefix + '.log')
    elif r['rc'] != 0:
        why = '%s exited %s (%s)' % (os.path.basename(exe), r['rc'], prefix + '.log')
    elif not os.path.exists(prefix + '.yaml'):
        why = 'no map saved (%s)' % (prefix + '.log')
    if why:
        meta['invalid'] = why
    if not _stopping.is_set() and not out_of_memory:   # (out of memory: tried again next time)
        write_json(meta_path, meta)           # last, at once: its presence means the run is complete
    meta['cached'] = False
    return meta


# ------------------------------------------------------------------------------ peers

def peers_available(build: bool) -> Dict[str, Optional[str]]:
    """peer -> None (usable) or why not. MRPT's driver is built here (``build``), not inside a
    timed merge; m-explore is used only where its node is installed."""
    import mrpt_merge
    import peer
    out: Dict[str, Optional[str]] = {}
    ok, why = peer.available()
    out['mexplore'] = None if ok else why
    ok, why = mrpt_merge.available()
    if ok and build:
        try:
            say('%s accuracy: MRPT driver: %s' % (stamp(), mrpt_merge.binary()))
        except RuntimeError as e:
            ok, why = False, 'MRPT\'s driver did not build: %s' % e
    out['mrpt'] = None if ok else why
    return out


# ------------------------------------------------------------------------------ a condition

class Condition:
    """One world and seed: its bags, its five SLAM runs (``self.gm``), its scores."""

    def __init__(self, index: int, world: str, seed: int):
        self.index, self.world, self.seed = index, world, seed
        self.world_yaml, self.title = WORLDS[world]
        self.lock = threading.Lock()
        self.gm: Dict[str, Dict[str, Any]] = {}
        self.bag: Dict[str, Any] = {}
        self.t_first: Optional[float] = None
        self.t_done: Optional[float] = None
        self.result: Optional[Dict[str, Any]] = None
        self.run_dir = os.path.join(ARGS.work, 'runs', '%s-s%d' % (world, seed))

    @property
    def name(self) -> str:
        return '%s seed %d' % (self.world, self.seed)

    def started(self) -> None:
        with self.lock:
            if self.t_first is None:
                self.t_first = time.time()

    # --- 1. bags
    def make_bags(self) -> None:
        self.started()
        doc = {'world': os.path.abspath(self.world_yaml), 'world_digest': world_digest(self.world_yaml),
               'seed': self.seed, 'args': BAG_ARGS,
               'sources': {os.path.relpath(p, REPO): file_digest(p) for p in SIM_SOURCES if os.path.exists(p)}}
        key = key_of(doc)
        d = os.path.join(ARGS.work, 'bags', '%s-s%d-%s' % (self.world, self.seed, key))
        self.bag = {'dir': d, 'key': key, 'team': os.path.join(d, 'team.bag'),
                    'single': os.path.join(d, 'team_single.bag'), 'truth': os.path.join(d, 'team.truth.yaml')}
        cached = cached_bags(d)
        if cached is not None:
            self.bag.update(cached, cached=True)
            say('%s %s: bags cached (%s)' % (stamp(), self.name, d))
        else:
            say('%s %s: making the bags (make_robot_bags --world %s --seed %d %s) ...'
                % (stamp(), self.name, os.path.relpath(self.world_yaml, REPO), self.seed, ' '.join(BAG_ARGS)))
            r = make_bags_dir(d, doc, lambda tmp: [
                PY, os.path.join(REPO, 'scripts', 'make_robot_bags'), '-o', os.path.join(tmp, 'team.bag'),
                '--world', os.path.abspath(self.world_yaml), '--seed', str(self.seed)] + BAG_ARGS)
            self.bag.update(wall_s=r['wall_s'], cpu_s=r['cpu_s'], cached=False)
            say('%s %s: bags made in %.0f s' % (stamp(), self.name, r['wall_s']))
        # what the bags hold: the SLAM runs are keyed by it (digested once, kept in content.json)
        contents = bag_contents(d, log=self.log)
        if contents is None or any(n not in contents for n in BAG_FILES):
            raise RuntimeError('bags incomplete in %s (%s)' % (d, ', '.join(n for n in BAG_FILES
                                                                             if n not in (contents or {}))))
        self.bag['content'] = {n: contents[n]['sha1'] for n in BAG_FILES}

    def truth_doc(self) -> Dict[str, Any]:
        from multi_map_merge.lab.evaluate import load_truth
        return load_truth(self.bag['truth'])

    def log(self, line: str) -> None:
        say('%s %s: %s' % (stamp(), self.name, line))

    # --- 2. one robot's SLAM (--slam: rbpf_slam or gmapping)
    def gmapping(self, robot: str) -> None:
        self.started()
        res = self._gmapping(robot)
        with self.lock:
            self.gm[robot] = res
        label = SLAMS[ARGS.slam]['label']
        if res.get('invalid'):
            say('%s %s: %s %s INVALID: %s' % (stamp(), self.name, label, robot, res['invalid']))
        else:
            say('%s %s: %s %-6s %4d scans in its bag, %4d processed%s, %s' % (
                stamp(), self.name, label, robot, res['scans'], res['processed'],
                ', %d dropped' % res['dropped'] if res.get('dropped') else '',
                'cached' if res.get('cached') else '%.0f s wall, %s CPU s' % (res['wall_s'], res['cpu_s'])))
        if res.get('migrated_now'):
            say('  (an old-scheme result of the same bag content, %s: copied into %s)'
                % (res['migrated_from']['meta'], os.path.dirname(res['map'])))

    def _gmapping(self, robot: str) -> Dict[str, Any]:
        slam = ARGS.slam
        exe = replay_binary(slam)
        if exe is None:
            return {'invalid': slam_missing(slam)}
        if robot == SINGLE:
            bag_file, name = 'team_single.bag', self.truth_doc().get('single', {}).get('name', 'tb3_0')
        else:
            bag_file, name = 'team.bag', robot
        bag = os.path.join(self.bag['dir'], bag_file)
        content = self.bag['content'][bag_file]
        topic = '/%s/scan' % name
        st = os.stat(exe)
        # keyed by what the bag holds, not by the sources that made it (a bag remade alike finds it)
        # and by the SLAM, its config and its binary ('gmapping_seed': the SLAM's seed, the old name)
        doc = {'bag': content, 'robot': robot, 'topic': topic, 'gmapping_seed': self.seed, 'slam': slam,
               'config': file_digest(SLAMS[slam]['config']), 'binary': [exe, st.st_size, int(st.st_mtime)]}
        every = self.snapshot_every() if slam == 'rbpf' else None
        if every:      # the maps along the way too (bench/timeline.py): another run than one without
            doc['snapshot_every'] = every
        key = key_of(doc)
        prefix, meta = resolve_gmapping(ARGS.work, self.world, self.seed, robot, bag_file, content, doc,
                                        log=self.log)
        if meta is not None:
            return meta
        td = self.truth_doc()
        info = td.get('single', {}) if robot == SINGLE else td['robots'].get(name, {})
        timeout = 600.0 + 4.0 * float(info.get('duration_s', 1800.0))
        return run_gmapping(exe, bag, topic, name, self.seed, SLAMS[slam]['config'], prefix,
                            {'key': key, 'args': doc, 'robot': robot}, timeout, ARGS.port,
                            os.path.join(ARGS.work, 'ros_home'), slam=slam, snapshot_every=every)

    def snapshot_every(self) -> float:
        """The SLAM's snapshot period here (s of bag time; timeline.snapshot_every of the lone
        robot's drive)."""
        import timeline
        return timeline.snapshot_every(float(self.truth_doc().get('single', {}).get('duration_s', 500.0)))

    # --- 4. coverage over time (bench/timeline.py, a process of its own)
    def timeline(self) -> Dict[str, Any]:
        if ARGS.slam != 'rbpf':
            return {'invalid': 'coverage over time needs rbpf_slam\'s snapshots (--slam rbpf)'}
        bad = [r for r in TEAM + [SINGLE] if (self.gm.get(r) or {}).get('invalid') or r not in self.gm]
        if bad:
            return {'invalid': 'SLAM runs missing: %s' % ', '.join(bad)}
        prefix = {r: os.path.splitext(self.gm[r]['map'])[0] for r in TEAM + [SINGLE]}
        out = os.path.join(self.run_dir, 'timeline.json')
        if os.path.exists(out):
            os.remove(out)
        cmd = [PY, os.path.join(HERE, 'timeline.py'), '--truth', self.bag['truth'], '--world', self.world_yaml,
               '--every', str(self.snapshot_every()), '--out', out, '--single', prefix[SINGLE],
               '--team'] + ['%s=%s' % (r, prefix[r]) for r in TEAM]
        log = os.path.join(self.run_dir, 'timeline.log')
        r = run_timed(cmd, log, child_env(), 3600)
        doc = read_json(out)
        if r['rc'] != 0 or not isinstance(doc, dict):
            return {'invalid': 'timeline.py failed (exit %s, %s)' % (r['rc'], log)}
        doc['cpu_s'] = r['cpu_s']
        return doc

    # --- 3. merges and scores
    def score(self) -> None:
        t0 = time.time()
        try:
            self.result = self._score()
        except Exception as e:                    # noqa: BLE001 (named in the row and printed)
            traceback.print_exc()
            why = 'scoring failed: %s: %s' % (type(e).__name__, e)
            self.result = {'rows': {r: Invalid(why) for r in ROWS}, 'details': {}, 'merged_counts': {}}
        try:
            self.result['timeline'] = self.timeline()
        except Exception as e:                    # noqa: BLE001 (named in the report and printed)
            traceback.print_exc()
            self.result['timeline'] = {'invalid': 'timeline failed: %s: %s' % (type(e).__name__, e)}
        self.t_done = time.time()
        self.result['score_wall_s'] = round(self.t_done - t0, 1)
        self.report()
        write_results()

    def _score(self) -> Dict[str, Any]:
        import numpy as np

        from multi_map_merge.core.mapio import MapFileError, load_map
        from multi_map_merge.core.transforms import se2
        truth_doc = self.truth_doc()
        truth = load_map(self.world_yaml)
        starts = truth_doc['starts']
        os.makedirs(self.run_dir, exist_ok=True)
        rows: Dict[str, Any] = {}
        details: Dict[str, Any] = {}
        counts: Dict[str, str] = {}

        def gm_map(robot):
            g = self.gm.get(robot) or {'invalid': 'not run'}
            if g.get('invalid'):
                return None, g['invalid']
            try:
                return load_map(g['map']), None
            except MapFileError as e:
                return None, str(e)

        # the single robot
        g, why = gm_map(SINGLE)
        if g is None:
            rows['single'] = Invalid('lone robot: %s' % why)
        else:
            s = best_score(g, truth, [se2(*truth_doc['single']['start'])])
            rows['single'] = s['fitness'] if 'fitness' in s else Invalid(s['invalid'])
            details['single'] = s
        # the robots' own maps, each alone, and their best fits
        maps, bad = {}, []
        for r in TEAM:
            g, why = gm_map(r)
            if g is None:
                bad.append((r, why))
            else:
                maps[r] = g
        own = {}
        for r, g in maps.items():
            own[r] = best_score(g, truth, [starts[r]])
        details['own'] = own
        if bad:
            for k in ('own', 'rigid', 'merged', 'merged_rigid', 'mexplore', 'mrpt'):
                rows[k] = Invalid(group_reasons(bad))
        else:
            vals = [own[r]['fitness'] if 'fitness' in own[r] else Invalid(own[r]['invalid']) for r in TEAM]
            rows['own'] = mean(vals)
            # the rigid bound: every map at its own best fit, composited in the truth's frame
            if all(is_valid(v) for v in vals):
                poses = {r: np.array(own[r]['T']) for r in TEAM}
                grid = compose_maps(maps, poses, truth, 'world')
                s = best_score(grid, truth, [np.eye(3)])
                rows['rigid'] = s['fitness'] if 'fitness' in s else Invalid(s['invalid'])
                details['rigid'] = s
            else:
                rows['rigid'] = Invalid('an own map could not be scored')
            # every robot's map frame where its robot really started (the reference's start in
            # the truth's frame): what knowing the start poses exactly would give
            grid = compose_maps(maps, {r: starts[r] for r in TEAM}, truth, 'world')
            s = best_score(grid, truth, [np.eye(3)])
            rows['starts'] = s['fitness'] if 'fitness' in s else Invalid(s['invalid'])
            details['starts'] = s
            paths = [self.gm[r]['map'] for r in TEAM]
            # ours
            rows['merged'], counts['merged'], details['merged'] = self.merge_ours(paths, truth, starts)
            # the same placements composited rigidly: what bending the maps (core/deform.py) gained
            rows['merged_rigid'], details['merged_rigid'] = self.unbent(maps, details['merged'], truth, starts)
            if all(is_valid(v) for v in vals) and details['merged'].get('transforms'):
                details['placements'] = placement_checks(details['merged']['transforms'], own, starts)
            # the peers
            for peer in ('mexplore', 'mrpt'):
                if PEERS.get(peer):
                    rows[peer] = Invalid(PEERS[peer])
                    continue
                rows[peer], counts[peer], details[peer] = self.merge_peer(peer, paths, maps, truth, starts)
        return {'rows': rows, 'details': details, 'merged_counts': counts}

    def merge_ours(self, paths, truth, starts):
        from multi_map_merge.core.mapio import load_map
        out = os.path.join(self.run_dir, 'ours')
        os.makedirs(out, exist_ok=True)
        cfg = os.path.join(out, 'config.yaml')
        with open(cfg, 'w') as f:
            f.write('workers: 1   # inline: the benchmark\'s job slots are its CPU budget\n')
            f.write('bend_maps: %s\n' % ('false' if ARGS.unbent else 'true'))
        merged, tf = os.path.join(out, 'merged.yaml'), os.path.join(out, 'transforms.yaml')
        for p in (merged, tf):
            if os.path.exists(p):
                os.remove(p)
        cmd = [PY, os.path.join(REPO, 'scripts', 'merge_maps')] + paths + [
            '-o', merged, '--transforms', tf, '--reference', TEAM[0], '--config', cfg]
        r = run_timed(cmd, os.path.join(out, 'merge_maps.log'), child_env(), 1800)
        if r['rc'] != 0 or not os.path.exists(merged) or not os.path.exists(tf):
            return Invalid('merge_maps failed (exit %s, %s)' % (r['rc'], os.path.join(out, 'merge_maps.log'))), None, {}
        import yaml
        with open(tf) as f:
            rep = yaml.safe_load(f)
        n = 1 + sum(1 for v in (rep.get('maps') or {}).values() if v.get('merged'))
        s = best_score(load_map(merged), truth, [starts[rep['reference']]])
        s['transforms'] = rep.get('maps')
        s['wall_s'] = r['wall_s']
        return (s['fitness'] if 'fitness' in s else Invalid(s['invalid'])), '%d/%d' % (n, len(paths)), s

    def unbent(self, maps, merged, truth, starts):
        """Our merge's placements (``merged``: merge_ours' details) composited rigidly and
        scored as the merge is."""
        import numpy as np

        from multi_map_merge.core.transforms import se2
        tf = merged.get('transforms') if isinstance(merged, dict) else None
        if tf is None:
            return Invalid('our merge failed'), {}
        ref = TEAM[0]
        poses = {ref: np.eye(3)}
        poses.update({r: se2(v['x'], v['y'], v['yaw']) for r, v in tf.items() if v.get('merged')})
        s = best_score(compose_maps(maps, poses, maps[ref], 'map'), truth, [starts[ref]])
        return (s['fitness'] if 'fitness' in s else Invalid(s['invalid'])), s

    def merge_peer(self, peer, paths, maps, truth, starts):
        import numpy as np
        import yaml
        out = os.path.join(self.run_dir, peer)
        os.makedirs(out, exist_ok=True)
        merged, tf = os.path.join(out, 'merged.yaml'), os.path.join(out, 'transforms.yaml')
        for p in (merged, tf):
            if os.path.exists(p):
                os.remove(p)
        tool = MEXPLORE_TOOL if peer == 'mexplore' else MRPT_TOOL
        if peer == 'mexplore':     # its node's own merged /map: no placements to composite
            cmd = [PY, tool] + paths + ['-o', merged, '--settle', '10']
        else:
            cmd = [PY, tool] + paths + ['-o', merged, '--transforms', tf, '--reference', TEAM[0],
                                        '--seed', str(self.seed)]
        log = os.path.join(out, 'merge.log')
        r = run_timed(cmd, log, child_env(), 1800)
        if r['rc'] != 0 or not os.path.exists(merged if peer == 'mexplore' else tf):
            return Invalid('%s failed (exit %s, %s)' % (os.path.basename(tool), r['rc'], log)), None, {}
        if peer == 'mexplore':
            from multi_map_merge.core.mapio import load_map
            s = best_score(load_map(merged), truth, [starts[TEAM[0]]])
            s['wall_s'] = r['wall_s']
            return (s['fitness'] if 'fitness' in s else Invalid(s['invalid'])), 'its merged /map', s
        with open(tf) as f:
            rep = yaml.safe_load(f) or {}
        ref = str(rep.get('reference', TEAM[0]))
        poses = {ref: np.eye(3)}
        for k, v in (rep.get('maps') or {}).items():
            if v.get('merged'):
                c, s_, sc = math.cos(v['yaw']), math.sin(v['yaw']), float(v.get('scale', 1.0))
                poses[str(k)] = np.array([[sc * c, -sc * s_, v['x']], [sc * s_, sc * c, v['y']], [0, 0, 1.0]])
        grid = compose_maps({k: maps[k] for k in poses}, poses, maps[ref], ref + '/map')
        s = best_score(grid, truth, [starts[ref]])
        s['transforms'] = rep.get('maps')
        s['reference'] = ref
        s['wall_s'] = r['wall_s']
        return (s['fitness'] if 'fitness' in s else Invalid(s['invalid'])), '%d/%d' % (len(poses), len(paths)), s

    # --- the report of one condition
    def timing(self) -> Dict[str, Any]:
        gm_wall = sum(g.get('wall_s') or 0 for g in self.gm.values() if not g.get('cached'))
        gm_cpu = sum(g.get('cpu_s') or 0 for g in self.gm.values() if not g.get('cached'))
        return {'span_s': round((self.t_done or time.time()) - (self.t_first or time.time()), 1),
                'bags_wall_s': None if self.bag.get('cached') else self.bag.get('wall_s'),
                'gmapping_wall_s_sum': round(gm_wall, 1), 'gmapping_cpu_s_sum': round(gm_cpu, 1),
                'score_wall_s': (self.result or {}).get('score_wall_s'),
                'cached': {'bags': bool(self.bag.get('cached')),
                           'gmapping': sorted(k for k, g in self.gm.items() if g.get('cached'))}}

    def report(self) -> None:
        res = self.result
        t = self.timing()
        rows = res['rows']
        lines = ['', '== %s: %s' % (self.name, self.title)]
        try:
            td = self.truth_doc()
            lines.append('  driven: %s; alone %.1f m' % (', '.join(
                '%s %.1f m' % (k, v.get('distance_m', float('nan'))) for k, v in sorted(td['robots'].items())),
                td.get('single', {}).get('distance_m', float('nan'))))
        except Exception:                         # noqa: BLE001 (the truth file's trouble is in the rows)
            pass
        label = SLAMS[ARGS.slam]['label']
        lines.append('  time: %.0f s span; bags %s; %s %.0f s wall, %.0f CPU s (summed over runs%s); '
                     'scoring %.0f s'
                     % (t['span_s'], 'cached' if t['cached']['bags'] else '%s s' % t['bags_wall_s'], label,
                        t['gmapping_wall_s_sum'], t['gmapping_cpu_s_sum'],
                        ', cached: ' + ' '.join(t['cached']['gmapping']) if t['cached']['gmapping'] else '',
                        res.get('score_wall_s') or 0))
        for r in [SINGLE] + TEAM:
            g = self.gm.get(r, {})
            who = 'lone robot' if r == SINGLE else r
            if 'scans' in g:
                lines.append('  %s %-10s %4d scans in its bag, %4d processed (update frame)%s%s%s%s' % (
                    label, who, g['scans'], g['processed'],
                    ', %d dropped' % g['dropped'] if g.get('dropped') else '',
                    ', %d without TF' % g['without_tf'] if g.get('without_tf') else '',
                    ', %s CPU s' % g['cpu_s'] if g.get('cpu_s') is not None else '',
                    ': INVALID: %s' % g['invalid'] if g.get('invalid') else ''))
            else:
                lines.append('  %s %-10s INVALID: %s' % (label, who, g.get('invalid', 'not run')))
        det = res.get('details', {})
        for r in ROWS:
            v = rows.get(r, Invalid('not run'))
            extra = ''
            d = det.get(r) if r != 'own' else None
            if is_valid(v) and isinstance(d, dict) and 'coverage' in d:
                extra = '  coverage %.3f  inlier RMSE %.3f m' % (d['coverage'], d['inlier_rmse'])
            if r in res.get('merged_counts', {}) and res['merged_counts'][r]:
                extra += '  (%s merged)' % res['merged_counts'][r]
            if r == 'own' and det.get('own'):
                extra = '  (' + ' '.join('%s %s' % (k, fmt(s.get('fitness')))
                                         for k, s in sorted(det['own'].items())) + ')'
            lines.append('  %-26s %s%s' % (ROW_NAMES[r], fmt(v) if is_valid(v) else 'INVALID: %s' % v.reason, extra))
        lines.append('  %-26s %s' % ('loss to the rigid bound', fmt(loss(rows.get('rigid'), rows.get('merged')))))
        for p in det.get('placements', []):
            lines.append('  placed %s: %.3f m %.2f deg off its best fit (%.3f m %.2f deg off its start); '
                         '2-sigma %s m; %s the 95%% ellipse%s%s'
                         % (p['robot'], p['err_m'], p['err_deg'], p['start']['err_m'], p['start']['err_deg'],
                            '%.3f' % p['sigma2_m'] if p['sigma2_m'] is not None else '-',
                            'within' if p['in95'] else 'outside', '; weak' if p['weak'] else '',
                            '; OFF' if p['off'] else ''))
        lines += timeline_lines(res.get('timeline') or {'invalid': 'not run'})
        say(*lines)

    def as_json(self) -> Dict[str, Any]:
        res = self.result or {'rows': {}, 'details': {}, 'merged_counts': {}}
        return {'world': self.world, 'seed': self.seed, 'bags': self.bag,
                'gmapping': self.gm, 'rows': {r: to_json(res['rows'].get(r, Invalid('not run'))) for r in ROWS},
                'loss_to_rigid_bound': to_json(loss(res['rows'].get('rigid'), res['rows'].get('merged'))),
                'merged_counts': res.get('merged_counts', {}), 'details': res.get('details', {}),
                'timeline': res.get('timeline', {'invalid': 'not run'}), 'timing': self.timing()}


def placement_checks(transforms, own, starts) -> List[Dict[str, Any]]:
    """Per robot our merge placed (``transforms``: merge_maps' ``maps``): its error against
    the truth by the maps' best rigid fits (``own[r]['T']``, relative to the reference's) and
    against the robots' true starts, under its covariance (bend_summary.placement_record)."""
    import numpy as np
    from bend_summary import placement_record

    from multi_map_merge.core.transforms import inverse, xyyaw
    ref = TEAM[0]
    out = []
    for r, v in sorted(transforms.items()):
        if not v.get('merged') or r == ref or 'T' not in own.get(r, {}):
            continue
        fit = xyyaw(inverse(np.array(own[ref]['T'])) @ np.array(own[r]['T']))
        start = xyyaw(inverse(starts[ref]) @ starts[r])
        cov = np.array(v['cov']).reshape(3, 3) if v.get('cov') else None
        rec = placement_record(r, (v['x'], v['y'], v['yaw']), fit, cov, v.get('sigma_position'),
                               bool(v.get('weak')), v.get('via', ''), fit_true=start)
        rec['start'] = rec.pop('fit')     # (placement_record's second truth: here the starts)
        out.append(rec)
    return out


def best_score(grid, truth, inits) -> Dict[str, Any]:
    """The best Fitness of ``grid`` on ``truth`` from each coarse pose of ``inits`` and from
    best_fit_score's eight headings; {'invalid': why} when it cannot be scored."""
    from multi_map_merge.core.grid import GridError
    from multi_map_merge.core.transforms import xyyaw
    from multi_map_merge.lab.evaluate import best_fit_score, score_map
    try:
        cands = [('start pose', score_map(grid, truth, T0)) for T0 in inits]
        cands.append(('best fit', best_fit_score(grid, truth)))
    except GridError as e:
        return {'invalid': 'cannot be scored: %s' % e}
    how, s = max(cands, key=lambda c: c[1].fitness)
    return {'fitness': float(s.fitness), 'inlier_rmse': float(s.inlier_rmse), 'coverage': float(s.coverage),
            'wrong_occupied_m2': float(s.wrong_occupied_m2), 'pose': list(xyyaw(s.T)), 'T': s.T.tolist(),
            'from': how, 'from_start_pose': float(cands[0][1].fitness) if inits else None}


def compose_maps(maps, poses, frame_grid, frame_id):
    """The maps warped by ``poses`` (3x3, map frame -> target frame) and composited as merge_maps
    composites (core/composite: Occupied > Free > Unknown) on ``frame_grid``'s lattice."""
    import numpy as np

    from multi_map_merge.core.composite import composite, lattice_for, warp_patch
    from multi_map_merge.core.config import MergeConfig
    c = MergeConfig()
    lattice = lattice_for(frame_grid)
    patches = []
    for k in sorted(poses):
        g = maps[k]
        kv = g.known_values(c.free_thresh, c.occupied_thresh)
        if kv is not None:
            patches.append(warp_patch(kv[1], kv[0], g.resolution, g.origin, np.asarray(poses[k], float),
                                      lattice, c.max_cells))
    grid = composite(patches, lattice, frame_id, c.max_cells)
    if grid is None:
        raise ValueError('nothing to composite')
    return grid


# ------------------------------------------------------------------------------ scheduling

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
                if self.pending == 0 or _stopping.is_set():
                    return
                _, _, fn = heapq.heappop(self.ready)
            try:
                fn()
            except Exception:                     # noqa: BLE001 (each job records its own failure)
                if not _stopping.is_set():
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


def plan(cond: Condition, sched: Scheduler) -> None:
    """The chain of one condition: bags -> five SLAM runs (the lone robot first, the longest)
    -> merges and scores."""
    i = cond.index
    left = {'n': 1 + len(TEAM)}

    def gm(robot):
        def job():
            try:
                cond.gmapping(robot)
            except Exception as e:                # noqa: BLE001 (the row says INVALID and why)
                if not _stopping.is_set():
                    traceback.print_exc()
                with cond.lock:
                    cond.gm[robot] = {'invalid': '%s run failed: %s: %s' % (SLAMS[ARGS.slam]['label'],
                                                                           type(e).__name__, e)}
            with cond.lock:
                left['n'] -= 1
                last = left['n'] == 0
            if last and not _stopping.is_set():
                sched.submit((i, 0), cond.score)
        return job

    def bags():
        try:
            cond.make_bags()
        except Exception as e:                    # noqa: BLE001
            traceback.print_exc()
            why = 'bags not made: %s' % e
            cond.result = {'rows': {r: Invalid(why) for r in ROWS}, 'details': {}, 'merged_counts': {}}
            cond.t_done = time.time()
            cond.report()
            write_results()
            return
        sched.submit((i, 1), gm(SINGLE))
        for k, r in enumerate(TEAM):
            sched.submit((i, 2 + k), gm(r))

    sched.submit((i, 0), bags)


# ------------------------------------------------------------------------------ results

CONDITIONS: List[Condition] = []
_write_lock = threading.Lock()


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


def write_results(final: bool = False) -> Dict[str, Any]:
    """accuracy.json and accuracy.md of what is done so far (rewritten after every condition)."""
    with _write_lock:
        done = [c for c in CONDITIONS if c.result is not None]
        conds = [{'world': c.world, 'seed': c.seed, 'rows': c.result['rows'],
                  'merged_counts': c.result.get('merged_counts', {}), 'timeline': c.result.get('timeline')}
                 for c in done]
        worlds = [w for w in ARGS.world_list if any(c['world'] == w for c in conds)] if not final else ARGS.world_list
        agg = aggregate(conds, worlds, merged_row=default_merged_row())
        line = summary_line(agg['overall'])
        doc = {'complete': final and len(done) == len(CONDITIONS), 'line': line,
               'args': {'seeds': ARGS.seed_list, 'worlds': ARGS.world_list, 'work': ARGS.work,
                        'jobs': ARGS.jobs, 'bag_args': BAG_ARGS,
                        'slam': ARGS.slam, 'slam_binary': replay_binary(ARGS.slam),
                        'slam_config': os.path.relpath(SLAMS[ARGS.slam]['config'], REPO)},
               'worlds': {w: {'title': WORLDS[w][1], 'truth': WORLDS[w][0],
                              'rows': {r: {'mean': to_json(d[r]['mean']), 'worst': to_json(d[r]['worst'])}
                                       for r in ROWS},
                              'loss_to_rigid_bound': {'mean': to_json(d['loss']['mean']),
                                                      'worst': to_json(d['loss']['worst'])},
                              'merged_minus_true_starts': d['vs_starts'], 'bent_minus_unbent': d['bend_gain'],
                              'time': d['time'],
                              'seeds': d['seeds']}
                          for w, d in agg['worlds'].items()},
               'merged_row': agg['merged_row'],
               'overall': {k: (to_json(v) if k in ROWS or k in ('worst_loss', 'merged_default', 'worst_vs_starts')
                               else v) for k, v in agg['overall'].items()},
               'peers': PEERS, 'runtime_s': round(time.time() - T_START, 1),
               'conditions': [c.as_json() for c in done]}
        os.makedirs(ARGS.results, exist_ok=True)
        with open(os.path.join(ARGS.results, ARGS.stem + '.json'), 'w') as f:
            json.dump(doc, f, indent=1, default=_json_default)
        titles = {w: WORLDS[w][1] for w in WORLDS}
        md = ['# Accuracy: 4 Turtlebot3s merged vs 1 alone, every map by %s (bench/accuracy.py --slam %s)'
              % (SLAMS[ARGS.slam]['label'], ARGS.slam), '',
              'Fitness (Open3D ICP at 0.10 m against the ground truth, the paper\'s Table 1); '
              '(k/4): robots the merge placed. %s%s' % (
                  'Complete run' if doc['complete']
                  else 'PARTIAL: %d of %d conditions done' % (len(done), len(CONDITIONS)),
                  ', %.0f s.' % doc['runtime_s']), '']
        md.append(markdown(conds, agg, worlds, titles))
        with open(os.path.join(ARGS.results, ARGS.stem + '.md'), 'w') as f:
            f.write('\n'.join(md))
        with open(os.path.join(ARGS.results, ARGS.stem + '.txt'), 'w') as f:
            f.write('\n'.join(_out_lines) + '\n')
        return {'agg': agg, 'line': line, 'done': done}


def default_merged_row() -> str:
    """The row that is the merger as it ships: ``merged`` (bent) when ``bend_maps`` is on by
    default (core/config.MergeConfig), else ``merged_rigid`` (the same placements composited
    rigidly: what the default merge publishes)."""
    from multi_map_merge.core.config import MergeConfig
    return 'merged' if MergeConfig().bend_maps else 'merged_rigid'


def target_lines(agg: Dict[str, Any]) -> List[str]:
    """Issue 51's targets per world and seed, and the times: printed after the Fitness tables."""
    mrow = agg['merged_row']
    lines = ['', 'targets (issue 51): the merge (%s, the default) at least the team at its true starts - %.2f '
             'in every seed; ~bend_maps on only where bent >= unbent - %.3f in every seed and above on the mean'
             % (ROW_NAMES[mrow], STARTS_TOLERANCE, BEND_TOLERANCE)]
    for w, d in agg['worlds'].items():
        vs = d['vs_starts']['per_seed']
        ok = all(is_valid(v) and v >= -STARTS_TOLERANCE for v in vs)
        lines.append('  %-6s merged minus true starts per seed %s: %s; bent minus unbent %s (mean %s): bend_maps %s'
                     % (w, ' '.join(fmt(v) for v in vs), 'MET' if ok else 'NOT MET',
                        ' '.join(fmt(v) for v in d['bend_gain']['per_seed']), fmt(d['bend_gain']['mean']),
                        bend_decision(d['bend_gain']['per_seed'])))
        t = d['time']
        lines.append('  %-6s time to 90%%: team %s (worst %s), single %s (worst %s); to 99%%: team %s, single %s'
                     % ((w,) + tuple(secs(t[k][m]) for k, m in (('team_t90', 'mean'), ('team_t90', 'worst'),
                                                                 ('single_t90', 'mean'), ('single_t90', 'worst'),
                                                                 ('team_t99', 'mean'), ('single_t99', 'mean')))))
        lines.append('  %-6s final Fitness: team %s (worst %s), single %s (worst %s); at the team\'s end the single '
                     'robot: Fitness %s, free area %s (team %s)'
                     % (w, fmt(t['end_team_fitness']['mean']), fmt(t['end_team_fitness']['worst']),
                        fmt(t['end_single_fitness']['mean']), fmt(t['end_single_fitness']['worst']),
                        fmt(t['equal_time_single_fitness']['mean']), fmt(t['equal_time_single_free']['mean']),
                        fmt(t['equal_time_team_free']['mean'])))
    return lines


def print_summary(res: Dict[str, Any]) -> None:
    agg = res['agg']
    lines = ['']
    for w, d in agg['worlds'].items():
        lines.append('== %s: over seeds %s' % (WORLDS[w][1], ', '.join(str(s) for s in d['seeds'])))
        lines.append('  %-26s %8s %8s' % ('Fitness', 'mean', 'worst'))
        for r in ROWS:
            lines.append('  %-26s %8s %8s' % (ROW_NAMES[r], fmt(d[r]['mean']), fmt(d[r]['worst'])))
        lines.append('  %-26s %8s %8s (largest)' % ('loss to the rigid bound', fmt(d['loss']['mean']),
                                                    fmt(d['loss']['worst'])))
        for r in ROWS + ('loss',):
            v = d[r]['mean']
            if isinstance(v, Invalid):
                lines.append('  INVALID %s: %s' % (ROW_NAMES.get(r, 'loss to the rigid bound'), v.reason))
    lines += target_lines(agg)
    recs = [p for c in res['done'] for p in ((c.result or {}).get('details') or {}).get('placements', [])]
    if recs:
        with_cov = [p for p in recs if p['in95'] is not None]
        off = [p for p in recs if p['off']]
        lines.append('')
        lines.append('placements: %d robots placed; %d of the %d with a covariance within their 95%% ellipse '
                     '(against the maps\' best rigid fits); off (> %.2f m or %.1f deg) %d, flagged weak %d of them'
                     % (len(recs), sum(1 for p in with_cov if p['in95']), len(with_cov), OFF[0], OFF[1],
                        len(off), sum(1 for p in off if p['weak'])))
    times = [c.timing()['span_s'] for c in res['done']]
    if times:
        lines.append('')
        lines.append('time: %.0f s in all; per condition (world, seed) %s' % (
            time.time() - T_START, ', '.join('%s s%d %.0f s' % (c.world, c.seed, c.timing()['span_s'])
                                             for c in res['done'])))
    say(*lines)


# ------------------------------------------------------------------------------ main

ARGS: Any = None
PEERS: Dict[str, Optional[str]] = {}
T_START = time.time()


def parse_args(argv: Optional[List[str]] = None):
    ap = argparse.ArgumentParser(prog='accuracy.py', description=__doc__.split('\n\n')[0])
    ap.add_argument('--seeds', type=int, default=5, help='how many seeds (default 5)')
    ap.add_argument('--first-seed', type=int, default=1, help='the first seed (default 1)')
    ap.add_argument('--worlds', default='home,intel',
                    help='comma-separated: %s (default home,intel)' % ', '.join(WORLDS))
    ap.add_argument('--quick', action='store_true', help='1 seed, the home only (results in accuracy_quick.*)')
    ap.add_argument('--work', default='/tmp/mmm_accuracy',
                    help='cache of bags and SLAM maps (default /tmp/mmm_accuracy)')
    ap.add_argument('--slam', choices=sorted(SLAMS), default=DEFAULT_SLAM,
                    help='the SLAM making every map: rbpf (rbpf_slam_replay, config/rbpf_lds02.yaml; the '
                         'default) or gmapping (slam_gmapping_replay, config/gmapping_lds02.yaml, where ROS has '
                         'gmapping: elsewhere every row is INVALID)')
    ap.add_argument('--results', default=os.path.join(HERE, 'results'), help='where accuracy.{json,md,txt} go')
    ap.add_argument('--jobs', type=int, default=2, help='heavy steps at once (1 or 2; default 2)')
    ap.add_argument('--port', type=int, default=12500, help='first port tried for the roscores (default 12500)')
    ap.add_argument('--no-build', action='store_true', help='do not build MRPT\'s driver (bench/mrpt_merge.py)')
    ap.add_argument('--unbent', action='store_true',
                    help='our merge with bend_maps false (default: true; the row "ours, unbent" composites '
                         'the same placements rigidly either way)')
    a = ap.parse_args(argv)
    if a.quick:
        a.seeds, a.worlds = 1, 'home'
    a.world_list = [w.strip() for w in a.worlds.split(',') if w.strip()]
    for w in a.world_list:
        if w not in WORLDS:
            ap.error('unknown world %r (known: %s)' % (w, ', '.join(WORLDS)))
    if a.seeds < 1:
        ap.error('--seeds must be at least 1')
    a.jobs = max(1, min(2, a.jobs))
    a.seed_list = list(range(a.first_seed, a.first_seed + a.seeds))
    a.stem = ('accuracy_quick' if a.quick else 'accuracy') + ('' if a.slam == DEFAULT_SLAM else '_' + a.slam)
    a.work = os.path.abspath(a.work)
    return a


def main(argv: Optional[List[str]] = None) -> int:
    global ARGS, PEERS
    ARGS = parse_args(argv)
    os.makedirs(ARGS.work, exist_ok=True)
    if 'home' in ARGS.world_list:
        _, home_yaml = write_home_map(os.path.join(ARGS.work, 'worlds', 'home.yaml'))
        WORLDS['home'] = (home_yaml, WORLDS['home'][1])
    if os.nice(0) < NICENESS:
        os.nice(NICENESS - os.nice(0))   # the merges and scores in here too, not only the children

    def on_signal(sig, _frame):
        raise SystemExit(128 + sig)
    for s in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, on_signal)
    try:
        for w in ARGS.world_list:
            if not os.path.exists(WORLDS[w][0]):
                say('accuracy: world %s: %s is absent: its rows are INVALID' % (w, WORLDS[w][0]))
        exe = replay_binary(ARGS.slam)
        say('accuracy: %d seeds (%s) x %d worlds (%s); work dir %s; %d jobs at once, nice 10'
            % (len(ARGS.seed_list), ', '.join(map(str, ARGS.seed_list)), len(ARGS.world_list),
               ', '.join(ARGS.world_list), ARGS.work, ARGS.jobs),
            'accuracy: SLAM %s: %s, %s' % (ARGS.slam, exe or 'NONE: every row is INVALID: %s' % slam_missing(ARGS.slam),
                                           os.path.relpath(SLAMS[ARGS.slam]['config'], REPO)))
        PEERS = peers_available(build=not ARGS.no_build)
        for p, why in PEERS.items():
            say('accuracy: peer %s: %s' % (p, 'ready' if why is None else 'INVALID: ' + why))
        sched = Scheduler()
        k = 0
        for seed in ARGS.seed_list:
            for w in ARGS.world_list:
                c = Condition(k, w, seed)
                CONDITIONS.append(c)
                k += 1
                if not os.path.exists(c.world_yaml):
                    why = 'world %s is absent' % c.world_yaml
                    c.result = {'rows': {r: Invalid(why) for r in ROWS}, 'details': {}, 'merged_counts': {}}
                    continue
                plan(c, sched)
        sched.run(ARGS.jobs)
        for c in CONDITIONS:
            if c.result is None:
                c.result = {'rows': {r: Invalid('not completed') for r in ROWS}, 'details': {}, 'merged_counts': {}}
        res = write_results(final=True)
        print_summary(res)
        say(res['line'])
        write_results(final=True)
        return 0
    except KeyboardInterrupt:
        say('accuracy: interrupted')
        return 130
    finally:
        stop_all()


if __name__ == '__main__':
    sys.exit(main())
