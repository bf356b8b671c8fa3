"""The one module that speaks ROS: messages <-> numpy grids, the merger node, and the small
helper nodes (map publisher, map saver). Everything else in the package is ROS-free.

Grids travel as ``rospy.numpy_msg`` messages: plain rospy packs ``int8[] data`` one element at
a time (about 170 ms for a 2000x2000 grid), numpy_msg sends the same bytes in about 1 ms.
"""
from __future__ import annotations

import fnmatch
import math
import threading
import time
from dataclasses import fields
from typing import Dict, List, Optional, Sequence

import numpy as np
import rospy
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import TransformStamped
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import MapMetaData, OccupancyGrid
from rospy.numpy_msg import numpy_msg
from std_srvs.srv import Trigger, TriggerResponse

from .config import MergeConfig
from .grid import Grid, GridError, apply_update, make_grid
from .merger import MapMerger
from .persist import load_state, save_state
from .transforms import se2, xyyaw

NumpyGrid = numpy_msg(OccupancyGrid)
NumpyGridUpdate = numpy_msg(OccupancyGridUpdate)


# ---------------------------------------------------------------- conversions
def quaternion_yaw(q) -> float:
    """Yaw (radians) of a geometry_msgs/Quaternion (planar part only)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def grid_from_msg(msg, max_cells: int) -> Grid:
    """Validated Grid from an OccupancyGrid (numpy_msg, or plain as rosbag reads it); raises
    GridError with the reason."""
    info = msg.info
    o = info.origin
    q = (o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w)
    # atan2 of infinities is finite, so the quaternion itself must be checked. An all-zero
    # quaternion is what an unset orientation looks like in ROS: taken as yaw 0.
    if not all(math.isfinite(v) for v in q):
        raise GridError('origin orientation is not finite: %r' % (q,))
    yaw = quaternion_yaw(o.orientation)
    # plain messages from a bag carry int8[] as bytes or a tuple: bytes are viewed, not copied
    data = np.frombuffer(msg.data, np.int8) if isinstance(msg.data, (bytes, bytearray)) else np.asarray(msg.data)
    return make_grid(data, int(info.width), int(info.height), float(info.resolution),
                     (float(o.position.x), float(o.position.y), yaw), msg.header.frame_id,
                     msg.header.stamp.to_sec(), max_cells)


def grid_to_msg(grid: Grid, stamp: rospy.Time, frame_id: Optional[str] = None):
    """numpy_msg OccupancyGrid of a Grid (data stays a numpy array: no per-cell packing)."""
    msg = NumpyGrid()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id if frame_id is not None else grid.frame_id
    msg.info = metadata(grid, stamp)
    msg.data = np.ascontiguousarray(grid.data, dtype=np.int8).ravel()
    return msg


def metadata(grid: Grid, stamp: rospy.Time) -> MapMetaData:
    info = MapMetaData()
    info.map_load_time = stamp
    info.resolution = float(grid.resolution)
    info.width, info.height = grid.width, grid.height
    info.origin.position.x, info.origin.position.y = float(grid.origin[0]), float(grid.origin[1])
    info.origin.orientation.z = math.sin(grid.origin[2] / 2.0)
    info.origin.orientation.w = math.cos(grid.origin[2] / 2.0)
    return info


def transform_msg(T: np.ndarray, parent: str, child: str, stamp: rospy.Time) -> TransformStamped:
    """TransformStamped ``parent -> child`` from the 3x3 pose of child in parent (metres)."""
    x, y, yaw = xyyaw(T)
    t = TransformStamped()
    t.header.stamp = stamp
    t.header.frame_id = parent
    t.child_frame_id = child
    t.transform.translation.x, t.transform.translation.y = x, y
    t.transform.rotation.z = math.sin(yaw / 2.0)
    t.transform.rotation.w = math.cos(yaw / 2.0)
    return t


def load_config() -> MergeConfig:
    """Every parameter of the node, read once from the private namespace; the defaults are
    MergeConfig's, which equal config/map_merge.yaml."""
    default = MergeConfig()
    return MergeConfig.from_dict({f.name: rospy.get_param('~' + f.name, getattr(default, f.name))
                                  for f in fields(MergeConfig)})


# ---------------------------------------------------------------- the merger node
class MergeNode:
    """Thin ROS shell around :class:`MapMerger`.

    Subscribes ``/<robot>/<map_topic>`` for every discovered (or listed) robot, runs estimation
    in a worker thread at ``estimation_rate``, composites and publishes ``/map`` at
    ``merge_rate``, broadcasts ``merged_map_frame -> <robot>/map`` at ``tf_rate``, and
    publishes per-robot state on ``/diagnostics``.
    """

    def __init__(self, config: MergeConfig):
        self.cfg = config
        self.merger = MapMerger(config)
        self._subs: Dict[str, list] = {}
        self._bad: Dict[str, str] = {}
        self._latest: Dict[str, Grid] = {}   # last accepted raw grid per robot (for map_updates)
        self._saved_version = -1
        self._lock = threading.Lock()
        self._map_pub = rospy.Publisher('map', NumpyGrid, queue_size=1, latch=True)
        self._meta_pub = rospy.Publisher('map_metadata', MapMetaData, queue_size=1, latch=True)
        self._diag_pub = rospy.Publisher('/diagnostics', DiagnosticArray, queue_size=10)
        self._tf = tf2_ros.TransformBroadcaster()
        self._last_est = 0.0
        self._est_seconds = 0.0
        rospy.Service('~reset', Trigger, self._reset)
        if config.transforms_file:
            try:
                n = self.merger.restore_state(load_state(config.transforms_file))
                rospy.loginfo('multi_map_merge: %d saved links read from %s; each is verified again '
                              'before use', n, config.transforms_file)
            except ValueError as e:
                rospy.logerr('multi_map_merge: %s (starting without saved transforms)', e)
            self._saved_version = self.merger.state_version
        self._gone: Dict[str, bool] = {}
        self._frame_warned: Dict[str, str] = {}
        if config.robots:
            self.merger.propose_reference(sorted(r.strip('/') for r in config.robots)[0])
        for r in config.robots:
            self._subscribe(r.strip('/'))
        self._discover(None)
        rospy.Timer(rospy.Duration(1.0 / config.discovery_rate), self._discover)
        rospy.Timer(rospy.Duration(1.0 / config.merge_rate), self._publish_map)
        rospy.Timer(rospy.Duration(1.0 / config.tf_rate), self._publish_tf)
        rospy.Timer(rospy.Duration(1.0), self._publish_diagnostics)
        self._worker = threading.Thread(target=self._estimation_loop, name='estimation', daemon=True)
        self._worker.start()
        self._ready = None   # the latest merged grid, composited off the publishing path
        self._compositor = threading.Thread(target=self._compositing_loop, name='compositing', daemon=True)
        self._compositor.start()
        rospy.loginfo('multi_map_merge: merging %s maps matching %s; reference %s; merged frame %s',
                      '/<robot>/' + config.map_topic,
                      config.robots or config.robot_namespace_pattern,
                      config.reference_robot or '(first robot by name)', config.merged_map_frame)

    # -- inputs
    def _discover(self, _event) -> None:
        self._watch()
        if self.cfg.robots:
            return
        try:
            topics = rospy.get_published_topics()
        except Exception as e:  # master gone for a moment: try again next time
            rospy.logwarn_throttle(30, 'multi_map_merge: topic discovery failed: %s' % e)
            return
        found = []
        for topic, ttype in topics:
            parts = topic.strip('/').split('/')
            if len(parts) != 2 or parts[1] != self.cfg.map_topic or ttype != 'nav_msgs/OccupancyGrid':
                continue
            if fnmatch.fnmatch(parts[0], self.cfg.robot_namespace_pattern):
                found.append(parts[0])
        if found:
            # robot 1 = first by name among the robots seen at discovery, whichever map comes first
            self.merger.propose_reference(sorted(found)[0])
        for robot in found:
            self._subscribe(robot)

    def _watch(self) -> None:
        """Log a robot whose map publisher went away, and its return. Its last map and
        transform stay in the merge: what it mapped is still true."""
        with self._lock:
            subs = dict(self._subs)
        for robot, (map_sub, _) in subs.items():
            gone = map_sub.get_num_connections() == 0 and robot in self._latest
            if gone and not self._gone.get(robot):
                rospy.logwarn('multi_map_merge: robot %s vanished (no publisher of %s): keeping its '
                              'last map and transform', robot, map_sub.name)
            elif not gone and self._gone.get(robot):
                rospy.loginfo('multi_map_merge: robot %s is back', robot)
            self._gone[robot] = gone

    def _subscribe(self, robot: str) -> None:
        with self._lock:
            if robot in self._subs:
                return
            topic = '/%s/%s' % (robot, self.cfg.map_topic)
            self._subs[robot] = [
                rospy.Subscriber(topic, NumpyGrid, self._on_map, callback_args=robot,
                                 queue_size=1, buff_size=2 ** 26),
                rospy.Subscriber(topic + '_updates', NumpyGridUpdate, self._on_update,
                                 callback_args=robot, queue_size=10, buff_size=2 ** 24)]
        rospy.loginfo('multi_map_merge: robot %s found, subscribed to %s', robot, topic)
        self._read_init_pose(robot)

    def _read_init_pose(self, robot: str) -> None:
        """m-explore's per-robot prior, ``/<robot>/map_merge/init_pose_{x,y,yaw}`` (metres,
        radians; the robot's map frame in a common world frame), for a robot that
        ``initial_poses`` does not list. Users coming from m-explore, and the turtlebot3
        multi-robot launch files, set these."""
        if not self.cfg.init_pose_params or robot in self.cfg.initial_poses:
            return
        names = ['/%s/map_merge/init_pose_%s' % (robot, k) for k in ('x', 'y', 'yaw')]
        try:
            if not all(rospy.has_param(n) for n in names):
                return
            pose = [float(rospy.get_param(n)) for n in names]
        except (KeyError, TypeError, ValueError) as e:
            rospy.logerr('multi_map_merge: ignoring the initial pose of %s: %s', robot, e)
            return
        except Exception as e:   # the master gone for a moment
            rospy.logwarn('multi_map_merge: could not read the initial pose of %s: %s', robot, e)
            return
        if not all(math.isfinite(v) for v in pose):
            rospy.logerr('multi_map_merge: ignoring the initial pose of %s: not finite %s', robot, pose)
            return
        # a new dict, not an update: the estimation thread reads the old one meanwhile
        self.cfg.initial_poses = dict(self.cfg.initial_poses, **{robot: pose})
        rospy.loginfo('multi_map_merge: initial pose of %s from /%s/map_merge/init_pose_*: x=%.3f m '
                      'y=%.3f m yaw=%.2f deg', robot, robot, pose[0], pose[1], math.degrees(pose[2]))

    def _refuse(self, robot: str, reason: str) -> None:
        if self._bad.get(robot) != reason:  # once per robot and reason, not per message
            rospy.logerr('multi_map_merge: ignoring map of %s: %s', robot, reason)
            self._bad[robot] = reason
        self.merger.report_error(robot, reason)

    def _accept(self, robot: str, grid: Grid) -> None:
        frame = grid.frame_id.lstrip('/')
        if not frame or frame in (self.cfg.merged_map_frame.lstrip('/'), 'map'):
            # A robot's map frame must be its own: a bag recorded by a lone robot says "map",
            # which is the merged frame here. Its TF child becomes <robot>/map.
            own = '%s/map' % robot
            if frame and self._frame_warned.get(robot) != frame:
                rospy.logwarn('multi_map_merge: map of %s is in frame "%s", not one of its own: '
                              'publishing its TF as %s', robot, grid.frame_id, own)
                self._frame_warned[robot] = frame
            grid.frame_id = own
        if robot in self._bad:
            rospy.loginfo('multi_map_merge: map of %s is valid again', robot)
            del self._bad[robot]
        self._latest[robot] = grid
        event = self.merger.update_map(robot, grid)
        if event:
            rospy.logwarn('multi_map_merge: %s', event)

    def _on_map(self, msg, robot: str) -> None:
        try:
            grid = grid_from_msg(msg, self.cfg.max_cells)
        except (GridError, ValueError, TypeError) as e:
            self._refuse(robot, str(e))
            return
        self._accept(robot, grid)

    def _on_update(self, msg, robot: str) -> None:
        base = self._latest.get(robot)
        if base is None:
            return  # an update before any full map has nothing to apply to
        try:
            grid = apply_update(base, int(msg.x), int(msg.y), int(msg.width), int(msg.height),
                                np.asarray(msg.data))
        except (GridError, ValueError, TypeError) as e:
            self._refuse(robot, 'map_updates: %s' % e)
            return
        self._accept(robot, grid)

    # -- estimation, off the publishing path
    def _estimation_loop(self) -> None:
        period = 1.0 / self.cfg.estimation_rate
        while not rospy.is_shutdown():
            t0 = time.monotonic()
            try:
                for event in self.merger.estimate():
                    rospy.loginfo('multi_map_merge: %s', event)
            except Exception as e:  # a bad cycle must not end estimation for good
                rospy.logerr('multi_map_merge: estimation failed: %r', e)
            self._est_seconds = time.monotonic() - t0
            self._last_est = time.time()
            self._persist()
            left = period - self._est_seconds
            end = time.monotonic() + max(0.0, left)
            while not rospy.is_shutdown() and time.monotonic() < end:
                time.sleep(min(0.1, end - time.monotonic() + 1e-3))

    def _persist(self) -> None:
        if not self.cfg.transforms_file or self.merger.state_version == self._saved_version:
            return
        version = self.merger.state_version
        try:
            save_state(self.cfg.transforms_file, self.merger.export_state())
            self._saved_version = version
        except OSError as e:
            rospy.logerr_throttle(60, 'multi_map_merge: cannot save %s: %s' % (self.cfg.transforms_file, e))

    # -- outputs
    def _compositing_loop(self) -> None:
        """Warp and composite in a thread of its own, so that a map that takes long to warp
        never delays the /map timer: the timer publishes whatever grid is ready."""
        period = 1.0 / self.cfg.merge_rate
        while not rospy.is_shutdown():
            t0 = time.monotonic()
            try:
                grid = self.merger.compose()
                if grid is not None:
                    self._ready = grid
            except Exception as e:
                rospy.logerr_throttle(10, 'multi_map_merge: compositing failed: %r' % e)
            time.sleep(max(0.01, period / 2.0 - (time.monotonic() - t0)))

    def _publish_map(self, _event) -> None:
        grid = self._ready
        if grid is None:
            return
        now = rospy.Time.now()
        self._map_pub.publish(grid_to_msg(grid, now, self.cfg.merged_map_frame))
        self._meta_pub.publish(metadata(grid, now))

    def _publish_tf(self, _event) -> None:
        frames = self.merger.frames()
        now = rospy.Time.now()
        # On a bag's clock two timer ticks can share a stamp: tf2 would warn of repeated data
        if now == getattr(self, '_last_tf_stamp', None):
            return
        self._last_tf_stamp = now
        out = []
        for robot, pl in self.merger.placements().items():
            child = frames.get(robot)
            if child and child != self.cfg.merged_map_frame:
                out.append(transform_msg(pl.T, self.cfg.merged_map_frame, child, now))
        if out:
            self._tf.sendTransform(out)

    def _publish_diagnostics(self, _event) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = rospy.Time.now()
        now = time.time()
        for robot, st in self.merger.status().items():
            s = DiagnosticStatus()
            s.name = 'multi_map_merge: %s' % robot
            s.hardware_id = robot
            kv = [('merged', str(st.merged).lower()), ('reference', str(st.reference).lower()),
                  ('linked_to', ' '.join(st.linked_to) or '-'),
                  ('publisher', 'gone' if self._gone.get(robot) else 'ok')]
            if st.placement is not None:
                pl = st.placement
                x, y, yaw = xyyaw(pl.T)
                kv += [('via', pl.via or '-'), ('chain', ' -> '.join(pl.path)),
                       ('inlier_ratio', '%.3f' % pl.reliability), ('agreement', '%.3f' % pl.agreement),
                       ('inliers', str(pl.inliers)), ('x', '%.3f' % x), ('y', '%.3f' % y),
                       ('yaw', '%.4f' % yaw), ('age_s', '%.1f' % (now - pl.stamp))]
            if st.last_attempt is not None:
                a = st.last_attempt
                kv += [('last_pair', st.last_attempt_with), ('last_inlier_ratio', '%.3f' % a.reliability),
                       ('last_agreement', '%.3f' % a.agreement), ('last_inliers', str(a.inliers)),
                       ('last_result', 'accepted' if a.accepted else a.reason)]
            if st.error:
                s.level, s.message = DiagnosticStatus.ERROR, 'input ignored: ' + st.error
            elif st.reference:
                s.level, s.message = DiagnosticStatus.OK, 'reference map'
            elif st.merged:
                s.level, s.message = DiagnosticStatus.OK, 'merged via %s' % st.placement.via
            elif st.linked_to:
                s.level = DiagnosticStatus.WARN
                s.message = ('not merged: linked to %s, but no chain of verified links to the '
                             'reference yet' % ', '.join(st.linked_to))
            else:
                s.level = DiagnosticStatus.WARN
                s.message = 'not merged' + (': ' + st.last_attempt.reason if st.last_attempt else '')
            s.values = [KeyValue(k, v) for k, v in kv]
            arr.status.append(s)
        s = DiagnosticStatus()
        s.name, s.hardware_id = 'multi_map_merge: node', 'map_merge'
        s.level, s.message = DiagnosticStatus.OK, 'estimation cycle %.2f s' % self._est_seconds
        s.values = [KeyValue('last_estimation_s', '%.3f' % self._est_seconds),
                    KeyValue('robots', str(len(self.merger.frames()))),
                    KeyValue('merged', str(len(self.merger.placements())))]
        arr.status.append(s)
        self._diag_pub.publish(arr)

    def _reset(self, _req) -> TriggerResponse:
        self.merger.reset()
        rospy.logwarn('multi_map_merge: all transforms forgotten (reset service)')
        return TriggerResponse(True, 'all transforms forgotten')


def run_merge_node() -> None:
    rospy.init_node('map_merge')
    MergeNode(load_config())
    rospy.spin()


# ---------------------------------------------------------------- demo / test helpers
def _revealed(grid: Grid, radius: float) -> Optional[Grid]:
    """The part of ``grid`` a robot starting at its frame's origin has seen after exploring
    ``radius`` metres, on a grid cropped to it the way gmapping grows its canvas (new size,
    new origin at a whole number of cells)."""
    from .transforms import cell_to_metric
    W = cell_to_metric(grid.resolution, grid.origin)
    rr, cc = np.mgrid[0:grid.height, 0:grid.width]
    x = W[0, 0] * cc + W[0, 1] * rr + W[0, 2]
    y = W[1, 0] * cc + W[1, 1] * rr + W[1, 2]
    seen = np.hypot(x, y) <= radius
    data = np.where(seen, grid.data, -1).astype(np.int8)
    rows = np.flatnonzero((data >= 0).any(axis=1))
    cols = np.flatnonzero((data >= 0).any(axis=0))
    if rows.size == 0:
        return None
    m = 20
    r0, r1 = max(0, rows[0] - m), min(grid.height, rows[-1] + 1 + m)
    c0, c1 = max(0, cols[0] - m), min(grid.width, cols[-1] + 1 + m)
    o = W @ np.array([c0 - 0.5, r0 - 0.5, 1.0])
    return Grid(np.ascontiguousarray(data[r0:r1, c0:c1]), grid.resolution,
                (float(o[0]), float(o[1]), grid.origin[2]), grid.frame_id)


def run_map_publisher(robots: Sequence[str], grids: Sequence[Grid], steps: int, period: float,
                      start_poses: Optional[Sequence[Sequence[float]]] = None,
                      once: bool = False) -> None:
    """Publish each grid on ``/<robot>/map`` (latched, frame ``<robot>/map``) as gmapping would:
    growing in ``steps`` steps from the robot's start (the frame origin), one every ``period``
    seconds, then the whole map again every ``period`` seconds. Also broadcasts the robot's
    own ``<robot>/map -> <robot>/odom -> <robot>/base_footprint`` so TF chains are complete.
    """
    rospy.init_node('map_publisher', anonymous=True)
    pubs = [rospy.Publisher('/%s/map' % r, NumpyGrid, queue_size=1, latch=True) for r in robots]
    tfb = tf2_ros.TransformBroadcaster()
    full_radius = [max(1e-3, float(np.hypot(*np.array([[g.origin[0], g.origin[1]],
                                                        [g.origin[0] + g.width * g.resolution,
                                                         g.origin[1] + g.height * g.resolution]]).T).max()) * 1.5)
                   for g in grids]
    poses = list(start_poses) if start_poses else [(0.0, 0.0, 0.0)] * len(robots)
    k = 0
    next_map = 0.0
    rate = rospy.Rate(10)
    while not rospy.is_shutdown():
        now = rospy.Time.now()
        if time.monotonic() >= next_map:
            k += 1
            for r, g, pub, rad in zip(robots, grids, pubs, full_radius):
                part = g if k >= steps else _revealed(g, rad * k / float(steps))
                if part is not None:
                    pub.publish(grid_to_msg(part, now, '%s/map' % r))
            next_map = time.monotonic() + period
            if once and k >= steps:
                rospy.sleep(1.0)
                return
        tfs = []
        for r, p in zip(robots, poses):
            tfs.append(transform_msg(np.eye(3), '%s/map' % r, '%s/odom' % r, now))
            tfs.append(transform_msg(se2(*p), '%s/odom' % r, '%s/base_footprint' % r, now))
        tfb.sendTransform(tfs)
        rate.sleep()


def wait_for_map(topic: str, timeout: float) -> Optional[Grid]:
    """First OccupancyGrid on ``topic`` within ``timeout`` seconds, as a Grid (None if none)."""
    try:
        msg = rospy.wait_for_message(topic, NumpyGrid, timeout=timeout)
    except rospy.ROSException:
        return None
    return grid_from_msg(msg, 10 ** 9)


def wait_for_master(timeout: float) -> bool:
    """True once a ROS master answers at ROS_MASTER_URI (within ``timeout`` seconds)."""
    import rosgraph
    end = time.time() + timeout
    while time.time() < end:
        if rosgraph.is_master_online():
            return True
        time.sleep(0.2)
    return False


def diagnostics_by_robot(msg, out: Dict[str, Dict[str, str]]) -> None:
    """Store the merger's per-robot diagnostics of ``msg`` in ``out``: robot -> its key/values
    plus 'message'."""
    for st in msg.status:
        if st.hardware_id:
            d = {kv.key: kv.value for kv in st.values}
            d['message'] = st.message
            out[st.hardware_id] = d


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


def init_node(name: str) -> None:
    rospy.init_node(name, anonymous=True)


def log(msg: str) -> None:
    rospy.loginfo(msg)


def ros_ok() -> bool:
    return not rospy.is_shutdown()


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


# ---------------------------------------------------------------- bags
BAG_EPOCH = 1_600_000_000.0   # bag time of a simulated run's t = 0 (fixed: bags are reproducible)


def write_robot_bag(path: str, runs, clock_rate: float = 10.0) -> Dict[str, int]:
    """Write robots' runs (:class:`multi_map_merge.simulate.RobotRun`) to a rosbag as real
    Turtlebot3s running gmapping record them, each robot under ``/<name>/``:
    ``/<name>/scan`` (LaserScan, frame ``<name>/base_scan``), ``/<name>/odom`` (Odometry),
    ``/<name>/map`` (OccupancyGrid, frame ``<name>/map``), ``/tf`` (``<name>/odom ->
    <name>/base_footprint`` at the odometry rate, ``<name>/base_footprint -> <name>/base_scan``
    with every scan, gmapping's ``<name>/map -> <name>/odom``), and ``/clock``.
    Returns the number of messages per topic. lz4-compressed."""
    import rosbag
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage

    from .simulate import compose, relative
    NumpyScan = numpy_msg(LaserScan)
    counts: Dict[str, int] = {}
    records = []   # (time s, order, topic, msg): sorted before writing

    def add(t, topic, msg, order=0):
        records.append((t, order, topic, msg))
        counts[topic] = counts.get(topic, 0) + 1

    def stamp(t):
        return rospy.Time.from_sec(BAG_EPOCH + t)

    end = 0.0
    for run in runs:
        n = run.name
        f_map, f_odom, f_base, f_scan = n + '/map', n + '/odom', n + '/base_footprint', n + '/base_scan'
        dt = run.t[1] - run.t[0] if len(run.t) > 1 else 0.05
        v = np.hypot(*np.diff(run.odom[:, :2], axis=0).T) / dt
        w = np.diff(np.unwrap(run.odom[:, 2])) / dt
        map_odom = compose(run.slam, relative(run.odom, np.zeros_like(run.odom)))   # slam ⊕ odom^-1
        scan_at = set(int(s) for s in run.scans.steps)
        for i, t in enumerate(run.t):
            st = stamp(t)
            od = Odometry()
            od.header.stamp, od.header.frame_id, od.child_frame_id = st, f_odom, f_base
            x, y, yaw = run.odom[i]
            od.pose.pose.position.x, od.pose.pose.position.y = x, y
            od.pose.pose.orientation.z, od.pose.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            if i > 0:
                od.twist.twist.linear.x, od.twist.twist.angular.z = v[i - 1], w[i - 1]
            add(t, '/%s/odom' % n, od)
            tfs = [transform_msg(se2(*run.odom[i]), f_odom, f_base, st)]
            if i in scan_at:
                o = run.scans.offset
                tr = transform_msg(se2(o[0], o[1], 0.0), f_base, f_scan, st)
                tr.transform.translation.z = o[2]
                tfs.append(tr)
            add(t, '/tf', TFMessage(tfs))
            add(t, '/tf', TFMessage([transform_msg(se2(*map_odom[i]), f_map, f_odom, st)]), 1)
        sc = run.scans
        for k, step in enumerate(sc.steps):
            t = float(run.t[step])
            m = NumpyScan()
            m.header.stamp, m.header.frame_id = stamp(t), f_scan
            m.angle_min = sc.angle_min
            m.angle_increment = sc.angle_increment
            m.angle_max = sc.angle_min + sc.angle_increment * (sc.ranges.shape[1] - 1)
            m.scan_time = 1.0 / 5.0
            m.time_increment = m.scan_time / sc.ranges.shape[1]
            m.range_min, m.range_max = sc.range_min, sc.range_max
            m.ranges = np.ascontiguousarray(sc.ranges[k], np.float32)
            m.intensities = np.zeros(0, np.float32)
            add(t, '/%s/scan' % n, m, 2)
        for t, grid in run.maps:
            add(t, '/%s/map' % n, grid_to_msg(grid, stamp(t), f_map), 3)
        end = max(end, float(run.t[-1]))
    for t in np.arange(0.0, end + 1e-9, 1.0 / clock_rate):
        c = Clock()
        c.clock = stamp(float(t))
        add(float(t), '/clock', c, -1)
    records.sort(key=lambda r: (r[0], r[1]))
    with rosbag.Bag(path, 'w', compression='lz4') as bag:
        for t, _, topic, msg in records:
            bag.write(topic, msg, stamp(t))
    return counts


def read_bag_maps(path: str, max_cells: int = 100_000_000) -> Dict[str, List[Grid]]:
    """Every OccupancyGrid in a bag, per topic, in order (numpy all the way)."""
    import rosbag
    out: Dict[str, List[Grid]] = {}
    with rosbag.Bag(path) as bag:
        topics = [t for t, i in bag.get_type_and_topic_info().topics.items() if i.msg_type == 'nav_msgs/OccupancyGrid']
        for topic, msg, _ in bag.read_messages(topics=topics):
            out.setdefault(topic, []).append(grid_from_msg(msg, max_cells))
    return out


def record_replay(robots: Sequence[str], period: float = 0.5, idle: float = 4.0,
                  timeout: float = 3600.0, merged_frame: str = 'map', start_timeout: float = 60.0,
                  base_frame: str = 'base_footprint') -> Dict:
    """Watch a replay through the merger until the bag ends (``/clock`` still for ``idle``
    wall seconds after it moved, or no ``/clock`` at all within ``start_timeout``, or
    ``timeout``, or shutdown). Every ``period`` wall seconds it looks up, by tf2, each robot's
    ``<robot>/<base_frame>`` in its ``<robot>/map`` frame (its trajectory), that map frame in
    ``merged_frame`` (the merged TF), and the base frame in ``merged_frame`` (through both).
    Returns {'map': last merged Grid or None, 'robots': {name: {'trajectory': [[t, x, y, yaw] in
    <robot>/map, ...], 'tf': [x, y, yaw] of <robot>/map in the merged frame, or None, 'base':
    [x, y, yaw] of its base frame in the merged frame, or None, 'diagnostics': {...}}},
    'robot_maps': {name: the robot's last
    /<name>/map Grid}, 'clock': last /clock seconds}."""
    from rosgraph_msgs.msg import Clock
    state: Dict = {'map': None, 'clock': None, 'clock_wall': None, 'diag': {}, 'robot_maps': {}}

    def on_map(msg, robot=None):
        try:
            grid = grid_from_msg(msg, 10 ** 9)
        except (GridError, ValueError):
            return
        if robot is None:
            state['map'] = grid
        else:
            state['robot_maps'][robot] = grid

    def on_clock(msg):
        c = msg.clock.to_sec()
        if state['clock'] is None or c > state['clock']:
            state['clock'], state['clock_wall'] = c, time.time()

    subs = [rospy.Subscriber('/map', NumpyGrid, on_map, queue_size=1, buff_size=2 ** 26),
            rospy.Subscriber('/clock', Clock, on_clock, queue_size=10),
            rospy.Subscriber('/diagnostics', DiagnosticArray, diagnostics_by_robot, callback_args=state['diag'],
                             queue_size=10)]
    subs += [rospy.Subscriber('/%s/map' % r, NumpyGrid, on_map, callback_args=r, queue_size=1, buff_size=2 ** 26)
             for r in robots]
    buf = tf2_ros.Buffer(cache_time=rospy.Duration(3600.0))
    tf2_ros.TransformListener(buf)
    traj: Dict[str, List] = {r: [] for r in robots}
    last_tf: Dict[str, Optional[List[float]]] = {r: None for r in robots}
    last_base: Dict[str, Optional[List[float]]] = {r: None for r in robots}
    end = time.time() + timeout
    while not rospy.is_shutdown() and time.time() < end:
        time.sleep(period)              # wall time: the sim clock stops when the bag ends
        if state['clock_wall'] is not None and time.time() - state['clock_wall'] > idle:
            break
        if state['clock_wall'] is None and time.time() > end - timeout + start_timeout:
            rospy.logerr('record_replay: no /clock within %.0f s: is the bag playing?', start_timeout)
            break
        for r in robots:
            # the trajectory in the robot's own map frame (there from its first scan on), and
            # where the merger puts that frame: together, the trajectory through the merged TF
            for parent, child, store in (('%s/map' % r, '%s/%s' % (r, base_frame), 'traj'),
                                         (merged_frame, '%s/map' % r, 'tf'),
                                         (merged_frame, '%s/%s' % (r, base_frame), 'base')):
                try:
                    t = buf.lookup_transform(parent, child, rospy.Time(0))
                except (tf2_ros.LookupException, tf2_ros.ConnectivityException,
                        tf2_ros.ExtrapolationException):
                    continue
                tr = t.transform
                p = [float(tr.translation.x), float(tr.translation.y), float(quaternion_yaw(tr.rotation))]
                if store == 'tf':
                    last_tf[r] = p
                elif store == 'base':
                    last_base[r] = p
                elif not traj[r] or traj[r][-1][0] != t.header.stamp.to_sec():
                    traj[r].append([t.header.stamp.to_sec()] + p)
    for s in subs:
        s.unregister()
    return {'map': state['map'], 'clock': state['clock'], 'robot_maps': state['robot_maps'],
            'robots': {r: {'trajectory': traj[r], 'tf': last_tf[r], 'base': last_base[r],
                           'diagnostics': state['diag'].get(r, {})}
                       for r in robots}}


def run_tf_relay(src: str = '/tf_bag', dst: str = '/tf', drop_parent: str = '*/map',
                 drop_child: str = '*/odom') -> None:
    """Republish ``src`` (tf2_msgs/TFMessage) on ``dst`` without the transforms whose parent
    and child match ``drop_parent`` and ``drop_child`` (fnmatch patterns): a recorded bag's own
    SLAM ``map -> odom`` must not fight the live gmapping that replaces it."""
    from tf2_msgs.msg import TFMessage
    pub = rospy.Publisher(dst, TFMessage, queue_size=100)
    dropped = set()

    def on_tf(msg):
        keep = []
        for t in msg.transforms:
            p, c = t.header.frame_id.lstrip('/'), t.child_frame_id.lstrip('/')
            if fnmatch.fnmatch(p, drop_parent) and fnmatch.fnmatch(c, drop_child):
                if (p, c) not in dropped:
                    dropped.add((p, c))
                    rospy.loginfo('tf_relay: dropping the recorded %s -> %s (live SLAM publishes it)', p, c)
                continue
            keep.append(t)
        if keep:
            pub.publish(TFMessage(keep))

    rospy.Subscriber(src, TFMessage, on_tf, queue_size=100)
    rospy.spin()


def bag_start(path: str) -> float:
    """Bag time (s) of a bag's first message."""
    import rosbag
    with rosbag.Bag(path) as bag:
        return bag.get_start_time()


def run_frame_prefix_relay(prefix: str, time_offset: float) -> None:
    """One robot of a team made of single-robot bags (each names its frames ``odom``,
    ``base_link``, ``laser`` on the one ``/tf``): republish ``scan_raw``, ``odom_raw`` and
    ``tf_raw`` (relative to the node's namespace) as ``scan``, ``odom`` and ``/tf`` with every
    frame id prefixed (``<prefix>/odom`` ...) and every stamp moved by ``time_offset`` seconds,
    so that runs recorded minutes apart play at once under one ``/clock``."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage
    shift = rospy.Duration.from_sec(time_offset)

    def frame(f: str) -> str:
        return '%s/%s' % (prefix, f.lstrip('/')) if f else f

    def moved(header) -> None:
        header.stamp = header.stamp + shift
        header.frame_id = frame(header.frame_id)

    pubs = {}

    def relay(name, msg_type, fix, out=None):
        pubs[name] = rospy.Publisher(out or name, msg_type, queue_size=50)

        def on_msg(msg):
            fix(msg)
            pubs[name].publish(msg)
        rospy.Subscriber(name + '_raw', msg_type, on_msg, queue_size=50)

    def fix_odom(msg):
        moved(msg.header)
        msg.child_frame_id = frame(msg.child_frame_id)

    def fix_tf(msg):
        for t in msg.transforms:
            moved(t.header)
            t.child_frame_id = frame(t.child_frame_id)

    relay('scan', LaserScan, lambda m: moved(m.header))
    relay('odom', Odometry, fix_odom)
    relay('tf', TFMessage, fix_tf, '/tf')
    rospy.loginfo('frame_prefix_relay: frames under %s/, stamps %+.3f s', prefix, time_offset)
    rospy.spin()
