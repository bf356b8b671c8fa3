#!/usr/bin/env python3
"""rostest: the merger node's own status on /diagnostics, in real situations (node_status.test).

Two robots carrying overlapping pieces of the Intel map are merged: the node's status is OK,
its hardware id the node's name. Then one of the node's estimation worker processes is killed
(SIGKILL, as the kernel's OOM killer does) and tb3_1's map grows, so that the next estimation
cycle needs the pool: that cycle raises, and the node's status is ERROR with the exception's
type and text; the cycle after starts a new pool, estimates, and the status is OK again. Then
tb3_1's maps stop while its publisher stays (a stuck gmapping): after ~stale_map_timeout (4 s
in node_status.test) the node's status is WARN naming it stale and tb3_1's own status says for
how long, still merged; its maps come again and both are OK. Last, tb3_1's map publisher goes
away: the node's status is WARN naming tb3_1 as vanished.

The robots send their map every second, as gmapping does every map_update_interval (an
unchanged map too): a map sent once would be stale after 4 s.
"""
import math
import os
import signal
import sys
import threading
import time
import xmlrpc.client

import numpy as np
import rosgraph
import rosnode
import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticStatus
from rostest_helpers import MERGER, PiecesTest, wait_until

from multi_map_merge.core.grid import Grid

PKG = 'multi_map_merge'


def node_pid(name):
    """The process id of a ROS node, asked through its own XML-RPC API."""
    uri = rosnode.get_api_uri(rosgraph.Master('/test_node_status'), name)
    code, msg, pid = xmlrpc.client.ServerProxy(uri).getPid('/test_node_status')
    assert code == 1, msg
    return int(pid)


def children(pid):
    """Process ids whose parent is ``pid`` (from /proc)."""
    out = []
    for d in os.listdir('/proc'):
        if not d.isdigit():
            continue
        try:
            with open('/proc/%s/stat' % d) as f:
                stat = f.read()
        except OSError:
            continue
        if int(stat[stat.rindex(')') + 2:].split()[1]) == pid:
            out.append(int(d))
    return out


def cmdline(pid):
    try:
        with open('/proc/%d/cmdline' % pid, 'rb') as f:
            return f.read().replace(b'\0', b' ').decode(errors='replace')
    except OSError:
        return ''


def worker_pids(node):
    """The estimation workers of the node: its children forked at its start (core/workers.py's
    start_pool), or those of its multiprocessing forkserver where the pool was started later."""
    kids = children(node)
    servers = [p for p in kids if 'forkserver' in cmdline(p)]
    forked = [p for p in kids if p not in servers and 'resource_tracker' not in cmdline(p)]
    return forked + [w for s in servers for w in children(s)]


class TestNodeStatus(PiecesTest):

    NODE = 'test_node_status'
    ROBOTS = ['tb3_0', 'tb3_1']
    POSES = [(0.5, 1.0, math.radians(-30.0)), (-2.0, 3.0, math.radians(150.0))]
    merged_at = None
    STALE_MAP_TIMEOUT = 4.0   # node_status.test's ~stale_map_timeout

    @classmethod
    def setUpClass(cls):
        super().setUpClass()
        cls.latest = {}              # robot -> the grid it sends every second
        cls.feeding = set()          # the robots sending now
        cls.feed_lock = threading.Lock()
        threading.Thread(target=cls._feed, daemon=True).start()

    @classmethod
    def _feed(cls):
        while not rospy.is_shutdown():
            with cls.feed_lock:
                for r in sorted(cls.feeding):
                    cls.player.publish(r, cls.latest[r])
            time.sleep(1.0)

    def send(self, robot, grid):
        """``robot``'s map is ``grid`` from now on, sent now and every second."""
        with self.feed_lock:
            self.latest[robot] = grid
            self.feeding.add(robot)
            self.player.publish(robot, grid)

    def _node(self, after, level, text=''):
        st = self.listen.node_status(after)
        return st if st and st[0].level == level and text in st[0].message else None

    def test_1_merged_is_ok(self):
        t0 = time.time()
        for k, (g, _) in enumerate(self.pieces):
            self.send(self.ROBOTS[k], g)
        st = wait_until(lambda: self._node(t0, DiagnosticStatus.OK), 40.0)
        self.assertTrue(st, 'the node status never OK with two robots: %s' % (self.listen.node_status(),))
        s, kv = st
        print('node: level %d "%s" %s (hardware id %s)' % (s.level, s.message, kv, s.hardware_id))
        self.assertEqual(s.hardware_id, MERGER)
        self.assertEqual(s.name, '%s: node' % MERGER)
        self.assertEqual((kv['robots'], kv['merged']), ('2', '2'))
        self.assertEqual(kv['last_error'], '-')
        type(self).merged_at = time.time()
        # node_status.test's ~workers (3, more than CI's cores) was read before the node's
        # threads started: its workers were forked from it, not from a forkserver started later
        # (which imports OpenCV again)
        kids = children(node_pid('/' + MERGER))
        self.assertFalse([p for p in kids if 'forkserver' in cmdline(p)], [cmdline(p) for p in kids])
        self.assertEqual(len(worker_pids(node_pid('/' + MERGER))), 3, [cmdline(p) for p in kids])

    def test_2_failed_estimation_is_error_then_recovers(self):
        self.assertIsNotNone(self.merged_at, 'test_1 did not run')
        node = node_pid('/' + MERGER)
        workers = wait_until(lambda: worker_pids(node), 10.0)
        self.assertTrue(workers, 'no estimation worker process under the node (pid %d)' % node)
        t0 = time.time()
        os.kill(workers[0], signal.SIGKILL)
        time.sleep(0.5)
        # tb3_1's map grows (an occupied block where it knew nothing): the next cycle has work
        g = self.pieces[1][0]
        data = g.data.copy()
        rows, cols = np.nonzero(data == -1)
        k = next(i for i in range(len(rows)) if rows[i] > 10 and cols[i] > 10
                 and (data[rows[i]:rows[i] + 6, cols[i]:cols[i] + 6] == -1).all())
        data[rows[k]:rows[k] + 6, cols[k]:cols[k] + 6] = 100
        self.send('tb3_1', Grid(data, g.resolution, g.origin, g.frame_id))
        st = wait_until(lambda: self._node(t0, DiagnosticStatus.ERROR), 20.0)
        self.assertTrue(st, 'no ERROR after a worker was killed: %s' % (self.listen.node_status(),))
        s, kv = st
        print('node after the kill of worker %d: level %d "%s" %s' % (workers[0], s.level, s.message, kv))
        self.assertTrue(s.message.startswith('estimation failed: BrokenProcessPool: '), s.message)
        self.assertIn('terminated abruptly', s.message)
        self.assertTrue(kv['last_error'].startswith('BrokenProcessPool: '), kv)
        # the next cycle starts a new pool and estimates the grown map: OK again, tb3_1 merged
        t1 = time.time()
        st = wait_until(lambda: self._node(t1, DiagnosticStatus.OK), 30.0)
        self.assertTrue(st, 'the node did not recover: %s' % (self.listen.node_status(),))
        print('node after recovery: "%s" %s' % (st[0].message, st[1]))
        self.assertEqual(st[1]['last_error'], '-')
        self.assertEqual(st[1]['merged'], '2')
        self.assertTrue(worker_pids(node), 'no new worker processes')
        self.assertNotIn(workers[0], worker_pids(node))
        self.assert_tf(1)

    def test_3_stopped_maps_are_warn_then_clear(self):
        """tb3_1's publisher stays, its maps stop: WARN naming it (node and robot), merged
        still; they come again: OK."""
        self.assertIsNotNone(self.merged_at, 'test_1 did not run')
        with self.feed_lock:
            self.feeding.discard('tb3_1')
        t0 = time.time()
        st = wait_until(lambda: self._node(t0, DiagnosticStatus.WARN, 'stale: tb3_1'), 20.0)
        self.assertTrue(st, 'no WARN naming tb3_1 stale after its maps stopped: %s' % (self.listen.node_status(),))
        t_warn = time.time()
        s, kv = st
        print('node with tb3_1 stopped: level %d "%s" %s' % (s.level, s.message, kv))
        self.assertGreaterEqual(time.time() - t0, self.STALE_MAP_TIMEOUT - 1.5)   # not at once
        self.assertEqual(kv['stale'], 'tb3_1')
        self.assertEqual((kv['vanished'], kv['merged']), ('-', '2'))
        self.assertNotIn('tb3_0', s.message)      # still sending
        r = wait_until(lambda: self.listen.status('tb3_1', t_warn), 5.0)   # (stale since the node said so)
        self.assertTrue(r)
        print('tb3_1 stopped: level %d "%s" %s' % (r[0].level, r[0].message, r[1]))
        self.assertEqual(r[0].level, DiagnosticStatus.WARN)
        self.assertIn('no map for', r[0].message)
        self.assertGreater(float(r[1]['map_age_s']), self.STALE_MAP_TIMEOUT)
        self.assertEqual((r[1]['publisher'], r[1]['merged']), ('ok', 'true'))   # kept merged
        r0 = self.listen.status('tb3_0', t0)
        self.assertLess(float(r0[1]['map_age_s']), 2.5)
        # its maps come again: OK
        with self.feed_lock:
            self.feeding.add('tb3_1')
        t1 = time.time()
        st = wait_until(lambda: self._node(t1, DiagnosticStatus.OK), 10.0)
        self.assertTrue(st, 'still not OK once tb3_1 sends maps again: %s' % (self.listen.node_status(),))
        self.assertEqual(st[1]['stale'], '-')
        t_ok = time.time()
        r = wait_until(lambda: self.listen.status('tb3_1', t_ok), 5.0)
        self.assertEqual(r[0].level, DiagnosticStatus.OK, r[0].message)
        self.assertLess(float(r[1]['map_age_s']), 2.5)

    def test_4_vanished_robot_is_warn(self):
        self.assertIsNotNone(self.merged_at, 'test_1 did not run')
        with self.feed_lock:
            self.feeding.discard('tb3_1')
            self.player.pubs['tb3_1'].unregister()
        t0 = time.time()
        st = wait_until(lambda: self._node(t0, DiagnosticStatus.WARN, 'tb3_1'), 15.0)
        self.assertTrue(st, 'no WARN naming tb3_1 after its map publisher went away: %s'
                        % (self.listen.node_status(),))
        s, kv = st
        print('node with tb3_1 gone: level %d "%s" %s' % (s.level, s.message, kv))
        self.assertIn('vanished: tb3_1', s.message)
        self.assertEqual(kv['vanished'], 'tb3_1')
        r = wait_until(lambda: self.listen.status('tb3_1', t0), 5.0)
        self.assertTrue(r)
        self.assertEqual(r[1]['publisher'], 'gone')
        self.assertEqual(r[1]['merged'], 'true')      # its last map and transform are kept
        self.assertEqual(r[0].level, DiagnosticStatus.WARN)


if __name__ == '__main__':
    rostest.rosrun(PKG, 'node_status', TestNodeStatus, sys.argv)
