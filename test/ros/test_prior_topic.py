#!/usr/bin/env python3
"""rostest: priors given while running, as rviz's 2D Pose Estimate gives them.

Two robots' maps (pieces of the Intel map at known poses) merge where the maps say. Then
tb3_1's prior is published on /tb3_1/map_merge/prior (geometry_msgs/PoseWithCovarianceStamped),
in a frame of the test's ("survey", tied to the merged frame by a TF the test broadcasts): it
puts tb3_1's map frame 5 m and 40 degrees away from where the maps place it. The kept link
contradicts it and is dropped, the pair is estimated again and rejected under it, and with
~trust_initial_poses the robot is placed at its prior: the TF map -> tb3_1/map is the prior,
transformed into the merged frame. /tb3_1/map_merge/clear_prior (std_msgs/Empty) removes it:
the link places the robot where the maps say again. Bad priors (a zero quaternion, a frame
with no TF) are logged and ignored, and the node keeps merging. Last, scan_frame_relay
republishes a robot's scans in its own laser frame.
"""
import math
import sys
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from rosgraph_msgs.msg import Log
from rostest_helpers import INTEL_MAP, RobotPlayer, fmt_pose, lookup, make_pieces, rviz_prior, shared_file, wait_until
from sensor_msgs.msg import LaserScan
from std_msgs.msg import Empty

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import inverse, pose_distance, se2, xyyaw
from multi_map_merge.ros.convert import set_yaw

PKG = 'multi_map_merge'
ROBOTS = ['tb3_0', 'tb3_1']
POSES = [(1.5, -1.0, math.radians(20.0)), (-3.0, 2.0, math.radians(150.0))]
SURVEY = se2(1.0, -2.0, 0.5)      # the test's frame "survey" in the merged frame


class TestPriorTopic(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        rospy.init_node('test_prior_topic', anonymous=True)
        world = load_map(shared_file(INTEL_MAP))
        cls.pieces = make_pieces(world, 2, POSES)
        cls.T_true = inverse(cls.pieces[0][1]) @ cls.pieces[1][1]
        cls.buf = tf2_ros.Buffer(rospy.Duration(30.0))
        cls.tfl = tf2_ros.TransformListener(cls.buf)
        cls.static = tf2_ros.StaticTransformBroadcaster()
        t = TransformStamped()
        t.header.stamp = rospy.Time.now()
        t.header.frame_id, t.child_frame_id = 'map', 'survey'
        x, y, yaw = xyyaw(SURVEY)
        t.transform.translation.x, t.transform.translation.y = x, y
        set_yaw(t.transform.rotation, yaw)
        cls.static.sendTransform(t)
        cls.log_lock = threading.Lock()
        cls.logs = []
        rospy.Subscriber('/rosout', Log, cls._on_log, queue_size=100)
        cls.prior_pub = rospy.Publisher('/tb3_1/map_merge/prior', PoseWithCovarianceStamped, queue_size=1)
        cls.clear_pub = rospy.Publisher('/tb3_1/map_merge/clear_prior', Empty, queue_size=1)
        cls.player = RobotPlayer(ROBOTS)
        for r, (g, _) in zip(ROBOTS, cls.pieces):
            cls.player.publish(r, g)

    @classmethod
    def tearDownClass(cls):
        cls.player._stop = True

    @classmethod
    def _on_log(cls, msg):
        if msg.name.endswith('map_merge'):
            with cls.log_lock:
                cls.logs.append(msg.msg)

    def logged(self, text):
        with self.log_lock:
            return [m for m in self.logs if text in m]

    def tf_near(self, T, tol_m, tol_rad):
        def near():
            got = lookup(self.buf, 'map', 'tb3_1/map', 0.5)
            if got is None:
                return None
            d, a = pose_distance(got, T)
            return [got] if d <= tol_m and a <= tol_rad else None
        return near

    def publish_prior(self, T, frame):
        msg = rviz_prior(T, frame)
        self.assertTrue(wait_until(lambda: self.prior_pub.get_num_connections() > 0, 10.0),
                        'the node does not subscribe to /tb3_1/map_merge/prior')
        self.prior_pub.publish(msg)

    def test_1_prior_moves_the_robot_and_clearing_it_undoes_the_gate(self):
        maps_say = wait_until(self.tf_near(self.T_true, 0.1, math.radians(1.0)), 60.0)
        self.assertIsNotNone(maps_say, 'tb3_1 not merged where the maps say: %s'
                             % fmt_pose(lookup(self.buf, 'map', 'tb3_1/map', 1.0)))
        # the prior, 5 m and 40 degrees from the link, given in the frame "survey"
        W = self.T_true @ se2(3.0, 4.0, math.radians(40.0))
        self.publish_prior(inverse(SURVEY) @ W, 'survey')
        at_prior = wait_until(self.tf_near(W, 1e-3, 1e-4), 30.0)
        got = lookup(self.buf, 'map', 'tb3_1/map', 1.0)
        print('prior %s, TF %s' % (fmt_pose(W), fmt_pose(got)))
        self.assertIsNotNone(at_prior, 'tb3_1 not placed at its prior %s: TF %s' % (fmt_pose(W), fmt_pose(got)))
        self.assertTrue(self.logged('prior of tb3_1 from /tb3_1/map_merge/prior'), self.logs[-10:])
        self.assertTrue(self.logged('link tb3_0 -> tb3_1 dropped: it contradicts the new prior'), self.logs[-10:])
        # it stays there: the pair, estimated again under the prior, is rejected
        time.sleep(3.0)
        self.assertTrue(self.tf_near(W, 1e-3, 1e-4)(), 'tb3_1 left its prior')
        # cleared: the maps place it again
        self.assertTrue(wait_until(lambda: self.clear_pub.get_num_connections() > 0, 10.0))
        self.clear_pub.publish(Empty())
        back = wait_until(self.tf_near(self.T_true, 0.1, math.radians(1.0)), 60.0)
        self.assertIsNotNone(back, 'tb3_1 not back where the maps say after clear_prior: %s'
                             % fmt_pose(lookup(self.buf, 'map', 'tb3_1/map', 1.0)))
        self.assertTrue(self.logged('prior of tb3_1 cleared'))

    def test_2_bad_priors_are_logged_and_ignored(self):
        before = lookup(self.buf, 'map', 'tb3_1/map', 5.0)
        self.assertIsNotNone(before)
        zero = PoseWithCovarianceStamped()
        zero.header.frame_id = 'map'
        self.prior_pub.publish(zero)                      # zero quaternion
        self.assertTrue(wait_until(lambda: self.logged('orientation is not a rotation'), 10.0))
        self.publish_prior(se2(1.0, 1.0, 0.0), 'nowhere')   # a frame with no TF
        self.assertTrue(wait_until(lambda: self.logged('no TF from its frame "nowhere"'), 15.0), self.logs[-5:])
        time.sleep(2.0)
        d, a = pose_distance(lookup(self.buf, 'map', 'tb3_1/map', 2.0), before)
        self.assertLess(d, 0.05)
        self.assertLess(a, math.radians(0.5))

    def test_3_scan_frame_relay(self):
        got = []
        rospy.Subscriber('/tb3_5/scan_framed', LaserScan, got.append, queue_size=10)
        pub = rospy.Publisher('/tb3_5/scan', LaserScan, queue_size=10)
        self.assertTrue(wait_until(lambda: pub.get_num_connections() > 0, 10.0))
        scan = LaserScan()
        scan.header.frame_id = 'base_scan'              # what ld08_driver (noetic) stamps
        scan.ranges = list(np.linspace(0.2, 3.0, 360))
        end = time.time() + 10.0
        while not got and time.time() < end:
            scan.header.stamp = rospy.Time.now()
            pub.publish(scan)
            time.sleep(0.2)
        self.assertTrue(got, 'nothing on /tb3_5/scan_framed')
        self.assertEqual(got[0].header.frame_id, 'tb3_5/base_scan')
        self.assertEqual(len(got[0].ranges), 360)
        self.assertAlmostEqual(got[0].ranges[-1], 3.0, places=5)


if __name__ == '__main__':
    rostest.rosrun(PKG, 'prior_topic', TestPriorTopic, sys.argv)
