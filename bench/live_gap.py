#!/usr/bin/env python3
"""Does estimation block publishing? The live node, with robots whose estimation takes seconds.

    python3 bench/live_gap.py [--robots 14] [--seconds 30] [--port 11800] [--no-peer] [--no-build]

Runs `make build` first (unless --no-build) and takes the environment of the workspace's
devel/setup.bash, so it needs nothing sourced.

Starts its own roscore (port 11800, another free one if taken), publishes N large robot maps (windows of the edmonton
ground-truth map, or of the shipped intel map without ../shared) as gmapping would, runs
map_merge_node (merge_rate 2 Hz, tf_rate 20 Hz), and records for a while when /map messages and
`map -> tb3_N/map` TF messages arrive, plus each estimation cycle's duration from /diagnostics.
Reports the largest gap between /map messages in merge periods, and the TF rate. When m-explore is
built (../shared/peers/mexplore), its live node is measured the same way on the same maps.
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(REPO, 'src'))
from inputs import pieces_windows, world_map  # noqa: E402
from peer import live_node  # noqa: E402
from report import machine  # noqa: E402

from multi_map_merge.core.mapio import save_map  # noqa: E402


def port_free(port):
    with socket.socket() as s:
        try:
            s.bind(('127.0.0.1', port))
            return True
        except OSError:
            return False


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def ros_env(build=True):
    """The environment of the catkin workspace (`make build` first): os.environ + setup.bash."""
    ws = None
    if build:
        r = subprocess.run(['make', '-C', REPO, 'build'], capture_output=True, text=True,
                           env=dict(os.environ, PATH='/usr/bin:/bin:/usr/sbin:/sbin:' + os.environ.get('PATH', '')))
        if r.returncode != 0:
            sys.exit('make build failed:\n' + (r.stdout + r.stderr)[-2000:])
        for line in r.stdout.splitlines():
            if line.startswith('built: '):
                ws = line.split(': ', 1)[1].strip()
    if ws is None:   # the Makefile's WS: /tmp/multi_map_merge_ws_<md5 of the clone's path>[:8]
        import hashlib
        ws = '/tmp/multi_map_merge_ws_' + hashlib.md5((REPO + '\n').encode()).hexdigest()[:8]
    setup = os.path.join(ws, 'devel', 'setup.bash')
    if not os.path.exists(setup):
        sys.exit('%s is missing: run `make build` first' % setup)
    out = subprocess.run(['bash', '-c', 'source %s && env -0' % setup], capture_output=True,
                         env=dict(os.environ, PATH='/usr/bin:/bin:' + os.environ.get('PATH', ''))).stdout
    env = dict(kv.split('=', 1) for kv in out.decode().split('\0') if '=' in kv)
    env['PATH'] = '/usr/bin:/bin:' + env.get('PATH', '')
    return env


def measure(seconds, robots, merge_period):
    """Record /map and TF arrival times and estimation durations for ``seconds``."""
    import rospy
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import OccupancyGrid
    from rospy.numpy_msg import numpy_msg
    from tf2_msgs.msg import TFMessage
    maps, tfs, est = [], [], []
    children = {'%s/map' % r for r in robots}

    def on_map(_m):
        maps.append(time.time())

    def on_tf(m):
        for t in m.transforms:
            if t.child_frame_id in children:
                tfs.append(time.time())
                break

    def on_diag(m):
        for s in m.status:
            if s.hardware_id == 'map_merge':
                for kv in s.values:
                    if kv.key == 'last_estimation_s':
                        est.append(float(kv.value))
    subs = [rospy.Subscriber('/map', numpy_msg(OccupancyGrid), on_map, queue_size=5, buff_size=2 ** 27),
            rospy.Subscriber('/tf', TFMessage, on_tf, queue_size=100),
            rospy.Subscriber('/diagnostics', DiagnosticArray, on_diag, queue_size=10)]
    t_start = time.time()
    t_end = t_start + seconds
    while time.time() < t_end:
        time.sleep(0.1)
    for s in subs:
        s.unregister()
    # Gaps from the first /map on, the end of the window included: a node that stops publishing
    # shows as one long open gap instead of none.
    gaps = [b - a for a, b in zip(maps, maps[1:])] + ([t_end - maps[-1]] if maps else [seconds])
    tf_times = sorted(tfs)
    tf_gaps = [b - a for a, b in zip(tf_times, tf_times[1:])]
    return {'window_s': seconds, 'map_messages': len(maps),
            'first_map_after_s': (maps[0] - t_start) if maps else None,
            'max_map_gap_s': max(gaps) if gaps else None,
            'max_map_gap_periods': (max(gaps) / merge_period) if gaps else None,
            'open_gap_at_end_s': (t_end - maps[-1]) if maps else None,
            'tf_messages': len(tfs),
            'tf_rate_hz': (len(tfs) / float(t_end - tf_times[0])) if tfs else 0.0,
            'max_tf_gap_s': max(tf_gaps + [t_end - tf_times[-1]]) if tf_times else None,
            'longest_estimation_s': max(est) if est else None,
            'estimation_cycles_s': sorted(set(round(e, 3) for e in est))[-5:]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--robots', type=int, default=14,
                    help='robots (windows of half edmonton, about 1.8 M cells: estimation cycles of seconds)')
    ap.add_argument('--seconds', type=float, default=30.0)
    ap.add_argument('--no-build', action='store_true', help='skip `make build` (workspace already built)')
    ap.add_argument('--port', type=int, default=11800, help='roscore port (a free one if taken)')
    ap.add_argument('--no-peer', action='store_true', help='do not run m-explore\'s node')
    ap.add_argument('--out', default=os.path.join(HERE, 'results'))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    world = world_map('edmonton') or world_map('intel')
    tmp = tempfile.mkdtemp(prefix='mmm_live_')
    robots = ['tb3_%d' % k for k in range(a.robots)]
    paths, cells = [], []
    for r, (g, _) in zip(robots, pieces_windows(world, a.robots, 0.5)):
        p = os.path.join(tmp, r + '.yaml')
        save_map(g, p)
        paths.append(p)
        cells.append(g.width * g.height)
    port = a.port if port_free(a.port) else free_port()
    # a private master on the loopback: works where the machine's own hostname does not resolve
    env = dict(ros_env(not a.no_build), ROS_MASTER_URI='http://127.0.0.1:%d' % port, ROS_IP='127.0.0.1',
               ROS_HOME=os.path.join(tmp, 'ros'), ROS_LOG_DIR=os.path.join(tmp, 'ros', 'log'))
    env.pop('ROS_HOSTNAME', None)
    os.environ.update(env)
    procs = []

    def start(cmd, log):
        p = subprocess.Popen(cmd, env=env, stdout=open(os.path.join(tmp, log), 'w'), stderr=subprocess.STDOUT,
                             start_new_session=True)
        procs.append(p)
        return p

    def stop(ps):
        for p in ps:
            try:
                os.killpg(p.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
        for p in ps:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)

    results = {'machine': machine(), 'robots': a.robots, 'map_cells': int(sorted(cells)[len(cells) // 2]),
               'settings': {'publish_maps': '--steps 1 --period 5', 'merge_rate': 2.0, 'tf_rate': 20.0,
                            'merge_period_s': 0.5, 'estimation_rate': 'node default'}}
    try:
        start(['roscore', '-p', env['ROS_MASTER_URI'].rsplit(':', 1)[1]], 'roscore.log')
        import rosgraph
        import rospy
        for _ in range(100):
            if rosgraph.is_master_online():
                break
            time.sleep(0.2)
        rospy.init_node('live_gap', anonymous=True)
        start(['rosrun', 'multi_map_merge', 'publish_maps', '--steps', '1', '--period', '5']
              + ['%s:%s' % (r, p) for r, p in zip(robots, paths)], 'publish.log')
        time.sleep(2.0)
        node = start(['rosrun', 'multi_map_merge', 'map_merge_node', '_merge_rate:=2.0', '_tf_rate:=20.0'],
                     'ours.log')
        # measured from the start: the cold estimation of every robot happens inside the window
        results['ours'] = measure(a.seconds, robots, 0.5)
        stop([node])
        peer = None if a.no_peer else live_node()
        if peer:
            node = start([peer, '_known_init_poses:=false', '_merging_rate:=2.0', '_discovery_rate:=0.5',
                          '_estimation_rate:=1.0'], 'mexplore.log')
            results['mexplore'] = measure(a.seconds, robots, 0.5)
            stop([node])
        else:
            results['mexplore'] = ('not measured (--no-peer)' if a.no_peer else
                                   'NOT measured: m-explore is not built (../shared/peers/mexplore/build.sh)')
    finally:
        stop(list(reversed(procs)))
    with open(os.path.join(a.out, 'live.json'), 'w') as f:
        json.dump(results, f, indent=1)
    print(json.dumps(results, indent=1))
    o = results['ours']
    f = lambda v, fmt='%.2f': '-' if v is None else fmt % v  # noqa: E731
    print('\nLIVE NODE, %d robots of %d cells each, merge_rate 2 Hz, %.0f s window' % (
        a.robots, results['map_cells'], a.seconds))
    print('ours:      %3d /map (first after %s s), max /map gap %s s = %s merge periods (target <= 1.5); '
          'TF map -> tb3_N/map %.1f Hz (target 20, max gap %s s); longest estimation cycle %s s' % (
              o['map_messages'], f(o['first_map_after_s'], '%.1f'), f(o['max_map_gap_s']),
              f(o['max_map_gap_periods']), o['tf_rate_hz'], f(o['max_tf_gap_s']), f(o['longest_estimation_s'])))
    if isinstance(results['mexplore'], dict):
        p = results['mexplore']
        print('m-explore: %3d /map (first after %s s), max /map gap %s%s s = %s merge periods '
              '(end of window included); it broadcasts no TF' % (
                  p['map_messages'], f(p['first_map_after_s'], '%.1f'), '>= ' if not p['map_messages'] else '',
                  f(p['max_map_gap_s']),
                  f(p['max_map_gap_periods'])))
    else:
        print('m-explore:', results['mexplore'])


if __name__ == '__main__':
    main()
