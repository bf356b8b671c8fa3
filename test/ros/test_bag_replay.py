#!/usr/bin/env python3
"""rostest: a generated robots' bag through `roslaunch multi_map_merge bag_replay.launch`
(real rosbag play --clock, /use_sim_time, the node, tf2), scored against the bag's truth."""
import math
import os
import subprocess
import sys
import tempfile
import unittest

import numpy as np
import rospkg
import rostest
from rostest_helpers import stop_launch

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import se2
from multi_map_merge.lab.evaluate import load_truth, score_map, transform_errors
from multi_map_merge.ros.replay import record_replay
from multi_map_merge.ros.tools import init_node

ROBOTS = ['tb3_0', 'tb3_1', 'tb3_2']


class TestBagReplay(unittest.TestCase):

    def test_replay_merges_every_robot_where_the_truth_says(self):
        pkg = rospkg.RosPack().get_path('multi_map_merge')
        tmp = tempfile.mkdtemp(prefix='mmm_bag_')
        bag = os.path.join(tmp, 'house3.bag')
        r = subprocess.run([sys.executable, os.path.join(pkg, 'scripts', 'make_robot_bags'), '-o', bag,
                            '--robots', '3', '--seed', '2', '--no-single'], capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertTrue(os.path.getsize(bag) > 1_000_000)
        init_node('test_bag_replay')
        launch = subprocess.Popen(['roslaunch', 'multi_map_merge', 'bag_replay.launch', 'bag:=' + bag,
                                   'slam:=recorded', 'rviz:=false', 'rate:=4', 'output:=log'],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        try:
            rec = record_replay(ROBOTS, period=0.5, idle=4.0, timeout=200.0)
        finally:
            stop_launch(launch)
        truth = load_truth(bag[:-4] + '.truth.yaml')
        self.assertIsNotNone(rec['clock'], 'no /clock: the bag did not play')
        self.assertGreater(rec['clock'], 1_600_000_100.0, 'the bag did not play to its end')
        # every robot merged (diagnostics) and placed by TF where the truth says
        est = {}
        for name in ROBOTS:
            got = rec['robots'][name]
            self.assertEqual(got['diagnostics'].get('merged'), 'true', '%s: %s' % (name, got['diagnostics']))
            self.assertIsNotNone(got['tf'], '%s: no TF map -> %s/map' % (name, name))
            est[name] = se2(*got['tf'])
            self.assertGreater(len(got['trajectory']), 20, name)
        starts = {k: se2(*v['start']) for k, v in truth['robots'].items()}
        errors = transform_errors(est, starts, 'tb3_0')
        # the merged map, against the ground truth: the paper's Fitness
        self.assertIsNotNone(rec['map'])
        s = score_map(rec['map'], load_map(truth['world_path']), starts['tb3_0'])
        print('bag replay: Fitness %.4f, inlier RMSE %.3f m, transform errors %s' % (
            s.fitness, s.inlier_rmse, ', '.join('%s %.3f m %.2f deg' % (k, *e) for k, e in sorted(errors.items()))))
        # each robot's SLAM map drifts a little from its start pose (measured: 0.4-0.7 deg here)
        for name, (d, a) in errors.items():
            self.assertLess(d, 0.10, '%s: %.3f m from the truth' % (name, d))
            self.assertLess(a, 1.5, '%s: %.2f deg from the truth' % (name, a))
        self.assertGreater(s.fitness, 0.95)
        self.assertLess(s.inlier_rmse, 0.06)
        # a trajectory through the merged TF ends where that robot truly ended (within 0.3 m)
        end = rec['robots']['tb3_1']['trajectory'][-1]
        p = np.linalg.inv(starts['tb3_0']) @ starts['tb3_1'] @ np.array([end[1], end[2], 1.0])
        q = est['tb3_1'] @ np.array([end[1], end[2], 1.0])
        self.assertLess(math.hypot(*(p[:2] - q[:2])), 0.3)


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'bag_replay', TestBagReplay)
