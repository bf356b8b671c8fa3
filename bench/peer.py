"""m-explore's side of the benchmarks: its ``map_merge`` node (package ``multirobot_map_merge``,
Ubuntu's ``ros-noetic-multirobot-map-merge``), run as the ROS node it is, where it is installed.

Nothing of m-explore is built here: it is measured only where ``rospack find
multirobot_map_merge`` succeeds. Elsewhere (Debian 12 has no such package) every figure of it says
NOT_INSTALLED, never a number.

One measurement (:func:`run_node`): a master of its own (a port in 12500-12599), the robots' maps
published latched on ``/robot_k/map`` by a feeder (this file with ``--feed``, in its own process:
rospy is initialised once per process), the node started with ``known_init_poses`` false (it
estimates the transforms itself, as ours does) or true with each robot's
``/robot_k/map_merge/init_pose_{x,y,z,yaw}`` set, as its parameters say; then its merged ``/map``
is read. Figures: the time from the node's start to its first merged ``/map`` (m-explore publishes
one only once it has placed two maps or more), the CPU seconds of its process by then and its peak
RSS (VmHWM). A run that saw no ``/map`` in time says INVALID with why, not a number.

Its cold estimation (:func:`run_estimation`), comparable to ours' ``cold_ms``: m-explore estimates
from scratch every estimation cycle (map_merge.cpp ``poseEstimation`` feeds every grid to
combine_grids' ``MergingPipeline::estimateTransforms``: AKAZE features of every map, every pair
matched, the biggest component, affine estimation and bundle adjustment; nothing is kept between
cycles). Its node is run unmodified with its own DEBUG lines on (a rosconsole config for its logger
``ros.multirobot_map_merge``) stamped with the wall time (``ROSCONSOLE_FORMAT`` ``${walltime}``),
``estimation_rate`` 100 Hz (so that cycles run back to back: ``ros::Rate`` does not sleep after a
cycle longer than its period) and ``merging_rate`` 0.01 Hz (no compositing or publishing competes
for the 2 cores). A cycle's estimate time runs from its ``computing features`` line (the grids
fed, inside ``estimateTransforms``) to the next cycle's ``Grid pose estimation started.`` line
(``estimateTransforms`` returned, its lock released); only cycles that started after every map's
``received full map update`` count.

Where it is: ``rospack find multirobot_map_merge`` in this process's environment, or in the
catkin workspace whose setup file ``MMM_MEXPLORE_SETUP`` names (sourced with ``--extend`` over this
environment): a build by hand where no package has it (Debian 12), kept out of the repository.
"""
from __future__ import annotations

import json
import math
import os
import re
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time

from multi_map_merge.lab import processes

PACKAGE, NODE = 'multirobot_map_merge', 'map_merge'
NOT_INSTALLED = 'm-explore not installed (ros-noetic-multirobot-map-merge): not measured'
SETUP_VAR = 'MMM_MEXPLORE_SETUP'     # a catkin setup.bash of a workspace holding multirobot_map_merge


def mexplore_env(setup=None, base=None):
    """(environment, why not): ``base`` (this process's environment, /usr/bin first on PATH)
    extended by the catkin ``setup`` file (``source setup --extend``: m-explore's package found by
    rospack and catkin_find, this workspace's paths kept); why is '' or says what went wrong
    with ``setup``, whose environment then is ``base``'s."""
    base = dict(os.environ if base is None else base)
    base['PATH'] = '/usr/bin:/bin:' + base.get('PATH', '')
    if not setup:
        return base, ''
    if not os.path.isfile(setup):
        return base, '%s=%s: no such file: m-explore not measured' % (SETUP_VAR, setup)
    r = subprocess.run(['bash', '-c', 'source "$0" --extend >/dev/null && env -0', setup],
                       capture_output=True, env=base)
    if r.returncode != 0:
        return base, '%s=%s: sourcing it failed (%s): m-explore not measured' % (
            SETUP_VAR, setup, r.stderr.decode(errors='replace').strip()[-200:])
    env = dict(kv.split('=', 1) for kv in r.stdout.decode(errors='replace').split('\0') if '=' in kv)
    env.pop('_', None)
    return env, ''


ENV, SETUP_WHY = mexplore_env(os.environ.get(SETUP_VAR))
PORTS = range(12500, 12600)
# the node's rates (Hz): discovery of robots' topics, estimation, merging; its defaults (0.05,
# 0.5, 4) would make the first discovery alone wait 20 s
RATES = {'discovery_rate': 1.0, 'estimation_rate': 1.0, 'merging_rate': 2.0}


def node_path():
    """The installed map_merge executable, or None."""
    r = subprocess.run(['rospack', 'find', PACKAGE], capture_output=True, text=True, env=ENV)
    if r.returncode != 0:
        return None
    r = subprocess.run(['catkin_find', '--first-only', '--libexec', PACKAGE, NODE],
                       capture_output=True, text=True, env=ENV)
    p = r.stdout.strip()
    if r.returncode == 0 and p and os.access(p, os.X_OK):
        return p
    # <prefix>/share/multirobot_map_merge -> <prefix>/lib/multirobot_map_merge/map_merge
    share = subprocess.run(['rospack', 'find', PACKAGE], capture_output=True, text=True, env=ENV).stdout.strip()
    p = os.path.join(os.path.dirname(os.path.dirname(share)), 'lib', PACKAGE, NODE)
    return p if os.access(p, os.X_OK) else None


def available():
    """(True, '') or (False, why): m-explore's node is installed."""
    if SETUP_WHY:
        return False, SETUP_WHY
    r = subprocess.run(['rospack', 'find', PACKAGE], capture_output=True, text=True, env=ENV)
    if r.returncode != 0:
        return False, NOT_INSTALLED
    if node_path() is None:
        return False, '%s found but not its %s node: m-explore not measured' % (PACKAGE, NODE)
    return True, ''


def live_node():
    """The node's executable when installed, else None (bench/live_gap.py, bench/soak.py)."""
    return node_path() if available()[0] else None


def free_port():
    """A free port of 12500-12599 not handed out before in this process (threads may run
    several nodes at once): ``lab.processes.free_port``."""
    return processes.free_port(PORTS)


def _listening(port):
    with socket.socket() as s:
        return s.connect_ex(('127.0.0.1', port)) == 0


def _proc_figures(pid):
    """(CPU s, peak RSS MB) of a live process, from /proc."""
    with open('/proc/%d/stat' % pid) as f:
        fields = f.read().rsplit(')', 1)[1].split()
    cpu = (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    hwm = None
    with open('/proc/%d/status' % pid) as f:
        for line in f:
            if line.startswith('VmHWM:'):
                hwm = int(line.split()[1]) / 1024.0
    return cpu, hwm


def _stop(p, group=False):
    """SIGINT, SIGKILL after 10 s: to ``p``'s process group (``lab.processes.stop_group``) or to
    ``p`` alone (a child of this process's group)."""
    if group:
        processes.stop_group(p, 10.0)
        return
    if p.poll() is None:
        p.send_signal(signal.SIGINT)
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


class _Session:
    """A master of its own, the maps' feeder (their params set, maps latched) and m-explore's
    node started with ``node_args`` and ``node_env``; everything stopped by ``close``. ``why``
    is '' or why it did not start (then the node was not started)."""

    def __init__(self, paths, poses, timeout, settle, work, wait_map, node_args, node_env=None):
        self.work, self.why = work, ''
        self.node = self.feeder = None
        port = free_port()
        env = dict(ENV, ROS_MASTER_URI='http://127.0.0.1:%d' % port, ROS_IP='127.0.0.1',
                   ROS_HOME=os.path.join(work, 'ros_home'))
        env.pop('ROS_HOSTNAME', None)
        self.log = open(os.path.join(work, 'mexplore.log'), 'w')
        self.master = subprocess.Popen(['rosmaster', '--core', '-p', str(port)], stdout=self.log,
                                       stderr=subprocess.STDOUT, env=env, start_new_session=True)
        self.result = os.path.join(work, 'first_map.json')
        self.stop_file = os.path.join(work, 'feed.stop')
        t_end = time.time() + 20
        while not _listening(port):                    # the master is up
            if self.master.poll() is not None or time.time() > t_end:
                self.why = 'the master did not start on port %d (%s)' % (port, self.log.name)
                return
            time.sleep(0.1)
        spec = os.path.join(work, 'feed.json')
        with open(spec, 'w') as f:
            json.dump({'paths': [os.path.abspath(p) for p in paths], 'poses': poses, 'timeout': timeout,
                       'settle': settle, 'result': self.result, 'wait_map': wait_map, 'stop': self.stop_file,
                       'merged_yaml': os.path.join(work, 'merged.yaml')}, f)
        self.feeder = subprocess.Popen([sys.executable, os.path.abspath(__file__), '--feed', spec],
                                       stdout=self.log, stderr=subprocess.STDOUT, env=env)
        ready = os.path.join(work, 'feed.ready')
        t_end = time.time() + 60
        while not os.path.exists(ready):           # params set, maps latched
            if self.feeder.poll() is not None or time.time() > t_end:
                self.why = 'the maps\' feeder did not start (%s)' % self.log.name
                return
            time.sleep(0.1)
        self.t0 = time.time()
        self.node = subprocess.Popen([node_path()] + node_args, stdout=self.log, stderr=subprocess.STDOUT,
                                     env=dict(env, **(node_env or {})))
        with open(os.path.join(work, 'node_start'), 'w') as f:
            f.write(repr(self.t0))

    def close(self):
        open(self.stop_file, 'w').close()
        for p in (self.node, self.feeder):
            if p is not None:
                _stop(p)
        _stop(self.master, group=True)
        self.log.close()


def run_node(paths, poses=None, timeout=120.0, settle=0.0, out_dir=None):
    """m-explore's node on the maps ``paths`` (map_server yaml files; robot k publishes
    ``paths[k]`` on /robot_k/map). ``poses``: None (``known_init_poses`` false) or [x, y, yaw]
    per map, its ``init_pose``. After the first merged /map, /map is read ``settle`` s more and
    the last one saved. Returns {'first_map_s', 'cpu_s', 'rss_mb', 'merged_yaml', 'maps_seen'}
    or {'invalid': why}."""
    ok, why = available()
    if not ok:
        return {'invalid': why}
    work = out_dir or tempfile.mkdtemp(prefix='mmm_mexplore_')
    os.makedirs(work, exist_ok=True)
    args = ['_known_init_poses:=%s' % ('false' if poses is None else 'true')] + [
        '_%s:=%s' % kv for kv in RATES.items()]
    s = _Session(paths, poses, timeout, settle, work, True, args)
    try:
        if s.why:
            return {'invalid': s.why}
        figures = None
        while s.feeder.poll() is None:
            if s.node.poll() is not None:
                return {'invalid': 'm-explore\'s node exited (%s, see %s)' % (s.node.returncode, s.log.name)}
            if figures is None and os.path.exists(s.result + '.first'):
                figures = _proc_figures(s.node.pid)     # at its first merged map
            time.sleep(0.05)
        if not os.path.exists(s.result):
            return {'invalid': 'no merged /map from m-explore within %.0f s: INVALID (%s)' % (timeout, s.log.name)}
        with open(s.result) as f:
            got = json.load(f)
        cpu_end, rss = _proc_figures(s.node.pid)
        cpu_first = figures[0] if figures else cpu_end
        return {'first_map_s': got['first_t'] - s.t0, 'cpu_s': cpu_first, 'cpu_end_s': cpu_end, 'rss_mb': rss,
                'merged_yaml': got.get('merged_yaml'), 'maps_seen': got['count'], 'log': s.log.name}
    finally:
        s.close()


# m-explore 2.1.4's own DEBUG lines (map_merge.cpp, merging_pipeline.cpp) that time its estimation
CYCLE_START, FEATURES_START = 'Grid pose estimation started.', 'computing features'
MAP_RECEIVED = 'received full map update'
MATCHED = 'calculating transforms in global reference frame'   # a cycle found two maps or more matched
# rosconsole's line: wall time (s.ns), severity, message
LOG_FORMAT = 'MMMT ${walltime} ${severity} ${message}'
# a line of it, whatever rosconsole wraps it in (colour codes on a terminal or not)
LOG_LINE = re.compile(r'MMMT (\d+\.\d+) +[A-Z]+ (.*?)(?:\x1b\[0m)?$')
# the node's rates for the estimation run (Hz): cycles back to back, no compositing in between
ESTIMATION_RATES = {'discovery_rate': 1.0, 'estimation_rate': 100.0, 'merging_rate': 0.01}
ESTIMATION_CYCLES = 9   # as many as ours' 3 processes x 3 cycles on the small rows


def estimation_cycles(lines, robots):
    """The complete estimation cycles in m-explore's log ``lines`` (LOG_FORMAT, DEBUG on) that
    started after ``robots`` maps had arrived: [{'start', 'features', 'end' (wall s), 'estimate_ms'
    (its ``computing features`` line to the next cycle's start: ``estimateTransforms`` of every
    map), 'cycle_ms' (start to the next start: also taking the grids and feeding them), 'matched'
    (it found two maps or more matched and went on to place them)}], in order. Lines of other formats are ignored."""
    events = []
    for line in lines:
        m = LOG_LINE.search(line)
        if m:
            events.append((float(m.group(1)), m.group(2).strip()))
    received, cycles, current = 0, [], None
    for t, msg in events:
        if msg == MAP_RECEIVED:
            received += 1
        elif msg == CYCLE_START:
            if current is not None and current.get('features') is not None:
                cycles.append(dict(current, end=t, estimate_ms=(t - current['features']) * 1000.0,
                                   cycle_ms=(t - current['start']) * 1000.0))
            current = {'start': t, 'features': None, 'matched': False} if received >= robots else None
        elif msg == FEATURES_START and current is not None:
            current['features'] = t
        elif msg == MATCHED and current is not None:
            current['matched'] = True
    return cycles


def run_estimation(paths, cycles=None, max_seconds=120.0, out_dir=None):
    """m-explore's cold estimation on the maps ``paths``, timed from its own log (see the
    module's docstring): its node started with ``known_init_poses`` false and ESTIMATION_RATES,
    stopped after ``cycles`` (ESTIMATION_CYCLES when None) complete cycles with every map (or
    after ``max_seconds``, with at least one). Returns {'estimate_ms': median over the cycles,
    'estimate_first_ms': the first cycle with every map, 'estimate_runs_ms', 'cycle_ms' (median,
    with taking and feeding the grids), 'cycles', 'matched_cycles' (cycles that found maps
    matched), 'rss_mb', 'cpu_s' (the node's, at its end), 'log'} or {'invalid': why}; times in
    ms of the wall clock."""
    ok, why = available()
    if not ok:
        return {'invalid': why}
    cycles = cycles or ESTIMATION_CYCLES
    work = out_dir or tempfile.mkdtemp(prefix='mmm_mexplore_est_')
    os.makedirs(work, exist_ok=True)
    config = os.path.join(work, 'rosconsole.config')
    with open(config, 'w') as f:
        f.write('log4j.logger.ros=INFO\nlog4j.logger.ros.%s=DEBUG\n' % PACKAGE)
    args = ['_known_init_poses:=false'] + ['_%s:=%s' % kv for kv in ESTIMATION_RATES.items()]
    node_env = {'ROSCONSOLE_CONFIG_FILE': config, 'ROSCONSOLE_FORMAT': LOG_FORMAT,
                'ROSCONSOLE_STDOUT_LINE_BUFFERED': '1'}
    s = _Session(paths, None, max_seconds + 30.0, 0.0, work, False, args, node_env)
    try:
        if s.why:
            return {'invalid': s.why}
        got = []
        t_end = s.t0 + max_seconds
        while len(got) < cycles and time.time() < t_end:
            if s.node.poll() is not None:
                return {'invalid': 'm-explore\'s node exited (%s, see %s)' % (s.node.returncode, s.log.name)}
            time.sleep(0.2)
            with open(s.log.name) as f:
                got = estimation_cycles(f, len(paths))
        cpu, rss = _proc_figures(s.node.pid)
    finally:
        s.close()
    if not got:
        return {'invalid': 'no complete estimation cycle of m-explore with all %d maps within %.0f s: '
                           'INVALID (%s)' % (len(paths), max_seconds, s.log.name)}
    got = got[:cycles]
    est = [c['estimate_ms'] for c in got]
    return {'estimate_ms': float(statistics.median(est)), 'estimate_first_ms': est[0], 'estimate_runs_ms': est,
            'cycle_ms': float(statistics.median(c['cycle_ms'] for c in got)), 'cycles': len(got),
            'matched_cycles': sum(1 for c in got if c['matched']),
            'rss_mb': rss, 'cpu_s': cpu, 'log': s.log.name}


def _feed(spec_path):
    """The feeder (its own process): sets the init poses, publishes every map latched on
    /robot_k/map, waits for m-explore's merged /map, writes when the first came and saves the
    last one."""
    import rospy
    from nav_msgs.msg import OccupancyGrid

    from multi_map_merge.core.grid import Grid
    from multi_map_merge.core.mapio import load_map, save_map
    with open(spec_path) as f:
        spec = json.load(f)
    rospy.init_node('mmm_peer_feed', disable_signals=True)
    pubs = []
    for k, path in enumerate(spec['paths']):
        ns = '/robot_%d' % k
        if spec['poses'] is not None:
            x, y, yaw = spec['poses'][k]
            for key, v in (('x', x), ('y', y), ('z', 0.0), ('yaw', yaw)):
                rospy.set_param('%s/map_merge/init_pose_%s' % (ns, key), float(v))
        g = load_map(path)
        m = OccupancyGrid()
        m.header.frame_id = 'robot_%d/map' % k
        m.header.stamp = rospy.Time.now()
        m.info.resolution = g.resolution
        m.info.width, m.info.height = g.width, g.height
        m.info.origin.position.x, m.info.origin.position.y = g.origin[0], g.origin[1]
        m.info.origin.orientation.z, m.info.origin.orientation.w = math.sin(g.origin[2] / 2), math.cos(g.origin[2] / 2)
        m.data = g.data.ravel().tolist()
        p = rospy.Publisher(ns + '/map', OccupancyGrid, queue_size=1, latch=True)
        p.publish(m)
        pubs.append(p)
    got = {'count': 0, 'first_t': None, 'last': None}

    def on_map(msg):
        got['count'] += 1
        got['last'] = msg
        if got['first_t'] is None:
            got['first_t'] = time.time()
            open(spec['result'] + '.first', 'w').close()

    rospy.Subscriber('/map', OccupancyGrid, on_map, queue_size=1)
    open(os.path.join(os.path.dirname(spec_path), 'feed.ready'), 'w').close()
    start = os.path.join(os.path.dirname(spec_path), 'node_start')
    while not os.path.exists(start):
        if os.path.exists(spec['stop']):
            return 1
        time.sleep(0.05)
    t_end = float(open(start).read()) + spec['timeout']
    if not spec['wait_map']:            # the maps latched until the measurement ends
        while time.time() < t_end and not os.path.exists(spec['stop']):
            time.sleep(0.05)
        return 0
    while time.time() < t_end and (got['first_t'] is None or time.time() < got['first_t'] + spec['settle']):
        time.sleep(0.05)
    if got['first_t'] is None:
        return 1
    msg = got['last']
    import numpy as np
    o = msg.info.origin
    yaw = 2 * math.atan2(o.orientation.z, o.orientation.w)
    grid = Grid(np.array(msg.data, np.int8).reshape(msg.info.height, msg.info.width), msg.info.resolution,
                (o.position.x, o.position.y, yaw), frame_id='map')
    save_map(grid, spec['merged_yaml'])
    with open(spec['result'], 'w') as f:
        json.dump({'first_t': got['first_t'], 'count': got['count'], 'merged_yaml': spec['merged_yaml']}, f)
    return 0


def column(res, key, fmt='%.2f'):
    """A table cell of a run_node result: the figure, or why there is none."""
    if res is None or 'invalid' in res:
        return (res or {}).get('invalid', NOT_INSTALLED)
    return fmt % res[key]


def main(argv=None):
    """``peer.py A.yaml B.yaml ... -o merged.yaml [--settle S] [--timeout S]``: m-explore's node on
    the maps (known_init_poses false), its last merged /map ``settle`` s after its first saved as
    merged.yaml, its figures printed as one JSON line; exit 3 when it is not installed, 1 when it
    gave no merged map. ``peer.py A.yaml B.yaml ... --estimate [--cycles N]``: its estimation
    cycles instead (run_estimation), one JSON line."""
    import argparse
    import shutil
    ap = argparse.ArgumentParser(description=main.__doc__.split('\n\n')[0])
    ap.add_argument('maps', nargs='+')
    ap.add_argument('-o', '--output')
    ap.add_argument('--settle', type=float, default=10.0)
    ap.add_argument('--timeout', type=float, default=300.0)
    ap.add_argument('--estimate', action='store_true', help='time its estimation cycles (no merged map)')
    ap.add_argument('--cycles', type=int, default=ESTIMATION_CYCLES)
    a = ap.parse_args(argv)
    if not available()[0]:
        print(available()[1], file=sys.stderr)
        return 3
    if a.estimate:
        res = run_estimation(a.maps, cycles=a.cycles)
        print(json.dumps(res))
        return 1 if 'invalid' in res else 0
    if not a.output:
        ap.error('-o/--output is required (or --estimate)')
    res = run_node(a.maps, timeout=a.timeout, settle=a.settle)
    print(json.dumps(res))
    if 'invalid' in res:
        return 1
    src = res['merged_yaml']
    base = os.path.splitext(a.output)[0]
    shutil.copy(os.path.splitext(src)[0] + '.pgm', base + '.pgm')
    with open(src) as f, open(a.output, 'w') as g:
        g.write(f.read().replace(os.path.basename(os.path.splitext(src)[0]) + '.pgm', os.path.basename(base) + '.pgm'))
    return 0


if __name__ == '__main__':
    if len(sys.argv) == 3 and sys.argv[1] == '--feed':
        sys.exit(_feed(sys.argv[2]))
    sys.exit(main())
