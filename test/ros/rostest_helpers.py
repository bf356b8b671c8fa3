"""Helpers shared by the rostest scripts in this directory (not a test itself): the shared
data (others' maps, read in place), waiting, a listener of the merger's outputs, a player of robots' maps,
pieces of a map at known poses, comparisons with the truth, the set-up of a test on such
pieces (:class:`PiecesTest`), stopping a launch, making a bag of LDS-02 driver scans."""
import math
import os
import subprocess
import sys
import threading
import time
import unittest
from typing import Dict, List, Sequence

import cv2
import numpy as np
import rospkg
import rospy
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import OccupancyGrid
from rospy.numpy_msg import numpy_msg

from multi_map_merge.core.grid import FREE, OCCUPIED, UNKNOWN, known_bbox
from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import cell_to_metric, pose_distance, se2, xyyaw
from multi_map_merge.lab.pieces import cut_piece, split_rects
from multi_map_merge.ros.convert import grid_to_msg, quaternion_yaw, set_yaw, transform_msg
from multi_map_merge.ros.diagnostics import diagnostics_by_robot

NumpyGrid = numpy_msg(OccupancyGrid)
MERGER = 'map_merge'   # the merger node's name in the rostests (launch/map_merge.launch)
# four robots on pieces of the Intel map (test_merge_node.py, test_dask_cluster.py): the pose
# (x m, y m, yaw rad) of each robot's map frame in the world (Intel map) frame
FOUR_ROBOTS = ['tb3_0', 'tb3_1', 'tb3_2', 'tb3_3']
FOUR_POSES = [(1.5, -1.0, math.radians(20.0)),
              (-3.0, 2.0, math.radians(180.0)),
              (4.0, 3.5, math.radians(-95.0)),
              (-2.5, -4.0, math.radians(135.0))]
START_RADIUS = 10.0     # m explored from its start (its frame's origin) in each robot's first map


def shared_data() -> str:
    """``../shared/data`` beside the package (``MMM_SHARED_DATA`` overrides it; point it at a
    missing directory to see the tests skip)."""
    env = os.environ.get('MMM_SHARED_DATA')
    if env is not None:
        return env
    pkg = os.path.realpath(rospkg.RosPack().get_path('multi_map_merge'))
    return os.path.join(os.path.dirname(pkg), 'shared', 'data')


def skip_without_gmapping(test: unittest.TestCase) -> None:
    """Skip ``test`` when ROS finds no package gmapping (the real slam_gmapping node)."""
    try:
        rospkg.RosPack().get_path('gmapping')
    except rospkg.ResourceNotFound:
        test.skipTest('no gmapping: ROS has no package gmapping (Ubuntu: ros-noetic-gmapping; '
                      'slam:=rbpf runs this package\'s rbpf_slam instead)')


def stop_launch(proc: subprocess.Popen, timeout: float = 20.0) -> None:
    """Stop a roslaunch started with ``start_new_session=True``: SIGINT to its process group
    (roslaunch then stops its nodes), SIGKILL if it has not ended within ``timeout``
    (``multi_map_merge.lab.processes.stop_group``, the benchmarks' helper too)."""
    from multi_map_merge.lab.processes import stop_group
    stop_group(proc, timeout)


# others' files in ../shared/data (../shared/data/README.md), never shipped with the project
INTEL_MAP = 'ground_truth/intel_gt.yaml'      # the Intel lab (CARMEN log, rasterised)
HOUSE_MAP = 'aws/small_house/map.yaml'        # the AWS RoboMaker small house


def shared_file(*parts: str) -> str:
    """The path of ``parts`` under :func:`shared_data` (others' data, read in place), or skip the
    test (unittest.SkipTest, also from setUpClass) with one line naming the missing path."""
    path = os.path.join(shared_data(), *parts)
    if not os.path.exists(path):
        raise unittest.SkipTest("%s is absent: others' data is read in place from ../shared/data, "
                                "not shipped" % path)
    return path


def make_lds02_driver_bag(test: unittest.TestCase, bag: str, robots: int) -> None:
    """``make_robot_bags --lds02-driver``: a bag of ``robots`` robots' sensors alone (no SLAM),
    their scans shaped as the LDS-02 driver publishes them (seed 2), written to ``bag``; a
    failure fails ``test``."""
    pkg = rospkg.RosPack().get_path('multi_map_merge')
    r = subprocess.run([sys.executable, os.path.join(pkg, 'scripts', 'make_robot_bags'), '-o', bag,
                        '--robots', str(robots), '--seed', '2', '--no-single', '--sensors-only', '--lds02-driver'],
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, universal_newlines=True)
    test.assertEqual(r.returncode, 0, r.stderr)


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


def wait_for_merge(robots: Sequence[str], timeout: float, settle: float = 0.0) -> Dict[str, Dict[str, str]]:
    """Per-robot key/values of the merger's /diagnostics once every robot in ``robots`` is
    merged and ``settle`` more seconds have passed (or at ``timeout``)."""
    latest: Dict[str, Dict[str, str]] = {}

    sub = rospy.Subscriber('/diagnostics', DiagnosticArray, diagnostics_by_robot, callback_args=latest)
    end = time.time() + timeout
    merged_since = None
    while time.time() < end and not rospy.is_shutdown():
        done = all(latest.get(r, {}).get('merged') == 'true' for r in robots)
        if done and merged_since is None:
            merged_since = time.time()
        if done and time.time() - merged_since >= settle:
            break
        time.sleep(0.2)
    sub.unregister()
    return dict(latest)


def lookup_transforms(parent: str, children: List[str], timeout: float) -> Dict[str, np.ndarray]:
    """tf2 lookups ``parent -> child`` (3x3 poses, metres); children not found are left out."""
    buf = tf2_ros.Buffer()
    tf2_ros.TransformListener(buf)
    out = {}
    end = time.time() + timeout
    for c in children:
        while time.time() < end and not rospy.is_shutdown():
            try:
                t = buf.lookup_transform(parent, c, rospy.Time(0), rospy.Duration(0.5))
                tr = t.transform
                out[c] = se2(tr.translation.x, tr.translation.y, quaternion_yaw(tr.rotation))
                break
            except (tf2_ros.LookupException, tf2_ros.ConnectivityException,
                    tf2_ros.ExtrapolationException):
                time.sleep(0.1)
    return out


class Collector:
    """Every message of ``topic`` that ``keep`` accepts, in arrival order (thread-safe)."""

    def __init__(self, topic, msg_type, keep=lambda msg: True, queue_size=100):
        self._lock = threading.Lock()
        self._msgs = []
        self._keep = keep
        rospy.Subscriber(topic, msg_type, self._on_msg, queue_size=queue_size)

    def _on_msg(self, msg):
        if self._keep(msg):
            with self._lock:
                self._msgs.append(msg)

    def messages(self):
        with self._lock:
            return list(self._msgs)

    def clear(self):
        with self._lock:
            del self._msgs[:]


class Listener:
    """Keeps the latest /map (and how many arrived) and /diagnostics per robot, with the wall
    time they arrived. The merger sends /map (latched) only when the merged map changed: wait
    for the content a test needs (:meth:`map_where`), not for "the next /map"."""

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
                # the merger node's statuses (diagnostic_updater names them '<node>: <task>'):
                # one per robot, whose hardware id is the robot, and the node's, whose is the node's
                if s.name.startswith(MERGER + ': ') and s.hardware_id:
                    self.diag[s.hardware_id] = (s, now)
            self.diag_time = now

    def latest_map(self):
        """The latest /map received (None before the first)."""
        with self.lock:
            return self.map_msg

    def map_where(self, pred):
        """The latest /map if ``pred(msg)`` holds for it, else None (for :func:`wait_until`)."""
        msg = self.latest_map()
        return msg if msg is not None and pred(msg) else None

    def maps_received(self):
        """How many /map messages arrived so far."""
        with self.lock:
            return self.map_count

    def node_status(self, after=0.0):
        """(DiagnosticStatus, values dict) of the merger node itself if reported after ``after``."""
        return self.status(MERGER, after)

    def status(self, robot, after=0.0):
        """(DiagnosticStatus, values dict) of ``robot`` if reported after ``after``, else None."""
        with self.lock:
            s = self.diag.get(robot)
        if s is None or s[1] <= after:
            return None
        return s[0], {kv.key: kv.value for kv in s[0].values}

    def all_merged(self, robots, after=0.0):
        """robot -> :meth:`status` of every one of ``robots`` if each reported itself merged
        after ``after``, else None."""
        out = {}
        for r in robots:
            s = self.status(r, after)
            if s is None or s[1].get('merged') != 'true':
                return None
            out[r] = s
        return out


class RobotPlayer:
    """Latched ``/<robot>/map`` publishers plus each robot's own TF chain at 10 Hz. A robot of
    ``late`` has no map topic until its first map is published (as a gmapping started later)."""

    def __init__(self, robots, late=()):
        self.robots = list(robots)
        self.pubs = {r: rospy.Publisher('/%s/map' % r, NumpyGrid, queue_size=1, latch=True)
                     for r in self.robots if r not in late}
        self._tf = tf2_ros.TransformBroadcaster()
        self._stop = False
        self._thread = threading.Thread(target=self._tf_loop, daemon=True)
        self._thread.start()

    def add(self, robot):
        self.pubs[robot] = rospy.Publisher('/%s/map' % robot, NumpyGrid, queue_size=1, latch=True)
        self.robots.append(robot)

    def publish(self, robot, grid):
        if robot not in self.pubs:
            self.pubs[robot] = rospy.Publisher('/%s/map' % robot, NumpyGrid, queue_size=1, latch=True)
        self.pubs[robot].publish(grid_to_msg(grid, rospy.Time.now(), '%s/map' % robot))

    def stop(self):
        """End the TF thread (the publishers stay: their maps stay latched)."""
        self._stop = True

    def _tf_loop(self):
        while not rospy.is_shutdown() and not self._stop:
            now = rospy.Time.now()
            tfs = []
            for r in list(self.robots):
                tfs.append(transform_msg(np.eye(3), '%s/map' % r, '%s/odom' % r, now))
                tfs.append(transform_msg(se2(0.4, -0.2, 0.3), '%s/odom' % r, '%s/base_footprint' % r, now))
            self._tf.sendTransform(tfs)
            time.sleep(0.1)


def publish_latched(robots, grids):
    """Publish each grid once on ``/<robot>/map`` (latched, frame ``<robot>/map``), as a robot
    whose map does not change. Returns the publishers: keep them, or the maps go with them."""
    pubs = []
    for r, g in zip(robots, grids):
        pub = rospy.Publisher('/%s/map' % r, NumpyGrid, queue_size=1, latch=True)
        pub.publish(grid_to_msg(g, rospy.Time.now(), '%s/map' % r))
        pubs.append(pub)
    return pubs


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


def union_known_of(world, pieces):
    """How many known world cells the pieces ([(grid, T_world_grid)]) cover together."""
    return int(((world.levels() != UNKNOWN) & (union_mask_of(world, pieces) > 0)).sum())


def rviz_prior(T, frame):
    """What rviz's SetInitialPose tool (a robot's prior tool) publishes for a press at T's
    position dragged towards T's heading in the fixed frame ``frame``: its covariance is the
    tool's default, 0.5 m and pi/12 rad standard deviations."""
    msg = PoseWithCovarianceStamped()
    msg.header.frame_id = frame
    msg.header.stamp = rospy.Time.now()
    x, y, yaw = xyyaw(T)
    msg.pose.pose.position.x, msg.pose.pose.position.y = x, y
    set_yaw(msg.pose.pose.orientation, yaw)
    msg.pose.covariance[0] = msg.pose.covariance[7] = 0.5 * 0.5
    msg.pose.covariance[35] = (math.pi / 12.0) ** 2
    return msg


def fmt_pose(T):
    x, y, a = xyyaw(T)
    return '(%.3f, %.3f, %.2f deg)' % (x, y, math.degrees(a))


def known_cells(msg):
    """Number of known cells of an OccupancyGrid message."""
    return int((np.asarray(msg.data) >= 0).sum())


def same_map(a, b):
    """True when two OccupancyGrid messages describe the same grid (geometry and cells)."""
    return (a.info.width == b.info.width and a.info.height == b.info.height
            and abs(a.info.resolution - b.info.resolution) < 1e-9
            and abs(a.info.origin.position.x - b.info.origin.position.x) < 1e-9
            and abs(a.info.origin.position.y - b.info.origin.position.y) < 1e-9
            and np.array_equal(np.asarray(a.data), np.asarray(b.data)))


# ---------------------------------------------------------------- a test on pieces at known poses
class PiecesTest(unittest.TestCase):
    """The set-up of a rostest that plays robots carrying pieces of a shipped map cut at known
    poses (class attributes NODE, ROBOTS, POSES; WORLD, a map in ../shared/data): the world map, the
    pieces (robot k's in frame ``tb3_k/map``), the true pose of every robot's map frame in the
    merged frame (the reference tb3_0's), the area the pieces cover, a tf2 buffer, a
    :class:`Listener` and a :class:`RobotPlayer` (nothing published yet). Plus the checks of a
    merged map and of the TF against that truth."""

    NODE = 'test_pieces'
    ROBOTS = ['tb3_0', 'tb3_1']
    LATE = ()    # robots whose map topic appears only with their first map (RobotPlayer)
    POSES = [(0.0, 0.0, 0.0), (0.0, 0.0, 0.0)]
    WORLD = INTEL_MAP

    @classmethod
    def setUpClass(cls):
        rospy.init_node(cls.NODE, anonymous=True)
        cls.world = load_map(shared_file(cls.WORLD))
        cls.pieces = make_pieces(cls.world, len(cls.POSES), cls.POSES)
        cls.T_world_map = cls.pieces[0][1]          # merged frame = reference tb3_0's map frame
        cls.T_true = [np.linalg.inv(cls.T_world_map) @ T for _, T in cls.pieces]
        cls.union = union_mask_of(cls.world, cls.pieces)
        cls.union_known = int(((cls.world.levels() != UNKNOWN) & (cls.union > 0)).sum())
        cls.buf = tf2_ros.Buffer(rospy.Duration(30.0))
        cls.tfl = tf2_ros.TransformListener(cls.buf)
        cls.listen = Listener()
        cls.player = RobotPlayer(cls.ROBOTS, cls.LATE)

    @classmethod
    def tearDownClass(cls):
        cls.player.stop()

    def whole_merge(self, msg):
        """True when ``msg`` knows as many cells as the union of every piece (within 5%): the
        merge of all the robots' whole maps has reached /map."""
        return abs(known_cells(msg) - self.union_known) < 0.05 * self.union_known

    def assert_matches_truth(self, msg, label='merged', pieces=None):
        """The merged map ``msg`` is the union of the pieces seen from the reference's frame:
        its canvas within 4 cells of the one the pieces need, its walls on true walls, no free
        cell on a wall, nothing outside the pieces, and (nearly) every known cell of the union.
        ``pieces``: other maps of the robots ([(grid, T_world_grid)], robot k's k-th, e.g. parts
        of their pieces) than the whole pieces."""
        self.assertEqual(msg.header.frame_id, 'map')
        union = self.union if pieces is None else union_mask_of(self.world, pieces)
        pieces = self.pieces if pieces is None else pieces
        (_, _, w, h), _ = expected_canvas(pieces, self.T_true)
        self.assertLessEqual(abs(msg.info.width - w), 4, 'width %d, expected %d' % (msg.info.width, w))
        self.assertLessEqual(abs(msg.info.height - h), 4, 'height %d, expected %d' % (msg.info.height, h))
        sc = compare_with_truth(msg, self.world, self.T_world_map, union)
        print('%s vs truth: %s' % (label, sc))
        self.assertGreaterEqual(sc['occ_precision'], 0.95, sc)
        self.assertLessEqual(sc['free_wrong'], 0.02, sc)
        self.assertLessEqual(sc['outside'], 0.01, sc)
        self.assertGreaterEqual(sc['recall'], 0.97, sc)
        self.assertLess(abs(sc['known'] - sc['union_known']) / float(sc['union_known']), 0.05, sc)
        return sc

    def assert_tf(self, k, label='', tol_m=0.10, tol_deg=1.0):
        """The TF ``map -> tb3_k/map`` is robot k's true pose, within ``tol_m`` / ``tol_deg``."""
        r = self.ROBOTS[k]
        T = lookup(self.buf, 'map', '%s/map' % r, 5.0)
        self.assertIsNotNone(T, 'no TF map -> %s/map' % r)
        d, a = pose_distance(T, self.T_true[k])
        print('%s TF map -> %s/map %s, true %s: error %.4f m, %.3f deg'
              % (label, r, fmt_pose(T), fmt_pose(self.T_true[k]), d, math.degrees(a)))
        self.assertLess(d, tol_m, '%s: %.3f m off' % (r, d))
        self.assertLess(math.degrees(a), tol_deg, '%s: %.3f deg off' % (r, math.degrees(a)))
        return T
