#!/usr/bin/env python3
"""rostest: fixing a doubtful merge by clicking a robot's prior in rviz (prior_click.test).

The Turtlebot3 double house (../shared/data/tb3_house/whole_map: two near-identical halves,
180 degrees apart about where the robots started) cut into two robots' maps at known poses:
tb3_0 the upper half, tb3_1 the lower one, sharing a 2 m strip through the start.
(a) With no priors the merger stacks tb3_1's half on tb3_0's: the TF map -> tb3_1/map is the
    look-alike placement, about 180 degrees and metres from the truth.
(b) A rough click with rviz's prior tool for tb3_1 (the tool's topic and the fixed frame read
    from rviz/multi_map_merge.rviz; the message rviz's SetInitialPose tool sends: a
    geometry_msgs/PoseWithCovarianceStamped in the fixed frame, its covariance), 0.5 m and
    10 degrees off the truth.
(c) The merger drops the stacked link, searches the walls near the prior and finds the true
    link: by tf2, tb3_1 within 0.10 m and 1 degree of the truth (not at the click: 0.5 m
    away), merged via tb3_0 (a link, not the prior: ~trust_initial_poses is off).
(d) /tb3_1/map_merge/clear_prior: the maps alone place tb3_1 again, stacked as in (a).
Skipped without ../shared/data.
"""
import math
import os
import sys
import time
import unittest

import rospkg
import rospy
import rostest
import tf2_ros
import yaml
from geometry_msgs.msg import PoseWithCovarianceStamped
from rosgraph_msgs.msg import Log
from rostest_helpers import Listener, RobotPlayer, fmt_pose, lookup, rviz_prior, shared_data, wait_until
from std_msgs.msg import Empty

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import inverse, pose_distance, se2
from multi_map_merge.lab.pieces import halves

PKG = 'multi_map_merge'
ROBOTS = ['tb3_0', 'tb3_1']
POSES = [(0.5, 0.3, 0.2), (-1.0, 0.7, -0.4)]     # the robots' map frames in the house's frame
CLICK = se2(0.3, 0.4, math.radians(10.0))        # the click, relative to the truth: 0.5 m, 10 deg


def rviz_prior_tool(robot):
    """(fixed frame, topic of ``robot``'s prior tool) as rviz/multi_map_merge.rviz sets them."""
    path = os.path.join(rospkg.RosPack().get_path(PKG), 'rviz', 'multi_map_merge.rviz')
    with open(path) as f:
        vm = yaml.safe_load(f)['Visualization Manager']
    topics = [t['Topic'] for t in vm['Tools'] if t.get('Class') == 'rviz/SetInitialPose'
              and t.get('Topic', '').startswith('/%s/' % robot)]
    return vm['Global Options']['Fixed Frame'], topics[0]


class TestPriorClick(unittest.TestCase):

    def error(self, T=None):
        """(metres, degrees) of the TF map -> tb3_1/map from ``T`` (the truth), None without TF."""
        got = lookup(self.buf, 'map', 'tb3_1/map', 0.5)
        if got is None:
            return None
        d, a = pose_distance(got, self.T_true if T is None else T)
        return d, math.degrees(a)

    def tf_where(self, pred):
        def check():
            e = self.error()
            return e if e is not None and pred(*e) else None
        return check

    def test_click_fixes_the_stacked_halves(self):
        d = os.path.join(shared_data(), 'tb3_house', 'whole_map.yaml')
        if not os.path.exists(d):
            self.skipTest('../shared/data/tb3_house is absent')
        rospy.init_node('test_prior_click', anonymous=True)
        (a, Ta), (b, Tb) = halves(load_map(d), 0.0, 1.0, POSES, ['%s/map' % r for r in ROBOTS])
        self.T_true = inverse(Ta) @ Tb           # tb3_1's map frame in the merged frame (tb3_0's)
        self.buf = tf2_ros.Buffer(rospy.Duration(30.0))
        self.tfl = tf2_ros.TransformListener(self.buf)
        listen = Listener()
        logs = []
        rospy.Subscriber('/rosout', Log, lambda m: logs.append(m.msg) if m.name.endswith('map_merge') else None,
                         queue_size=100)
        player = RobotPlayer(ROBOTS)
        player.publish('tb3_0', a)
        player.publish('tb3_1', b)
        frame, topic = rviz_prior_tool('tb3_1')
        self.assertEqual((frame, topic), ('map', '/tb3_1/map_merge/prior'))
        prior_pub = rospy.Publisher(topic, PoseWithCovarianceStamped, queue_size=1)
        clear_pub = rospy.Publisher('/tb3_1/map_merge/clear_prior', Empty, queue_size=1)

        # (a) no priors: the lower half stacked on the upper one
        stacked = wait_until(self.tf_where(lambda m, deg: deg > 170.0), 60.0)
        print('(a) no prior: TF map -> tb3_1/map %s, truth %s: error %s'
              % (fmt_pose(lookup(self.buf, 'map', 'tb3_1/map', 1.0)), fmt_pose(self.T_true), stacked))
        self.assertIsNotNone(stacked, 'tb3_1 not stacked onto the look-alike half: error %s' % (self.error(),))
        self.assertGreater(stacked[0], 2.0)

        # (b) the click, in rviz's fixed frame
        W = self.T_true @ CLICK
        self.assertTrue(wait_until(lambda: prior_pub.get_num_connections() > 0, 10.0))
        prior_pub.publish(rviz_prior(W, frame))
        t0 = time.time()

        # (c) the true link found near the click
        fixed = wait_until(self.tf_where(lambda m, deg: m < 0.10 and deg < 1.0), 60.0)
        err = self.error()
        off_d, off_a = pose_distance(W, self.T_true)
        print('(c) click %s (%.2f m, %.1f deg off the truth): TF %s, error %s after %.1f s'
              % (fmt_pose(W), off_d, math.degrees(off_a), fmt_pose(lookup(self.buf, 'map', 'tb3_1/map', 1.0)),
                 err, time.time() - t0))
        self.assertIsNotNone(fixed, 'tb3_1 not within 0.10 m / 1 deg of the truth after the click: error %s'
                             % (err,))
        d_click, a_click = self.error(W)
        self.assertGreater(d_click, 0.4, 'tb3_1 put at the click, not where its walls meet')
        since = time.time()
        st = wait_until(lambda: listen.status('tb3_1', since), 10.0)
        self.assertIsNotNone(st)
        print('    /diagnostics: %s (%s)' % (st[0].message, st[1]))
        self.assertEqual(st[1].get('merged'), 'true')
        self.assertEqual(st[1].get('via'), 'tb3_0', 'tb3_1 not placed by a link')
        self.assertTrue([m for m in logs if 'link tb3_0 -> tb3_1 dropped: it contradicts the new prior' in m],
                        logs[-10:])
        # it stays there
        time.sleep(3.0)
        err = self.error()
        self.assertTrue(err[0] < 0.10 and err[1] < 1.0, err)

        # (d) cleared: the maps alone place tb3_1 again, on the look-alike half
        self.assertTrue(wait_until(lambda: clear_pub.get_num_connections() > 0, 10.0))
        clear_pub.publish(Empty())
        back = wait_until(self.tf_where(lambda m, deg: deg > 170.0), 60.0)
        print('(d) prior cleared: error %s' % (self.error(),))
        self.assertIsNotNone(back, 'tb3_1 not back on the look-alike placement after clear_prior: %s'
                             % (self.error(),))
        player.stop()


if __name__ == '__main__':
    rostest.rosrun(PKG, 'prior_click', TestPriorClick, sys.argv)
