"""``python3 -m multi_map_merge_ros2.home_team [--robots N] [--timeout S]``: a team of N robots'
maps for a merger node to merge, with the answer known. Each robot's map is a piece of the
project's own home (``multi_map_merge.lab.home``, drawn by our code), cut out in a frame of its
own at a pose chosen here, and published transient-local on ``/tb3_<k>/map`` as a map server
does. It then listens on /tf for ``map -> tb3_<k>/map`` and prints how far each is from the
truth (tb3_0's frame being the merged frame), exiting 0 once every robot is within 0.10 m and
1 degree, 1 when ``--timeout`` seconds pass first. The merger runs apart (the README's ROS 2
quick start); this starts no merger."""
from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from multi_map_merge.core.grid import Grid
from multi_map_merge.core.transforms import pose_distance, se2

#: where robot k's map frame lies in the home (x m, y m, yaw rad), k < 4; more robots cycle these
#: turned by 0.3 rad per round
POSES = ((0.0, 0.0, 0.0), (1.5, -0.8, 0.6), (-1.2, 0.9, -0.9), (0.7, 1.3, 2.0))
MAX_DISTANCE = 0.10           # m
MAX_ANGLE = math.radians(1.0)


def team(n: int) -> List[Tuple[Grid, np.ndarray]]:
    """n robots' maps cut from the home, overlapping: [(grid in frame tb3_k/map, T_home_k)]."""
    from multi_map_merge.lab.home import home_grid
    from multi_map_merge.lab.pieces import cut_piece, split_rects
    home = home_grid()
    poses = [(x, y, yaw + 0.3 * (k // len(POSES)))
             for k, (x, y, yaw) in ((k, POSES[k % len(POSES)]) for k in range(n))]
    return [cut_piece(home, rect, pose, 'tb3_%d/map' % k)
            for k, (rect, pose) in enumerate(zip(split_rects(home, n, 0.35), poses))]


def errors(received: Dict[str, np.ndarray], pieces: Sequence[Tuple[Grid, np.ndarray]]
           ) -> Dict[str, Optional[Tuple[float, float]]]:
    """tb3_k -> (metres, radians) of its received TF from the truth, None before any."""
    T0 = pieces[0][1]
    out = {}
    for k, (_, T_k) in enumerate(pieces):
        T = received.get('tb3_%d/map' % k)
        out['tb3_%d' % k] = None if T is None else pose_distance(T, np.linalg.inv(T0) @ T_k)
    return out


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog='home_team', description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--robots', type=int, default=3, help='how many robots (2 or more; default 3)')
    ap.add_argument('--timeout', type=float, default=60.0, help='seconds to wait for every TF (default 60)')
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if args.robots < 2:
        ap.error('--robots must be at least 2')
    import rclpy
    from nav_msgs.msg import OccupancyGrid
    from rclpy.executors import SingleThreadedExecutor
    from tf2_msgs.msg import TFMessage

    from .convert import grid_to_msg, quaternion_yaw
    from .outputs import LATCHED

    pieces = team(args.robots)
    rclpy.init()
    node = rclpy.create_node('home_team')
    received: Dict[str, np.ndarray] = {}

    def on_tf(msg):
        for t in msg.transforms:
            if t.header.frame_id == 'map':
                tr = t.transform
                received[t.child_frame_id] = se2(tr.translation.x, tr.translation.y, quaternion_yaw(tr.rotation))
    node.create_subscription(TFMessage, '/tf', on_tf, 100)
    pubs = []
    for k, (grid, _) in enumerate(pieces):
        pub = node.create_publisher(OccupancyGrid, '/tb3_%d/map' % k, LATCHED)
        pub.publish(grid_to_msg(grid, node.get_clock().now().to_msg()))
        pubs.append(pub)
    print('home_team: %d maps published on /tb3_0/map .. /tb3_%d/map; waiting for map -> tb3_k/map on /tf'
          % (len(pieces), len(pieces) - 1), flush=True)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spin = threading.Thread(target=executor.spin, daemon=True)
    spin.start()
    end = time.monotonic() + args.timeout
    placed = False
    while time.monotonic() < end and not placed:
        time.sleep(1.0)
        errs = errors(dict(received), pieces)
        placed = all(e is not None and e[0] < MAX_DISTANCE and e[1] < MAX_ANGLE for e in errs.values())
    for robot, e in errors(dict(received), pieces).items():
        told = 'no TF' if e is None else '%.3f m, %.2f deg from the truth' % (e[0], math.degrees(e[1]))
        print('%s: %s' % (robot, told))
    print('home_team: %s' % ('every robot placed within %.2f m and 1 deg' % MAX_DISTANCE if placed
                             else 'not every robot placed within %.0f s' % args.timeout), flush=True)
    executor.shutdown()   # (the spinning thread ends before the node goes: rclpy aborts otherwise)
    spin.join(5.0)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0 if placed else 1


if __name__ == '__main__':
    sys.exit(main())
