#!/usr/bin/env python3
"""rostest: the live merger node on four robots' maps cut out of the Intel map.

The test node plays four gmapping robots: on ``/tb3_N/map`` (latched, frame ``tb3_N/map``) it
publishes first a small part of its piece (what the robot saw near its start, its frame's origin,
on a cropped grid with its own origin: ``tools.revealed``, as ``publish_maps`` grows its maps),
then, once those are merged and /map has stayed silent over several merge periods (it is sent
only when the merge changes), the whole piece, which must bring a new /map. It broadcasts
each robot's ``tb3_N/map -> tb3_N/odom -> tb3_N/base_footprint`` itself. Each piece was moved
into its robot's frame by a pose we chose, so the answer is known: the merged ``/map`` (in the
reference tb3_0's frame) is compared cell by cell with the world map warped into that frame, and
the TF ``map -> tb3_N/map`` with the true relative poses.

The helpers are in rostest_helpers.py, shared with the other rostests.
"""
import math
import sys
import time

import numpy as np
import rospy
import rostest
from geometry_msgs.msg import PoseWithCovarianceStamped
from rostest_helpers import (
    FOUR_POSES,
    FOUR_ROBOTS,
    START_RADIUS,
    PiecesTest,
    expected_canvas,
    fmt_pose,
    grid_of,
    known_cells,
    known_extent,
    lookup,
    wait_until,
)
from visualization_msgs.msg import Marker, MarkerArray

from multi_map_merge.core.transforms import pose_distance, se2
from multi_map_merge.ros.convert import covariance_of, quaternion_yaw
from multi_map_merge.ros.tools import revealed

PKG = 'multi_map_merge'
ROBOTS = FOUR_ROBOTS
MERGE_PERIOD = 0.25     # s, 1 / merge_rate of merge_node.test
QUIET_PERIODS = 12      # merge periods an unchanged merge must stay silent on /map


class TestMergeNode(PiecesTest):

    NODE = 'test_merge_node'
    ROBOTS = ROBOTS
    POSES = FOUR_POSES
    LATE = ('tb3_0',)   # its gmapping starts last: no map topic until its first map
    t_full = None

    def test_1_growing_maps_merge(self):
        """Small first maps (merged as they are); then, the merge unchanged, no /map for several
        merge periods; then the whole pieces on grown grids with new origins: a new /map with
        more known cells, and every robot still merged."""
        t0 = time.time()
        parts = {}
        for r, (g, _) in zip(ROBOTS, self.pieces):
            parts[r] = revealed(g, START_RADIUS)
            self.assertLess(parts[r].width * parts[r].height, g.width * g.height)
        # tb3_1's map comes first, alone (tb3_0's topic not even there): tb3_1 is the reference
        # for now; tb3_0's map comes before any other robot is merged with it: tb3_0 takes the
        # reference over, as it would have been had its map come first (test_2 and test_3 check
        # the merged map and the TF in tb3_0's frame)
        self.player.publish('tb3_1', parts['tb3_1'])
        alone = wait_until(lambda: (lambda s: s if s and s[1].get('reference') == 'true' else None)(
            self.listen.status('tb3_1', t0)), 20.0)
        self.assertTrue(alone, 'tb3_1, alone with a map, never the reference: %s' % (self.listen.status('tb3_1'),))
        time.sleep(1.0)   # a few discoveries (2 Hz) and estimation cycles with tb3_1 alone
        for r in ROBOTS:
            if r != 'tb3_1':
                self.player.publish(r, parts[r])
        # the first (small) maps alone are enough to place every robot
        first = wait_until(lambda: self.listen.all_merged(ROBOTS, t0), 40.0)
        self.assertTrue(first, 'the small first maps were not all merged: %s' % self._messages())
        # /map is sent on change only: with every small map placed and nothing new coming, a few
        # estimation cycles later (2 Hz here) the merge stands still and /map stays silent
        time.sleep(2.0)
        small = self.listen.latest_map()
        self.assertIsNotNone(small, 'no /map of the small maps')
        n0 = self.listen.maps_received()
        time.sleep(QUIET_PERIODS * MERGE_PERIOD)
        n1 = self.listen.maps_received()
        print('/map messages: %d after the small maps merged, %d more in %d merge periods of an '
              'unchanged merge' % (n0, n1 - n0, QUIET_PERIODS))
        self.assertEqual(n1, n0, '%d /map messages in %d merge periods of an unchanged merge'
                         % (n1 - n0, QUIET_PERIODS))
        self.assertIs(self.listen.latest_map(), small)

        type(self).t_full = time.time()
        for r, (g, _) in zip(ROBOTS, self.pieces):
            self.player.publish(r, g)
        # the robots' maps grew: a new /map, knowing more than the small maps' merge
        grown = wait_until(lambda: self.listen.map_where(lambda m: known_cells(m) > known_cells(small)), 20.0)
        self.assertTrue(grown, 'no new /map after every robot\'s map grew (%d /map so far, the last '
                        'with %d known cells)' % (self.listen.maps_received(), known_cells(self.listen.latest_map())))
        print('/map of the small maps: %d known cells; after they grew: %d' % (known_cells(small), known_cells(grown)))
        # a few estimation cycles on the whole maps, then every robot still merged
        merged = wait_until(lambda: self.listen.all_merged(ROBOTS, self.t_full + 3.0), 40.0)
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
        # the /map of every robot's whole map (sent once, latched: no "next /map" to wait for)
        msg = wait_until(lambda: self.listen.map_where(self.whole_merge), 10.0)
        self.assertIsNotNone(msg, 'no /map of the whole maps: the latest knows %d cells, the pieces %d'
                             % (known_cells(self.listen.latest_map()), self.union_known))
        lv, res, origin = grid_of(msg)
        self.assertAlmostEqual(res, self.world.resolution, places=6)
        self.assertAlmostEqual(origin[2], 0.0, places=6)

        (x0, y0, w, h), ext = expected_canvas(self.pieces, self.T_true)
        cell = res
        print('merged %dx%d origin (%.3f, %.3f); expected %dx%d origin (%.3f, %.3f)'
              % (msg.info.width, msg.info.height, origin[0], origin[1], w, h, x0, y0))
        self.assertLessEqual(abs(origin[0] - x0), 4 * cell)
        self.assertLessEqual(abs(origin[1] - y0), 4 * cell)
        got = known_extent(lv, res, origin)
        print('known extent merged %s, union %s' % (np.round(got, 2), np.round(ext, 2)))
        for a, b in zip(got, ext):
            self.assertLessEqual(abs(a - b), 3 * cell, 'known extent %s, union of pieces %s' % (got, ext))
        self.assert_matches_truth(msg)

    def _check_tf(self, label):
        for k in range(len(ROBOTS)):
            self.assert_tf(k, label)
        d0, a0 = pose_distance(lookup(self.buf, 'map', 'tb3_0/map', 1.0), np.eye(3))
        self.assertLess(d0, 1e-6)
        self.assertLess(a0, 1e-6)

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
            m = self.listen.all_merged(ROBOTS, t_reset)
            if not m:
                return None
            # a placement adopted after the reset: its age is younger than the reset
            for r in ROBOTS[1:]:
                if float(m[r][1]['age_s']) > time.time() - t_reset:
                    return None
            return m
        self.assertTrue(wait_until(remerged, 30.0), 'no re-merge after /map_merge/reset')
        self._check_tf('after reset:')
        # the latest /map is the whole merge once more
        msg = wait_until(lambda: self.listen.map_where(self.whole_merge), 10.0)
        self.assertIsNotNone(msg, 'the /map after the reset is not the whole merge: %d known cells, the '
                             'pieces %d' % (known_cells(self.listen.latest_map()), self.union_known))
        self.assert_matches_truth(msg, 'after reset:')

    def test_5_markers_at_every_robots_origin(self):
        """/map_merge/markers (latched): in the merged frame, an arrow and a name per placed robot
        at its map frame's origin, where the TF puts it, and a line per kept link between two
        robots' origins."""
        self.assertIsNotNone(self.t_full, 'test_1 did not run')
        got = []
        sub = rospy.Subscriber('/map_merge/markers', MarkerArray, got.append, queue_size=5)

        def every_robot():
            arr = got[-1] if got else None
            if arr is None or len([m for m in arr.markers if m.ns == 'robots']) != len(ROBOTS):
                return None
            return arr
        arr = wait_until(every_robot, 10.0)
        sub.unregister()
        self.assertTrue(arr, 'no markers of the %d robots: %s' % (len(ROBOTS), [
            [(m.ns, m.id) for m in a.markers] for a in got[-1:]]))
        self.assertEqual(arr.markers[0].action, Marker.DELETEALL)
        for m in arr.markers[1:]:
            self.assertEqual(m.header.frame_id, 'map')
            self.assertEqual(m.action, Marker.ADD)
        arrows = {m.id: m for m in arr.markers if m.ns == 'robots'}
        names = {m.text.split()[0]: m.id for m in arr.markers if m.ns == 'robot_names'}
        self.assertEqual(sorted(names), ROBOTS)
        origin = {}
        for k, r in enumerate(ROBOTS):
            a = arrows[names[r]]
            self.assertEqual(a.type, Marker.ARROW)
            T = lookup(self.buf, 'map', '%s/map' % r, 5.0)
            self.assertIsNotNone(T, 'no TF map -> %s/map' % r)
            yaw = 2 * math.atan2(a.pose.orientation.z, a.pose.orientation.w)
            d, da = pose_distance(se2(a.pose.position.x, a.pose.position.y, yaw), T)
            print('%s: arrow at (%.3f, %.3f, %.2f deg), TF %s: %.6f m, %.6f deg apart; true pose error %.3f m'
                  % (r, a.pose.position.x, a.pose.position.y, math.degrees(yaw), fmt_pose(T), d,
                     math.degrees(da), pose_distance(T, self.T_true[k])[0]))
            self.assertLess(d, 1e-4)
            self.assertLess(da, 1e-4)
            origin[r] = (a.pose.position.x, a.pose.position.y)
        lines = [m for m in arr.markers if m.ns == 'links']
        labels = [m.text for m in arr.markers if m.ns == 'link_labels']
        print('links: %s' % labels)
        self.assertGreaterEqual(len(lines), len(ROBOTS) - 1, 'four placed robots need three links at least')
        self.assertEqual(len(labels), len(lines))
        for line, text in zip(lines, labels):
            a, b = text.split(':')[0].split('-')
            ends = [(p.x, p.y) for p in line.points]
            self.assertEqual(len(ends), 2)
            for end, robot in zip(ends, (a, b)):
                self.assertAlmostEqual(end[0], origin[robot][0], places=6)
                self.assertAlmostEqual(end[1], origin[robot][1], places=6)

        ellipses = [m for m in arr.markers if m.ns == 'robot_ellipses']
        self.assertEqual(len(ellipses), len(ROBOTS) - 1, 'a 2-sigma ellipse per merged robot but the reference')
        for e in ellipses:
            self.assertEqual(e.type, Marker.CYLINDER)
            self.assertIn((e.pose.position.x, e.pose.position.y), list(origin.values()))

    def test_6_pose_with_covariance_per_robot(self):
        """/<robot>/map_merge/pose (latched): the pose of the robot's map frame in the merged
        frame, equal to the TF map -> <robot>/map; its covariance the merger's (its position
        sigma and weak flag as /diagnostics report them, reported after the pose arrived),
        positive definite in x, y, yaw, z/roll/pitch 0; the reference at identity, covariance 0."""
        self.assertIsNotNone(self.t_full, 'test_1 did not run')
        got = {}
        subs = [rospy.Subscriber('/%s/map_merge/pose' % r, PoseWithCovarianceStamped,
                                 lambda m, r=r: got.__setitem__(r, (m, time.time())), queue_size=5)
                for r in ROBOTS]
        self.assertTrue(wait_until(lambda: len(got) == len(ROBOTS), 10.0), 'poses of %s only' % sorted(got))
        max_sigma = rospy.get_param('/map_merge/max_position_sigma')
        for k, r in enumerate(ROBOTS):
            msg, t_msg = got[r]
            self.assertEqual(msg.header.frame_id, 'map')
            p = msg.pose.pose
            P = se2(p.position.x, p.position.y, quaternion_yaw(p.orientation))
            T = lookup(self.buf, 'map', '%s/map' % r, 5.0)
            self.assertIsNotNone(T, 'no TF map -> %s/map' % r)
            d, da = pose_distance(P, T)
            c6 = np.array(msg.pose.covariance).reshape(6, 6)
            cov = covariance_of(msg)
            st = wait_until(lambda r=r, t=t_msg: self.listen.status(r, t + 0.01), 5.0)
            self.assertTrue(st, 'no /diagnostics of %s after its pose' % r)
            kv = st[1]
            print('%s: pose %s, TF %s: %.6f m %.6f deg apart; cov diag %s; diagnostics sigma_position %s weak %s'
                  % (r, fmt_pose(P), fmt_pose(T), d, math.degrees(da), np.diag(c6), kv.get('sigma_position'),
                     kv.get('weak')))
            self.assertLess(d, 1e-4)
            self.assertLess(da, 1e-4)
            self.assertFalse(c6[2:5].any() or c6[:, 2:5].any(), 'z, roll, pitch must be 0: %s' % c6)
            self.assertTrue(np.array_equal(c6, c6.T))
            if k == 0:
                self.assertLess(pose_distance(P, np.eye(3))[0], 1e-9)
                self.assertFalse(c6.any(), 'the reference is exact: %s' % c6)
                self.assertEqual((kv['sigma_position'], kv['weak']), ('0.0000', 'false'))
                continue
            self.assertIsNotNone(cov, '%s: covariance unknown (-1)' % r)
            self.assertGreater(np.linalg.eigvalsh(cov)[0], 0.0, '%s: not positive definite: %s' % (r, cov))
            sigma = math.sqrt(np.linalg.eigvalsh(cov[:2, :2])[-1])
            self.assertAlmostEqual(sigma, float(kv['sigma_position']), delta=6e-5)
            self.assertEqual(kv['weak'], str(2 * sigma > max_sigma).lower())
            err = pose_distance(P, self.T_true[k])[0]
            print('%s: true pose error %.4f m, %.1f sigma' % (r, err, err / sigma))
        for s in subs:
            s.unregister()


if __name__ == '__main__':
    rostest.rosrun(PKG, 'merge_node', TestMergeNode, sys.argv)
