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

Its cold estimation: ``peer_estimate.py``.

Where it is: ``rospack find multirobot_map_merge`` in this process's environment, or in the
catkin workspace whose setup file ``MMM_MEXPLORE_SETUP`` names (sourced with ``--extend`` over this
environment): a build by hand where no package has it (Debian 12), kept out of the repository.
"""
from __future__ import annotations

import json
import math
import os
import signal
import socket
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


def proc_figures(pid):
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


class Session:
    """A master of its own, the maps' feeder (their params set, maps latched) and m-explore's
    node started with ``node_args`` and ``node_env``; everything stopped by ``close``. ``why``
    is '' or why it did not start (then the node was not started)."""

    def __init__(self, paths, poses, timeout, settle, work, wait_map, node_args, node_env=None):
        self.work, self.why = work, ''
        self.node = self.feeder = None
        port = free_port()
        env = processes.ros_env(ENV, port, os.path.join(work, 'ros_home'))
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
    s = Session(paths, poses, timeout, settle, work, True, args)
    try:
        if s.why:
            return {'invalid': s.why}
        figures = None
        while s.feeder.poll() is None:
            if s.node.poll() is not None:
                return {'invalid': 'm-explore\'s node exited (%s, see %s)' % (s.node.returncode, s.log.name)}
            if figures is None and os.path.exists(s.result + '.first'):
                figures = proc_figures(s.node.pid)     # at its first merged map
            time.sleep(0.05)
        if not os.path.exists(s.result):
            return {'invalid': 'no merged /map from m-explore within %.0f s: INVALID (%s)' % (timeout, s.log.name)}
        with open(s.result) as f:
            got = json.load(f)
        cpu_end, rss = proc_figures(s.node.pid)
        cpu_first = figures[0] if figures else cpu_end
        return {'first_map_s': got['first_t'] - s.t0, 'cpu_s': cpu_first, 'cpu_end_s': cpu_end, 'rss_mb': rss,
                'merged_yaml': got.get('merged_yaml'), 'maps_seen': got['count'], 'log': s.log.name}
    finally:
        s.close()


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
    ap.add_argument('--cycles', type=int, default=9)
    a = ap.parse_args(argv)
    if not available()[0]:
        print(available()[1], file=sys.stderr)
        return 3
    if a.estimate:
        import peer_estimate
        res = peer_estimate.run_estimation(a.maps, cycles=a.cycles)
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
