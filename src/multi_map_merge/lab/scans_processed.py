"""Did every robot's SLAM keep up? Scans received and processed, per robot, after a replay.

    python3 -m multi_map_merge.lab.scans_processed --bag B.bag --logs LOGDIR [--robots tb3_0 ...]
            [--config config/gmapping_lds02.yaml] [--min-share 0.9]
            [--scan-topic /{robot}/scan] [--odom-topic /{robot}/odom]

A live ``slam_gmapping`` (or this package's ``rbpf_slam``, launched with slam:=rbpf: the same
update rule, parameters and output) takes its scans from a subscriber queue of 5 and drops the
oldest while it is busy; on a robot it keeps up and processes every scan its update rule asks for (after
``linearUpdate`` m, ``angularUpdate`` rad or ``temporalUpdate`` s since the last one). A replay
that plays a bag faster than the machine's SLAM nodes can follow makes them process fewer, and
their maps are then not what a robot's would be. This tool counts, per robot:

- ``scans``: the robot's scans in the bag;
- ``received``: the scans that reached its SLAM's update rule (the others were dropped
  from its queue while it was busy);
- ``processed``: the scans its SLAM processed (one ``update frame N`` line each on its
  stdout, which roslaunch's ``output="log"`` writes to ``LOGDIR/**/<ns>-slam_gmapping-*-stdout.log``,
  or ``<ns>-rbpf_slam-*-stdout.log`` for rbpf_slam);
- ``expected``: the scans gmapping's update rule selects from the bag's own odometry
  (:func:`gmapping_updates`): what it processes when it drops none.

Exit status 1 when a robot's SLAM processed under ``--min-share`` of its expected scans.
"""
from __future__ import annotations

import argparse
import glob
import math
import os
import re
import sys
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import yaml

UPDATE_LINE = re.compile(r'^update frame (\d+)\s*$', re.M)
# the SLAM nodes that print one such line per scan processed, by node name (launch/includes/slam_robot.launch)
SLAM_NODES = ('slam_gmapping', 'rbpf_slam')


def gmapping_updates(t: np.ndarray, odom: np.ndarray, linear: float, angular: float,
                     temporal: float) -> np.ndarray:
    """Mask of the scans gmapping's ``GridSlamProcessor::processScan`` processes when it sees
    every scan: the first one, then each one after which the odometry travelled ``linear`` m or
    turned ``angular`` rad in all (summed from scan to scan, as gmapping sums them) or more than
    ``temporal`` s passed since the last processed scan (``temporal`` < 0: never by time).
    ``t``: (S,) scan stamps, seconds; ``odom``: (S, 3) odometry poses (x, y m, yaw rad) at them."""
    keep = np.zeros(len(t), bool)
    if len(t) == 0:
        return keep
    keep[0] = True
    lin = ang = 0.0
    last_t = t[0]
    for i in range(1, len(t)):
        d = odom[i] - odom[i - 1]
        lin += math.hypot(d[0], d[1])
        ang += abs(math.atan2(math.sin(d[2]), math.cos(d[2])))
        if lin >= linear or ang >= angular or (temporal >= 0.0 and t[i] - last_t > temporal):
            keep[i] = True
            lin = ang = 0.0
            last_t = t[i]
    return keep


def count_updates(log_dir: str, robot: str) -> Optional[Tuple[int, int]]:
    """(processed, received): the ``update frame N`` lines in the stdout log of ``robot``'s
    slam_gmapping or rbpf_slam under ``log_dir`` (any depth; roslaunch's ``latest`` link is not
    counted twice), and the scans that reached the update rule (N counts every one of them,
    processed or not: the largest N + 1), summed over the logs found. None when there is no
    such log."""
    paths = [p for node in SLAM_NODES
             for p in glob.glob(os.path.join(log_dir, '**', '%s-%s-*-stdout.log' % (robot, node)), recursive=True)]
    paths = sorted({os.path.realpath(p) for p in paths})
    if not paths:
        return None
    processed = received = 0
    for p in paths:
        with open(p, errors='replace') as f:
            frames = [int(n) for n in UPDATE_LINE.findall(f.read())]
        processed += len(frames)
        received += max(frames) + 1 if frames else 0
    return processed, received


def _interp_odom(t_odom: np.ndarray, odom: np.ndarray, t: np.ndarray) -> np.ndarray:
    yaw = np.unwrap(odom[:, 2])
    return np.stack([np.interp(t, t_odom, odom[:, 0]), np.interp(t, t_odom, odom[:, 1]),
                     np.interp(t, t_odom, yaw)], axis=1)


def bag_scans_and_odom(bag_path: str, robots: Sequence[str], scan_topic: str = '/{robot}/scan',
                       odom_topic: str = '/{robot}/odom') -> Dict[str, Dict[str, np.ndarray]]:
    """Per robot, the stamps of its scans (topic ``scan_topic``, ``{robot}`` replaced by its name)
    and its odometry (``odom_topic``) at them, from a bag (seconds; x, y m, yaw rad)."""
    from ..ros.replay import read_stamps_and_poses  # rosbag: only when reading a bag
    scan_topics = {r: scan_topic.format(robot=r) for r in robots}
    odom_topics = {r: odom_topic.format(robot=r) for r in robots}
    read = read_stamps_and_poses(bag_path, list(scan_topics.values()), list(odom_topics.values()))
    scans = {r: read[scan_topics[r]] for r in robots}
    odo = {r: read[odom_topics[r]] for r in robots}
    out = {}
    for r in robots:
        if not scans[r] or len(odo[r]) < 2:
            continue
        o = np.array(sorted(odo[r]))
        t = np.array(sorted(scans[r]))
        out[r] = {'t': t, 'odom': _interp_odom(o[:, 0], o[:, 1:], t)}
    return out


def load_rule(config_path: str) -> Dict[str, float]:
    """gmapping's update rule from its parameter file (its defaults where unset: 1 m, 0.5 rad,
    no temporal update)."""
    with open(config_path) as f:
        c = yaml.safe_load(f) or {}
    return {'linear': float(c.get('linearUpdate', 1.0)), 'angular': float(c.get('angularUpdate', 0.5)),
            'temporal': float(c.get('temporalUpdate', -1.0))}


def report(bag_path: str, log_dir: str, robots: Sequence[str], rule: Dict[str, float],
           min_share: float = 0.9, label: str = '', scan_topic: str = '/{robot}/scan',
           odom_topic: str = '/{robot}/odom') -> List[Dict]:
    """Per robot: scans, processed, expected (see the module's doc); prints one line each."""
    data = bag_scans_and_odom(bag_path, robots, scan_topic, odom_topic)
    rows = []
    for r in robots:
        d = data.get(r)
        scans = 0 if d is None else len(d['t'])
        expected = 0 if d is None else int(gmapping_updates(d['t'], d['odom'], **rule).sum())
        counted = count_updates(log_dir, r)
        processed, received = counted if counted is not None else (None, None)
        share = None if processed is None or expected == 0 else processed / expected
        ok = share is not None and share >= min_share
        rows.append({'robot': r, 'scans': scans, 'received': received, 'processed': processed,
                     'expected': expected, 'share': share, 'kept_up': ok})
        if counted is None:
            print('%s%s: %d scans in the bag; no log of its SLAM under %s' % (label, r, scans, log_dir))
            continue
        print('%s%s: %d scans in the bag, %d reached its SLAM, it processed %d of the %d its update rule '
              'asks for (%.0f%%)%s' % (label, r, scans, received, processed, expected, 100 * (share or 0.0),
                                      '' if ok else ': it fell behind'))
    return rows


def main(argv: Optional[List[str]] = None) -> int:
    here = os.path.dirname(os.path.abspath(__file__))
    default_cfg = os.path.normpath(os.path.join(here, '..', '..', '..', 'config', 'gmapping_lds02.yaml'))
    ap = argparse.ArgumentParser(prog='scans_processed', description=__doc__.split('\n\n')[0])
    ap.add_argument('--bag', required=True, help='the bag that was replayed')
    ap.add_argument('--logs', required=True, help='the ROS log directory of the replay (ROS_LOG_DIR)')
    ap.add_argument('--robots', nargs='+', default=['tb3_0', 'tb3_1', 'tb3_2', 'tb3_3'])
    ap.add_argument('--config', default=default_cfg, help='gmapping parameters (default: %(default)s)')
    ap.add_argument('--min-share', type=float, default=0.9,
                    help='least share of the expected scans a SLAM node must process (default %(default)s)')
    ap.add_argument('--scan-topic', default='/{robot}/scan', help='the scans in the bag (default %(default)s)')
    ap.add_argument('--odom-topic', default='/{robot}/odom', help='the odometry in the bag (default %(default)s)')
    ap.add_argument('--label', default='', help='text before each line')
    a = ap.parse_args(argv)
    if not os.path.exists(a.bag):
        print('scans_processed: no bag %s' % a.bag, file=sys.stderr)
        return 2
    rows = report(a.bag, a.logs, a.robots, load_rule(a.config), a.min_share, a.label, a.scan_topic,
                  a.odom_topic)
    return 0 if all(r['kept_up'] for r in rows) else 1


if __name__ == '__main__':
    sys.exit(main())
