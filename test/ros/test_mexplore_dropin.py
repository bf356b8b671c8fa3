#!/usr/bin/env python3
"""rostest: our node as a drop-in for m-explore's.

m-explore's own launch file for its map_merge node (multirobot_map_merge 2.1.4,
map_merge/launch/map_merge.launch, read in place from ../shared/data/mexplore; skipped where
absent) is read and
only the node's ``pkg`` and ``type`` are changed (ElementTree; every other attribute and every
parameter is checked to be unchanged), then started with roslaunch. Its parameters are
m-explore's (robot_map_topic, robot_namespace "", world_frame "world", merging_rate 0.5,
discovery_rate 0.05, estimation_rate 0.1, estimation_confidence, known_init_poses false) and its
node lives in the namespace map_merge, as m-explore's does. Three robots' maps (pieces of the
Intel map at known poses) are published on /tb3_0/map, /tb3_1/map and, in a nested namespace,
/team/tb3_2/map (m-explore finds a robot's map topic under any namespace); the merged map must
come out where m-explore's would (/map_merge/map, frame world) and every robot be placed by the
TF world -> <robot>/map (team/tb3_2/map for the nested one, looked up through tf2) at its true
pose. The node's log names each m-explore parameter it read and
warns only about estimation_confidence (which has no equivalent here). rviz's config for this
launch file (``robots_rviz --node /map_merge/map_merge``) shows the topics the live node publishes
(its markers, its merged map) and each robot's goal on its own move_base; the default config's
markers (``/map_merge/markers``) are published by no one here.
"""
import math
import os
import subprocess
import sys
import tempfile
import unittest
import xml.etree.ElementTree as ET

import rospkg
import rospy
import rostest
import tf2_ros
import yaml
from rostest_helpers import INTEL_MAP, NumpyGrid, RobotPlayer, lookup, make_pieces, shared_file, stop_launch, wait_until

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import inverse, pose_distance

PKG = 'multi_map_merge'
ROBOTS = ['tb3_0', 'tb3_1', 'team/tb3_2']   # the last nested (after tb3_0 by name: tb3_0 stays the reference)
POSES = [(1.5, -1.0, math.radians(20.0)), (-3.0, 2.0, math.radians(180.0)), (4.0, 3.5, math.radians(-95.0))]


def dropin_launch(path):
    """m-explore's launch file with its node's pkg and type (only those) made ours."""
    tree = ET.parse(path)
    (node,) = tree.getroot().iter('node')
    assert (node.get('pkg'), node.get('type')) == ('multirobot_map_merge', 'map_merge'), node.attrib
    before = ET.tostring(tree.getroot())
    node.set('pkg', 'multi_map_merge')
    node.set('type', 'map_merge_node')
    after = ET.tostring(tree.getroot())
    # nothing else changed: undoing the two attributes gives the file's own tree back
    node.set('pkg', 'multirobot_map_merge')
    node.set('type', 'map_merge')
    assert ET.tostring(tree.getroot()) == before
    return after.decode()


class TestMexploreDropin(unittest.TestCase):

    def test_mexplore_launch_file_runs_our_node(self):
        mexplore = shared_file('mexplore', 'map_merge.launch')
        rospy.init_node('test_mexplore_dropin', anonymous=True)
        world = load_map(shared_file(INTEL_MAP))
        pieces = make_pieces(world, 3, POSES)
        truth = {r: inverse(pieces[0][1]) @ T for r, (_, T) in zip(ROBOTS, pieces)}
        self.piece_known = [int((g.data >= 0).sum()) for g, _ in pieces]
        player = RobotPlayer(ROBOTS)
        for r, (g, _) in zip(ROBOTS, pieces):
            player.publish(r, g)
        merged = []
        rospy.Subscriber('/map_merge/map', NumpyGrid, merged.append, queue_size=1, buff_size=2 ** 26)
        buf = tf2_ros.Buffer(rospy.Duration(30.0))
        tf2_ros.TransformListener(buf)
        with tempfile.TemporaryDirectory() as d:
            launch = os.path.join(d, 'map_merge.launch')
            with open(launch, 'w') as f:
                f.write(dropin_launch(mexplore))
            out = open(os.path.join(d, 'roslaunch.out'), 'w+')
            # the node's output is "screen" in m-explore's file: its log lines, from the first
            proc = subprocess.Popen(['roslaunch', launch], start_new_session=True, stdout=out,
                                    stderr=subprocess.STDOUT)
            try:
                self._check(buf, truth, merged)
                self._check_rviz(d)
            finally:
                stop_launch(proc)
                player._stop = True
                out.seek(0)
                screen = out.read()
                out.close()
        print(screen[-3000:])
        self._check_log(screen)

    def _check(self, buf, truth, merged):
        # m-explore's rates: discovery every 20 s, estimation every 10 s
        def placed():
            out = {}
            for r in ROBOTS[1:]:
                T = lookup(buf, 'world', '%s/map' % r, 0.2)
                if T is None:
                    return None
                out[r] = T
            return out
        got = wait_until(placed, 150.0, period=1.0)
        self.assertIsNotNone(got, 'not every robot placed in "world"')
        for r, T in got.items():
            d, a = pose_distance(T, truth[r])
            print('%s: %.3f m, %.3f deg from its true pose' % (r, d, math.degrees(a)))
            self.assertLess(d, 0.1, r)
            self.assertLess(a, math.radians(1.0), r)
        ref = lookup(buf, 'world', 'tb3_0/map', 2.0)
        self.assertIsNotNone(ref)
        self.assertLess(pose_distance(ref, truth['tb3_0'])[0], 1e-6)
        self.assertTrue(wait_until(lambda: merged, 10.0), 'no merged map on /map_merge/map')
        # every robot's map in it: more known cells than the largest piece alone has. The TF of
        # a new placement goes out at once, the merged map at the next merge period: the /map
        # in hand may predate the last placement, so wait (a few periods) for the next ones
        def known():
            return int((merged[-1].data >= 0).sum())
        wait_until(lambda: known() > 1.2 * max(self.piece_known), 10.0)
        msg = merged[-1]
        self.assertEqual(msg.header.frame_id, 'world')
        self.assertGreater(known(), 1.2 * max(self.piece_known), (known(), self.piece_known))

    def _check_rviz(self, d):
        """rviz for this launch file (robots_rviz --node /map_merge/map_merge, as the README says)
        shows what the live node publishes: its markers, its merged map, every robot's map; each
        robot's 2D Nav Goal goes to its own move_base. The config for our own launch file's node
        name (the default, /map_merge) points at markers no node publishes here."""
        published = dict(rospy.get_published_topics())

        def written(*args):
            path = os.path.join(d, 'rviz%d.rviz' % len(os.listdir(d)))
            r = subprocess.run([sys.executable, os.path.join(rospkg.RosPack().get_path(PKG), 'scripts', 'robots_rviz'),
                                '--robots', ' '.join(ROBOTS), '--write-only', '--output', path] + list(args),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True)
            self.assertEqual(r.returncode, 0, r.stderr)
            with open(path) as f:
                vm = yaml.safe_load(f)['Visualization Manager']
            markers = [x['Marker Topic'] for x in vm['Displays'] if x['Class'] == 'rviz/MarkerArray']
            maps = [x['Topic'] for x in vm['Displays'] if x['Class'] == 'rviz/Map']
            goals = [t['Topic'] for t in vm['Tools'] if t['Class'] == 'rviz/SetGoal']
            return markers, maps, goals
        markers, maps, goals = written('--node', '/map_merge/map_merge')
        print('rviz --node /map_merge/map_merge: markers %s, maps %s, goals %s' % (markers, maps, goals))
        self.assertEqual(markers, ['/map_merge/map_merge/markers'])
        self.assertEqual(published.get(markers[0]), 'visualization_msgs/MarkerArray', published)
        self.assertEqual(maps, ['/map_merge/map'] + ['/%s/map' % r for r in ROBOTS])
        for topic in maps:
            self.assertEqual(published.get(topic), 'nav_msgs/OccupancyGrid', (topic, published))
        self.assertEqual(goals, ['/%s/move_base_simple/goal' % r for r in ROBOTS])
        markers, maps, _ = written()
        self.assertEqual((markers, maps[0]), (['/map_merge/markers'], '/map'))
        self.assertNotIn(markers[0], published)

    def _check_log(self, screen):
        lines = [ln for ln in screen.splitlines() if 'multi_map_merge: ' in ln]
        for alias in ('robot_map_topic', 'robot_namespace', 'world_frame', 'merging_rate'):
            self.assertTrue([ln for ln in lines if '~%s read as' % alias in ln], alias)
        warnings = [ln for ln in lines if ln.startswith('[WARN]')]
        self.assertEqual(len([ln for ln in warnings if 'estimation_confidence' in ln]), 1, warnings)
        self.assertEqual([ln for ln in warnings if 'estimation_confidence' not in ln], [])
        self.assertEqual([ln for ln in lines if ln.startswith('[ERROR]')], [])


if __name__ == '__main__':
    rostest.rosrun(PKG, 'mexplore_dropin', TestMexploreDropin, sys.argv)
