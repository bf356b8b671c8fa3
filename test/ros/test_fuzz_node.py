#!/usr/bin/env python3
"""rostest: hundreds of random bad OccupancyGrids and OccupancyGridUpdates into the live node;
it stays alive, keeps publishing, and the merged map stays exactly as it was."""
import time
import unittest

import numpy as np
import rosnode
import rospy
import rostest
from diagnostic_msgs.msg import DiagnosticStatus
from map_msgs.msg import OccupancyGridUpdate
from rospy.numpy_msg import numpy_msg
from rostest_helpers import INTEL_MAP, Listener, RobotPlayer, make_pieces, same_map, shared_file, wait_until

from multi_map_merge.core.grid import Grid
from multi_map_merge.core.mapio import load_map
from multi_map_merge.lab.pieces import bad_grids
from multi_map_merge.ros.convert import NumpyGrid, grid_to_msg

PKG = 'multi_map_merge'


class TestFuzzNode(unittest.TestCase):

    def test_bad_inputs_change_nothing(self):
        rospy.init_node('test_fuzz_node', anonymous=True)
        world = load_map(shared_file(INTEL_MAP))
        pieces = make_pieces(world, 2, [(0.5, 1.0, -0.5), (-2.0, 3.0, 2.6)])
        listen = Listener()
        player = RobotPlayer(['tb3_0', 'tb3_1'])
        for r, (g, _) in zip(['tb3_0', 'tb3_1'], pieces):
            player.publish(r, g)
        merged = wait_until(lambda: all((listen.status(r) or (None, {}))[1].get('merged') == 'true'
                                        for r in ('tb3_0', 'tb3_1')), 40.0)
        self.assertTrue(merged, 'the two good robots did not merge')
        time.sleep(1.0)
        snapshot = wait_until(listen.latest_map, 5.0)
        self.assertIsNotNone(snapshot)
        n0 = listen.maps_received()

        rng = np.random.default_rng(5)
        bad_pub = rospy.Publisher('/tb3_1/map', NumpyGrid, queue_size=50)
        new_pub = rospy.Publisher('/tb3_7/map', NumpyGrid, queue_size=50, latch=True)
        upd_pub = rospy.Publisher('/tb3_1/map_updates', numpy_msg(OccupancyGridUpdate), queue_size=50)
        time.sleep(1.5)   # let the node connect (and discover tb3_7)
        sent = 0
        for data, w, h, res, origin in bad_grids(rng, 300):
            msg = grid_to_msg(Grid(np.zeros((1, 1), np.int8), 0.05), rospy.Time.now(), 'tb3_1/map')
            msg.info.width, msg.info.height, msg.info.resolution = w, h, res
            msg.info.origin.position.x, msg.info.origin.position.y = origin[0], origin[1]
            if not np.isfinite(origin[2]):
                msg.info.origin.orientation.z = origin[2]    # a non-finite yaw
            msg.data = np.clip(data, -128, 127).astype(np.int8)
            (bad_pub if sent % 3 else new_pub).publish(msg)
            u = numpy_msg(OccupancyGridUpdate)()
            u.header.frame_id = 'tb3_1/map'
            u.x, u.y = int(rng.integers(0, 2000)), int(rng.integers(0, 2000))
            u.width, u.height = int(rng.integers(0, 500)), int(rng.integers(0, 500))
            u.data = rng.integers(-128, 128, int(rng.integers(0, 1000))).astype(np.int8)
            upd_pub.publish(u)
            sent += 1
            time.sleep(0.01)
        self.assertEqual(sent, 300)

        # alive, merged map exactly as before (not even sent again), still served to a new
        # subscriber (latched), errors reported
        self.assertTrue(rosnode.rosnode_ping('/map_merge', max_count=1))
        t1 = time.time()
        time.sleep(1.0)   # a merge period or four for a change, were there one, to be sent
        self.assertTrue(same_map(listen.latest_map(), snapshot), 'bad input changed the merged map')
        self.assertEqual(listen.maps_received(), n0, 'bad input made /map be sent again')
        fresh = rospy.wait_for_message('/map', NumpyGrid, timeout=5.0)
        self.assertTrue(same_map(fresh, snapshot), 'a new subscriber got another /map')
        st1 = wait_until(lambda: listen.status('tb3_1', t1), 5.0)
        self.assertTrue(st1)
        self.assertEqual(st1[1].get('merged'), 'true')
        self.assertEqual(st1[0].level, DiagnosticStatus.ERROR)
        st7 = wait_until(lambda: listen.status('tb3_7', t1), 5.0)
        self.assertTrue(st7, 'the bad-only robot is not reported')
        self.assertEqual(st7[1].get('merged'), 'false')
        self.assertEqual(st7[0].level, DiagnosticStatus.ERROR)
        # and a good map still goes through afterwards
        t2 = time.time()
        player.publish('tb3_1', pieces[1][0])
        ok = wait_until(lambda: (lambda s: s if s and s[0].level == DiagnosticStatus.OK else None)(
            listen.status('tb3_1', t2)), 10.0)
        self.assertTrue(ok, 'tb3_1 did not recover')
        player.stop()


if __name__ == '__main__':
    rostest.rosrun(PKG, 'fuzz_node', TestFuzzNode)
