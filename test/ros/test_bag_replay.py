#!/usr/bin/env python3
"""rostest: a generated robots' bag through `roslaunch multi_map_merge bag_replay.launch`
(real rosbag play --clock, /use_sim_time, the node, tf2), scored against the bag's truth.
Argument ``--slam``: ``recorded`` (the bag's maps, the default), ``rbpf`` (one live rbpf_slam per
robot, this package's RBPF SLAM, makes the maps from the bag's scans: bag_replay_gmapping.test) or
``gmapping`` (the same with a real slam_gmapping; skipped where ROS has no gmapping)."""
import math
import os
import subprocess
import sys
import tempfile
import unittest

import numpy as np
import rospkg
import rospy
import rostest
from replay_pacer import MAX_HOLD_S, ReplayPacer, keep_up_failures
from rostest_helpers import skip_without_gmapping, stop_launch

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import se2
from multi_map_merge.lab.evaluate import load_truth, score_map, transform_errors
from multi_map_merge.lab.scans_processed import load_rule
from multi_map_merge.ros.replay import record_replay
from multi_map_merge.ros.tools import init_node

ROBOTS = ['tb3_0', 'tb3_1', 'tb3_2']
SLAM = 'recorded'   # --slam on the command line
# what each mode must reach: transform error (m, deg) of every robot, the merged map's Fitness
# and inlier RMSE (m) against the ground truth, and the playback rate
LIMITS = {
    # the bag's maps drift a little from each robot's start pose (0.4-0.7 deg measured in the AWS
    # house; in the project's home, seed 2, one robot 0.13 m and another 1.50 deg off its start)
    'recorded': dict(metres=0.15, degrees=2.0, fitness=0.95, rmse=0.06, end=0.3, rate=4),
    # real gmapping's maps of the LDS-02 scans have thicker walls, and each bends against its
    # robot's start pose by a few degrees (see docs/measurements.md): looser, but a robot merged
    # in the wrong place (metres, or a turn) still fails
    'gmapping': dict(metres=0.25, degrees=6.0, fitness=0.55, rmse=0.07, end=0.5, rate=1.5),
}
# gmapping's particle filter over MRPT: held to gmapping's limits but for the distance. Its seed
# comes from the clock, and a robot's own map can sit a few tenths of a metre from its start at its
# best fit: robots came 0.15-0.21 m from their starts in two live runs, and in a pristine make test
# (2026-12-06) tb3_1 0.467 m, its own map 0.204 m and 2.27 deg from its best fit. A robot merged in
# the wrong place is metres off, or turned beyond the 6 degrees.
LIMITS['rbpf'] = dict(LIMITS['gmapping'], metres=0.50)
# wall seconds a replay into live SLAM nodes may take, held by them (ReplayPacer) on a busy machine
LIVE_TIMEOUT_S = 400.0


class TestBagReplay(unittest.TestCase):

    def test_replay_merges_every_robot_where_the_truth_says(self):
        slam = SLAM
        limit = LIMITS[slam]
        rp = rospkg.RosPack()
        pkg = rp.get_path('multi_map_merge')
        if slam == 'gmapping':
            skip_without_gmapping(self)
        tmp = tempfile.mkdtemp(prefix='mmm_bag_')
        bag = os.path.join(tmp, 'house3.bag')
        r = subprocess.run([sys.executable, os.path.join(pkg, 'scripts', 'make_robot_bags'), '-o', bag,
                            '--robots', '3', '--seed', '2', '--no-single']
                           # live SLAM gets only what the robots' sensors record
                           + (['--sensors-only'] if slam != 'recorded' else []), capture_output=True, text=True)
        self.assertEqual(r.returncode, 0, r.stderr)
        self.assertTrue(os.path.getsize(bag) > 1_000_000)
        init_node('test_bag_replay')
        logs = os.path.join(tmp, 'logs')    # the live SLAM's "update frame N" lines, counted below
        launch = subprocess.Popen(['roslaunch', 'multi_map_merge', 'bag_replay.launch', 'bag:=' + bag,
                                   'slam:=' + slam, 'rviz:=false', 'rate:=%g' % limit['rate'],
                                   'robot_count:=%d' % len(ROBOTS), 'output:=log'],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                                  env=dict(os.environ, ROS_LOG_DIR=logs))
        try:
            if slam == 'recorded':
                rec = record_replay(ROBOTS, period=0.5, idle=4.0, timeout=200.0)
            else:
                # the live SLAM nodes pace the playback (a held playback stops /clock: idle
                # covers the longest hold)
                with ReplayPacer(ROBOTS, logs) as pacer:
                    rec = record_replay(ROBOTS, period=0.5, idle=MAX_HOLD_S + 4.0, timeout=LIVE_TIMEOUT_S)
                print('bag replay, slam %s: %s' % (slam, pacer.summary()))
        finally:
            stop_launch(launch)
        truth = load_truth(bag[:-4] + '.truth.yaml')
        self.assertIsNotNone(rec['clock'], 'no /clock: the bag did not play')
        if slam != 'recorded':
            # did each robot's SLAM keep up with the bag: if not, that is the failure (the machine
            # was too busy), not the merge of maps made from too few scans
            rule = load_rule(os.path.join(pkg, 'config', 'gmapping_lds02.yaml'))
            lagged = keep_up_failures(bag, logs, ROBOTS, rule, label='bag replay, slam %s: ' % slam)
            self.assertGreater(rec['clock'], 1_600_000_100.0, 'SLAM could not keep up: the bag did not play to its '
                                                              'end in %.0f s' % LIVE_TIMEOUT_S)
            self.assertEqual(lagged, [], '\n'.join(lagged))
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
        print('bag replay, slam %s: Fitness %.4f, inlier RMSE %.3f m, transform errors %s' % (
            slam, s.fitness, s.inlier_rmse,
            ', '.join('%s %.3f m %.2f deg' % (k, *e) for k, e in sorted(errors.items()))))
        if slam != 'recorded':
            # each robot's own live SLAM map aligned alone to the ground truth: how good the
            # merge's inputs were, and how far the merge is from each map's own best fit
            own = {}
            for name in ROBOTS:
                self.assertIn(name, rec['robot_maps'], '%s: no /%s/map from %s' % (name, name, slam))
                own[name] = score_map(rec['robot_maps'][name], load_map(truth['world_path']), starts[name])
            fit_errors = transform_errors(est, {k: v.T for k, v in own.items()}, 'tb3_0')
            print('bag replay, slam %s: robots\' own maps Fitness %s; errors against each map\'s best '
                  'fit: %s' % (slam, ', '.join('%.4f' % own[k].fitness for k in ROBOTS),
                               ', '.join('%s %.3f m %.2f deg' % (k, *e) for k, e in sorted(fit_errors.items()))))
        self.assertGreater(s.fitness, limit['fitness'])
        for name, (d, a) in errors.items():
            self.assertLess(d, limit['metres'], '%s: %.3f m from the truth' % (name, d))
            self.assertLess(a, limit['degrees'], '%s: %.2f deg from the truth' % (name, a))
        self.assertLess(s.inlier_rmse, limit['rmse'])
        # a trajectory through the merged TF ends where that robot truly ended
        end = rec['robots']['tb3_1']['trajectory'][-1]
        p = np.linalg.inv(starts['tb3_0']) @ starts['tb3_1'] @ np.array([end[1], end[2], 1.0])
        q = est['tb3_1'] @ np.array([end[1], end[2], 1.0])
        self.assertLess(math.hypot(*(p[:2] - q[:2])), limit['end'])


if __name__ == '__main__':
    argv = rospy.myargv()
    SLAM = argv[argv.index('--slam') + 1] if '--slam' in argv else 'recorded'
    rostest.rosrun('multi_map_merge', 'bag_replay', TestBagReplay)
