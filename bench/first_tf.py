#!/usr/bin/env python3
"""A team's first TF: the live node, from the robots' maps' arrival to the first
``map -> tb3_N/map`` a tf2 listener resolves.

    python3 bench/first_tf.py MAP.yaml [MAP.yaml ...] [--reps 3] [--port 12700]
        -> one JSON line: {"first_tf_s": median, "all_tf_s": median, "runs": [...], ...}

Each run: a master of its own, ``map_merge_node`` started with every default but the rates that
m-explore's node is measured with (bench/peer.py RATES: discovery and estimation at 1 Hz), and,
once the node is up (its imports and worker pool done, as on a robot before the maps come), a
measuring process (this file with ``--measure``) that publishes the maps latched on
``/tb3_k/map`` (frame ``tb3_k/map``) and polls a real tf2 buffer every 5 ms. Figures per run:
``first_tf_s`` (the first robot besides the reference, tb3_0, resolved in ``map``) and
``all_tf_s`` (every one of them resolved), seconds from just before the maps were published. They include the
node's waits for its discovery and estimation timers (up to a period each at 1 Hz), as the peer's
first merged /map does. A run in which a robot never resolved within the time-out says INVALID
with why, not a number. Needs the workspace's environment (``make build``; make bench has it).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

from multi_map_merge.lab import processes

# the rates the peer is measured with (bench/peer.py RATES), so that both wait alike
RATES = {'discovery_rate': 1.0, 'estimation_rate': 1.0}
TIMEOUT = 60.0   # s per run, from the maps' publication


def measure(spec_path: str) -> int:
    """The measuring process: publish the maps, poll tf2 for each robot's map frame in ``map``."""
    import rospy
    import tf2_ros
    from nav_msgs.msg import OccupancyGrid

    from multi_map_merge.core.mapio import load_map
    from multi_map_merge.ros.convert import grid_to_msg
    with open(spec_path) as f:
        spec = json.load(f)
    rospy.init_node('mmm_first_tf', disable_signals=True)
    buf = tf2_ros.Buffer()
    tf2_ros.TransformListener(buf)
    msgs = []
    for k, path in enumerate(spec['paths']):
        g = load_map(path)
        msgs.append((rospy.Publisher('/tb3_%d/map' % k, OccupancyGrid, queue_size=1, latch=True),
                     grid_to_msg(g, rospy.Time.now(), 'tb3_%d/map' % k)))
    time.sleep(1.0)                    # the publishers registered (no map yet: nothing to discover)
    t0 = time.time()
    for pub, msg in msgs:
        pub.publish(msg)
    seen = {}
    # tb3_0 is the reference (the first robot by name): the node may broadcast its identity
    # before any other robot is placed; the others are what a team waits for
    frames = ['tb3_%d/map' % k for k in range(1, len(spec['paths']))]
    while time.time() < t0 + spec['timeout'] and len(seen) < len(frames):
        for fr in frames:
            if fr not in seen and buf.can_transform('map', fr, rospy.Time(0)):
                seen[fr] = time.time() - t0
        time.sleep(0.005)
    print(json.dumps({'seen': seen, 'robots': len(frames)}), flush=True)
    return 0


def one_run(paths, base_port: int, work: str) -> dict:
    """One run (see the module's docstring): {'first_tf_s', 'all_tf_s', 'seen'} or {'invalid'}."""
    procs = processes.Processes()
    try:
        with processes.Roscore(base_port, os.path.join(work, 'roscore.log'), os.path.join(work, 'ros'),
                               procs=procs) as core:
            args = ['rosrun', 'multi_map_merge', 'map_merge_node'] + ['_%s:=%s' % kv for kv in RATES.items()]
            node = procs.start(args, os.path.join(work, 'node.log'), core.env)
            end = time.time() + 60
            while True:                  # the node up: its merged /map advertised
                if '/map' in [t for t, _ in core.master.getPublishedTopics('')]:
                    break
                if node.poll() is not None or time.time() > end:
                    return {'invalid': 'our node did not come up (see %s)' % os.path.join(work, 'node.log')}
                time.sleep(0.1)
            spec = os.path.join(work, 'spec.json')
            with open(spec, 'w') as f:
                json.dump({'paths': [os.path.abspath(p) for p in paths], 'timeout': TIMEOUT}, f)
            out = subprocess.run([sys.executable, os.path.abspath(__file__), '--measure', spec],
                                 capture_output=True, text=True, env=core.env, timeout=TIMEOUT + 60)
            lines = [ln for ln in out.stdout.splitlines() if ln.startswith('{')]
            if not lines:
                return {'invalid': 'the measuring process failed: %s' % (out.stderr.strip()[-300:])}
            got = json.loads(lines[-1])
    finally:
        procs.stop_all()
    seen, n = got['seen'], got['robots']
    if len(seen) < n:
        return {'invalid': 'only %d of the %d robots besides the reference resolved in map within %.0f s: '
                           'INVALID' % (len(seen), n, TIMEOUT),
                'seen': seen}
    times = sorted(seen.values())
    return {'first_tf_s': times[0], 'all_tf_s': times[-1], 'seen': seen}


def first_tf(paths, reps: int = 3, base_port: int = 12700) -> dict:
    """``reps`` runs on the maps ``paths``: the medians, every run, the rates; INVALID (with why)
    when any run is."""
    runs = []
    for _ in range(reps):
        r = one_run(paths, base_port, tempfile.mkdtemp(prefix='mmm_first_tf_'))
        runs.append(r)
        if 'invalid' in r:
            return {'invalid': r['invalid'], 'runs': runs, 'rates': RATES}
    return {'first_tf_s': statistics.median(r['first_tf_s'] for r in runs),
            'all_tf_s': statistics.median(r['all_tf_s'] for r in runs), 'runs': runs, 'rates': RATES}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--measure', help=argparse.SUPPRESS)
    ap.add_argument('paths', nargs='*', help='map_server yaml files, one per robot (tb3_0 first)')
    ap.add_argument('--reps', type=int, default=3)
    ap.add_argument('--port', type=int, default=12700, help='first port tried for the private master')
    a = ap.parse_args(argv)
    if a.measure:
        return measure(a.measure)
    if len(a.paths) < 2:
        ap.error('give two maps or more')
    print(json.dumps(first_tf(a.paths, a.reps, a.port)))
    return 0


if __name__ == '__main__':
    sys.exit(main())
