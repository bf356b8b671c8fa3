#!/usr/bin/env python3
"""rostest: rbpf_slam (rbpf_slam.test) live on one Turtlebot3 exploring the project's own home.

make_robot_bags records what a team's sensors give (LDS-02 scans, odometry with the gyro's
heading, TF) into a bag, rosbag play --clock replays it, and the node under test makes the map
from it as slam_gmapping would. Checked on its outputs: the map's frame, values and fit to the
world (Fitness against the home's ground truth from the robot's true start), map_metadata, the
TF chain tb3_0/map -> tb3_0/odom -> tb3_0/base_footprint, dynamic_map (the same map), and that
it processed every scan gmapping's update rule selects from the bag's odometry."""
import glob
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import unittest

import numpy as np
import rospkg
import rospy
import rostest
import tf2_ros
from nav_msgs.msg import MapMetaData
from nav_msgs.srv import GetMap
from replay_pacer import ReplayPacer, keep_up_line

from multi_map_merge.core.mapio import load_map
from multi_map_merge.lab.evaluate import load_truth, score_map
from multi_map_merge.lab.scans_processed import bag_scans_and_odom, gmapping_updates, load_rule
from multi_map_merge.ros.convert import NumpyGrid, grid_from_msg
from multi_map_merge.ros.tools import init_node

ROBOT = 'tb3_0'
RATE = 2.0          # playback rate: one robot's filter keeps up with it on two cores
MIN_FITNESS = 0.75  # the robot's own map against the world (measured 0.84-0.90 on the house)
KEEP_UP = 0.95      # the least share of the scans its update rule selects that the node must process
PLAYER = 'rbpf_slam_test_play'   # the rosbag play node's name: its ~pause_playback paces it


def package_root() -> str:
    return rospkg.RosPack().get_path('multi_map_merge')


class TestRbpfSlam(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        init_node('test_rbpf_slam')
        cls.tmp = tempfile.mkdtemp(prefix='rbpf_slam_test_')
        cls.bag = os.path.join(cls.tmp, 'home.bag')
        subprocess.run([sys.executable, os.path.join(package_root(), 'scripts', 'make_robot_bags'),
                        '-o', cls.bag, '--robots', '4', '--seed', '2', '--sensors-only', '--no-single'],
                       check=True, stdout=subprocess.DEVNULL)
        cls.truth = load_truth(os.path.join(cls.tmp, 'home.truth.yaml'))
        cls.maps = []
        cls.lock = threading.Lock()

        def on_map(msg):
            with cls.lock:
                cls.maps.append(msg)
        cls.sub = rospy.Subscriber('/%s/map' % ROBOT, NumpyGrid, on_map, queue_size=5)
        cls.tf = tf2_ros.Buffer(rospy.Duration(600.0))
        cls.listener = tf2_ros.TransformListener(cls.tf)
        t0 = time.time()
        # one robot of the team: its scans, odometry and TF (the bag's /tf holds every robot's),
        # the playback paced by the node (ReplayPacer: held while it lags on a busy machine)
        with ReplayPacer([ROBOT], rospkg.get_log_dir(), players=['/' + PLAYER]) as pacer:
            subprocess.run(['rosbag', 'play', '-q', '--clock', '-r', str(RATE), cls.bag, '--topics', '/tf',
                            '/%s/scan' % ROBOT, '/%s/odom' % ROBOT, '__name:=' + PLAYER], check=True)
        cls.play_s = time.time() - t0
        print('rbpf_slam: %s' % pacer.summary())
        # the last map the node publishes after the last scan it processed
        time.sleep(3.0)
        with cls.lock:
            cls.last = cls.maps[-1] if cls.maps else None
        # did the node keep up: if not, every test fails with that line, not with what follows from it
        cls.processed, cls.expected = cls.counts()
        cls.lagged = (keep_up_line(ROBOT, cls.processed, cls.expected, None, pacer.slams[ROBOT].played)
                      if cls.processed is None or cls.processed < KEEP_UP * cls.expected else None)

    @classmethod
    def counts(cls):
        """(scans the node processed, or None without its log; scans its update rule selects)."""
        d = bag_scans_and_odom(cls.bag, [ROBOT])[ROBOT]
        rule = load_rule(os.path.join(package_root(), 'config', 'rbpf_lds02.yaml'))
        expected = int(gmapping_updates(d['t'], d['odom'], **rule).sum())
        logs = glob.glob(os.path.join(rospkg.get_log_dir(), '**', '%s-rbpf_slam-*-stdout.log' % ROBOT),
                         recursive=True)
        if not logs:
            return None, expected
        with open(max(logs, key=os.path.getmtime)) as f:
            return sum(1 for line in f if line.startswith('update frame ')), expected

    def setUp(self):
        if self.lagged:
            self.fail(self.lagged)

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def test_map_fits_the_world(self):
        self.assertIsNotNone(self.last, 'no map on /%s/map' % ROBOT)
        m = self.last
        self.assertEqual(m.header.frame_id, '%s/map' % ROBOT)
        self.assertAlmostEqual(m.info.resolution, 0.05, places=6)
        values = set(np.unique(np.asarray(m.data, np.int8)).tolist())
        self.assertLessEqual(values, {-1, 0, 100})
        grid = grid_from_msg(m, 25_000_000)
        world = load_map(self.truth['world_path'])
        score = score_map(grid, world, T_init=self.truth['starts'][ROBOT])
        print('rbpf_slam: %d maps in %.0f s of playback; last %dx%d, Fitness %.4f, RMSE %.3f m, coverage %.3f'
              % (len(self.maps), self.play_s, m.info.width, m.info.height, score.fitness,
                 score.inlier_rmse, score.coverage))
        self.assertGreaterEqual(score.fitness, MIN_FITNESS)
        self.assertGreater(score.coverage, 0.2)

    def test_metadata_is_the_maps(self):
        meta = rospy.wait_for_message('/%s/map_metadata' % ROBOT, MapMetaData, timeout=10.0)
        self.assertEqual((meta.width, meta.height), (self.last.info.width, self.last.info.height))
        self.assertAlmostEqual(meta.origin.position.x, self.last.info.origin.position.x, places=6)

    def test_dynamic_map_is_the_latest_map(self):
        got = rospy.ServiceProxy('/%s/dynamic_map' % ROBOT, GetMap)().map
        self.assertEqual(got.header.frame_id, '%s/map' % ROBOT)
        np.testing.assert_array_equal(np.asarray(got.data, np.int8), np.asarray(self.last.data, np.int8))

    def test_tf_chain(self):
        # map -> odom is the node's, odom -> base_footprint the bag's: the robot is in its map
        t = self.tf.lookup_transform('%s/map' % ROBOT, '%s/base_footprint' % ROBOT, rospy.Time(0),
                                     rospy.Duration(5.0))
        grid = grid_from_msg(self.last, 25_000_000)
        h, w = grid.data.shape
        c = ((t.transform.translation.x - grid.origin[0]) / grid.resolution,
             (t.transform.translation.y - grid.origin[1]) / grid.resolution)
        self.assertTrue(0 <= c[0] < w and 0 <= c[1] < h, 'robot at cell %s, outside its %dx%d map' % (c, w, h))
        self.assertEqual(int(grid.data[int(c[1]), int(c[0])]), 0, 'the robot stands on a cell not free')

    def test_every_scan_the_rule_asks_for_processed(self):
        self.assertIsNotNone(self.processed, 'no stdout log of the node under %s' % rospkg.get_log_dir())
        print('rbpf_slam: %d processed of the %d scans its update rule selects' % (self.processed, self.expected))
        self.assertGreaterEqual(self.processed, KEEP_UP * self.expected)
        self.assertLessEqual(self.processed, self.expected + 2)


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'rbpf_slam', TestRbpfSlam)
