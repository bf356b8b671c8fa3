#!/usr/bin/env python3
"""Does estimation block publishing? The live node, with robots whose estimation takes seconds.

    python3 bench/live_gap.py [--robots 8] [--seconds 40]    (after `make build`, setup.bash sourced)

Starts its own roscore on a free port, publishes N large robot maps (windows of the edmonton
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
from run_bench import PEER_WS, machine, pieces_windows, world_map  # noqa: E402
from multi_map_merge.mapio import save_map  # noqa: E402


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def measure(seconds, robots, merge_period):
    """Record /map and TF arrival times and estimation durations for ``seconds``."""
    import rospy
    from diagnostic_msgs.msg import DiagnosticArray
    from rospy.numpy_msg import numpy_msg
    from nav_msgs.msg import OccupancyGrid
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
    t_end = time.time() + seconds
    while time.time() < t_end:
        time.sleep(0.1)
    for s in subs:
        s.unregister()
    gaps = [b - a for a, b in zip(maps, maps[1:])]
    tf_times = sorted(tfs)
    tf_gaps = [b - a for a, b in zip(tf_times, tf_times[1:])]
    return {'map_messages': len(maps), 'max_map_gap_s': max(gaps) if gaps else None,
            'max_map_gap_periods': (max(gaps) / merge_period) if gaps else None,
            'tf_rate_hz': (len(tfs) / float(tf_times[-1] - tf_times[0])) if len(tfs) > 1 else 0.0,
            'max_tf_gap_s': max(tf_gaps) if tf_gaps else None,
            'longest_estimation_s': max(est) if est else None,
            'estimation_cycles_s': sorted(set(round(e, 3) for e in est))[-5:]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--robots', type=int, default=8)
    ap.add_argument('--seconds', type=float, default=40.0)
    ap.add_argument('--out', default=os.path.join(HERE, 'results'))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    world = world_map('edmonton') or world_map('intel')
    tmp = tempfile.mkdtemp(prefix='mmm_live_')
    robots = ['tb3_%d' % k for k in range(a.robots)]
    paths = []
    for r, (g, _) in zip(robots, pieces_windows(world, a.robots, 0.5)):
        p = os.path.join(tmp, r + '.yaml')
        save_map(g, p)
        paths.append(p)
    env = dict(os.environ, ROS_MASTER_URI='http://localhost:%d' % free_port(), ROS_HOME=os.path.join(tmp, 'ros'))
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

    results = {'machine': machine(), 'robots': a.robots, 'map_cells': int(world.width * world.height * 0.25)}
    try:
        start(['roscore', '-p', env['ROS_MASTER_URI'].rsplit(':', 1)[1]], 'roscore.log')
        import rosgraph
        import rospy
        for _ in range(100):
            if rosgraph.is_master_online():
                break
            time.sleep(0.2)
        rospy.init_node('live_gap', anonymous=True)
        start(['rosrun', 'multi_map_merge', 'publish_maps', '--steps', '4', '--period', '6']
              + ['%s:%s' % (r, p) for r, p in zip(robots, paths)], 'publish.log')
        time.sleep(2.0)
        node = start(['rosrun', 'multi_map_merge', 'map_merge_node', '_merge_rate:=2.0', '_tf_rate:=20.0',
                      '_estimation_rate:=1.0'], 'ours.log')
        # measured from the start: the cold estimation of every robot happens inside the window
        results['ours'] = measure(a.seconds, robots, 0.5)
        stop([node])
        peer = os.path.join(PEER_WS, 'devel', 'lib', 'multirobot_map_merge', 'map_merge')
        if os.path.exists(peer):
            node = start([peer, '_known_init_poses:=false', '_merging_rate:=2.0', '_discovery_rate:=0.5',
                          '_estimation_rate:=1.0'], 'mexplore.log')
            results['mexplore'] = measure(a.seconds, robots, 0.5)
            stop([node])
        else:
            results['mexplore'] = 'not built (../shared/peers/mexplore/build.sh)'
    finally:
        stop(list(reversed(procs)))
    print(json.dumps(results, indent=1))
    o = results['ours']
    print('\nours: max /map gap %.2f s = %.2f merge periods (target <= 1.5), TF %.1f Hz (max gap %.2f s), '
          'longest estimation cycle %.2f s' % (o['max_map_gap_s'] or -1, o['max_map_gap_periods'] or -1,
                                                 o['tf_rate_hz'], o['max_tf_gap_s'] or -1, o['longest_estimation_s'] or -1))
    if isinstance(results['mexplore'], dict):
        p = results['mexplore']
        print('m-explore: max /map gap %s s = %s merge periods, %d /map messages in %.0f s (it sends no TF)'
              % (p['max_map_gap_s'], p['max_map_gap_periods'], p['map_messages'], a.seconds))
    with open(os.path.join(a.out, 'live.json'), 'w') as f:
        json.dump(results, f, indent=1)


if __name__ == '__main__':
    main()
