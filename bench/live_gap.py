#!/usr/bin/env python3
"""Does estimation block publishing? The live node while a long estimation runs and /map has new
content to publish every merge period.

    bench/bench.py live-gap [--robots 4] [--late 28] [--join-at 12] [--seconds 40] [--min-periods 4]
                              [--port 11800] [--no-peer] [--no-build]

Runs `make build` first (unless --no-build) and takes the environment of the workspace's
devel/setup.bash, so it needs nothing sourced.

Starts its own roscore (port 11800, another free one if taken) and a map publisher (this script,
--publish): ``--robots`` robots whose maps (windows of the edmonton ground-truth map, or of the
intel one, both in ../shared/data) grow twice per merge period for the whole window, so that the
merged map changes every period and /map has a reason of content to flow (a node that publishes
/map only when the merge changed stays silent otherwise); at ``--join-at`` seconds ``--late``
robots with big maps (windows of half the map, about 1.8 M cells each) join at once: their cold
estimation lasts seconds while the others keep growing. Runs map_merge_node (merge_rate 2 Hz,
tf_rate 20 Hz) and records when /map messages arrive (and whether their cells changed), when
`map -> tb3_N/map` TF messages arrive, and each estimation cycle's duration from /diagnostics.

Reported: the largest gap between /map messages whose cells changed during the long estimation
cycles, in merge periods (target <= 1.5), and the TF rate. INVALID instead of a figure when no
estimation cycle of at least ``--min-periods`` merge periods is known to have run inside the
measured span (from the first /map to the end of the window) for at least that long: then the
bench did not create the condition it measures. A cycle still running when the window ends is
waited for (/diagnostics only, up to a minute) and counts for its part inside the window. Where
m-explore's node is installed (ros-noetic-multirobot-map-merge: `rospack find
multirobot_map_merge`), it is measured the same way on the same maps; elsewhere its line says it
is not installed (bench/peer.py).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
import results as results_io  # noqa: E402
from inputs import pieces_windows, world_map  # noqa: E402
from peer import NOT_INSTALLED, live_node  # noqa: E402
from report import machine  # noqa: E402

from multi_map_merge.core.mapio import save_map  # noqa: E402
from multi_map_merge.lab import processes  # noqa: E402


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


DIAG_PERIOD = 1.0   # s: the node publishes /diagnostics once a second
DIAG_GRACE_S = 60.0   # s: /diagnostics heard after the window for the cycle running at its end


def publisher(spec):
    """The robots' maps (--publish SPEC): each robot's topic appears when it joins; a growing
    robot's map reveals the cells within a radius of its known centre that widens every period
    from ``grow_from`` of the largest radius to all of it over ``grow_s`` seconds (a new map, a new
    merge, every period); a robot that does not grow publishes its whole map once, latched."""
    import numpy as np
    import rospy

    from multi_map_merge.ros.convert import NumpyGrid, grid_to_msg
    rospy.init_node('live_gap_maps', anonymous=True)
    robots = []
    for r in spec['robots']:
        robots.append(dict(r, pub=None, **growing_map(r['path'])))
    period, t0 = spec['period'], time.monotonic()
    k = 0
    while not rospy.is_shutdown():
        t = time.monotonic() - t0
        for r in robots:
            if t < r['join_s']:
                continue
            g = r['grid']
            if r['pub'] is None:
                r['pub'] = rospy.Publisher('/%s/map' % r['name'], NumpyGrid, queue_size=1, latch=True)
            elif not r['grow']:
                continue
            if r['grow']:
                f = spec['grow_from'] + (1.0 - spec['grow_from']) * min(1.0, t / spec['grow_s'])
                data = np.where(r['dist'] <= f * r['dmax'], g.data, np.int8(-1))
                g = type(g)(data, g.resolution, g.origin, g.frame_id)
            r['pub'].publish(grid_to_msg(g, rospy.Time.now(), '%s/map' % r['name']))
        k += 1
        time.sleep(max(0.0, t0 + k * period - time.monotonic()))


def measure(seconds, robots, merge_period, min_periods=4):
    """Record /map arrival times (with a checksum of the cells), TF arrival times and estimation
    durations from /diagnostics (with their arrival times) for ``seconds``."""
    import zlib

    import numpy as np
    import rospy
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import OccupancyGrid
    from rospy.numpy_msg import numpy_msg
    from tf2_msgs.msg import TFMessage
    maps, tfs, est = [], [], []
    children = {'%s/map' % r for r in robots}

    def on_map(m):
        t = time.time()
        maps.append((t, zlib.crc32(np.ascontiguousarray(m.data).tobytes()) ^ (m.info.width << 16) ^ m.info.height))

    def on_tf(m):
        for t in m.transforms:
            if t.child_frame_id in children:
                tfs.append(time.time())
                break

    def on_diag(m):
        for s in m.status:
            for kv in s.values:
                if kv.key == 'last_estimation_s':
                    est.append((time.time(), float(kv.value)))
    subs = [rospy.Subscriber('/map', numpy_msg(OccupancyGrid), on_map, queue_size=5, buff_size=2 ** 27),
            rospy.Subscriber('/tf', TFMessage, on_tf, queue_size=100),
            rospy.Subscriber('/diagnostics', DiagnosticArray, on_diag, queue_size=10)]
    t_start = time.time()
    t_end = t_start + seconds
    while time.time() < t_end:
        time.sleep(0.1)
    for s in subs[:2]:
        s.unregister()
    # A cycle still running when the window ends is reported only when it ends: /diagnostics
    # is heard a while longer, so that a long cycle that began inside the window is known (its
    # part inside the window is what counts, in analyse())
    reported = len(est)
    deadline = time.time() + DIAG_GRACE_S
    while time.time() < deadline and not cycle_ended_since(est, reported):
        time.sleep(0.1)
    subs[2].unregister()
    return analyse(maps, tfs, est, t_start, t_end, merge_period, min_periods)


def cycle_ended_since(est, k):
    """Whether /diagnostics reported another estimation duration after its ``k``-th report."""
    return any(v != est[k - 1][1] for _, v in est[k:]) if k else len(est) > 0


def analyse(maps, tfs, est, t_start, t_end, merge_period, min_periods=4):
    """The figures of one recording (times in seconds since the epoch): see the module docstring.

    An estimation cycle of ``v`` seconds first reported at ``t`` ended at most DIAG_PERIOD before
    ``t``, so it surely ran over [t - v, t - DIAG_PERIOD]: the cycles whose sure part lies inside
    the measured span (first /map .. end) for ``min_periods`` merge periods or more are the long
    ones (a cycle reported after ``t_end`` counts for its part before it); the gaps between /map
    messages whose cells changed are taken across them."""
    times = [t for t, _ in maps]
    changed = [t for k, (t, c) in enumerate(maps) if k == 0 or c != maps[k - 1][1]]

    def gaps(ts):   # (from, to) of every gap from the first message on, the window's end included
        return [(a, b) for a, b in zip(ts, ts[1:])] + ([(ts[-1], t_end)] if ts else [])
    cycles, last = [], None
    for t, v in est:
        if v != last:
            cycles.append((t, v))
        last = v
    span = (changed[0], t_end) if changed else None
    need = min_periods * merge_period
    long_cycles = []
    for t, v in cycles:
        a, b = t - v, t - DIAG_PERIOD
        if span and v >= need and min(b, span[1]) - max(a, span[0]) >= need:
            long_cycles.append((max(a, span[0]), min(b, span[1]), v))
    across = [b - a for a, b in gaps(changed) if any(a < e and b > s for s, e, _ in long_cycles)]
    tf_times = sorted(tfs)
    tf_gaps = [b - a for a, b in zip(tf_times, tf_times[1:])]
    all_gaps = [b - a for a, b in gaps(times)]
    out = {'window_s': t_end - t_start, 'map_messages': len(maps), 'map_messages_changed': len(changed),
           'first_map_after_s': (times[0] - t_start) if times else None,
           'max_map_gap_s': max(all_gaps) if all_gaps else None,
           'max_changed_map_gap_s': max([b - a for a, b in gaps(changed)] or [None]) if changed else None,
           'open_gap_at_end_s': (t_end - times[-1]) if times else None,
           'estimation_cycles_s': [round(v, 3) for _, v in cycles],
           'longest_estimation_s': max([v for _, v in cycles] or [None]) if cycles else None,
           'long_cycles_in_span': [[round(s - t_start, 2), round(e - t_start, 2), v] for s, e, v in long_cycles],
           'min_periods': min_periods,
           'tf_messages': len(tfs),
           'tf_rate_hz': (len(tfs) / float(t_end - tf_times[0])) if tfs else 0.0,
           'max_tf_gap_s': max(tf_gaps + [t_end - tf_times[-1]]) if tf_times else None}
    if not long_cycles:
        out['valid'] = False
        out['invalid_because'] = ('no estimation cycle of >= %d merge periods (%.1f s) surely ran inside the '
                                  'measured span (first changed /map .. end) for that long: cycles seen %s s'
                                  % (min_periods, need, out['estimation_cycles_s'][-8:]))
    else:
        out['valid'] = True
        out['max_gap_across_long_s'] = max(across)
        out['max_gap_across_long_periods'] = max(across) / merge_period
    return out



def private_ros_env(base: dict, port: int, tmp: str) -> dict:
    """``base`` with a private master on the loopback at ``port`` (works where the machine's own
    hostname does not resolve), ROS_HOME and logs under ``tmp``; set in this process too."""
    env = dict(base, ROS_MASTER_URI='http://127.0.0.1:%d' % port, ROS_IP='127.0.0.1',
               ROS_HOME=os.path.join(tmp, 'ros'), ROS_LOG_DIR=os.path.join(tmp, 'ros', 'log'))
    env.pop('ROS_HOSTNAME', None)
    os.environ.update(env)
    return env


class Processes(list):
    """The processes a benchmark starts (each in a session of its own, its output in a log file
    under ``tmp``: ``lab.processes.start_group``), stopped as roslaunch stops nodes: SIGINT, then
    SIGKILL after 10 s (``lab.processes.stop_group``)."""

    def __init__(self, env: dict, tmp: str):
        super().__init__()
        self.env, self.tmp = env, tmp

    def start(self, cmd, log):
        p = processes.start_group(cmd, os.path.join(self.tmp, log), self.env, cwd=os.getcwd(), append=False)
        self.append(p)
        return p

    @staticmethod
    def stop(ps):
        for p in ps:
            processes.signal_group(p, signal.SIGINT)
        for p in ps:
            processes.stop_group(p, 10.0)


def mexplore_node(no_peer: bool):
    """(m-explore's live node with the settings the live benches give it, '') or (None, why
    it is not measured)."""
    peer = None if no_peer else live_node()
    if peer:
        return [peer, '_known_init_poses:=false', '_merging_rate:=2.0', '_discovery_rate:=0.5',
                '_estimation_rate:=1.0'], ''
    return None, ('not measured (--no-peer)' if no_peer else NOT_INSTALLED)


def growing_map(path: str) -> dict:
    """A robot's whole map (``grid``) and, per cell, its distance in cells from the map's known
    centre (``dist``; ``dmax``, the farthest known cell's): revealing the cells within a radius
    that widens makes the map grow as a robot's would."""
    import numpy as np

    from multi_map_merge.core.mapio import load_map
    g = load_map(path)
    known = g.data >= 0
    rr, cc = np.nonzero(known)
    d = np.hypot(np.arange(g.height)[:, None] - rr.mean(), np.arange(g.width)[None, :] - cc.mean())
    return {'grid': g, 'dist': d.astype(np.float32), 'dmax': float(d[known].max())}


def bench_processes(spec: dict, tmp: str, port: int, build: bool):
    """The map publisher's ``spec`` written to ``tmp``/publish.json, and the :class:`Processes`
    of a run on a private master at ``port`` (another free one if taken): (processes, port)."""
    with open(os.path.join(tmp, 'publish.json'), 'w') as f:
        json.dump(spec, f)
    port = port if processes.port_free(port) else processes.free_port()
    return Processes(private_ros_env(ros_env(build), port, tmp), tmp), port

def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--robots', type=int, default=4,
                    help='robots whose maps grow every merge period (windows of 35%% of edmonton)')
    ap.add_argument('--late', type=int, default=28,
                    help='robots joining at --join-at with big maps (windows of half edmonton, ~1.8 M cells)')
    ap.add_argument('--join-at', type=float, default=12.0, help='seconds after the node\'s start')
    ap.add_argument('--seconds', type=float, default=40.0)
    ap.add_argument('--min-periods', type=int, default=4,
                    help='a long estimation cycle: at least this many merge periods inside the measured span')
    ap.add_argument('--no-build', action='store_true', help='skip `make build` (workspace already built)')
    ap.add_argument('--port', type=int, default=11800, help='roscore port (a free one if taken)')
    ap.add_argument('--no-peer', action='store_true', help='do not run m-explore\'s node')
    ap.add_argument('--publish', help=argparse.SUPPRESS)   # the map publisher's own process
    ap.add_argument('--out', default=os.path.join(HERE, 'results'))
    a = ap.parse_args()
    if a.publish:
        return publisher(json.load(open(a.publish)))
    os.makedirs(a.out, exist_ok=True)
    world = world_map('edmonton') or world_map('intel', required=True)
    tmp = tempfile.mkdtemp(prefix='mmm_live_')
    n = a.robots + a.late
    robots = ['tb3_%d' % k for k in range(n)]
    pieces = pieces_windows(world, a.robots, 0.35, seed=3) + pieces_windows(world, a.late, 0.5, seed=4)
    # the growing robots send a new map twice per merge period: whatever the phase between their
    # messages and the node's timer, every merge period has new cells to publish
    spec = {'period': 0.25, 'grow_from': 0.6, 'grow_s': a.seconds, 'robots': []}
    cells = []
    for k, (r, (g, _)) in enumerate(zip(robots, pieces)):
        p = os.path.join(tmp, r + '.yaml')
        save_map(g, p)
        grow = k < a.robots
        cells.append(g.width * g.height)
        # the publisher starts 2 s before the node: the late robots join --join-at after the node
        spec['robots'].append({'name': r, 'path': p, 'grow': grow, 'join_s': 0.0 if grow else a.join_at + 2.0})
    procs, port = bench_processes(spec, tmp, a.port, not a.no_build)
    env, start, stop = procs.env, procs.start, procs.stop

    results = {'machine': machine(), 'robots': n, 'growing': a.robots, 'late': a.late, 'join_at_s': a.join_at,
               'map_cells_growing': int(sorted(cells[:a.robots])[a.robots // 2]) if a.robots else None,
               'map_cells_late': int(sorted(cells[a.robots:])[a.late // 2]) if a.late else None,
               'settings': {'publisher': 'growing every 0.25 s from 60%% to 100%% of their radius over %.0f s; '
                                         'late robots latched once at join' % a.seconds,
                            'merge_rate': 2.0, 'tf_rate': 20.0, 'merge_period_s': 0.5,
                            'estimation_rate': 'node default', 'min_periods': a.min_periods}}

    def run(cmd, log):
        """One node on the maps: a fresh publisher (the late robots join relative to it), the
        node 2 s later, recorded from the node's start."""
        pub = start([sys.executable, os.path.abspath(__file__), '--publish', os.path.join(tmp, 'publish.json')],
                    'publish_' + log)
        time.sleep(2.0)
        node = start(cmd, log)
        try:
            r = measure(a.seconds, robots, 0.5, a.min_periods)
        finally:
            stop([node, pub])
        return r

    try:
        start(['roscore', '-p', env['ROS_MASTER_URI'].rsplit(':', 1)[1]], 'roscore.log')
        import rosgraph
        import rospy
        for _ in range(100):
            if rosgraph.is_master_online():
                break
            time.sleep(0.2)
        rospy.init_node('live_gap', anonymous=True)
        results['ours'] = run(['rosrun', 'multi_map_merge', 'map_merge_node', '_merge_rate:=2.0', '_tf_rate:=20.0'],
                              'ours.log')
        peer, why_not = mexplore_node(a.no_peer)
        results['mexplore'] = run(peer, 'mexplore.log') if peer else why_not
    finally:
        stop(list(reversed(procs)))
    results_io.write_json(os.path.join(a.out, 'live.json'), results, vars(a))
    print(json.dumps(results, indent=1))
    o = results['ours']
    f = lambda v, fmt='%.2f': '-' if v is None else fmt % v  # noqa: E731
    print('\nLIVE NODE, %d robots growing every merge period (%s cells) + %d joining at %.0f s (%s cells), '
          'merge_rate 2 Hz, %.0f s window' % (a.robots, results['map_cells_growing'], a.late, a.join_at,
                                             results['map_cells_late'], a.seconds))
    common = ('%3d /map (%d with new cells; first after %s s), TF map -> tb3_N/map %.1f Hz (max gap %s s), '
              'estimation cycles %s s' % (o['map_messages'], o['map_messages_changed'],
                                         f(o['first_map_after_s'], '%.1f'), o['tf_rate_hz'], f(o['max_tf_gap_s']),
                                         o['estimation_cycles_s'][-6:]))
    if o['valid']:
        print('ours:      largest gap between changed /map across the long estimation cycles %s s = %s merge periods '
              '(target <= 1.5); long cycles in the span (s from start, s): %s; %s' % (
                  f(o['max_gap_across_long_s']), f(o['max_gap_across_long_periods']), o['long_cycles_in_span'],
                  common))
    else:
        print('ours:      INVALID: %s; %s' % (o['invalid_because'], common))
    if isinstance(results['mexplore'], dict):
        p = results['mexplore']
        print('m-explore: %3d /map (%d with new cells; first after %s s), largest gap between changed /map %s s '
              '(end of window included; its estimation cycles are not reported, so not tied to them); it '
              'broadcasts no TF' % (p['map_messages'], p['map_messages_changed'], f(p['first_map_after_s'], '%.1f'),
                                    f(p['max_changed_map_gap_s'])))
    else:
        print('m-explore:', results['mexplore'])


if __name__ == '__main__':
    main()
