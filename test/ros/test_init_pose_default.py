#!/usr/bin/env python3
"""rostest: with the defaults (``~known_init_poses`` false) m-explore's per-robot priors
``/<robot>/map_merge/init_pose_*`` are ignored. The set-up of ROBOTIS's Gazebo multi-robot
launch (init_pose_* = the spawn positions, 14 m apart, every map frame at the world origin):
two pieces of the Intel map published in one frame are merged at identity, not 14 m apart."""
import math
import unittest

import rospy
import rostest
from rostest_helpers import INTEL_MAP, lookup_transforms, make_pieces, publish_latched, shared_file, wait_for_merge

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import xyyaw
from multi_map_merge.ros.tools import init_node

ROBOTS = ['tb3_0', 'tb3_1']


class TestInitPoseDefault(unittest.TestCase):

    def test_init_pose_params_ignored_by_default(self):
        init_node('test_init_pose_default')
        self.assertFalse(rospy.get_param('/map_merge/known_init_poses'))
        self.assertEqual(rospy.get_param('/tb3_1/map_merge/init_pose_x'), 7.0)   # the trap is set
        pieces = make_pieces(load_map(shared_file(INTEL_MAP)), 2, [(0.0, 0.0, 0.0)] * 2)
        pubs = publish_latched(ROBOTS, [g for g, _ in pieces])  # noqa: F841 (kept: latched maps)
        diag = wait_for_merge(['tb3_1'], timeout=60.0, settle=2.0)
        self.assertEqual(diag.get('tb3_1', {}).get('merged'), 'true', diag.get('tb3_1'))
        self.assertNotEqual(diag['tb3_1'].get('via'), 'initial_pose', diag['tb3_1'])
        tf = lookup_transforms('map', ['tb3_1/map'], 10.0)
        self.assertIn('tb3_1/map', tf)
        x, y, yaw = xyyaw(tf['tb3_1/map'])
        print('tb3_1/map in map: x=%.3f y=%.3f yaw=%.2f deg (%s)' % (x, y, math.degrees(yaw), diag['tb3_1']))
        self.assertLess(math.hypot(x, y), 0.1)
        self.assertLess(abs(math.degrees(yaw)), 1.0)


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'init_pose_default', TestInitPoseDefault)
