"""``make_robot_bags``: rosbags of several Turtlebot3s mapping a building, with the truth.

    make_robot_bags -o house.bag [--world home|aws-small-house|MAP.yaml] [--robots 4] [--seed 1]
    make_robot_bags -o intel.bag --carmen intel-corrected.log.gz --world intel_gt.yaml
    make_robot_bags -o real.bag --sensors-only --lds02-driver   # scans as ROBOTIS's LDS-02 driver sends them

Writes ``house.bag`` (the team: ``/tb3_N/scan``, ``/tb3_N/odom``, ``/tb3_N/map``, ``/tf``,
``/clock``), with a world map also ``house_single.bag`` (one robot exploring everything alone),
and ``house.truth.yaml``: the ground-truth map and the pose of every robot's map frame in it,
read by ``evaluate_map --truth``. Scans are ray cast in the world map (LDS-02), or with
``--carmen`` the real scans of a CARMEN log cut into the robots' stretches. The world is by
default the project's own home (multi_map_merge.lab.home, 119 m2 of free floor), written beside the
bag as ``home.yaml`` + ``home.pgm`` for the truth file to name; ``aws-small-house`` is the AWS
small house read in place from ../shared/data (multi_map_merge.lab.worlds); any other value is
a map_server ``.yaml``. See :mod:`multi_map_merge.lab.simulate` for the models. Exit status 2
names a bad input file.
"""
from __future__ import annotations

import os
import sys
import time
from typing import List, Optional

import numpy as np
import yaml

from ..cli.args import parser
from ..core.mapio import MapFileError
from ..core.transforms import wrap_angle
from .simulate import SimConfig, ld08_driver_scans, read_carmen, simulate_carmen, simulate_world
from .worlds import AWS_SMALL_HOUSE, HOME, world_map

# ``--world``'s default: the project's own home, drawn by lab/home.py (no file to install)
DEFAULT_WORLD = HOME

# CARMEN logs: the buildings are bigger and the scans sparser than a Turtlebot3's. Their poses
# are already a SLAM result on a far better laser (1 cm noise, 80 m) than an LDS-02 (3 m used):
# the drift added on top is 5% of the LDS-02 model's (see the README for what larger drift does)
CARMEN_DEFAULTS = dict(max_urange=10.0, map_update_interval=10.0)
CARMEN_DRIFT = 0.05


def odom_heading_error(run) -> float:
    """Degrees: the largest heading error of the robot's odometry over its run."""
    err = wrap_angle(run.odom[:, 2] - (run.true[:, 2] - run.true[0, 2]))
    return float(np.degrees(np.max(np.abs(err))))


def _run_info(run) -> dict:
    return {'start': [round(float(v), 6) for v in run.start], 'distance_m': round(run.distance, 2),
            'turned_rad': round(run.turned, 2), 'duration_s': round(float(run.t[-1]), 1),
            'scans': int(len(run.scans.steps)), 'maps': len(run.maps),
            'odom_heading_error_deg': round(odom_heading_error(run), 2)}


def main(argv: Optional[List[str]] = None) -> int:
    ap = parser('make_robot_bags', __doc__)
    ap.add_argument('-o', '--output', required=True,
                    help='bag to write (NAME.bag; also NAME_single.bag, NAME.truth.yaml)')
    ap.add_argument('--world', default=DEFAULT_WORLD,
                    help='%s (default: the project\'s own home, written beside the bag as home.yaml), %s (the '
                         'AWS small house in ../shared/data), or a ground-truth map_server .yaml'
                         % (HOME, AWS_SMALL_HOUSE))
    ap.add_argument('--carmen', help='CARMEN log (.log or .log.gz): real scans instead of ray casting')
    ap.add_argument('--robots', type=int, default=4)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--no-single', action='store_true', help='do not write the single-robot bag')
    ap.add_argument('--sensors-only', action='store_true',
                    help='write only what the robots\' sensors record (scans, odometry, their TF): no SLAM '
                         'model\'s maps or map -> odom, for a live gmapping to make them')
    ap.add_argument('--slam-drift', type=float, default=None,
                    help='scale of the SLAM drift model (default 1 for ray casting, %.2f for CARMEN logs; '
                         '0 = perfect SLAM)' % CARMEN_DRIFT)
    ap.add_argument('--wheel-heading', action='store_true',
                    help='odometry takes its heading from the wheels (a robot without an IMU), not from '
                         'the gyro as a Burger\'s does')
    ap.add_argument('--lds02-driver', action='store_true',
                    help='record the scans as ROBOTIS\'s LDS-02 driver for Noetic (ld08_driver) publishes them: '
                         'each revolution of its own length, 0 for no point, range 0-100 m, in frame base_scan '
                         'whatever the robot (scan_frame_relay makes them fit for gmapping, in <robot>/base_scan, '
                         'where the TF puts the laser); the truth and the SLAM model\'s maps are unchanged')
    a = ap.parse_args(argv)
    if a.robots < 1 or a.robots > 16:
        print('make_robot_bags: --robots must be 1..16', file=sys.stderr)
        return 2
    base = a.output[:-4] if a.output.endswith('.bag') else a.output
    os.makedirs(os.path.dirname(os.path.abspath(base)), exist_ok=True)
    try:
        world_path, world = world_map(a.world, os.path.dirname(os.path.abspath(base)))
    except (MapFileError, OSError) as e:
        print('make_robot_bags: %s (--world)' % e, file=sys.stderr)
        return 2
    from ..ros.replay import write_robot_bag  # rosbag: only when writing
    extra = dict(CARMEN_DEFAULTS) if a.carmen else {}
    cfg = SimConfig(robots=a.robots, seed=a.seed, wheel_heading=a.wheel_heading, **extra)
    if a.slam_drift is None:
        a.slam_drift = CARMEN_DRIFT if a.carmen else 1.0
    s = a.slam_drift ** 2
    cfg.slam_trans_var *= s
    cfg.slam_rot_var *= s
    cfg.slam_turn_var *= s
    cfg.slam_bias *= a.slam_drift
    t0 = time.time()
    lone = None
    if a.carmen:
        try:
            log = read_carmen(a.carmen)
        except ValueError as e:
            print('make_robot_bags: %s' % e, file=sys.stderr)
            return 2
        team = simulate_carmen(log, cfg)
    else:
        # the lone robot drives about three times as long as the team: not simulated unless written
        team, lone = simulate_world(world, cfg, lone=not a.no_single)
    if a.lds02_driver:
        shape_rng = np.random.default_rng(a.seed + 1000)
        for run in team + ([lone] if lone is not None else []):
            run.scans = ld08_driver_scans(run.scans, shape_rng, cfg.scan_rate)
    t_sim = time.time() - t0
    # ld08_driver stamps its scans base_scan whatever its frame_id parameter says
    scan_frame = 'base_scan' if a.lds02_driver else None
    counts = write_robot_bag(base + '.bag', team, slam=not a.sensors_only, scan_frame=scan_frame)
    truth = {'world': os.path.relpath(world_path, os.path.dirname(os.path.abspath(base))),
             'source': ('carmen:' + os.path.basename(a.carmen)) if a.carmen else 'raycast',
             'seed': a.seed, 'scans': 'ld08_driver' if a.lds02_driver else 'fixed',
             'odometry_heading': 'wheels' if a.wheel_heading else 'gyro',
             'slam_drift': None if a.sensors_only else a.slam_drift,
             'slam_model': not a.sensors_only, 'reference': team[0].name,
             'bag': os.path.basename(base + '.bag'),
             'robots': {r.name: _run_info(r) for r in team}}
    if lone is not None and not a.no_single:
        write_robot_bag(base + '_single.bag', [lone], slam=not a.sensors_only, scan_frame=scan_frame)
        truth['single'] = dict(_run_info(lone), bag=os.path.basename(base + '_single.bag'), name=lone.name)
    with open(base + '.truth.yaml', 'w') as f:
        f.write('# written by make_robot_bags: pose (x, y, yaw; m, rad) of each robot\'s map frame\n'
                '# (its start) in the ground-truth map\'s frame\n')
        yaml.safe_dump(truth, f, sort_keys=False)
    print('make_robot_bags: %d robots (%s) in %.1f s + bag %.1f s: %s' % (
        len(team), truth['source'], t_sim, time.time() - t0 - t_sim, base + '.bag'))
    for r in team:
        print('  %-6s %6.1f m driven  %5.0f s  %4d scans  %3d maps  odometry heading off by up to %.1f deg  '
              'start (%.2f, %.2f, %.2f)' % (r.name, r.distance, r.t[-1], len(r.scans.steps), len(r.maps),
                                            odom_heading_error(r), *r.start))
    if 'single' in truth:
        print('  single %6.1f m driven  %5.0f s  odometry heading off by up to %.1f deg: %s' % (
            lone.distance, lone.t[-1], odom_heading_error(lone), base + '_single.bag'))
    print('  topics: ' + ', '.join('%s %d' % kv for kv in sorted(counts.items())))
    return 0
