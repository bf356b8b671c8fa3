#!/usr/bin/env python3
"""rostest: three real robots' raw bags (isr_small: laser, odometry, TF, recorded minutes apart,
every one naming its frames odom, base_link, laser) replayed as one team by
team_bags_gmapping.launch: frames prefixed, stamps on one clock, one live SLAM per robot (``SLAM``:
rbpf, this package's rbpf_slam, gmapping's algorithm; gmapping: slam_gmapping, skipped where ROS
has none), the merger on top. Every robot merged, every overlapping pair agreeing on the live
transforms, every robot's base frame resolving through `map` by tf2. "gmapping" below is either."""
import os
import subprocess
import tempfile
import unittest

import numpy as np
import rospkg
import rostest
from replay_pacer import MAX_HOLD_S, ReplayPacer, keep_up_failures
from rostest_helpers import shared_data, skip_without_gmapping, stop_launch

from multi_map_merge.core.transforms import pose_to_image, se2
from multi_map_merge.core.verify import agreement
from multi_map_merge.lab.scans_processed import load_rule
from multi_map_merge.ros.replay import record_replay
from multi_map_merge.ros.tools import init_node

ROBOTS = ['tb3_0', 'tb3_1', 'tb3_2']
RATE = 3.0         # at most: the live SLAM nodes pace the players (ReplayPacer)
LIVE_TIMEOUT_S = 400.0   # wall seconds the replay may take, holds included
SLAM = 'rbpf'      # team_bags_gmapping.launch's slam (its default is gmapping: given here)


class TestTeamBagsGmapping(unittest.TestCase):

    def test_three_real_robots_raw_bags_through_live_gmapping_merge(self):
        bags = [os.path.join(shared_data(), 'mrgs', 'bags_raw', 'isr_small_raw_%d.bag' % k) for k in (1, 2, 3)]
        if not all(os.path.exists(b) for b in bags):
            self.skipTest('../shared/data/mrgs is absent: the real robots\' raw bags are not here')
        if SLAM == 'gmapping':
            skip_without_gmapping(self)
        init_node('test_team_bags_gmapping')
        logs = tempfile.mkdtemp(prefix='mmm_team_bags_')   # the SLAM nodes' "update frame N" lines
        # isr_small_raw_1 is the longest run (154 s): the team runs on its clock
        launch = subprocess.Popen(['roslaunch', 'multi_map_merge', 'team_bags_gmapping.launch', 'rviz:=false',
                                   'rate:=%g' % RATE, 'clock_bag:=0', 'output:=log', 'slam:=' + SLAM]
                                  + ['bag_%d:=%s' % (i, b) for i, b in enumerate(bags)],
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
                                  env=dict(os.environ, ROS_LOG_DIR=logs))
        try:
            # the merger's timers run on the bag's clock: what it published is sampled while
            # the bags play (the TF, its /diagnostics, each robot's last gmapping map); the live
            # SLAM nodes pace the three players together (a hold stops /clock: idle covers it)
            with ReplayPacer(ROBOTS, logs, players=['/play_%s' % r for r in ROBOTS],
                             scan_topic='/{robot}/scan_raw') as pacer:
                rec = record_replay(ROBOTS, period=0.5, idle=MAX_HOLD_S + 4.0, timeout=LIVE_TIMEOUT_S,
                                    base_frame='base_link')
            print(pacer.summary())
        finally:
            stop_launch(launch)
        self.assertIsNotNone(rec['clock'], 'no /clock: the bags did not play')
        # each robot's SLAM kept up with its bag: if not, that is the failure (the machine too busy)
        rule = load_rule(os.path.join(rospkg.RosPack().get_path('multi_map_merge'), 'config', 'gmapping_default.yaml'))
        lagged = [line for r, b in zip(ROBOTS, bags)
                  for line in keep_up_failures(b, logs, [r], rule, scan_topic='/scan', odom_topic='/odom')]
        self.assertEqual(lagged, [], '\n'.join(lagged))
        tf, finals = {}, rec['robot_maps']
        for r in ROBOTS:
            got = rec['robots'][r]
            print('%s: %s; map frame in map %s' % (r, got['diagnostics'].get('message'), got['tf']))
            if r != ROBOTS[0]:
                self.assertEqual(got['diagnostics'].get('merged'), 'true', '%s: %s' % (r, got['diagnostics']))
            self.assertIsNotNone(got['tf'], 'no TF map -> %s/map' % r)
            self.assertIsNotNone(got['base'], '%s/base_link does not resolve through map' % r)
            self.assertIn(r, finals, 'no map from %s\'s gmapping' % r)
            self.assertEqual(finals[r].frame_id, '%s/map' % r)
            tf[r] = se2(*got['tf'])
        # one consistent map: where two robots' last gmapping maps overlap under the live TF,
        # their walls meet walls, not free space (the merger's own verification score)
        overlapping = 0
        for a, b in [('tb3_0', 'tb3_1'), ('tb3_1', 'tb3_2'), ('tb3_0', 'tb3_2')]:
            ga, gb = finals[a], finals[b]
            A = pose_to_image(np.linalg.inv(tf[a]) @ tf[b], ga.resolution, ga.origin,
                              gb.resolution, gb.origin)
            ag, overlap = agreement(ga.levels(), gb.levels(), A, 2)
            print('%s-%s: agreement %.3f over %d cells known in both' % (a, b, ag, overlap))
            if overlap >= 400:
                overlapping += 1
                self.assertGreaterEqual(ag, 0.90, '%s-%s disagree live: %.3f' % (a, b, ag))
        self.assertGreaterEqual(overlapping, 2, 'the three robots overlap in at least two pairs')


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'team_bags_gmapping', TestTeamBagsGmapping)
