"""The ROS-free half of `make demo` (``scripts/run_demo`` drives ROS; this module never imports rospy).

    python3 -m multi_map_merge.demo_tools inputs WORLD.yaml OUT_DIR [--robots 4] [--seed 3]
    python3 -m multi_map_merge.demo_tools config BASE.yaml OUT.yaml key=value ...
    python3 -m multi_map_merge.demo_tools report STATUS.yaml MERGED.yaml PNG robot:map.yaml ...
                                                 [--truth truth.yaml] [--title TEXT]

``inputs`` cuts overlapping pieces of a real map, each moved into a frame of its own at a known
pose (``tb3_N.yaml`` and ``truth.yaml``: pose of every frame in tb3_0's frame). ``config`` writes
a copy of the merger's parameter file with a few values changed. ``report`` prints every
robot's transform, reliability and agreement as the node reported them on /diagnostics (and
the error against the known pose, when known), and draws the inputs and the merged map side by
side. Its exit status is 1 when a robot was not merged or is further than 0.1 m / 1 degree from
its known pose.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from typing import Dict, List, Optional, Sequence

import cv2
import numpy as np
import yaml

from .grid import Grid
from .mapio import grid_to_pgm, load_map, save_map
from .synth import cut_piece, random_poses, split_rects
from .transforms import pose_distance, se2, xyyaw

MAX_ERROR_M = 0.1
MAX_ERROR_DEG = 1.0


def make_inputs(world_yaml: str, out_dir: str, robots: int = 4, seed: int = 3) -> Dict[str, np.ndarray]:
    """Cut ``robots`` overlapping pieces of the world map, each in its own frame ``tb3_N/map``;
    write them as ``out_dir/tb3_N.yaml`` and the true pose of each frame in tb3_0's frame as
    ``out_dir/truth.yaml`` ({robot: {x, y, yaw}}, metres and radians). Returns the poses."""
    world = load_map(world_yaml)
    os.makedirs(out_dir, exist_ok=True)
    rects = split_rects(world, robots, 0.3)
    poses = random_poses(robots, seed, 4.0)
    pieces = [cut_piece(world, r, p, 'tb3_%d/map' % i) for i, (r, p) in enumerate(zip(rects, poses))]
    T0inv = np.linalg.inv(pieces[0][1])
    truth = {}
    for i, (g, T) in enumerate(pieces):
        save_map(g, os.path.join(out_dir, 'tb3_%d.yaml' % i))
        truth['tb3_%d' % i] = T0inv @ T
    with open(os.path.join(out_dir, 'truth.yaml'), 'w') as f:
        yaml.safe_dump({k: dict(zip(('x', 'y', 'yaw'), map(float, xyyaw(T)))) for k, T in truth.items()}, f)
    return truth


def load_truth(path: str) -> Dict[str, np.ndarray]:
    with open(path) as f:
        d = yaml.safe_load(f) or {}
    return {k: se2(v['x'], v['y'], v['yaw']) for k, v in d.items()}


def write_config(base_yaml: str, out_yaml: str, overrides: Dict[str, object]) -> None:
    """``base_yaml`` with ``overrides`` applied (values parsed as YAML), written to ``out_yaml``."""
    with open(base_yaml) as f:
        cfg = yaml.safe_load(f) or {}
    unknown = set(overrides) - set(cfg)
    if unknown:
        raise KeyError('not a merger parameter: %s' % ', '.join(sorted(unknown)))
    cfg.update(overrides)
    with open(out_yaml, 'w') as f:
        yaml.safe_dump(cfg, f, default_flow_style=None, sort_keys=False)


def side_by_side(inputs: Sequence[Grid], names: Sequence[str], merged: Grid, path: str,
                 height: int = 420) -> None:
    """PNG: every input map, then the merged map, each scaled to one height, with a title."""
    tiles = []
    items = list(zip(inputs, names)) + [(merged, 'merged (%dx%d)' % (merged.width, merged.height))]
    for g, title in items:
        img = grid_to_pgm(g)
        s = height / float(img.shape[0])
        img = cv2.resize(img, (max(1, int(round(img.shape[1] * s))), height), interpolation=cv2.INTER_AREA)
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        img = cv2.copyMakeBorder(img, 36, 6, 6, 6, cv2.BORDER_CONSTANT, value=(255, 255, 255))
        cv2.putText(img, title, (8, 26), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 2, cv2.LINE_AA)
        tiles.append(img)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if not cv2.imwrite(path, np.hstack(tiles)):
        raise OSError('could not write %s' % path)


def _f(d: Dict[str, str], key: str, fmt: str) -> str:
    try:
        return fmt % float(d[key])
    except (KeyError, TypeError, ValueError):
        return '-'


def report(status: Dict, names: Sequence[str], truth: Optional[Dict[str, np.ndarray]] = None) -> bool:
    """Print one line per robot from the collected /diagnostics values and TF lookups (see
    ``scripts/run_demo``); True when every robot is merged (and within tolerance of the truth)."""
    robots = status.get('robots', {})
    print('%-6s %-6s %8s %8s %9s %7s %9s %7s %-7s %s' % (
        'robot', 'merged', 'x [m]', 'y [m]', 'yaw [deg]', 'inlier', 'agreement', 'inliers', 'via',
        'error vs known pose' if truth else 'TF map -> robot/map'))
    ok = True
    for n in names:
        d = robots.get(n, {})
        merged = d.get('merged') == 'true'
        ok &= merged
        if not merged:
            print('%-6s %-6s  %s' % (n, 'no', d.get('message', 'no diagnostics from the merger')))
            continue
        yaw = _f(d, 'yaw', '%.6f')
        ref = d.get('reference') == 'true'
        line = '%-6s %-6s %8s %8s %9s %7s %9s %7s %-7s ' % (
            n, 'yes', _f(d, 'x', '%.3f'), _f(d, 'y', '%.3f'),
            '%.2f' % math.degrees(float(yaw)) if yaw != '-' else '-',
            _f(d, 'inlier_ratio', '%.3f'), _f(d, 'agreement', '%.3f'),
            '-' if ref else d.get('inliers', '-'), '(ref)' if ref else d.get('via', '-'))
        tf = d.get('tf')
        if truth is not None and n in truth:
            if tf is None:
                line += 'no TF'
                ok = False
            else:
                dist, dyaw = pose_distance(se2(*tf), truth[n])
                good = dist <= MAX_ERROR_M and math.degrees(dyaw) <= MAX_ERROR_DEG
                ok &= good
                line += '%.3f m, %.2f deg%s' % (dist, math.degrees(dyaw), '' if good else '  TOO FAR')
        else:
            line += ('x=%.3f y=%.3f yaw=%.2f deg' % (tf[0], tf[1], math.degrees(tf[2]))
                     if tf is not None else 'no TF')
        print(line)
    if 'merged_after_s' in status:
        print('every robot merged %.1f s after the merger started' % status['merged_after_s']
              if status.get('all_merged') else
              'NOT every robot merged within %.0f s' % status.get('timeout_s', 0))
    return ok


def _main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog='demo_tools', description=__doc__.split('\n\n')[0])
    sub = ap.add_subparsers(dest='cmd', required=True)
    p = sub.add_parser('inputs', help='cut robot maps with known poses out of a real map')
    p.add_argument('world')
    p.add_argument('out_dir')
    p.add_argument('--robots', type=int, default=4)
    p.add_argument('--seed', type=int, default=3)
    p = sub.add_parser('config', help='copy the merger parameters with some values changed')
    p.add_argument('base')
    p.add_argument('out')
    p.add_argument('overrides', nargs='*', help='key=value (value parsed as YAML)')
    p = sub.add_parser('report', help='print transforms and draw the side-by-side PNG')
    p.add_argument('status', help='YAML written by run_demo from /diagnostics and TF')
    p.add_argument('merged', help='merged map .yaml (from save_map)')
    p.add_argument('png')
    p.add_argument('maps', nargs='+', help='robot:map.yaml pairs, as given to publish_maps')
    p.add_argument('--truth', help='truth.yaml from `inputs`')
    p.add_argument('--title', default='')
    a = ap.parse_args(argv)

    if a.cmd == 'inputs':
        make_inputs(a.world, a.out_dir, a.robots, a.seed)
        return 0
    if a.cmd == 'config':
        kv = {}
        for item in a.overrides:
            k, sep, v = item.partition('=')
            if not sep:
                ap.error('%r is not key=value' % item)
            kv[k] = yaml.safe_load(v)
        write_config(a.base, a.out, kv)
        return 0
    names, grids = [], []
    for item in a.maps:
        robot, _, path = item.partition(':')
        names.append(robot)
        grids.append(load_map(path))
    with open(a.status) as f:
        status = yaml.safe_load(f) or {}
    if a.title:
        print('\n== %s' % a.title)
    ok = report(status, names, load_truth(a.truth) if a.truth else None)
    if os.path.exists(a.merged):
        side_by_side(grids, names, load_map(a.merged), a.png)
    else:
        print('no merged map saved (%s)' % a.merged)
        ok = False
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(_main())
