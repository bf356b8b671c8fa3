#!/usr/bin/env python3
"""rostest: ROBOTIS's Gazebo multi-robot merge launch file, as it stands, running our node.

``turtlebot3_gazebo/launch/multi_map_merge.launch`` (ROBOTIS turtlebot3_simulations, noetic;
Apache-2.0, read in place from ../shared/data/robotis/turtlebot3_simulations; skipped where
absent) is read and
only its merge node's ``pkg`` and ``type`` are changed to ours (ElementTree; undoing the two gives
the file's own tree back). Where ROS has no ``tf`` static_transform_publisher executable (Debian
12), its three identity ``map -> tb3_N/map`` publishers run as ``tf_sender.py`` (the same
arguments, the same messages on /tf every 100 ms). The launch sets ``known_init_poses`` true and
writes each robot's spawn position (-7, -1), (7, -1), (0.5, 3) to
``/tb3_N/map_merge/init_pose_*``.

What Gazebo and ROBOTIS's gmapping launch (``multi_turtlebot3_slam.launch``: xmin/ymin -10,
xmax/ymax 10, 0.05 m) would give: the diff-drive plugin publishes odometry from the world
(``odometrySource world``), so each robot's odom frame is Gazebo's world frame and gmapping's
map frame starts on it; every ``tb3_N/map`` is in the world frame. Here the world is the AWS
small house map (its spawn points are free floor there) and each robot's map a 20 m x 20 m
gmapping grid in that frame holding the house around its spawn point; each robot's TF
``tb3_N/map -> tb3_N/odom`` is the identity and ``tb3_N/odom -> tb3_N/base_footprint`` its spawn
pose (ROBOTIS's multi_turtlebot3.launch: yaws 1.57, 1.57, 0).

The truth: every robot's map frame is the merged frame (``map -> tb3_N/map`` the identity). The
test asserts that the node says, once, on /rosout, that the priors are spawn poses of robots
whose maps share one frame and what to change; that every robot is merged by a verified link
(not at a prior); that the node's own TF (the /tf messages whose sender is the merger, in a tf2
buffer of their own: ROBOTIS's identity publishers send the same frames) places every map frame
within 0.05 m / 0.5 degrees of the identity; that every robot's base resolves through ``map`` at
its spawn pose; that the merged /map is the house where the robots mapped it; and that the
node's set-up check names each of the three static_transform_publishers.
"""
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
import unittest
import xml.etree.ElementTree as ET

import numpy as np
import roslib.packages
import rospkg
import rospy
import rostest
import tf2_ros
from rosgraph_msgs.msg import Log
from rostest_helpers import (
    HOUSE_MAP,
    MERGER,
    Listener,
    NumpyGrid,
    compare_with_truth,
    fmt_pose,
    lookup,
    shared_file,
    stop_launch,
    union_mask_of,
    wait_until,
)
from tf2_msgs.msg import TFMessage

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import pose_distance, se2
from multi_map_merge.lab.pieces import in_world_frame
from multi_map_merge.ros.convert import grid_to_msg, transform_msg

PKG = 'multi_map_merge'
ROBOTS = ['tb3_0', 'tb3_1', 'tb3_2']
# where multi_turtlebot3.launch spawns them (x, y, yaw); multi_map_merge.launch writes x, y and yaw 0
SPAWN = {'tb3_0': (-7.0, -1.0, 1.57), 'tb3_1': (7.0, -1.0, 1.57), 'tb3_2': (0.5, 3.0, 0.0)}
# what each robot mapped around its spawn point: x0, x1, y0, y1 (metres, world frame)
MAPPED = {'tb3_0': (-9.6, 0.5, -6.0, 6.0), 'tb3_1': (1.5, 9.8, -6.0, 6.0), 'tb3_2': (-3.5, 5.0, -2.5, 6.0)}
SHARED_FRAME_LINE = 'are spawn poses of robots whose maps share one frame'


def gazebo_map(world, robot):
    """Robot's gmapping map as ROBOTIS's Gazebo set-up makes it: 400 x 400 cells of 0.05 m from
    (-10, -10) (multi_turtlebot3_slam.launch's xmin, ymin, xmax, ymax) in the world frame, the
    world known where the robot mapped (MAPPED)."""
    return in_world_frame(world, MAPPED[robot], (-10.0, -10.0, 10.0, 10.0), '%s/map' % robot)


def robotis_launch_with_our_node(path, static_tf_stand_in):
    """ROBOTIS's launch file with its merge node's pkg and type (only those) made ours, and,
    when ``static_tf_stand_in``, its static_transform_publishers' pkg and type made tf_sender.py
    (their arguments kept)."""
    tree = ET.parse(path)
    before = ET.tostring(tree.getroot())
    nodes = list(tree.getroot().iter('node'))
    (merge,) = [n for n in nodes if n.get('name') == 'map_merge']
    assert (merge.get('pkg'), merge.get('type')) == ('multirobot_map_merge', 'map_merge'), merge.attrib
    statics = [n for n in nodes if n.get('type') == 'static_transform_publisher']
    assert len(statics) == 3 and all(n.get('pkg') == 'tf' for n in statics), [n.attrib for n in statics]
    merge.set('pkg', PKG)
    merge.set('type', 'map_merge_node')
    if static_tf_stand_in:
        for n in statics:
            n.set('pkg', PKG)
            n.set('type', 'tf_sender.py')
    after = ET.tostring(tree.getroot())
    # nothing else changed: undoing those attributes gives the file's own tree back
    merge.set('pkg', 'multirobot_map_merge')
    merge.set('type', 'map_merge')
    for n in statics:
        n.set('pkg', 'tf')
        n.set('type', 'static_transform_publisher')
    assert ET.tostring(tree.getroot()) == before
    return after.decode()


class TestRobotisGazeboLaunch(unittest.TestCase):

    def test_robotis_gazebo_merge_launch_with_our_node(self):
        robotis = shared_file('robotis', 'turtlebot3_simulations', 'multi_map_merge.launch')
        rospy.init_node('test_robotis_gazebo_launch', anonymous=True)
        self.world = load_map(shared_file(HOUSE_MAP))
        grids = {r: gazebo_map(self.world, r) for r in ROBOTS}
        self.union = union_mask_of(self.world, [(grids[r], np.eye(3)) for r in ROBOTS])
        self.lock = threading.Lock()
        self.logs = []
        rospy.Subscriber('/rosout', Log, self._on_log, queue_size=200)
        # the merger's own TF: /tf messages whose sender is the merger, in a buffer of their own
        self.own = tf2_ros.Buffer(rospy.Duration(30.0))
        rospy.Subscriber('/tf', TFMessage, self._on_tf, queue_size=200)
        self.buf = tf2_ros.Buffer(rospy.Duration(30.0))
        tf2_ros.TransformListener(self.buf)
        self.listen = Listener()
        # the map topics are there from the start (the node finds the robots at once), their maps
        # come once the node's log reaches this test (a log line is not latched: the spawn
        # poses' line would come before /rosout connects)
        pubs = {r: rospy.Publisher('/%s/map' % r, NumpyGrid, queue_size=1, latch=True) for r in ROBOTS}
        stop = threading.Event()
        threading.Thread(target=self._robots_tf, args=(stop,), daemon=True).start()
        try:
            have_tf = bool(roslib.packages.find_node('tf', 'static_transform_publisher'))
        except rospkg.ResourceNotFound:    # no package tf at all (Debian 12: not packaged)
            have_tf = False
        print('tf static_transform_publisher %s' % ('found: ROBOTIS\'s lines run as they are' if have_tf else
                                                     'not installed: run as tf_sender.py, same arguments'))
        with tempfile.TemporaryDirectory() as d:
            launch = os.path.join(d, 'multi_map_merge.launch')
            with open(launch, 'w') as f:
                f.write(robotis_launch_with_our_node(robotis, not have_tf))
            out = open(os.path.join(d, 'roslaunch.out'), 'w+')
            proc = subprocess.Popen(['roslaunch', launch], start_new_session=True, stdout=out,
                                    stderr=subprocess.STDOUT)
            try:
                # the trap is set: spawn positions as priors, read under known_init_poses
                x = wait_until(lambda: rospy.get_param('/tb3_1/map_merge/init_pose_x', None), 30.0)
                self.assertEqual(x, 7.0)
                self.assertTrue(rospy.get_param('/map_merge/known_init_poses'))
                heard = wait_until(lambda: self.logs, 30.0)
                print('the merger\'s log %s on /rosout' % ('heard' if heard else 'not heard in 30 s'))
                for r in ROBOTS:
                    pubs[r].publish(grid_to_msg(grids[r], rospy.Time.now(), '%s/map' % r))
                self._check_merge()
            finally:
                stop_launch(proc)
                stop.set()
                out.seek(0)
                screen = out.read()
                out.close()
        print(screen[-3000:])
        self._check_screen(screen)

    # -- inputs and listeners
    def _on_log(self, msg):
        if msg.name == '/' + MERGER:
            with self.lock:
                self.logs.append(msg)

    def _on_tf(self, msg):
        if getattr(msg, '_connection_header', {}).get('callerid') != '/' + MERGER:
            return
        for t in msg.transforms:
            self.own.set_transform(t, 'merger')

    def _robots_tf(self, stop):
        """Each robot's TF as in Gazebo: its map frame on its odom frame (gmapping at the start),
        its base at its spawn pose in odom (odometry from the world)."""
        br = tf2_ros.TransformBroadcaster()
        while not stop.is_set() and not rospy.is_shutdown():
            now = rospy.Time.now()
            tfs = []
            for r in ROBOTS:
                tfs.append(transform_msg(np.eye(3), '%s/map' % r, '%s/odom' % r, now))
                tfs.append(transform_msg(se2(*SPAWN[r]), '%s/odom' % r, '%s/base_footprint' % r, now))
            br.sendTransform(tfs)
            time.sleep(0.1)

    def warnings(self, text):
        with self.lock:
            return [m.msg for m in self.logs if m.level == Log.WARN and text in m.msg]

    # -- the checks
    def _check_merge(self):
        # ROBOTIS's rates: estimation every 10 s, merging every 2 s
        def merged():
            out = {}
            for r in ROBOTS[1:]:
                s = self.listen.status(r)
                if s is None or s[1].get('merged') != 'true':
                    return None
                out[r] = s[1]
            return out
        got = wait_until(merged, 120.0, period=1.0)
        for r in ROBOTS[1:]:
            print('%s: %s' % (r, self.listen.status(r)))
        self.assertIsNotNone(got, 'not every robot merged: %s' % {r: self.listen.status(r) for r in ROBOTS})
        for values in got.values():
            self.assertNotEqual(values.get('via'), 'initial_pose', values)
        # the one line saying what the priors are and what to change
        lines = self.warnings(SHARED_FRAME_LINE)
        print('\n'.join(lines))
        self.assertEqual(len(lines), 1, lines)
        self.assertIn('tb3_0, tb3_1, tb3_2 %s' % SHARED_FRAME_LINE, lines[0])
        self.assertIn('set known_init_poses false', lines[0])
        self.assertIn('static_transform_publishers', lines[0])
        # the merger's own TF: every map frame at the identity (the truth: one shared frame)
        for r in ROBOTS:
            T = lookup(self.own, 'map', '%s/map' % r, 10.0)
            self.assertIsNotNone(T, 'the merger sends no TF map -> %s/map' % r)
            d, a = pose_distance(T, np.eye(3))
            print('merger\'s TF map -> %s/map %s: %.4f m, %.3f deg from the truth (identity)'
                  % (r, fmt_pose(T), d, math.degrees(a)))
            self.assertLess(d, 0.05, r)
            self.assertLess(math.degrees(a), 0.5, r)
        # every robot's base through map, at its spawn pose (what rviz and move_base see)
        for r in ROBOTS:
            T = lookup(self.buf, 'map', '%s/base_footprint' % r, 10.0)
            self.assertIsNotNone(T, 'no TF map -> %s/base_footprint' % r)
            d, a = pose_distance(T, se2(*SPAWN[r]))
            print('map -> %s/base_footprint %s: %.4f m, %.3f deg from its spawn pose' % (r, fmt_pose(T), d,
                                                                                       math.degrees(a)))
            self.assertLess(d, 0.1, r)
            self.assertLess(math.degrees(a), 1.0, r)
        # the merged map: the house where the robots mapped it, every robot's part in it
        union_known = int(((self.world.levels() > 0) & (self.union > 0)).sum())
        msg = wait_until(lambda: self.listen.map_where(
            lambda m: abs(int((np.asarray(m.data) >= 0).sum()) - union_known) < 0.02 * union_known), 20.0)
        self.assertIsNotNone(msg, 'no /map holding every robot\'s map: %s known cells, %s in the union' % (
            self.listen.latest_map() and int((np.asarray(self.listen.latest_map().data) >= 0).sum()), union_known))
        self.assertEqual(msg.header.frame_id, 'map')
        sc = compare_with_truth(msg, self.world, np.eye(3), self.union)
        print('merged vs truth: %s' % sc)
        self.assertGreaterEqual(sc['occ_precision'], 0.98, sc)
        self.assertLessEqual(sc['free_wrong'], 0.01, sc)
        self.assertLessEqual(sc['outside'], 0.01, sc)
        self.assertGreaterEqual(sc['recall'], 0.98, sc)

    def _check_screen(self, screen):
        lines = [ln for ln in screen.splitlines() if 'multi_map_merge: ' in ln]
        # the set-up check names each of ROBOTIS's identity publishers of map -> tb3_N/map
        for r in ROBOTS:
            named = [ln for ln in lines if ln.startswith('[WARN]') and
                     'node /world_to_%s_tf_broadcaster publishes the TF map -> %s/map' % (r, r) in ln]
            self.assertEqual(len(named), 1, [ln for ln in lines if 'publishes the TF' in ln])
        self.assertEqual(len([ln for ln in lines if SHARED_FRAME_LINE in ln]), 1)
        self.assertEqual([ln for ln in lines if ln.startswith('[ERROR]')], [])


if __name__ == '__main__':
    rostest.rosrun(PKG, 'robotis_gazebo_launch', TestRobotisGazeboLaunch, sys.argv)
