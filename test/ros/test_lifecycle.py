#!/usr/bin/env python3
"""rostest: a robot's life seen by the live merger (see lifecycle.test)."""
import math
import os
import signal
import subprocess
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
import yaml
from map_msgs.msg import OccupancyGridUpdate
from rosgraph_msgs.msg import Log
from rospy.numpy_msg import numpy_msg
from rostest_helpers import INTEL_MAP, Listener, RobotPlayer, known_cells, lookup, make_pieces, shared_file, wait_until
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker, MarkerArray

from multi_map_merge.core.grid import Grid
from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import pose_distance
from multi_map_merge.ros.convert import NumpyGrid, grid_from_msg

PKG = 'multi_map_merge'


class TestLifecycle(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        rospy.init_node('test_lifecycle', anonymous=True)
        world = load_map(shared_file(INTEL_MAP))
        cls.pieces = make_pieces(world, 2, [(0.5, 1.0, -0.5), (-2.0, 3.0, 2.6)])
        cls.T_true = np.linalg.inv(cls.pieces[0][1]) @ cls.pieces[1][1]
        cls.listen = Listener()
        cls.logs, cls.log_lock = [], threading.Lock()
        rospy.Subscriber('/rosout', Log, cls._on_log, queue_size=200)
        cls.buf = tf2_ros.Buffer(rospy.Duration(30.0))
        cls.tfl = tf2_ros.TransformListener(cls.buf)
        cls.player = RobotPlayer(['tb3_0', 'tb3_1'])
        cls.markers = []   # (arrival, MarkerArray) of /map_merge/markers
        rospy.Subscriber('/map_merge/markers', MarkerArray, lambda m: cls.markers.append((time.time(), m)),
                         queue_size=20)

    @classmethod
    def _on_log(cls, msg):
        with cls.log_lock:
            cls.logs.append(msg)

    def logged(self, node, text, after):
        with self.log_lock:
            return [m for m in self.logs if m.name == node and text in m.msg and m.header.stamp.to_sec() >= after - 1]

    def merged(self, robot, after):
        st = self.listen.status(robot, after)
        return st if st and st[1].get('merged') == 'true' else None

    def test_1_life_of_a_robot(self):
        t0 = time.time()
        for r, (g, _) in zip(['tb3_0', 'tb3_1'], self.pieces):
            self.player.publish(r, g)
        self.assertTrue(wait_until(lambda: self.merged('tb3_1', t0), 40.0), 'tb3_1 never merged')
        g0 = self.pieces[0][0]

        # map_updates: write an occupied 6x6 block into tb3_0's map where it was unknown
        rows, cols = np.nonzero(g0.data == -1)
        k = next(i for i in range(len(rows)) if rows[i] > 10 and cols[i] > 10
                 and (g0.data[rows[i]:rows[i] + 6, cols[i]:cols[i] + 6] == -1).all())
        y, x = int(rows[k]), int(cols[k])
        upd = numpy_msg(OccupancyGridUpdate)()
        upd.header.frame_id = 'tb3_0/map'
        upd.x, upd.y, upd.width, upd.height = x, y, 6, 6
        upd.data = np.full(36, 100, np.int8)
        pub = rospy.Publisher('/tb3_0/map_updates', numpy_msg(OccupancyGridUpdate), queue_size=1, latch=True)
        time.sleep(1.0)
        pub.publish(upd)

        def block_in_map(msg):
            m = grid_from_msg(msg, 10 ** 9)
            # tb3_0 is the reference: the merged lattice is its own, shifted by whole cells
            dc = int(round((g0.origin[0] - m.origin[0]) / m.resolution))
            dr = int(round((g0.origin[1] - m.origin[1]) / m.resolution))
            return bool((m.data[y + dr:y + dr + 6, x + dc:x + dc + 6] == 100).all())
        # (/map is sent when the merged map changes: wait for the block in it, not for a message)
        self.assertTrue(wait_until(lambda: self.listen.map_where(block_in_map), 10.0),
                        'the map update did not reach /map')

        # gmapping restart of tb3_1: a small new map with a new origin
        known_before = known_cells(self.listen.latest_map())
        g1 = self.pieces[1][0]
        small = Grid(g1.data[:60, :60].copy(), g1.resolution, (0.0, 0.0, 0.0), 'tb3_1/map')
        t2 = time.time()
        self.player.publish('tb3_1', small)
        self.assertTrue(wait_until(lambda: self.logged('/map_merge', 'map of tb3_1 restarted', t2), 10.0))

        self.assertTrue(wait_until(lambda: self.listen.map_where(lambda m: known_cells(m) < 0.8 * known_before), 10.0),
                        'stale cells of the restarted map stayed in /map')

        # its placement and link were forgotten: the rviz markers drop its arrow and the link
        def markers_without_tb3_1():
            for t, arr in list(self.markers):
                names = [m.text for m in arr.markers if m.ns == 'robot_names']
                links = [m for m in arr.markers if m.ns == 'links']
                if t > t2 and arr.markers[0].action == Marker.DELETEALL and names == ['tb3_0 (reference)'] \
                        and not links:
                    return arr
            return None
        self.assertTrue(wait_until(markers_without_tb3_1, 10.0), 'the markers of the restarted tb3_1 stayed: %s'
                        % [[(m.ns, m.text) for m in a.markers] for _, a in self.markers[-1:]])

        # the robot vanishes (its publisher goes away) and comes back with its full map
        self.player.pubs['tb3_1'].unregister()
        t3 = time.time()
        self.assertTrue(wait_until(lambda: self.logged('/map_merge', 'robot tb3_1 vanished', t3), 10.0))
        self.player.pubs['tb3_1'] = rospy.Publisher('/tb3_1/map', NumpyGrid, queue_size=1, latch=True)
        time.sleep(0.5)
        self.player.publish('tb3_1', g1)
        self.assertTrue(wait_until(lambda: self.logged('/map_merge', 'robot tb3_1 is back', t3), 10.0))
        t4 = time.time()
        self.assertTrue(wait_until(lambda: self.merged('tb3_1', t4), 30.0), 'tb3_1 not merged again')
        T = lookup(self.buf, 'map', 'tb3_1/map', 5.0)
        d, a = pose_distance(T, self.T_true)
        self.assertLess(d, 0.1)
        self.assertLess(a, math.radians(1))

    def test_2_restart_of_the_merger_reloads_transforms(self):
        path = rospy.get_param('/map_merge/transforms_file')
        self.assertTrue(wait_until(lambda: os.path.exists(path), 10.0),
                        'state file (~transforms_file, its former name) not written')
        saved = yaml.safe_load(open(path))
        self.assertTrue(any({e['parent'], e['child']} == {'tb3_0', 'tb3_1'} for e in saved['edges']))
        # A second merger that cannot estimate anything itself (min_matches out of reach): if it
        # places tb3_1 right, that can only be the saved link, reloaded and verified again.
        proc = subprocess.Popen(['rosrun', PKG, 'map_merge_node', '__name:=map_merge_b', 'map:=/map_b',
                                 'map_metadata:=/map_metadata_b', '_transforms_file:=' + path,
                                 '_merged_map_frame:=map_b', '_min_matches:=100000000',
                                 '_estimation_rate:=2.0'],
                                start_new_session=True)
        # Both mergers now broadcast a parent of tb3_1/map (map, map_b); tf2 keeps one parent
        # per frame at a time, so a shared buffer flips between them. The second merger's own
        # transforms go into a buffer of their own, and are looked up there.
        own = tf2_ros.Buffer(rospy.Duration(30.0))

        def take(msg):
            for t in msg.transforms:
                if t.header.frame_id == 'map_b':
                    own.set_transform(t, 'map_merge_b')
        sub = rospy.Subscriber('/tf', TFMessage, take, queue_size=100)
        try:
            T = lookup(own, 'map_b', 'tb3_1/map', 30.0)
            self.assertIsNotNone(T, 'the restarted merger did not restore its saved link')
            d, a = pose_distance(T, self.T_true)
            self.assertLess(d, 0.1)
            self.assertLess(a, math.radians(1))
        finally:
            sub.unregister()
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(10)
            if os.path.exists(path):
                os.unlink(path)


if __name__ == '__main__':
    rostest.rosrun(PKG, 'lifecycle', TestLifecycle)
