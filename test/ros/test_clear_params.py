#!/usr/bin/env python3
"""rostest: stale parameters on the master no longer override m-explore's names (issue 32).

An earlier ``roslaunch multi_map_merge map_merge.launch`` leaves config/map_merge.yaml under
``/map_merge`` (``merged_map_frame: map``, ``merge_rate: 2.0``, ...): the test puts it there as
roslaunch does. Then the merger is launched with a config in m-explore's names
(``world_frame: world``, ``merging_rate: 1.0``) and its screen output read:

- ``map_merge.launch`` as shipped (``clear_params``): the stale parameters are gone from the
  master, the node says it read ``~world_frame`` as ``~merged_map_frame`` ('world') and
  ``~merging_rate`` as ``~merge_rate`` and warns about neither being ignored;
- the same file without ``clear_params`` (the launch before issue 32): the stale
  ``~merged_map_frame`` stays and wins, and the node's only word of it is the warning that
  ``~world_frame`` was ignored: the mistake the user did not see coming."""
import os
import subprocess
import sys
import tempfile
import threading
import time
import unittest

import rospkg
import rospy
import rostest
import yaml
from rostest_helpers import stop_launch

MEXPLORE = {'world_frame': 'world', 'merging_rate': 1.0}
READ = "~world_frame read as ~merged_map_frame (m-explore's name): 'world'"
IGNORED = "~world_frame (m-explore's name for ~merged_map_frame) ignored: ~merged_map_frame is set too and wins ('map')"


class Launch:
    """A roslaunch of the merger whose screen output is collected as it comes."""

    def __init__(self, launch_file, config):
        self.lines = []
        self.lock = threading.Lock()
        # rospy writes its INFO lines to stdout without flushing: into a pipe, unbuffered, or
        # they come only when the node ends (its WARN lines go to stderr, unbuffered anyway)
        self.proc = subprocess.Popen(['roslaunch', launch_file, 'config:=' + config, 'output:=screen'],
                                     stdout=subprocess.PIPE, stderr=subprocess.STDOUT, universal_newlines=True,
                                     start_new_session=True, env=dict(os.environ, PYTHONUNBUFFERED='1'))
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.proc.stdout:
            with self.lock:
                self.lines.append(line.rstrip('\n'))

    def text(self):
        with self.lock:
            return '\n'.join(self.lines)

    def wait_for(self, text, timeout):
        end = time.time() + timeout
        while time.time() < end:
            if text in self.text():
                return True
            time.sleep(0.2)
        return False

    def stop(self):
        stop_launch(self.proc)


class TestClearParams(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        rospy.init_node('test_clear_params', anonymous=True)
        cls.pkg = rospkg.RosPack().get_path('multi_map_merge')
        cls.tmp = tempfile.mkdtemp(prefix='mmm_clear_params_')
        cls.config = os.path.join(cls.tmp, 'mexplore_names.yaml')
        with open(cls.config, 'w') as f:
            yaml.safe_dump(MEXPLORE, f)

    def leave_stale_params(self):
        """What an earlier map_merge.launch leaves: the shipped YAML under /map_merge."""
        if rospy.has_param('/map_merge'):
            rospy.delete_param('/map_merge')
        with open(os.path.join(self.pkg, 'config', 'map_merge.yaml')) as f:
            rospy.set_param('/map_merge', yaml.safe_load(f))
        self.assertEqual(rospy.get_param('/map_merge/merged_map_frame'), 'map')

    def run_merger(self, launch_file, until):
        launch = Launch(launch_file, self.config)
        try:
            self.assertTrue(launch.wait_for(until, 60.0), 'the node did not say %r:\n%s' % (until, launch.text()))
            params = rospy.get_param('/map_merge')
        finally:
            launch.stop()
        return params, launch.text()

    def test_1_the_shipped_launch_clears_what_an_earlier_one_left(self):
        self.leave_stale_params()
        params, out = self.run_merger(os.path.join(self.pkg, 'launch', 'map_merge.launch'), READ)
        self.assertEqual(set(params), set(MEXPLORE), params)
        self.assertIn("~merging_rate read as ~merge_rate (m-explore's name): 1.0", out)
        self.assertNotIn('ignored', out)
        self.assertNotIn('is set too and wins', out)

    def test_2_without_clear_params_the_stale_name_wins(self):
        """The launch file as it was before issue 32 (no clear_params): what this test guards."""
        with open(os.path.join(self.pkg, 'launch', 'map_merge.launch')) as f:
            text = f.read()
        self.assertEqual(text.count(' clear_params="true"'), 1)
        old = os.path.join(self.tmp, 'map_merge_no_clear_params.launch')
        with open(old, 'w') as f:
            f.write(text.replace(' clear_params="true"', ''))
        self.leave_stale_params()
        params, out = self.run_merger(old, IGNORED)
        self.assertEqual(params['merged_map_frame'], 'map')
        self.assertEqual(params['world_frame'], 'world')


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'clear_params', TestClearParams, sys.argv)
