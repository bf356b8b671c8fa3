#!/usr/bin/env python3
"""rostest: the live merger node on four robots' maps cut out of the Intel map.

The test node plays four gmapping robots: on ``/tb3_N/map`` (latched, frame ``tb3_N/map``) it
publishes first a small part of its piece (what the robot saw near its start, on a cropped grid
with its own origin), then, once the merger has received those, the whole piece. It broadcasts
each robot's ``tb3_N/map -> tb3_N/odom -> tb3_N/base_footprint`` itself. Each piece was moved
into its robot's frame by a pose we chose, so the answer is known: the merged ``/map`` (in the
reference tb3_0's frame) is compared cell by cell with the world map warped into that frame, and
the TF ``map -> tb3_N/map`` with the true relative poses.

The helpers at the top are shared with test_bad_input.py.
"""
import math
import os
import sys
import threading
import time
import unittest

import cv2
import numpy as np
import rospy
import rostest
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import OccupancyGrid
from rospy.numpy_msg import numpy_msg

from multi_map_merge.core.grid import FREE, OCCUPIED, UNKNOWN, Grid, known_bbox
from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import cell_to_metric, pose_distance, se2, xyyaw
from multi_map_merge.lab.synth import cut_piece, split_rects
from multi_map_merge.ros.convert import grid_to_msg, quaternion_yaw, transform_msg

PKG = 'multi_map_merge'
NumpyGrid = numpy_msg(OccupancyGrid)
DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'data')


def data_file(name):
    """A map shipped with the package, under test/data (a missing one is an error, not a skip)."""
    path = os.path.join(DATA, name)
    if not os.path.exists(path):
        raise FileNotFoundError('test map %s is missing' % path)
    return path


# ---------------------------------------------------------------- waiting and listening
def wait_until(pred, timeout, period=0.1):
    """Poll ``pred`` until it returns something truthy (returned) or ``timeout`` s pass (None)."""
    end = time.time() + timeout
    while time.time() < end and not rospy.is_shutdown():
        v = pred()
        if v:
            return v
        time.sleep(period)
    return None


class Listener:
    """Keeps the latest /map and /diagnostics per robot, with the wall time they arrived."""

    def __init__(self):
        self.lock = threading.Lock()
        self.map_msg = None
        self.map_time = 0.0
        self.map_count = 0
        self.diag = {}        # robot -> (DiagnosticStatus, arrival time)
        self.diag_time = 0.0
        self.rosout = []      # rosgraph_msgs/Log of the merger node
        rospy.Subscriber('/map', NumpyGrid, self._on_map, queue_size=1, buff_size=2 ** 26)
        rospy.Subscriber('/diagnostics', DiagnosticArray, self._on_diag, queue_size=20)

    def _on_map(self, msg):
        with self.lock:
            self.map_msg, self.map_time = msg, time.time()
            self.map_count += 1

    def _on_diag(self, msg):
        now = time.time()
        with self.lock:
            for s in msg.status:
                if s.name.startswith('multi_map_merge: '):
                    self.diag[s.hardware_id] = (s, now)
            self.diag_time = now

    def map_after(self, t):
        """The latest /map if it arrived after wall time ``t``, else None."""
        with self.lock:
            return self.map_msg if self.map_msg is not None and self.map_time > t else None

    def status(self, robot, after=0.0):
        """(DiagnosticStatus, values dict) of ``robot`` if reported after ``after``, else None."""
        with self.lock:
            s = self.diag.get(robot)
        if s is None or s[1] <= after:
            return None
        return s[0], {kv.key: kv.value for kv in s[0].values}


class RobotPlayer:
    """Latched ``/<robot>/map`` publishers plus each robot's own TF chain at 10 Hz."""

    def __init__(self, robots):
        self.robots = list(robots)
        self.pubs = {r: rospy.Publisher('/%s/map' % r, NumpyGrid, queue_size=1, latch=True)
                     for r in self.robots}
        self._tf = tf2_ros.TransformBroadcaster()
        self._stop = False
        self._thread = threading.Thread(target=self._tf_loop, daemon=True)
        self._thread.start()

    def add(self, robot):
        self.pubs[robot] = rospy.Publisher('/%s/map' % robot, NumpyGrid, queue_size=1, latch=True)
        self.robots.append(robot)

    def publish(self, robot, grid):
        self.pubs[robot].publish(grid_to_msg(grid, rospy.Time.now(), '%s/map' % robot))

    def _tf_loop(self):
        while not rospy.is_shutdown() and not self._stop:
            now = rospy.Time.now()
            tfs = []
            for r in list(self.robots):
                tfs.append(transform_msg(np.eye(3), '%s/map' % r, '%s/odom' % r, now))
                tfs.append(transform_msg(se2(0.4, -0.2, 0.3), '%s/odom' % r, '%s/base_footprint' % r, now))
            self._tf.sendTransform(tfs)
            time.sleep(0.1)


def lookup(buf, parent, child, timeout):
    """3x3 pose of ``child`` in ``parent`` from tf2, or None if it does not resolve in time."""
    try:
        t = buf.lookup_transform(parent, child, rospy.Time(0), rospy.Duration(timeout))
    except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException):
        return None
    tr = t.transform
    return se2(tr.translation.x, tr.translation.y, quaternion_yaw(tr.rotation))


def grid_of(msg):
    """(levels uint8 HxW, resolution, (ox, oy, yaw)) of an OccupancyGrid message."""
    info = msg.info
    data = np.asarray(msg.data).astype(np.int16).reshape(info.height, info.width)
    lv = np.zeros(data.shape, np.uint8)
    lv[(data >= 0) & (data <= 19)] = FREE
    lv[data >= 65] = OCCUPIED
    o = info.origin
    return lv, float(info.resolution), (o.position.x, o.position.y, quaternion_yaw(o.orientation))


# ---------------------------------------------------------------- the known answer
def make_pieces(world, n, poses, overlap=0.35):
    """``n`` overlapping pieces of ``world``, piece k in frame ``tb3_k/map`` whose pose in the
    world frame is ``poses[k]``. Returns [(grid, T_world_k)]."""
    rects = split_rects(world, n, overlap)
    return [cut_piece(world, r, p, 'tb3_%d/map' % k) for k, (r, p) in enumerate(zip(rects, poses))]


def revealed(grid, radius):
    """What a robot has mapped after exploring ``radius`` metres around the middle of its piece,
    on a grid cropped to it the way gmapping's canvas starts small (new size, new origin a whole
    number of cells from the full grid's, yaw 0)."""
    lv = grid.levels()
    rows, cols = np.nonzero(lv)
    rc, cc = np.median(rows), np.median(cols)
    rr, ccs = np.mgrid[0:grid.height, 0:grid.width]
    seen = np.hypot(rr - rc, ccs - cc) * grid.resolution <= radius
    data = np.where(seen, grid.data, -1).astype(np.int8)
    box = known_bbox((data >= 0).astype(np.uint8), 20)
    r0, r1, c0, c1 = box
    o = (grid.origin[0] + c0 * grid.resolution, grid.origin[1] + r0 * grid.resolution, 0.0)
    return Grid(np.ascontiguousarray(data[r0:r1, c0:c1]), grid.resolution, o, grid.frame_id)


def sample_world(world_levels, world, T_world_map, res, origin, shape):
    """World levels (any uint8 array on the world grid) at the cell centres of a grid
    ``shape`` with ``res``/``origin`` in the frame ``map`` (nearest cell; outside -> 0)."""
    h, w = shape
    M = np.linalg.inv(cell_to_metric(world.resolution, world.origin)) @ T_world_map @ \
        cell_to_metric(res, origin)   # map-grid cells -> world cells
    return cv2.warpAffine(world_levels, M[:2], (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def expected_canvas(pieces, T_map):
    """The merged canvas the union of the pieces needs, on the reference lattice: per piece its
    known cells' bounding box (grown by one cell) in the merged frame by the true pose.
    Returns (x0, y0, width, height) in metres / cells, and the union's known-cell extent
    (xmin, xmax, ymin, ymax) in metres."""
    ref = pieces[0][0]
    res = ref.resolution
    lx, ly = ref.origin[0], ref.origin[1]
    i0 = j0 = 10 ** 9
    i1 = j1 = -10 ** 9
    ext = [np.inf, -np.inf, np.inf, -np.inf]
    for (g, _), T in zip(pieces, T_map):
        r0, r1, c0, c1 = known_bbox(g.levels(), 1)
        W = T @ cell_to_metric(res, g.origin)
        corners = np.array([[c0 - 0.5, r0 - 0.5, 1], [c1 - 0.5, r0 - 0.5, 1],
                            [c0 - 0.5, r1 - 0.5, 1], [c1 - 0.5, r1 - 0.5, 1]]).T
        m = (W @ corners)[:2]
        i0 = min(i0, int(math.floor((m[0].min() - lx) / res)))
        i1 = max(i1, int(math.ceil((m[0].max() - lx) / res)))
        j0 = min(j0, int(math.floor((m[1].min() - ly) / res)))
        j1 = max(j1, int(math.ceil((m[1].max() - ly) / res)))
        rr, cc = np.nonzero(g.levels())
        pts = W @ np.vstack([cc, rr, np.ones_like(cc)])
        ext = [min(ext[0], pts[0].min()), max(ext[1], pts[0].max()),
               min(ext[2], pts[1].min()), max(ext[3], pts[1].max())]
    return (lx + i0 * res, ly + j0 * res, i1 - i0, j1 - j0), ext


def known_extent(lv, res, origin):
    """(xmin, xmax, ymin, ymax) metres of the known cells' centres of a yaw-0 grid."""
    r0, r1, c0, c1 = known_bbox(lv)
    return (origin[0] + (c0 + 0.5) * res, origin[0] + (c1 - 0.5) * res,
            origin[1] + (r0 + 0.5) * res, origin[1] + (r1 - 0.5) * res)


def compare_with_truth(msg, world, T_world_map, union_mask):
    """Scores of the merged map against the world map seen from frame ``map``.

    ``union_mask`` is a uint8 mask on the world grid of the area the pieces cover. Returns a
    dict: occ_precision (merged occupied cells within 2 cells of a true wall), free_wrong
    (merged free cells on a true wall), outside (merged known cells outside the union, grown by
    2 cells), known (merged known cells), union_known (known world cells in the union), recall
    (union-known cells known in the merged map)."""
    lv, res, origin = grid_of(msg)
    wl = world.levels()
    k = np.ones((5, 5), np.uint8)
    occ = (wl == OCCUPIED).astype(np.uint8)
    occ_near = sample_world(cv2.dilate(occ, k), world, T_world_map, res, origin, lv.shape)
    occ_here = sample_world(occ, world, T_world_map, res, origin, lv.shape)
    union_known = ((wl != UNKNOWN) & (union_mask > 0)).astype(np.uint8)
    in_union = sample_world(cv2.dilate(union_known, k), world, T_world_map, res, origin, lv.shape)
    m_occ, m_free, m_known = lv == OCCUPIED, lv == FREE, lv != UNKNOWN
    # recall: every known cell of the union, carried into the merged grid's frame
    union_on_map = sample_world(union_known, world, T_world_map, res, origin, lv.shape)
    return dict(
        occ_precision=float(occ_near[m_occ].mean()) if m_occ.any() else 0.0,
        free_wrong=float(occ_here[m_free].mean()) if m_free.any() else 1.0,
        outside=float((in_union[m_known] == 0).mean()) if m_known.any() else 1.0,
        known=int(m_known.sum()),
        union_known=int(union_known.sum()),
        recall=float(m_known[union_on_map > 0].mean()) if union_on_map.any() else 0.0)


def union_mask_of(world, pieces):
    """uint8 mask on the world grid of the cells the pieces know (each piece's known cells
    carried back into the world grid by its true pose)."""
    mask = np.zeros(world.data.shape, np.uint8)
    for g, T in pieces:
        # world cells -> piece cells, sampled at the world cells' centres
        M = np.linalg.inv(cell_to_metric(g.resolution, g.origin)) @ np.linalg.inv(T) @ \
            cell_to_metric(world.resolution, world.origin)
        known = (g.levels() != UNKNOWN).astype(np.uint8)
        mask |= cv2.warpAffine(known, M[:2], (world.width, world.height),
                               flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return mask


def fmt_pose(T):
    x, y, a = xyyaw(T)
    return '(%.3f, %.3f, %.2f deg)' % (x, y, math.degrees(a))


# ---------------------------------------------------------------- the test
ROBOTS = ['tb3_0', 'tb3_1', 'tb3_2', 'tb3_3']
# pose (x m, y m, yaw rad) of each robot's map frame in the world (Intel map) frame
POSES = [(1.5, -1.0, math.radians(20.0)),
         (-3.0, 2.0, math.radians(180.0)),
         (4.0, 3.5, math.radians(-95.0)),
         (-2.5, -4.0, math.radians(135.0))]
TF_TOL_M = 0.10
TF_TOL_RAD = math.radians(1.0)


class TestMergeNode(unittest.TestCase):

    @classmethod
    def setUpClass(cls):
        rospy.init_node('test_merge_node', anonymous=True)
        cls.world = load_map(data_file('intel.yaml'))
        cls.pieces = make_pieces(cls.world, 4, POSES)
        T_w0 = cls.pieces[0][1]
        cls.T_world_map = T_w0                     # merged frame = reference tb3_0's map frame
        cls.T_true = [np.linalg.inv(T_w0) @ T for _, T in cls.pieces]
        cls.union = union_mask_of(cls.world, cls.pieces)
        cls.buf = tf2_ros.Buffer(rospy.Duration(30.0))
        cls.tfl = tf2_ros.TransformListener(cls.buf)
        cls.listen = Listener()
        cls.player = RobotPlayer(ROBOTS)
        cls.t_full = None

    @classmethod
    def tearDownClass(cls):
        cls.player._stop = True

    def _all_merged(self, after):
        out = {}
        for r in ROBOTS:
            s = self.listen.status(r, after)
            if s is None or s[1].get('merged') != 'true':
                return None
            out[r] = s
        return out

    def test_1_growing_maps_merge(self):
        """Small first maps (merged as they are), then the whole pieces on grown grids with new
        origins: every robot stays merged."""
        t0 = time.time()
        for r, (g, _) in zip(ROBOTS, self.pieces):
            part = revealed(g, 8.0)
            self.assertLess(part.width * part.height, g.width * g.height)
            self.player.publish(r, part)
        # the first (small) maps alone are enough to place every robot
        first = wait_until(lambda: self._all_merged(t0), 40.0)
        self.assertTrue(first, 'the small first maps were not all merged: %s' % self._messages())
        type(self).t_full = time.time()
        for r, (g, _) in zip(ROBOTS, self.pieces):
            self.player.publish(r, g)
        # a few estimation cycles (2 Hz here) on the whole maps, then every robot still merged
        merged = wait_until(lambda: self._all_merged(self.t_full + 3.0), 40.0)
        self.assertTrue(merged, 'not every robot merged: %s' % self._messages())
        for r, (st, kv) in merged.items():
            self.assertEqual(st.level, 0, '%s: %s' % (r, st.message))
            print('%s: %s %s' % (r, st.message, kv))
        self.assertEqual(merged['tb3_0'][1].get('reference'), 'true')

    def _messages(self):
        return {r: (s[0].message if s else None)
                for r, s in ((r, self.listen.status(r)) for r in ROBOTS)}

    def test_2_merged_map_matches_truth(self):
        self.assertIsNotNone(self.t_full, 'test_1 did not run')
        # a /map composed after every robot's whole map and placement were in
        t_ok = time.time()
        msg = wait_until(lambda: self.listen.map_after(t_ok), 10.0)
        self.assertIsNotNone(msg, 'no /map after the merge')
        self.assertEqual(msg.header.frame_id, 'map')
        lv, res, origin = grid_of(msg)
        self.assertAlmostEqual(res, self.world.resolution, places=6)
        self.assertAlmostEqual(origin[2], 0.0, places=6)

        (x0, y0, w, h), ext = expected_canvas(self.pieces, self.T_true)
        cell = res
        print('merged %dx%d origin (%.3f, %.3f); expected %dx%d origin (%.3f, %.3f)'
              % (msg.info.width, msg.info.height, origin[0], origin[1], w, h, x0, y0))
        self.assertLessEqual(abs(msg.info.width - w), 4, 'width %d, expected %d' % (msg.info.width, w))
        self.assertLessEqual(abs(msg.info.height - h), 4, 'height %d, expected %d' % (msg.info.height, h))
        self.assertLessEqual(abs(origin[0] - x0), 4 * cell)
        self.assertLessEqual(abs(origin[1] - y0), 4 * cell)
        got = known_extent(lv, res, origin)
        print('known extent merged %s, union %s' % (np.round(got, 2), np.round(ext, 2)))
        for a, b in zip(got, ext):
            self.assertLessEqual(abs(a - b), 3 * cell, 'known extent %s, union of pieces %s' % (got, ext))

        sc = compare_with_truth(msg, self.world, self.T_world_map, self.union)
        print('merged vs truth: %s' % sc)
        self.assertGreaterEqual(sc['occ_precision'], 0.95, sc)
        self.assertLessEqual(sc['free_wrong'], 0.02, sc)
        self.assertLessEqual(sc['outside'], 0.01, sc)
        self.assertGreaterEqual(sc['recall'], 0.97, sc)
        self.assertLess(abs(sc['known'] - sc['union_known']) / float(sc['union_known']), 0.05, sc)

    def _check_tf(self, label):
        errs = {}
        for k, r in enumerate(ROBOTS):
            T = lookup(self.buf, 'map', '%s/map' % r, 5.0)
            self.assertIsNotNone(T, 'no TF map -> %s/map' % r)
            d, a = pose_distance(T, self.T_true[k])
            errs[r] = (d, math.degrees(a))
            print('%s TF map -> %s/map %s, true %s: error %.4f m, %.3f deg'
                  % (label, r, fmt_pose(T), fmt_pose(self.T_true[k]), d, math.degrees(a)))
            self.assertLess(d, TF_TOL_M, '%s: %.3f m off' % (r, d))
            self.assertLess(a, TF_TOL_RAD, '%s: %.3f deg off' % (r, math.degrees(a)))
        d0, a0 = pose_distance(lookup(self.buf, 'map', 'tb3_0/map', 1.0), np.eye(3))
        self.assertLess(d0, 1e-6)
        self.assertLess(a0, 1e-6)
        return errs

    def test_3_tf_matches_true_poses(self):
        self.assertIsNotNone(self.t_full, 'test_1 did not run')
        self._check_tf('merged:')
        for r in ROBOTS:
            T = lookup(self.buf, 'map', '%s/base_footprint' % r, 5.0)
            self.assertIsNotNone(T, 'map -> %s/base_footprint does not resolve' % r)

    def test_4_reset_merges_again(self):
        self.assertIsNotNone(self.t_full, 'test_1 did not run')
        from std_srvs.srv import Trigger
        rospy.wait_for_service('/map_merge/reset', 10.0)
        t_reset = time.time()
        resp = rospy.ServiceProxy('/map_merge/reset', Trigger)()
        self.assertTrue(resp.success, resp.message)

        def remerged():
            m = self._all_merged(t_reset)
            if not m:
                return None
            # a placement adopted after the reset: its age is younger than the reset
            for r in ROBOTS[1:]:
                if float(m[r][1]['age_s']) > time.time() - t_reset:
                    return None
            return m
        self.assertTrue(wait_until(remerged, 30.0), 'no re-merge after /map_merge/reset')
        self._check_tf('after reset:')
        t_ok = time.time()
        msg = wait_until(lambda: self.listen.map_after(t_ok), 10.0)
        self.assertIsNotNone(msg)
        sc = compare_with_truth(msg, self.world, self.T_world_map, self.union)
        self.assertGreaterEqual(sc['occ_precision'], 0.95, sc)
        self.assertGreaterEqual(sc['recall'], 0.97, sc)


if __name__ == '__main__':
    rostest.rosrun(PKG, 'merge_node', TestMergeNode, sys.argv)
