"""Small ROS tools: the map publisher (saved maps published as growing gmapping maps), saving a
map topic, waiting for a map / the master (the demo). (The relays, light enough for a robot,
are in :mod:`multi_map_merge.ros.relays`.)"""
from __future__ import annotations

import sys
import time
from typing import List, Optional, Sequence

import numpy as np
import rospy
import tf2_ros

from ..core.grid import Grid
from ..core.mapio import load_map, save_map
from ..core.transforms import cell_to_metric, se2
from .convert import NumpyGrid, grid_from_msg, grid_to_msg, transform_msg


def revealed(grid: Grid, radius: float) -> Optional[Grid]:
    """The part of ``grid`` a robot starting at its frame's origin has seen after exploring
    ``radius`` metres, on a grid cropped to it the way gmapping grows its canvas (new size,
    new origin at a whole number of cells)."""
    W = cell_to_metric(grid.resolution, grid.origin)
    rr, cc = np.mgrid[0:grid.height, 0:grid.width]
    x = W[0, 0] * cc + W[0, 1] * rr + W[0, 2]
    y = W[1, 0] * cc + W[1, 1] * rr + W[1, 2]
    seen = np.hypot(x, y) <= radius
    data = np.where(seen, grid.data, -1).astype(np.int8)
    rows = np.flatnonzero((data >= 0).any(axis=1))
    cols = np.flatnonzero((data >= 0).any(axis=0))
    if rows.size == 0:
        return None
    m = 20
    r0, r1 = max(0, rows[0] - m), min(grid.height, rows[-1] + 1 + m)
    c0, c1 = max(0, cols[0] - m), min(grid.width, cols[-1] + 1 + m)
    o = W @ np.array([c0 - 0.5, r0 - 0.5, 1.0])
    return Grid(np.ascontiguousarray(data[r0:r1, c0:c1]), grid.resolution,
                (float(o[0]), float(o[1]), grid.origin[2]), grid.frame_id)


def run_map_publisher(robots: Sequence[str], grids: Sequence[Grid], steps: int, period: float,
                      start_poses: Optional[Sequence[Sequence[float]]] = None,
                      once: bool = False) -> None:
    """Publish each grid on ``/<robot>/map`` (latched, frame ``<robot>/map``) as gmapping would:
    growing in ``steps`` steps from the robot's start (the frame origin), one every ``period``
    seconds, then the whole map again every ``period`` seconds. Also broadcasts the robot's
    own ``<robot>/map -> <robot>/odom -> <robot>/base_footprint`` so TF chains are complete.
    """
    rospy.init_node('map_publisher', anonymous=True)
    pubs = [rospy.Publisher('/%s/map' % r, NumpyGrid, queue_size=1, latch=True) for r in robots]
    tfb = tf2_ros.TransformBroadcaster()
    full_radius = [max(1e-3, float(np.hypot(*np.array([[g.origin[0], g.origin[1]],
                                                        [g.origin[0] + g.width * g.resolution,
                                                         g.origin[1] + g.height * g.resolution]]).T).max()) * 1.5)
                   for g in grids]
    poses = list(start_poses) if start_poses else [(0.0, 0.0, 0.0)] * len(robots)
    k = 0
    next_map = 0.0
    rate = rospy.Rate(10)
    while not rospy.is_shutdown():
        now = rospy.Time.now()
        if time.monotonic() >= next_map:
            k += 1
            for r, g, pub, rad in zip(robots, grids, pubs, full_radius):
                part = g if k >= steps else revealed(g, rad * k / float(steps))
                if part is not None:
                    pub.publish(grid_to_msg(part, now, '%s/map' % r))
            next_map = time.monotonic() + period
            if once and k >= steps:
                rospy.sleep(1.0)
                return
        tfs = []
        for r, p in zip(robots, poses):
            tfs.append(transform_msg(np.eye(3), '%s/map' % r, '%s/odom' % r, now))
            tfs.append(transform_msg(se2(*p), '%s/odom' % r, '%s/base_footprint' % r, now))
        tfb.sendTransform(tfs)
        rate.sleep()


def wait_for_map(topic: str, timeout: float) -> Optional[Grid]:
    """First OccupancyGrid on ``topic`` within ``timeout`` seconds, as a Grid (None if none)."""
    try:
        msg = rospy.wait_for_message(topic, NumpyGrid, timeout=timeout)
    except rospy.ROSException:
        return None
    return grid_from_msg(msg, 10 ** 9)


def wait_for_master(timeout: float) -> bool:
    """True once a ROS master answers at ROS_MASTER_URI (within ``timeout`` seconds)."""
    import rosgraph
    end = time.time() + timeout
    while time.time() < end:
        if rosgraph.is_master_online():
            return True
        time.sleep(0.2)
    return False


def init_node(name: str) -> None:
    rospy.init_node(name, anonymous=True)


# ---------------------------------------------------------------- the scripts
def publish_maps_main(argv: Optional[List[str]] = None) -> int:
    """``publish_maps tb3_0:A.yaml tb3_1:B.yaml ... [--steps 4] [--period 2]``: publish saved
    maps on /<robot>/map as gmapping robots would (latched, growing), for demos and tests
    without robots."""
    from ..cli.args import parser
    ap = parser('publish_maps', publish_maps_main.__doc__)
    ap.add_argument('maps', nargs='+', help='robot:map.yaml pairs')
    ap.add_argument('--steps', type=int, default=4, help='growth steps before the whole map')
    ap.add_argument('--period', type=float, default=2.0, help='seconds between map messages')
    ap.add_argument('--once', action='store_true', help='stop after the whole map was published')
    a = ap.parse_args(rospy.myargv()[1:] if argv is None else argv)
    robots, grids = [], []
    for item in a.maps:
        robot, _, path = item.partition(':')
        if not path:
            ap.error('%r is not robot:map.yaml' % item)
        robots.append(robot)
        grids.append(load_map(path))
    run_map_publisher(robots, grids, a.steps, a.period, once=a.once)
    return 0


def save_map_main(argv: Optional[List[str]] = None) -> int:
    """``save_map -f merged [--topic /map] [--timeout 30]``: save the next OccupancyGrid on a
    topic as map_server files (map_saver is not in Debian)."""
    from ..cli.args import parser
    ap = parser('save_map', save_map_main.__doc__)
    ap.add_argument('-f', '--file', default='map', help='output base name (writes .pgm and .yaml)')
    ap.add_argument('--topic', default='/map')
    ap.add_argument('--timeout', type=float, default=30.0)
    a = ap.parse_args(rospy.myargv()[1:] if argv is None else argv)
    init_node('save_map')
    grid = wait_for_map(a.topic, a.timeout)
    if grid is None:
        print('save_map: no map on %s within %.0f s' % (a.topic, a.timeout), file=sys.stderr)
        return 1
    pgm, yml = save_map(grid, a.file + '.yaml')
    print('saved %s and %s (%dx%d cells)' % (pgm, yml, grid.width, grid.height))
    return 0
