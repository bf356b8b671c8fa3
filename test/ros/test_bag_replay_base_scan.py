#!/usr/bin/env python3
"""rostest: ``bag_replay.launch slam:=rbpf`` on a bag recorded as real LDS-02 robots record
it: ROBOTIS's ``ld08_driver`` stamps every scan ``base_scan`` whatever the robot, while the TF
(each robot's robot_state_publisher, ``tf_prefix``) puts the laser at ``tb3_0/base_scan``.

make_robot_bags writes one robot's sensors in the AWS house with ``--lds02-driver`` (its scans in
frame ``base_scan``). The bag is replayed twice from ``START`` s on, ``PLAY`` s each time, with
the roslaunch logs written under a directory of the test's:

- as shipped (``fix_scan_frame`` true): ``scan_frame_relay`` logs that it republishes
  ``/tb3_0/scan`` from frame "base_scan" in "tb3_0/base_scan" (and resamples it), and the
  robot's SLAM (``SLAM``: rbpf_slam, this package's, with gmapping's interface) publishes
  ``/tb3_0/map`` in frame ``tb3_0/map`` with walls in it;
- with ``fix_scan_frame:=false`` (what ``bag_replay.launch`` did before issue 32: no relay),
  the SLAM processes no scan (no ``update frame`` line) and publishes no map: the scans' frame
  ``base_scan`` is in no TF tree, so it has no laser pose for them. With gmapping the only word
  of it was tf's ``MessageFilter [target=tb3_0/odom ]: Dropped 100.00% of messages so far`` on
  roslaunch's screen (after 15 s of wall time), which names neither the frame nor the fix: the
  silent mistake. The warnings seen are printed, not asserted.
``SLAM = 'gmapping'`` runs it with slam_gmapping (skipped where ROS has no gmapping)."""
import glob
import os
import re
import subprocess
import sys
import tempfile
import time
import unittest

import numpy as np
import rospy
import rostest
from nav_msgs.msg import OccupancyGrid
from rostest_helpers import Collector, make_lds02_driver_bag, skip_without_gmapping, stop_launch

SLAM = 'rbpf'    # bag_replay.launch's slam: rbpf (this package's rbpf_slam) or gmapping

START = 60.0     # s into the bag: the robot is driving
PLAY = 25.0      # s of wall time each replay is given (rate 1)
RELAY_LINE = re.compile(r'scan_frame_relay: scans of /tb3_0/scan in frame "base_scan" republished on '
                        r'/tb3_0/scan_framed in "tb3_0/base_scan"')
RESAMPLED = 'scan_frame_relay: /tb3_0/scan for gmapping:'
UPDATE = re.compile(r'^update frame \d+', re.M)   # the SLAM processed a scan (either prints it)


def log_text(log_dir):
    """Everything roslaunch and its nodes wrote under ``log_dir`` (any depth)."""
    text = []
    for p in sorted({os.path.realpath(p) for p in glob.glob(os.path.join(log_dir, '**', '*.log'), recursive=True)}):
        with open(p, errors='replace') as f:
            text.append(f.read())
    return '\n'.join(text)


class TestBagReplayBaseScan(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        rospy.init_node('test_bag_replay_base_scan', anonymous=True)
        cls.maps = Collector('/tb3_0/map', OccupancyGrid, queue_size=5)

    def replay(self, bag, log_dir, *args):
        """Play the bag through bag_replay.launch slam:=SLAM for PLAY s; the maps seen."""
        self.maps.clear()
        os.makedirs(log_dir)
        # roslaunch's own output (the nodes' stderr, where roscpp's warnings go) beside the logs
        with open(os.path.join(log_dir, 'roslaunch-screen.log'), 'w') as screen:
            launch = subprocess.Popen(
                ['roslaunch', 'multi_map_merge', 'bag_replay.launch', 'bag:=' + bag, 'slam:=' + SLAM,
                 'robot_count:=1', 'rviz:=false', 'output:=log', 'start:=%g' % START] + list(args),
                stdout=screen, stderr=subprocess.STDOUT, start_new_session=True,
                env=dict(os.environ, ROS_LOG_DIR=log_dir))
            try:
                time.sleep(PLAY)
            finally:
                stop_launch(launch)
        return self.maps.messages()

    def test_base_scan_bags_map_only_through_the_relay(self):
        if SLAM == 'gmapping':
            skip_without_gmapping(self)
        tmp = tempfile.mkdtemp(prefix='mmm_base_scan_')
        bag = os.path.join(tmp, 'real.bag')
        make_lds02_driver_bag(self, bag, robots=1)

        # as shipped: the relay says what it does, the SLAM maps
        maps = self.replay(bag, os.path.join(tmp, 'relay'))
        text = log_text(os.path.join(tmp, 'relay'))
        self.assertRegex(text, RELAY_LINE)
        self.assertIn(RESAMPLED, text)
        self.assertRegex(text, UPDATE)
        self.assertTrue(maps, '%s published no /tb3_0/map through the relay' % SLAM)
        last = maps[-1]
        cells = np.asarray(last.data, np.int16)
        print('relay: %d maps, the last %dx%d in %s, %d occupied and %d free cells'
              % (len(maps), last.info.width, last.info.height, last.header.frame_id,
                 int((cells > 50).sum()), int((cells == 0).sum())))
        self.assertEqual(last.header.frame_id, 'tb3_0/map')
        self.assertGreater(int((cells > 50).sum()), 200)
        self.assertGreater(int((cells == 0).sum()), 2000)

        # no relay (bag_replay.launch before issue 32): the SLAM uses no scan, makes no map
        maps = self.replay(bag, os.path.join(tmp, 'norelay'), 'fix_scan_frame:=false')
        text = log_text(os.path.join(tmp, 'norelay'))
        warnings = [ln for ln in text.splitlines() if 'WARN' in ln and 'TF_REPEATED_DATA' not in ln]
        print('no relay: %d maps, %d scans processed; warnings: %s'
              % (len(maps), len(UPDATE.findall(text)), warnings[:5]))
        self.assertEqual(maps, [])
        self.assertIsNone(UPDATE.search(text), '%s processed a scan in frame base_scan' % SLAM)
        self.assertNotIn('scan_frame_relay', text)


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'bag_replay_base_scan', TestBagReplayBaseScan, sys.argv)
