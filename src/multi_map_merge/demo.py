"""`make demo`: four robots' maps published live as gmapping would, merged by the real node.

Starts its own roscore on a free port, publishes four pieces of the shipped Intel map (each in
its own frame, at a known pose, growing over a few seconds) on /tb3_N/map, launches
map_merge.launch, waits until every robot is merged, saves the merged map, prints each robot's
transform and reliability next to the known answer, draws a side-by-side PNG, and stops
everything it started. ROS is used only through subprocesses and :mod:`ros_adapter`.
"""
from __future__ import annotations

import math
import os
import signal
import socket
import subprocess
import sys
import time
from typing import Dict, List

import cv2
import numpy as np
import yaml

from .grid import Grid
from .mapio import grid_to_pgm, load_map, save_map
from .synth import cut_piece, random_poses, split_rects
from .transforms import pose_distance, xyyaw


def make_inputs(world_yaml: str, out_dir: str, robots: int, seed: int) -> Dict[str, np.ndarray]:
    """Cut ``robots`` overlapping pieces of the world map, each in its own frame; write them as
    ``tb3_N.yaml`` and the true pose of each frame in tb3_0's frame to ``truth.yaml``."""
    world = load_map(world_yaml)
    pieces = [cut_piece(world, r, p, 'tb3_%d/map' % i)
              for i, (r, p) in enumerate(zip(split_rects(world, robots, 0.3), random_poses(robots, seed, 4.0)))]
    truth = {}
    for i, (g, T) in enumerate(pieces):
        save_map(g, os.path.join(out_dir, 'tb3_%d.yaml' % i))
        truth['tb3_%d' % i] = np.linalg.inv(pieces[0][1]) @ T
    with open(os.path.join(out_dir, 'truth.yaml'), 'w') as f:
        yaml.safe_dump({k: dict(zip(('x', 'y', 'yaw'), map(float, xyyaw(T)))) for k, T in truth.items()}, f)
    return truth


def side_by_side(inputs: List[Grid], names: List[str], merged: Grid, path: str, height: int = 420) -> None:
    """PNG: every input map, then the merged map, scaled to one height, with titles."""
    tiles = []
    for g, title in list(zip(inputs, names)) + [(merged, 'merged (%dx%d)' % (merged.width, merged.height))]:
        img = grid_to_pgm(g)
        s = height / float(img.shape[0])
        img = cv2.resize(img, (max(1, int(img.shape[1] * s)), height), interpolation=cv2.INTER_AREA)
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        img = cv2.copyMakeBorder(img, 36, 6, 6, 6, cv2.BORDER_CONSTANT, value=(255, 255, 255))
        cv2.putText(img, title, (8, 26), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 0, 0), 2, cv2.LINE_AA)
        tiles.append(img)
    cv2.imwrite(path, np.hstack(tiles))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def main() -> int:
    repo = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..'))
    out = os.path.join(os.getcwd(), 'demo_output')
    inputs_dir = os.path.join(out, 'inputs')
    os.makedirs(inputs_dir, exist_ok=True)
    robots = 4
    names = ['tb3_%d' % i for i in range(robots)]
    truth = make_inputs(os.path.join(repo, 'test', 'data', 'intel.yaml'), inputs_dir, robots, seed=3)
    print('demo: %d robots, pieces of the Intel lab map (test/data/intel.yaml) in their own frames' % robots)

    env = dict(os.environ)
    env['ROS_MASTER_URI'] = 'http://localhost:%d' % free_port()
    env.setdefault('ROS_HOME', os.path.join(out, 'ros_home'))
    procs: List[subprocess.Popen] = []

    def start(cmd: List[str], log: str) -> subprocess.Popen:
        p = subprocess.Popen(cmd, env=env, stdout=open(os.path.join(out, log), 'w'),
                             stderr=subprocess.STDOUT, start_new_session=True)
        procs.append(p)
        return p

    try:
        port = env['ROS_MASTER_URI'].rsplit(':', 1)[1]
        start(['roscore', '-p', port], 'roscore.log')
        os.environ.update(env)
        from . import ros_adapter  # ROS only from here on, through the adapter
        if not ros_adapter.wait_for_master(20.0):
            print('demo: roscore did not start (see demo_output/roscore.log)', file=sys.stderr)
            return 1
        start(['rosrun', 'multi_map_merge', 'publish_maps', '--steps', '3', '--period', '2']
              + ['%s:%s' % (n, os.path.join(inputs_dir, n + '.yaml')) for n in names], 'publish_maps.log')
        start(['roslaunch', 'multi_map_merge', 'map_merge.launch', 'output:=log'], 'map_merge.log')
        t0 = time.time()
        ros_adapter.init_node('demo')
        status = ros_adapter.wait_for_merge(names, timeout=90.0, settle=8.0)
        merged_at = time.time() - t0
        grid = ros_adapter.wait_for_map('/map', 10.0)
        poses = ros_adapter.lookup_transforms('map', ['%s/map' % n for n in names], 10.0)
        if grid is None:
            print('demo: no merged map on /map', file=sys.stderr)
            return 1
        save_map(grid, os.path.join(out, 'merged.yaml'))
        side_by_side([load_map(os.path.join(inputs_dir, n + '.yaml')) for n in names], names, grid,
                     os.path.join(out, 'side_by_side.png'))
        print('\n%-6s %-7s %9s %9s %9s %8s %9s %6s  %s' % ('robot', 'merged', 'x [m]', 'y [m]', 'yaw [deg]',
                                                           'inlier', 'agreement', 'via', 'error vs truth'))
        ok = True
        for n in names:
            st = status.get(n, {})
            T = poses.get('%s/map' % n)
            if T is None:
                ok = False
                print('%-6s %-7s  (no TF map -> %s/map)  %s' % (n, 'no', n, st.get('message', '')))
                continue
            x, y, yaw = xyyaw(T)
            d, a = pose_distance(T, truth[n])
            print('%-6s %-7s %9.3f %9.3f %9.2f %8s %9s %6s  %.3f m, %.2f deg'
                  % (n, st.get('merged', '?'), x, y, math.degrees(yaw), st.get('inlier_ratio', '-'),
                     st.get('agreement', '-'), st.get('via', '-'), d, math.degrees(a)))
            ok &= d < 0.1 and math.degrees(a) < 1.0
        print('\nall robots merged %.1f s after start; merged map %dx%d cells at %.2f m'
              % (merged_at, grid.width, grid.height, grid.resolution))
        print('wrote demo_output/merged.{pgm,yaml}, demo_output/side_by_side.png (logs: demo_output/*.log)')
        return 0 if ok else 1
    finally:
        for p in reversed(procs):
            try:
                os.killpg(p.pid, signal.SIGINT)
            except ProcessLookupError:
                pass
        deadline = time.time() + 10
        for p in procs:
            try:
                p.wait(max(0.1, deadline - time.time()))
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
