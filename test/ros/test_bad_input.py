#!/usr/bin/env python3
"""rostest: the merger node facing a map that does not belong and maps that are malformed.

tb3_0 and tb3_1 carry overlapping pieces of the Intel map (known poses). tb3_2 carries the AWS
small house, another building: it must never be placed (no TF, diagnostics "not merged") and
must leave the merged map exactly as tb3_0 + tb3_1 made it. Then tb3_1 publishes malformed
maps: the node must refuse each one, say why (diagnostics and an ERROR log naming tb3_1), keep
running, and keep the merged map unchanged; a valid map afterwards clears the error.
"""
import math
import sys
import threading
import time

import rosnode
import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticStatus
from rosgraph_msgs.msg import Log
from rostest_helpers import HOUSE_MAP, PiecesTest, known_cells, lookup, same_map, shared_file, wait_until

from multi_map_merge.core.mapio import load_map
from multi_map_merge.ros.convert import NumpyGrid, grid_to_msg

PKG = 'multi_map_merge'
ESTIMATION_PERIOD = 0.5   # s, estimation_rate in bad_input.test


class TestBadInput(PiecesTest):

    NODE = 'test_bad_input'
    ROBOTS = ['tb3_0', 'tb3_1']
    POSES = [(0.5, 1.0, math.radians(-30.0)), (-2.0, 3.0, math.radians(150.0))]
    two_robot_map = None

    @classmethod
    def setUpClass(cls):
        super().setUpClass()
        cls.house = load_map(shared_file(HOUSE_MAP))
        cls.logs = []
        cls.log_lock = threading.Lock()
        rospy.Subscriber('/rosout', Log, cls._on_log, queue_size=100)

    @classmethod
    def _on_log(cls, msg):
        if msg.name == '/map_merge':
            with cls.log_lock:
                cls.logs.append(msg)

    def _status(self, robot, after=0.0):
        return self.listen.status(robot, after)

    def test_1_two_robots_merge(self):
        t0 = time.time()
        for k, (g, _) in enumerate(self.pieces):
            self.player.publish('tb3_%d' % k, g)
        ok = wait_until(lambda: (self._status('tb3_1', t0) or (None, {}))[1].get('merged') == 'true', 40.0)
        self.assertTrue(ok, 'tb3_1 was not merged with tb3_0')
        self.assert_tf(1)
        # the /map of both robots (sent once, latched)
        msg = wait_until(lambda: self.listen.map_where(self.whole_merge), 10.0)
        self.assertIsNotNone(msg, 'no /map of both robots: the latest knows %s cells, the two pieces %d'
                             % (known_cells(self.listen.latest_map()) if self.listen.latest_map() else None,
                                self.union_known))
        # the two-robot merge is right (so "unchanged" below means right, too)
        self.assert_matches_truth(msg, 'two-robot merge')
        type(self).two_robot_map = msg

    def test_2_foreign_map_is_not_merged(self):
        self.assertIsNotNone(self.two_robot_map, 'test_1 did not run')
        n0 = self.listen.maps_received()
        self.player.add('tb3_2')
        t0 = time.time()
        self.player.publish('tb3_2', self.house)
        # the node found tb3_2 and tried to match it ...
        st = wait_until(lambda: (lambda s: s if s and 'last_result' in s[1] else None)(
            self._status('tb3_2', t0)), 30.0)
        self.assertTrue(st, 'the merger never tried tb3_2')
        print('tb3_2 first attempt: %s %s' % (st[0].message, st[1]))
        # ... and, many estimation cycles later, still has not placed it
        t_try = time.time()
        self.assertIsNone(lookup(self.buf, 'map', 'tb3_2/map', 8 * ESTIMATION_PERIOD + 2.0),
                          'tb3_2 (another building) got a TF into map')
        st = wait_until(lambda: self._status('tb3_2', t_try), 5.0)
        self.assertTrue(st)
        s, kv = st
        print('tb3_2 later: %s %s' % (s.message, kv))
        self.assertEqual(kv.get('merged'), 'false')
        self.assertEqual(s.level, DiagnosticStatus.WARN)
        self.assertTrue(s.message.startswith('not merged'), s.message)
        self.assertNotEqual(kv.get('last_result'), 'accepted')
        # the node's own status warns, naming the robot it cannot merge
        node = wait_until(lambda: self.listen.node_status(t_try), 5.0)
        self.assertTrue(node, 'no status of the node itself')
        print('node: %s' % node[0].message)
        self.assertEqual(node[0].level, DiagnosticStatus.WARN)
        self.assertIn('not merged: tb3_2', node[0].message)
        self.assertEqual(node[1].get('not_merged'), 'tb3_2')
        # tb3_0 and tb3_1 are still placed, so the TF tree itself works
        self.assertIsNotNone(lookup(self.buf, 'map', 'tb3_1/map', 2.0))
        # the merged map is exactly the two-robot one, and was not even sent again
        msg = self.listen.latest_map()
        self.assertTrue(same_map(msg, self.two_robot_map),
                        'tb3_2 changed /map: %dx%d -> %dx%d' % (
                            self.two_robot_map.info.width, self.two_robot_map.info.height,
                            msg.info.width, msg.info.height))
        self.assertEqual(self.listen.maps_received(), n0, '/map sent again for an unchanged merge')

    def _malformed(self, kind):
        """A map message for tb3_1 that is wrong in one way."""
        g = self.pieces[1][0]
        msg = grid_to_msg(g, rospy.Time.now(), 'tb3_1/map')
        if kind == 'length':
            msg.data = msg.data[:-7]
        elif kind == 'width0':
            msg.info.width = 0
        elif kind == 'nan_origin':
            msg.info.origin.position.x = float('nan')
        elif kind == 'resolution0':
            msg.info.resolution = 0.0
        elif kind == 'value120':
            d = msg.data.copy()
            d[len(d) // 2] = 120
            msg.data = d
        return msg

    def test_3_malformed_maps_are_refused(self):
        self.assertIsNotNone(self.two_robot_map, 'test_1 did not run')
        cases = [('length', 'data length'), ('width0', 'empty grid'), ('nan_origin', 'origin is not finite'),
                 ('resolution0', 'resolution must be'), ('value120', 'outside -1..100')]
        pub = self.player.pubs['tb3_1']
        n0 = self.listen.maps_received()
        for kind, reason in cases:
            t0 = time.time()
            pub.publish(self._malformed(kind))

            def refused(t0=t0, reason=reason):
                st = self._status('tb3_1', t0)
                return st if st and st[0].level == DiagnosticStatus.ERROR and reason in st[0].message else None
            st = wait_until(refused, 10.0)
            self.assertTrue(st, '%s: diagnostics of tb3_1 do not report "%s": %s'
                            % (kind, reason, self._status('tb3_1')))
            print('%s -> diagnostics: %s' % (kind, st[0].message))

            def logged(reason=reason):
                with self.log_lock:
                    return [m for m in self.logs if m.level == Log.ERROR and 'tb3_1' in m.msg and reason in m.msg]
            lg = wait_until(logged, 5.0)
            self.assertTrue(lg, '%s: no ERROR log naming tb3_1 and "%s"' % (kind, reason))
            print('%s -> log: %s' % (kind, lg[-1].msg))
            # tb3_1 keeps its last valid map and placement
            self.assertEqual(st[1].get('merged'), 'true')

        # the node is alive, still publishing, and the merged map has not changed (nor been sent
        # again); a new subscriber still gets it (latched)
        self.assertTrue(rosnode.rosnode_ping('/map_merge', max_count=1))
        t1 = time.time()
        self.assertTrue(same_map(self.listen.latest_map(), self.two_robot_map), 'malformed input changed /map')
        self.assertEqual(self.listen.maps_received(), n0, 'malformed input made /map be sent again')
        fresh = rospy.wait_for_message('/map', NumpyGrid, timeout=5.0)
        self.assertTrue(same_map(fresh, self.two_robot_map), 'a new subscriber got another /map')
        self.assertTrue(wait_until(lambda: self._status('tb3_0', t1), 5.0), 'diagnostics stopped')
        self.assertIsNotNone(lookup(self.buf, 'map', 'tb3_1/map', 2.0))

    def test_4_valid_map_clears_error(self):
        self.assertIsNotNone(self.two_robot_map, 'test_1 did not run')
        t0 = time.time()
        self.player.publish('tb3_1', self.pieces[1][0])
        st = wait_until(lambda: (lambda s: s if s and s[0].level == DiagnosticStatus.OK else None)(
            self._status('tb3_1', t0)), 10.0)
        self.assertTrue(st, 'tb3_1 still in error after a valid map: %s' % (self._status('tb3_1'),))
        self.assertEqual(st[1].get('merged'), 'true')


if __name__ == '__main__':
    rostest.rosrun(PKG, 'bad_input', TestBadInput, sys.argv)
