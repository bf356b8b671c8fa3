#!/usr/bin/env python3
"""rostest: the merger warns, once per frame and naming the sender, when another node publishes
its TF map -> <robot>/map (setup_check.test), on /tf and on /tf_static; the installed
robot_state_publisher (1.15.2 or later here) gives no warning."""
import sys
import time
import unittest

import rospy
import rostest
from rosgraph_msgs.msg import Log
from rostest_helpers import MERGER, Collector, wait_until

PKG = 'multi_map_merge'
SENDERS = {'tb3_1/map': '/world_to_tb3_1_tf_broadcaster', 'tb3_2/map': '/tb3_2_static_map'}


class TestSetupCheck(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        rospy.init_node('test_setup_check', anonymous=True)
        cls.logs = Collector('/rosout', Log, keep=lambda m: m.name == '/' + MERGER)

    def warnings(self, text):
        return [m.msg for m in self.logs.messages() if m.level == Log.WARN and text in m.msg]

    def test_other_senders_of_a_robots_map_tf_are_named_once(self):
        def both():
            return all(self.warnings('map -> %s' % child) for child in SENDERS)
        self.assertTrue(wait_until(both, 45.0), self.warnings('publishes the TF'))
        time.sleep(5.0)   # 50 more /tf messages from the first sender: no more lines
        for child, node in SENDERS.items():
            lines = self.warnings('map -> %s' % child)
            print(lines)
            self.assertEqual(len(lines), 1, lines)
            self.assertIn('node %s publishes the TF map -> %s' % (node, child), lines[0])
        self.assertIn('/tf_static', self.warnings('map -> tb3_2/map')[0])
        self.assertEqual(self.warnings('-> odom'), [])
        self.assertEqual(self.warnings('robot_state_publisher'), [])


if __name__ == '__main__':
    rostest.rosrun(PKG, 'setup_check', TestSetupCheck, sys.argv)
