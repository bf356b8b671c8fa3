#!/usr/bin/env python3
"""The robot side's memory: each relay node's resident set (VmRSS, and its peak VmHWM, from
/proc/PID/status) after it started against a real master and, for scan_frame_relay, relayed
LDS-02 driver-shaped scans at 5 Hz for a few seconds.

    bench/bench.py relay-rss [--port 11511] [--src DIR] [--seconds 6]

``--src``: the package's src/ and scripts/ to measure from another checkout (e.g. an earlier
commit's ``git archive``), default this one. Needs a sourced workspace (rospy, roscore)."""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

from multi_map_merge.lab import processes

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))          # (bench/tools/ -> the checkout)
RELAYS = ('scan_frame_relay', 'tf_relay', 'frame_prefix_relay')

FEED = r'''
import math, random, rospy
from sensor_msgs.msg import LaserScan
rospy.init_node('feed_scans')
pub = rospy.Publisher('/tb3_0/scan', LaserScan, queue_size=5)
r = rospy.Rate(5)
while not rospy.is_shutdown():
    n = random.randint(440, 480)
    m = LaserScan()
    m.header.stamp, m.header.frame_id = rospy.Time.now(), 'base_scan'
    m.angle_min = random.uniform(0, 0.01); m.angle_increment = 2 * math.pi / n
    m.angle_max = m.angle_min + (n - 1) * m.angle_increment
    m.range_min, m.range_max = 0.0, 100.0
    m.ranges = [0.0 if random.random() < 0.05 else random.uniform(0.2, 6) for _ in range(n)]
    m.intensities = [100.0] * n
    pub.publish(m); r.sleep()
'''


def status(pid: int) -> dict:
    out = {}
    with open('/proc/%d/status' % pid) as f:
        for line in f:
            k, _, v = line.partition(':')
            if k in ('VmRSS', 'VmHWM'):
                out[k] = int(v.split()[0]) / 1024.0
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog='relay_rss', description=__doc__.split('\n\n')[0])
    ap.add_argument('--port', type=int, default=11511)
    ap.add_argument('--src', default=REPO, help='checkout to measure (its src/ and scripts/)')
    ap.add_argument('--seconds', type=float, default=6.0)
    a = ap.parse_args(argv)
    env = dict(os.environ, ROS_MASTER_URI='http://127.0.0.1:%d' % a.port, ROS_IP='127.0.0.1',
               PYTHONPATH=os.path.join(os.path.abspath(a.src), 'src') + os.pathsep + os.environ.get('PYTHONPATH', ''))
    env.pop('ROS_HOSTNAME', None)
    procs = []

    def start(cmd, **kw):
        p = subprocess.Popen(cmd, env=dict(env, **kw), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             start_new_session=True)
        procs.append(p)
        return p

    try:
        start(['rosmaster', '--core', '-p', str(a.port)])
        time.sleep(2.0)
        start([sys.executable, '-c', FEED])
        rows = []
        for name in RELAYS:
            p = start([sys.executable, os.path.join(os.path.abspath(a.src), 'scripts', name)], ROS_NAMESPACE='tb3_0')
            time.sleep(a.seconds)
            if p.poll() is not None:
                print('%s: exited with %s' % (name, p.returncode), file=sys.stderr)
                continue
            s = status(p.pid)
            rows.append((name, s['VmRSS'], s['VmHWM']))
            p.terminate()
            p.wait(10)
        for name, rss, hwm in rows:
            print('%-20s VmRSS %5.1f MB  VmHWM %5.1f MB' % (name, rss, hwm))
    finally:
        for p in reversed(procs):
            processes.stop_group(p, 10.0, signal.SIGTERM)   # each a session of its own (start)
    return 0


if __name__ == '__main__':
    sys.exit(main())
