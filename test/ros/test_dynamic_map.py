#!/usr/bin/env python3
"""rostest: ``dynamic_map`` (nav_msgs/GetMap, gmapping's service): before the reference robot's
first map it answers with an error; once two robots are merged it returns the merged map,
cell for cell what the latched /map carries, in the merged frame."""
import math
import unittest

import numpy as np
import rospy
import rostest
from nav_msgs.srv import GetMap
from rostest_helpers import INTEL_MAP, make_pieces, publish_latched, shared_file, wait_for_merge

from multi_map_merge.core.mapio import load_map
from multi_map_merge.ros.convert import NumpyGrid
from multi_map_merge.ros.tools import init_node

ROBOTS = ['tb3_0', 'tb3_1']


class TestDynamicMap(unittest.TestCase):

    def test_dynamic_map(self):
        init_node('test_dynamic_map')
        rospy.wait_for_service('/dynamic_map', 30.0)
        get_map = rospy.ServiceProxy('/dynamic_map', GetMap)
        with self.assertRaises(rospy.ServiceException):
            get_map()
        pieces = make_pieces(load_map(shared_file(INTEL_MAP)), 2,
                             [(0.0, 0.0, 0.0), (1.0, -2.0, math.radians(60.0))])
        pubs = publish_latched(ROBOTS, [g for g, _ in pieces])  # noqa: F841 (kept: latched maps)
        diag = wait_for_merge(['tb3_1'], timeout=60.0, settle=2.0)
        self.assertEqual(diag.get('tb3_1', {}).get('merged'), 'true', diag.get('tb3_1'))
        topic = rospy.wait_for_message('/map', NumpyGrid, timeout=10.0)
        got = get_map().map
        print('dynamic_map: %dx%d at %.3f m, frame %s; /map: %dx%d' % (
            got.info.width, got.info.height, got.info.resolution, got.header.frame_id,
            topic.info.width, topic.info.height))
        self.assertEqual(got.header.frame_id, 'map')
        self.assertEqual((got.info.width, got.info.height), (topic.info.width, topic.info.height))
        self.assertAlmostEqual(got.info.resolution, topic.info.resolution, places=6)
        self.assertAlmostEqual(got.info.origin.position.x, topic.info.origin.position.x, places=6)
        self.assertAlmostEqual(got.info.origin.position.y, topic.info.origin.position.y, places=6)
        data = np.asarray(got.data, np.int8)
        self.assertEqual(data.size, got.info.width * got.info.height)
        np.testing.assert_array_equal(data, np.asarray(topic.data, np.int8))
        # both robots' pieces are in it: more known cells than either piece alone
        known = int((data >= 0).sum())
        self.assertGreater(known, max(int((g.data >= 0).sum()) for g, _ in pieces))


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'dynamic_map', TestDynamicMap)
