#!/usr/bin/env python3
"""rostest: the three isr_small robots' real gmapping bags, replayed at once into /tb3_0..2
by replay_robot_bags.launch, end up merged into one consistent map (skipped without
../shared/data): under the live TF every pair of their last maps overlaps and agrees, and each
robot's walls lie on the walls of the others where they mapped the same place; the same check
fails with any robot moved 1 m."""
import math
import os
import subprocess
import time
import unittest

import cv2
import numpy as np
import rostest
from rostest_helpers import lookup_transforms, shared_data, stop_launch, wait_for_merge

from multi_map_merge.core.config import MergeConfig
from multi_map_merge.core.grid import OCCUPIED, UNKNOWN
from multi_map_merge.core.merger import MapMerger
from multi_map_merge.core.transforms import cell_to_metric, pose_distance, pose_to_image, se2
from multi_map_merge.core.verify import agreement
from multi_map_merge.ros.replay import read_bag_maps
from multi_map_merge.ros.tools import init_node, wait_for_map

ROBOTS = ['tb3_0', 'tb3_1', 'tb3_2']
# One consistent map of one small building: every pair of the three last maps overlaps under the
# TF (about 14000 cells each, on the offline merge's placements; 3000-10000 with a robot 1 m or
# 5 degrees off), walls meeting walls (agreement 0.986-0.998 offline; 0.08-0.46 with a robot
# 1 m or 5 degrees off); and each robot's walls, where another robot mapped the place, lie on
# that robot's walls (0.978-0.996 within 2 cells offline; 0.05-0.29 for a robot 1 m or 5 degrees off).
MIN_PAIR_OVERLAP = 2000     # known cells both maps have
MIN_PAIR_AGREEMENT = 0.95
MIN_WALLS_SEEN = 300        # a robot's wall cells on another robot's known cells
MIN_WALLS_ON_WALLS = 0.9    # of those, the share within NEAR_CELLS of that robot's walls
NEAR_CELLS = 2.0


def walls_on_others(finals, tf, r):
    """(robot ``r``'s wall cells that fall on a known cell of another robot's map under the TF
    ``tf`` (robot -> 3x3 pose of its map frame in the merged frame), the share of them within
    NEAR_CELLS of that robot's walls): the robots' maps checked against each other, not against
    a merge made of them."""
    g = finals[r]
    rr, cc = np.nonzero(g.levels() == OCCUPIED)
    metric = cell_to_metric(g.resolution, g.origin) @ np.stack([cc, rr, np.ones_like(rr)])
    seen = np.zeros(len(rr), bool)
    near = np.zeros(len(rr), bool)
    for o, h in finals.items():
        if o == r:
            continue
        levels = h.levels()
        dist = cv2.distanceTransform((levels != OCCUPIED).astype(np.uint8), cv2.DIST_L2, 5)
        p = np.linalg.inv(cell_to_metric(h.resolution, h.origin)) @ np.linalg.inv(tf[o]) @ tf[r] @ metric
        c, q = np.rint(p[0]).astype(int), np.rint(p[1]).astype(int)
        inside = np.nonzero((c >= 0) & (q >= 0) & (c < h.width) & (q < h.height))[0]
        k = inside[levels[q[inside], c[inside]] != UNKNOWN]
        seen[k] = True
        near[k] |= dist[q[k], c[k]] <= NEAR_CELLS
    return int(seen.sum()), float(near[seen].mean()) if seen.any() else 0.0


def consistency_failures(finals, tf, report=False):
    """What is wrong with the robots' last maps ``finals`` placed by ``tf`` as one map (robot ->
    3x3 pose, metres): a list of lines, empty when every pair overlaps and agrees and every
    robot's walls lie on the others' walls (the limits above). ``report``: print the figures."""
    out = []
    for a, b in [('tb3_0', 'tb3_1'), ('tb3_1', 'tb3_2'), ('tb3_0', 'tb3_2')]:
        ga, gb = finals[a], finals[b]
        A = pose_to_image(np.linalg.inv(tf[a]) @ tf[b], ga.resolution, ga.origin, gb.resolution, gb.origin)
        ag, overlap = agreement(ga.levels(), gb.levels(), A, 2)
        if report:
            print('%s-%s: agreement %.3f over %d cells both know' % (a, b, ag, overlap))
        if overlap < MIN_PAIR_OVERLAP:
            out.append('%s-%s overlap %d cells (< %d)' % (a, b, overlap, MIN_PAIR_OVERLAP))
        elif ag < MIN_PAIR_AGREEMENT:
            out.append('%s-%s agreement %.3f (< %.2f)' % (a, b, ag, MIN_PAIR_AGREEMENT))
    for r in sorted(finals):
        seen, on_walls = walls_on_others(finals, tf, r)
        if report:
            print('%s: %d wall cells on the others\' known cells, %.3f of them on their walls' % (r, seen, on_walls))
        if seen < MIN_WALLS_SEEN or on_walls < MIN_WALLS_ON_WALLS:
            out.append('%s: %d wall cells on the others\' known cells (>= %d wanted), %.3f on their walls '
                       '(>= %.2f wanted)' % (r, seen, MIN_WALLS_SEEN, on_walls, MIN_WALLS_ON_WALLS))
    return out


class TestMrgsReplay(unittest.TestCase):

    def test_three_real_robots_merge_into_one_consistent_map(self):
        bags = [os.path.join(shared_data(), 'mrgs', 'bags_gmapping', 'isr_small_gmapping_%d.bag' % k)
                for k in (1, 2, 3)]
        if not all(os.path.exists(b) for b in bags):
            self.skipTest('../shared/data/mrgs is absent: the real robots\' bags are not here')
        init_node('test_mrgs_replay')
        launch = subprocess.Popen(['roslaunch', 'multi_map_merge', 'replay_robot_bags.launch', 'rviz:=false',
                                   'rate:=6', 'output:=log'] + ['bag_%d:=%s' % (i, b) for i, b in enumerate(bags)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            t0 = time.time()
            # the bags last 137-153 s: about 25 s at 6x; then the merger works on the last maps
            diag = wait_for_merge(ROBOTS[1:], timeout=150.0, settle=40.0)
            print('merged after %.0f s: %s' % (time.time() - t0, {r: diag.get(r, {}).get('message') for r in ROBOTS}))
            for r in ROBOTS[1:]:
                self.assertEqual(diag.get(r, {}).get('merged'), 'true', '%s: %s' % (r, diag.get(r)))
            tf = lookup_transforms('map', ['%s/map' % r for r in ROBOTS], 10.0)
            merged = wait_for_map('/map', 10.0)
        finally:
            stop_launch(launch)
        self.assertEqual(sorted(tf), ['%s/map' % r for r in ROBOTS], 'TF of every robot, by tf2')
        self.assertIsNotNone(merged)
        finals = {r: read_bag_maps(b)['/map'][-1] for r, b in zip(ROBOTS, bags)}
        for g in finals.values():
            g.frame_id = ''
        live = {r: tf['%s/map' % r] for r in ROBOTS}
        failures = consistency_failures(finals, live, report=True)
        self.assertEqual(failures, [], 'the live merge is not one consistent map')
        # the check sees a robot 1 m off (the same maps, one robot's TF moved 1 m in its map frame)
        for r in ROBOTS:
            moved = dict(live, **{r: live[r] @ se2(1.0, 0.0, 0.0)})
            self.assertNotEqual(consistency_failures(finals, moved), [], '%s moved 1 m passes the check' % r)
        offline = MapMerger(MergeConfig.from_dict({'reference_robot': 'tb3_0', 'workers': 1}))
        for r in ROBOTS:
            offline.update_map(r, finals[r])
        offline.estimate()
        pl = offline.placements()
        for r in ROBOTS[1:]:
            if r in pl:
                d, a = pose_distance(pl[r].T, tf['%s/map' % r])
                print('%s: live vs offline on the last maps: %.3f m %.2f deg' % (r, d, math.degrees(a)))
                # Not asserted: the live merge sometimes ends on a corridor look-alike about
                # 1.4 m along (pair agreement 0.94 against 0.995 offline); see the README.


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'mrgs_replay', TestMrgsReplay)
