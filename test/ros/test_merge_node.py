#!/usr/bin/env python3
"""rostest: the live merger node on four robots' maps cut out of the Intel map.

The test node plays four gmapping robots: on ``/tb3_N/map`` (latched, frame ``tb3_N/map``) it
publishes first a small part of its piece (what the robot saw near its start, on a cropped grid
with its own origin), then, once the merger has received those, the whole piece. It broadcasts
each robot's ``tb3_N/map -> tb3_N/odom -> tb3_N/base_footprint`` itself. Each piece was moved
into its robot's frame by a pose we chose, so the answer is known: the merged ``/map`` (in the
reference tb3_0's frame) is compared cell by cell with the world map warped into that frame, and
the TF ``map -> tb3_N/map`` with the true relative poses.

The helpers are in rostest_helpers.py, shared with the other rostests.
"""
import math
import sys
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from nav_msgs.msg import OccupancyGrid
from rospy.numpy_msg import numpy_msg
from rostest_helpers import (
    Listener,
    RobotPlayer,
    compare_with_truth,
    data_file,
    expected_canvas,
    fmt_pose,
    grid_of,
    known_extent,
    lookup,
    make_pieces,
    revealed,
    union_mask_of,
    wait_until,
)

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import pose_distance

PKG = 'multi_map_merge'
NumpyGrid = numpy_msg(OccupancyGrid)
ROBOTS = ['tb3_0', 'tb3_1', 'tb3_2', 'tb3_3']
# pose (x m, y m, yaw rad) of each robot's map frame in the world (Intel map) frame
POSES = [(1.5, -1.0, math.radians(20.0)),
         (-3.0, 2.0, math.radians(180.0)),
         (4.0, 3.5, math.radians(-95.0)),
         (-2.5, -4.0, math.radians(135.0))]
TF_TOL_M = 0.10
TF_TOL_RAD = math.radians(1.0)


class TestMergeNode(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        rospy.init_node('test_merge_node', anonymous=True)
        cls.world = load_map(data_file('intel.yaml'))
        cls.pieces = make_pieces(cls.world, 4, POSES)
        T_w0 = cls.pieces[0][1]
        cls.T_world_map = T_w0                     # merged frame = reference tb3_0's map frame
        cls.T_true = [np.linalg.inv(T_w0) @ T for _, T in cls.pieces]
        cls.union = union_mask_of(cls.world, cls.pieces)
        cls.buf = tf2_ros.Buffer(rospy.Duration(30.0))
        cls.tfl = tf2_ros.TransformListener(cls.buf)
        cls.listen = Listener()
        cls.player = RobotPlayer(ROBOTS)
        cls.t_full = None

    @classmethod
    def tearDownClass(cls):
        cls.player._stop = True

    def _all_merged(self, after):
        out = {}
        for r in ROBOTS:
            s = self.listen.status(r, after)
            if s is None or s[1].get('merged') != 'true':
                return None
            out[r] = s
        return out

    def test_1_growing_maps_merge(self):
        """Small first maps (merged as they are), then the whole pieces on grown grids with new
        origins: every robot stays merged."""
        t0 = time.time()
        for r, (g, _) in zip(ROBOTS, self.pieces):
            part = revealed(g, 8.0)
            self.assertLess(part.width * part.height, g.width * g.height)
            self.player.publish(r, part)
        # the first (small) maps alone are enough to place every robot
        first = wait_until(lambda: self._all_merged(t0), 40.0)
        self.assertTrue(first, 'the small first maps were not all merged: %s' % self._messages())
        type(self).t_full = time.time()
        for r, (g, _) in zip(ROBOTS, self.pieces):
            self.player.publish(r, g)
        # a few estimation cycles (2 Hz here) on the whole maps, then every robot still merged
        merged = wait_until(lambda: self._all_merged(self.t_full + 3.0), 40.0)
        self.assertTrue(merged, 'not every robot merged: %s' % self._messages())
        for r, (st, kv) in merged.items():
            self.assertEqual(st.level, 0, '%s: %s' % (r, st.message))
            print('%s: %s %s' % (r, st.message, kv))
        self.assertEqual(merged['tb3_0'][1].get('reference'), 'true')

    def _messages(self):
        return {r: (s[0].message if s else None)
                for r, s in ((r, self.listen.status(r)) for r in ROBOTS)}

    def test_2_merged_map_matches_truth(self):
        self.assertIsNotNone(self.t_full, 'test_1 did not run')
        # a /map composed after every robot's whole map and placement were in
        t_ok = time.time()
        msg = wait_until(lambda: self.listen.map_after(t_ok), 10.0)
        self.assertIsNotNone(msg, 'no /map after the merge')
        self.assertEqual(msg.header.frame_id, 'map')
        lv, res, origin = grid_of(msg)
        self.assertAlmostEqual(res, self.world.resolution, places=6)
        self.assertAlmostEqual(origin[2], 0.0, places=6)

        (x0, y0, w, h), ext = expected_canvas(self.pieces, self.T_true)
        cell = res
        print('merged %dx%d origin (%.3f, %.3f); expected %dx%d origin (%.3f, %.3f)'
              % (msg.info.width, msg.info.height, origin[0], origin[1], w, h, x0, y0))
        self.assertLessEqual(abs(msg.info.width - w), 4, 'width %d, expected %d' % (msg.info.width, w))
        self.assertLessEqual(abs(msg.info.height - h), 4, 'height %d, expected %d' % (msg.info.height, h))
        self.assertLessEqual(abs(origin[0] - x0), 4 * cell)
        self.assertLessEqual(abs(origin[1] - y0), 4 * cell)
        got = known_extent(lv, res, origin)
        print('known extent merged %s, union %s' % (np.round(got, 2), np.round(ext, 2)))
        for a, b in zip(got, ext):
            self.assertLessEqual(abs(a - b), 3 * cell, 'known extent %s, union of pieces %s' % (got, ext))

        sc = compare_with_truth(msg, self.world, self.T_world_map, self.union)
        print('merged vs truth: %s' % sc)
        self.assertGreaterEqual(sc['occ_precision'], 0.95, sc)
        self.assertLessEqual(sc['free_wrong'], 0.02, sc)
        self.assertLessEqual(sc['outside'], 0.01, sc)
        self.assertGreaterEqual(sc['recall'], 0.97, sc)
        self.assertLess(abs(sc['known'] - sc['union_known']) / float(sc['union_known']), 0.05, sc)

    def _check_tf(self, label):
        errs = {}
        for k, r in enumerate(ROBOTS):
            T = lookup(self.buf, 'map', '%s/map' % r, 5.0)
            self.assertIsNotNone(T, 'no TF map -> %s/map' % r)
            d, a = pose_distance(T, self.T_true[k])
            errs[r] = (d, math.degrees(a))
            print('%s TF map -> %s/map %s, true %s: error %.4f m, %.3f deg'
                  % (label, r, fmt_pose(T), fmt_pose(self.T_true[k]), d, math.degrees(a)))
            self.assertLess(d, TF_TOL_M, '%s: %.3f m off' % (r, d))
            self.assertLess(a, TF_TOL_RAD, '%s: %.3f deg off' % (r, math.degrees(a)))
        d0, a0 = pose_distance(lookup(self.buf, 'map', 'tb3_0/map', 1.0), np.eye(3))
        self.assertLess(d0, 1e-6)
        self.assertLess(a0, 1e-6)
        return errs

    def test_3_tf_matches_true_poses(self):
        self.assertIsNotNone(self.t_full, 'test_1 did not run')
        self._check_tf('merged:')
        for r in ROBOTS:
            T = lookup(self.buf, 'map', '%s/base_footprint' % r, 5.0)
            self.assertIsNotNone(T, 'map -> %s/base_footprint does not resolve' % r)

    def test_4_reset_merges_again(self):
        self.assertIsNotNone(self.t_full, 'test_1 did not run')
        from std_srvs.srv import Trigger
        rospy.wait_for_service('/map_merge/reset', 10.0)
        t_reset = time.time()
        resp = rospy.ServiceProxy('/map_merge/reset', Trigger)()
        self.assertTrue(resp.success, resp.message)

        def remerged():
            m = self._all_merged(t_reset)
            if not m:
                return None
            # a placement adopted after the reset: its age is younger than the reset
            for r in ROBOTS[1:]:
                if float(m[r][1]['age_s']) > time.time() - t_reset:
                    return None
            return m
        self.assertTrue(wait_until(remerged, 30.0), 'no re-merge after /map_merge/reset')
        self._check_tf('after reset:')
        t_ok = time.time()
        msg = wait_until(lambda: self.listen.map_after(t_ok), 10.0)
        self.assertIsNotNone(msg)
        sc = compare_with_truth(msg, self.world, self.T_world_map, self.union)
        self.assertGreaterEqual(sc['occ_precision'], 0.95, sc)
        self.assertGreaterEqual(sc['recall'], 0.97, sc)


if __name__ == '__main__':
    rostest.rosrun(PKG, 'merge_node', TestMergeNode, sys.argv)
