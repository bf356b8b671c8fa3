#!/usr/bin/env python3
"""rostest: robots_rviz, as turtlebot3_multi_slam.launch starts it, for robots named alpha and
scout_7: rviz (under xvfb-run, on this test's master) loads the config written for them, and
its toolbar and Tool Properties show one prior tool per robot named after it ("alpha prior",
"scout_7 prior"), in the robots' order, between rviz's other tools. The config itself (its
displays, topics and window layout) is checked by test/unit/ros/test_launch_files.py. Skips,
saying so, only where rviz's Python bindings or xvfb-run are not installed."""
import os
import shutil
import subprocess
import sys
import tempfile
import unittest

import rospkg
import rostest

PKG = 'multi_map_merge'


class TestRobotsRviz(unittest.TestCase):

    def test_prior_tools_are_named_after_the_robots(self):
        try:
            from rviz import bindings  # noqa: F401
        except ImportError as e:
            self.skipTest("rviz's Python bindings are not installed (%s; Debian: python3-rviz)" % e)
        if shutil.which('xvfb-run') is None:
            self.skipTest('xvfb-run is not installed (Debian: xvfb)')
        script = os.path.join(rospkg.RosPack().get_path(PKG), 'scripts', 'robots_rviz')
        with tempfile.TemporaryDirectory() as d:
            r = subprocess.run(['xvfb-run', '-a', '-s', '-screen 0 1400x900x24', sys.executable, script,
                                '--robots', 'alpha scout_7', '--output', os.path.join(d, 'team.rviz'),
                                '--print-tools'], capture_output=True, text=True, timeout=60)
        print(r.stdout[-2000:], r.stderr[-2000:])
        self.assertEqual(r.returncode, 0)
        lines = {ln.split(': ', 1)[0]: ln.split(': ', 1)[1].split(' | ')
                 for ln in r.stdout.splitlines() if ln.startswith('robots_rviz tool')}
        for what in ('robots_rviz tools', 'robots_rviz tool properties'):
            names = lines.get(what)
            self.assertIsNotNone(names, r.stdout)
            self.assertEqual([n for n in names if n.endswith(' prior')], ['alpha prior', 'scout_7 prior'])
            self.assertNotIn('2D Pose Estimate', names)
            # a goal tool per robot, on its own move_base (no global 2D Nav Goal)
            self.assertEqual([n for n in names if n.endswith(' goal')], ['alpha goal', 'scout_7 goal'])
            self.assertNotIn('2D Nav Goal', names)


if __name__ == '__main__':
    rostest.rosrun(PKG, 'robots_rviz', TestRobotsRviz, sys.argv)
