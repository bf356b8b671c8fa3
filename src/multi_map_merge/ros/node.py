"""The merger node: discovers robots' maps, feeds them to :class:`MapMerger`, publishes the
merged map, the TF of every placed robot and /diagnostics. See the README's ROS API."""
from __future__ import annotations

import fnmatch
import functools
import math
import sys
import threading
import time
from typing import Dict, List, Optional

import diagnostic_updater
import numpy as np
import rospy
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import MapMetaData
from nav_msgs.srv import GetMap, GetMapResponse
from std_msgs.msg import Empty
from std_srvs.srv import Trigger, TriggerResponse
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from ..core.config import MergeConfig
from ..core.grid import Grid, GridError, apply_update, same_grid
from ..core.merger import MapMerger
from ..core.spawn import spawn_poses_in_one_frame
from ..core.state import load_state, save_state
from ..core.transforms import se2, xyyaw
from ..core.workers import start_pool
from .convert import (
    NumpyGrid,
    NumpyGridUpdate,
    grid_from_msg,
    grid_to_msg,
    metadata,
    pose_with_covariance_msg,
    quaternion_yaw,
    transform_msg,
)
from .diagnostics import node_diagnostic, robot_diagnostic, stale_maps
from .markers import markers_key, markers_msg
from .node_log import reference_message
from .params import check_library_param, resolve_params, robot_of_map_topic
from .setup_check import foreign_robot_map_tf, foreign_tf_warning, rsp_version_warning

#: seconds after start during which /tf is read for other senders of the node's transforms
TF_CHECK_SECONDS = 60.0


class _Updater(diagnostic_updater.Updater):
    """diagnostic_updater's Updater, whose ``~diagnostic_period`` (read again from the parameter
    server 4 times a second) is checked as the node's own parameters are: a bad value ('abc',
    0, a list) is logged once and the last good period kept, where the library would raise at
    every update and /diagnostics go silent."""

    def __init__(self, period: float, given):
        super().__init__()
        self.period = period
        self._given = given     # the value last read (an invalid one is logged once)

    def _check_diagnostic_period(self) -> None:
        now = rospy.Time.now()
        if now < self.last_time_period_checked + rospy.Duration(0.25):
            return
        try:
            given = rospy.get_param_cached('~diagnostic_period', 1.0)
        except Exception:   # the master gone for a moment: keep the period
            return
        self.last_time_period_checked = now
        if repr(given) == repr(self._given):   # (repr: nan is not equal to itself)
            return
        self._given = given
        period, error = check_library_param('diagnostic_period', given)
        if error:
            rospy.logerr('multi_map_merge: %s (keeping %g s)', error, self.period)
        else:
            self.period = period


def load_config() -> MergeConfig:
    return load_params().config


def load_params():
    """Every parameter of the node, read once from the private namespace and validated
    (:func:`resolve_params`): an invalid value is logged as an error naming the parameter and
    what it accepts, and its default is used; an unknown name gets a warning naming the closest
    known one; m-explore's names are read as aliases. Every parameter, its default and what it
    accepts are declared in the tables of :mod:`multi_map_merge.core.parameters` (MergeConfig
    and config/map_merge.yaml are made from them). Returns the :class:`Resolved` (its
    ``config`` is the node's)."""
    try:
        given = rospy.get_param('~', {})
    except KeyError:
        given = {}
    res = resolve_params(given if isinstance(given, dict) else {})
    for line in res.errors:
        rospy.logerr('multi_map_merge: %s', line)
    for line in res.warnings:
        rospy.logwarn('multi_map_merge: %s', line)
    for line in res.notes:
        rospy.loginfo('multi_map_merge: %s', line)
    return res


class MergeNode:
    """Thin ROS shell around :class:`MapMerger`.

    Subscribes ``/<robot>/<map_topic>`` for every discovered (or listed) robot, runs estimation
    in a worker thread at ``estimation_rate``, composites in another, publishes ``/map``
    (latched) when the merged map changed (checked at ``merge_rate``), broadcasts
    ``merged_map_frame -> <robot>/map`` at ``tf_rate`` (and, with its covariance, on
    ``/<robot>/map_merge/pose`` when it changes), and publishes its own and every robot's
    state on ``/diagnostics`` (``diagnostic_updater``).
    """

    def __init__(self, config: MergeConfig, diagnostic_period: float = 1.0, given_period=1.0):
        self.cfg = config
        self.merger = MapMerger(config)
        self._subs: Dict[str, list] = {}
        self._bad: Dict[str, str] = {}
        self._latest: Dict[str, Grid] = {}   # last accepted raw grid per robot (for map_updates)
        self._saved_version = -1
        self._lock = threading.Lock()
        self._map_pub = rospy.Publisher(config.merged_map_topic, NumpyGrid, queue_size=1, latch=True)
        self._meta_pub = rospy.Publisher(config.merged_map_topic + '_metadata', MapMetaData,
                                         queue_size=1, latch=True)
        # /tf as tf2_ros's TransformBroadcaster sends it (it is this publisher), without importing
        # tf2_ros, whose C++ bindings add to the node's memory (docs/measurements.md); they are
        # loaded only to look up a prior given in another frame
        self._tf_pub = rospy.Publisher('/tf', TFMessage, queue_size=100)
        # rviz: where each robot started and the kept links (latched, sent when they change)
        self._markers_pub = rospy.Publisher('~markers', MarkerArray, queue_size=1, latch=True)
        self._markers_key = None
        # /<robot>/map_merge/pose (latched, made as robots are placed) and what each last sent
        self._pose_pubs: Dict[str, rospy.Publisher] = {}
        self._pose_keys: Dict[str, tuple] = {}
        self._last_est = 0.0
        self._est_seconds = 0.0
        self._est_error: Optional[BaseException] = None   # what the last estimation cycle raised
        # /diagnostics: the node's status and one per robot (added as robots appear), at
        # ~diagnostic_period (the updater's parameter, 1 s by default)
        self._updater = _Updater(diagnostic_period, given_period)
        self._updater.setHardwareID(rospy.get_name().lstrip('/'))
        self._updater.add('node', self._node_diagnostic)
        self._diag_robots: set = set()
        rospy.Service('~reset', Trigger, self._reset)
        # gmapping's service, under gmapping's (relative) name, beside the `map` topic
        rospy.Service('dynamic_map', GetMap, self._get_map)
        if config.state_file:
            try:
                n = self.merger.restore_state(load_state(config.state_file))
                rospy.loginfo('multi_map_merge: %d saved links read from %s; each is verified again '
                              'before use', n, config.state_file)
            except ValueError as e:
                rospy.logerr('multi_map_merge: %s (starting without its saved links)', e)
            self._saved_version = self.merger.state_version
        self._gone: Dict[str, bool] = {}
        self._stale: set = set()   # robots whose maps stopped (logged once)
        self._started = time.time()   # (wall seconds: how long a robot of ~robots has been silent)
        self._frame_warned: Dict[str, str] = {}
        self._prior_subs: Dict[str, list] = {}
        self._prior_lock = threading.Lock()
        self._implicit_ref_prior = ''   # the reference given [0, 0, 0] for run-time priors
        self._tf_buffer = None          # made on the first prior given in another frame
        # m-explore's init_pose_* as read (robot -> [x, y, yaw]) while they may still be spawn
        # poses in one frame the maps share (core/spawn.py); once the grids say so, True, and every
        # robot's prior is [0, 0, 0]
        self._spawn_poses: Dict[str, List[float]] = {}
        self._spawn_checked = None      # the grids the last check saw
        self._spawn_shared = False
        # the reference robot: ~reference_robot, else the first of ~robots by name, else the first
        # by name among the robots with a map until another is merged with it (decide_reference)
        self._ref_logged = None
        self._ref_lock = threading.Lock()
        if config.robots:
            self.merger.propose_reference(sorted(r.strip('/') for r in config.robots)[0])
        self._log_reference()
        for r in config.robots:
            self._subscribe(r.strip('/'))
        self._ready = None   # the latest merged grid, composited off the publishing path
        self._sent = None    # (grid, placements) of the last /map sent
        self._check_setup()
        self._discover(None)
        rospy.Timer(rospy.Duration(1.0 / config.discovery_rate), self._discover)
        rospy.Timer(rospy.Duration(1.0 / config.merge_rate), self._publish_map)
        rospy.Timer(rospy.Duration(1.0 / config.merge_rate), self._publish_markers)
        rospy.Timer(rospy.Duration(1.0 / config.merge_rate), self._publish_poses)
        rospy.Timer(rospy.Duration(1.0 / config.tf_rate), self._publish_tf)
        rospy.Timer(rospy.Duration(0.2), self._update_diagnostics)
        self._worker = threading.Thread(target=self._estimation_loop, name='estimation', daemon=True)
        self._worker.start()
        self._compositor = threading.Thread(target=self._compositing_loop, name='compositing', daemon=True)
        self._compositor.start()
        rospy.loginfo('multi_map_merge: merging %s maps matching %s; reference %s; merged frame %s',
                      '/<robot>/' + config.map_topic,
                      config.robots or config.robot_namespace_pattern,
                      self.merger.reference or '(the first by name among the robots with a map, until '
                      'another robot is merged with it)', config.merged_map_frame)

    # -- what the set-up needs (ros/setup_check.py)
    def _check_setup(self) -> None:
        """At start: one warning when robot_state_publisher has no tf_prefix (older than 1.15.2),
        and one per frame when another node broadcasts merged frame -> a robot's map frame, the
        TF this node publishes (its sender is the messages' callerid, tf's authority). /tf_static
        is watched for the node's life (latched, seldom sent); /tf for TF_CHECK_SECONDS after
        start only, as every robot's TF at 50 Hz would cost this Python node a core."""
        try:
            import rospkg
            version = rospkg.RosPack().get_manifest('robot_state_publisher').version
        except Exception:   # not installed here (it runs on the robots): nothing to say
            version = None
        line = rsp_version_warning(version)
        if line:
            rospy.logwarn('multi_map_merge: %s', line)
        self._tf_warned: set = set()
        rospy.Subscriber('/tf_static', TFMessage, self._on_foreign_tf, callback_args=True, queue_size=10)
        sub = rospy.Subscriber('/tf', TFMessage, self._on_foreign_tf, callback_args=False, queue_size=100)
        rospy.Timer(rospy.Duration(TF_CHECK_SECONDS), lambda _e: sub.unregister(), oneshot=True)

    def _is_robot_map_frame(self, frame: str) -> bool:
        if frame in self.merger.frames().values():
            return True
        ns, _, last = frame.rpartition('/')
        if last != 'map' or not ns:
            return False
        if self.cfg.robots:
            return ns in {r.strip('/') for r in self.cfg.robots}
        return fnmatch.fnmatchcase(ns, self.cfg.robot_namespace_pattern)

    def _on_foreign_tf(self, msg, static: bool) -> None:
        authority = getattr(msg, '_connection_header', {}).get('callerid', '')
        for t in msg.transforms:
            parent, child = t.header.frame_id, t.child_frame_id
            key = (parent.lstrip('/'), child.lstrip('/'), authority)
            if key in self._tf_warned or not foreign_robot_map_tf(
                    parent, child, authority, self.cfg.merged_map_frame, rospy.get_name(),
                    self._is_robot_map_frame):
                continue
            self._tf_warned.add(key)
            rospy.logwarn('multi_map_merge: %s', foreign_tf_warning(parent, child, authority, static))

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
            if topic == self._map_pub.resolved_name:
                continue   # our own merged map (~merged_map_topic set to /<robot>/<map_topic>)
            robot = robot_of_map_topic(topic, ttype, self.cfg.map_topic, self.cfg.robot_namespace_pattern)
            if robot:
                found.append(robot)
        for robot in found:
            self._subscribe(robot)

    def _log_reference(self) -> None:
        """One info line when the reference robot is chosen, changes, or is fixed."""
        choice = self.merger.reference_choice()
        with self._ref_lock:
            key = (choice.robot, choice.fixed)
            if key == self._ref_logged or not choice.robot:
                return
            self._ref_logged = key
        rospy.loginfo('multi_map_merge: %s', reference_message(choice))

    def _watch(self) -> None:
        """Log a robot whose map publisher went away, or whose maps stopped (none for over
        ``~stale_map_timeout``), and its return. Its last map and transform stay in the merge:
        what it mapped is still true."""
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
        stale = stale_maps(self.merger.status(), self._gone, time.time(), self.cfg.stale_map_timeout)
        for robot, age in sorted(stale.items()):
            if robot not in self._stale:
                rospy.logwarn('multi_map_merge: no map of robot %s for %.0f s (over ~stale_map_timeout, %g s), '
                              'though %s still has a publisher: keeping its last map and transform',
                              robot, age, self.cfg.stale_map_timeout, subs[robot][0].name if robot in subs else
                              'its map topic')
        for robot in sorted(self._stale - set(stale)):
            if not self._gone.get(robot):
                rospy.loginfo('multi_map_merge: maps of robot %s arrive again', robot)
        self._stale = set(stale)

    def _subscribe(self, robot: str) -> None:
        with self._lock:
            if robot in self._subs:
                return
            topic = '/%s/%s' % (robot, self.cfg.map_topic)
            updates = '/%s/%s' % (robot, self.cfg.map_updates_topic or self.cfg.map_topic + '_updates')
            self._subs[robot] = [
                rospy.Subscriber(topic, NumpyGrid, self._on_map, callback_args=robot,
                                 queue_size=1, buff_size=2 ** 26),
                rospy.Subscriber(updates, NumpyGridUpdate, self._on_update,
                                 callback_args=robot, queue_size=10, buff_size=2 ** 24)]
        rospy.loginfo('multi_map_merge: robot %s found, subscribed to %s', robot, topic)
        self._read_init_pose(robot)
        self._subscribe_prior(robot)

    # -- priors given while running (rviz's 2D Pose Estimate)
    def _subscribe_prior(self, robot: str) -> None:
        """``/<robot>/map_merge/prior`` (geometry_msgs/PoseWithCovarianceStamped, what rviz's
        2D Pose Estimate publishes): where the robot's map frame origin (its start pose) lies
        in the merged frame; ``/<robot>/map_merge/clear_prior`` (std_msgs/Empty) removes it."""
        with self._prior_lock:
            if robot in self._prior_subs:
                return
            self._prior_subs[robot] = [
                rospy.Subscriber('/%s/map_merge/prior' % robot, PoseWithCovarianceStamped,
                                 self._on_prior, callback_args=robot, queue_size=1),
                rospy.Subscriber('/%s/map_merge/clear_prior' % robot, Empty,
                                 self._on_clear_prior, callback_args=robot, queue_size=1)]

    def _prior_in_merged_frame(self, msg) -> np.ndarray:
        """The 3x3 pose of a PoseWithCovarianceStamped in the merged frame (through TF when
        it is given in another frame); ValueError saying why not."""
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        values = [p.x, p.y, q.x, q.y, q.z, q.w]
        if not all(math.isfinite(v) for v in values):
            raise ValueError('not finite: %s' % values)
        if q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w < 1e-6:
            raise ValueError('its orientation is not a rotation (a zero quaternion)')
        T = se2(p.x, p.y, quaternion_yaw(q))
        frame = msg.header.frame_id.lstrip('/')
        merged = self.cfg.merged_map_frame.lstrip('/')
        if not frame or frame == merged:
            return T
        import tf2_ros
        if self._tf_buffer is None:
            self._tf_buffer = tf2_ros.Buffer()
            self._tf_listener = tf2_ros.TransformListener(self._tf_buffer)
        try:
            t = self._tf_buffer.lookup_transform(merged, frame, rospy.Time(0), rospy.Duration(2.0))
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException, tf2_ros.ExtrapolationException,
                tf2_ros.TransformException) as e:
            raise ValueError('no TF from its frame "%s" to the merged frame "%s": %s'
                             % (frame, merged, e)) from None
        tr = t.transform
        return se2(tr.translation.x, tr.translation.y, quaternion_yaw(tr.rotation)) @ T

    def _on_prior(self, msg, robot: str) -> None:
        topic = '/%s/map_merge/prior' % robot
        try:
            T = self._prior_in_merged_frame(msg)
        except ValueError as e:
            rospy.logerr('multi_map_merge: ignoring the prior of %s on %s: %s', robot, topic, e)
            return
        with self._prior_lock:
            ref = self.merger.reference
            priors = self.cfg.initial_poses
            if robot == ref:
                rospy.logwarn('multi_map_merge: ignoring the prior of %s on %s: %s is the reference, its map '
                              'frame is the merged frame (give the other robots\' priors)', robot, topic, robot)
                return
            if ref in priors:
                pose = list(xyyaw(se2(*priors[ref]) @ T))   # into the frame common to all priors
            elif any(r != robot for r in priors):
                rospy.logerr('multi_map_merge: ignoring the prior of %s on %s: the other priors (%s) are in '
                             'a frame of their own and the reference %s has none, so a pose in the merged '
                             'frame cannot be related to them; give %s a prior in ~initial_poses',
                             robot, topic, ', '.join(sorted(priors)), ref, ref)
                return
            else:
                # the merged frame (the reference's map frame) becomes the frame of the priors
                self._implicit_ref_prior = ref
                self.merger.set_initial_pose(ref, [0.0, 0.0, 0.0])
                pose = list(xyyaw(T))
            for event in self.merger.set_initial_pose(robot, pose):
                rospy.logwarn('multi_map_merge: %s', event)
        x, y, yaw = xyyaw(T)
        rospy.loginfo('multi_map_merge: prior of %s from %s: its map frame at x=%.3f m y=%.3f m yaw=%.2f deg '
                      'in %s%s; links contradicting it by more than %.2f m or %.1f deg are rejected%s',
                      robot, topic, x, y, math.degrees(yaw), self.cfg.merged_map_frame,
                      ' (given in %s)' % msg.header.frame_id if msg.header.frame_id.lstrip('/') not in
                      ('', self.cfg.merged_map_frame.lstrip('/')) else '',
                      self.cfg.initial_pose_tolerance[0], math.degrees(self.cfg.initial_pose_tolerance[1]),
                      ', and it is placed there while no link places it (~trust_initial_poses)'
                      if self.cfg.trust_initial_poses else '')

    def _on_clear_prior(self, _msg, robot: str) -> None:
        with self._prior_lock:
            if robot not in self.cfg.initial_poses:
                rospy.loginfo('multi_map_merge: /%s/map_merge/clear_prior: %s has no prior', robot, robot)
                return
            self.merger.set_initial_pose(robot, None)
            ref = self._implicit_ref_prior
            if ref and set(self.cfg.initial_poses) <= {ref}:
                self.merger.set_initial_pose(ref, None)
                self._implicit_ref_prior = ''
        rospy.loginfo('multi_map_merge: prior of %s cleared (/%s/map_merge/clear_prior): its pairs are '
                      'estimated again without it', robot, robot)

    def _read_init_pose(self, robot: str) -> None:
        """m-explore's per-robot prior, ``/<robot>/map_merge/init_pose_{x,y,yaw}`` (metres,
        radians; the robot's map frame in a common world frame), for a robot that
        ``initial_poses`` does not list, only under ``~known_init_poses`` (off by default, as in
        m-explore). ROBOTIS's Gazebo launch file writes spawn positions there while every
        robot's map is in the world frame: :meth:`_check_spawn_poses` tells that from the grids."""
        if not self.cfg.known_init_poses or robot in self.cfg.initial_poses:
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
        with self._prior_lock:
            self._spawn_poses[robot] = pose
            if self._spawn_shared:
                # the set-up is known: these are spawn poses in the frame every map shares
                self.merger.set_initial_pose(robot, [0.0, 0.0, 0.0])
                rospy.loginfo('multi_map_merge: initial pose of %s from /%s/map_merge/init_pose_*: x=%.3f m '
                              'y=%.3f m yaw=%.2f deg, a spawn pose in the frame the robots\' maps share (as '
                              'said above): its prior is [0, 0, 0]', robot, robot, pose[0], pose[1],
                              math.degrees(pose[2]))
                return
            # a new dict, not an update: the estimation thread reads the old one meanwhile
            self.cfg.initial_poses = dict(self.cfg.initial_poses, **{robot: pose})
        rospy.loginfo('multi_map_merge: initial pose of %s from /%s/map_merge/init_pose_*: x=%.3f m '
                      'y=%.3f m yaw=%.2f deg', robot, robot, pose[0], pose[1], math.degrees(pose[2]))

    def _check_spawn_poses(self) -> None:
        """Before each estimation cycle, until decided: are the init_pose_* priors spawn poses
        of robots whose maps share one frame (ROBOTIS's Gazebo set-up, core/spawn.py)? Then
        one warning says so and what to change, and every such robot's prior becomes [0, 0, 0]
        (its map frame is the shared frame). Priors changed since they were read (rviz) are
        left out."""
        with self._prior_lock:
            if self._spawn_shared or len(self._spawn_poses) < 2:
                return
            priors = {r: p for r, p in self._spawn_poses.items()
                      if self.cfg.initial_poses.get(r) == p and r in self._latest}
        grids = {r: self._latest[r] for r in priors}
        seen = tuple(sorted((r, id(g)) for r, g in grids.items()))
        if seen == self._spawn_checked:
            return
        self._spawn_checked = seen
        verdict = spawn_poses_in_one_frame(self.cfg, grids, priors)
        if verdict is None:
            return
        with self._prior_lock:
            self._spawn_shared = True
            # (robots read from init_pose_* whose maps have not come yet too: the set-up is one)
            changed = [r for r in sorted(self._spawn_poses) if self.cfg.initial_poses.get(r) == self._spawn_poses[r]]
            for r in changed:
                for event in self.merger.set_initial_pose(r, [0.0, 0.0, 0.0]):
                    rospy.logwarn('multi_map_merge: %s', event)
        rospy.logwarn(
            'multi_map_merge: ~known_init_poses: the init_pose_* of %s are spawn poses of robots whose maps '
            'share one frame, not the poses of their map frames (ROBOTIS\'s Gazebo set-up: every gmapping map '
            'starts in Gazebo\'s world frame): %s; merging with [0, 0, 0] as the prior of each. To say so in '
            'your launch file: set known_init_poses false (the maps alone place the robots) or every '
            'init_pose_x, _y, _yaw 0, and drop its static_transform_publishers of %s -> <robot>/map (this node '
            'broadcasts them)', ', '.join(changed), verdict.message(), self.cfg.merged_map_frame)

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
        self._log_reference()

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
            failed_before = self._est_error is not None
            try:
                self._check_spawn_poses()
                for event in self.merger.estimate():
                    rospy.loginfo('multi_map_merge: %s', event)
                self._log_reference()
                self._est_error = None
            except Exception as e:  # a bad cycle must not end estimation for good
                rospy.logerr('multi_map_merge: estimation failed: %r', e)
                self._est_error = e
            self._est_seconds = time.monotonic() - t0
            if (self._est_error is not None) != failed_before:
                self._updater.force_update()   # the node's status changed level: say so now
            self._last_est = time.time()
            self._persist()
            left = period - self._est_seconds
            end = time.monotonic() + max(0.0, left)
            while not rospy.is_shutdown() and time.monotonic() < end:
                time.sleep(min(0.1, end - time.monotonic() + 1e-3))

    def _persist(self) -> None:
        if not self.cfg.state_file or self.merger.state_version == self._saved_version:
            return
        version = self.merger.state_version
        try:
            save_state(self.cfg.state_file, self.merger.export_state())
            self._saved_version = version
        except OSError as e:
            rospy.logerr_throttle(60, 'multi_map_merge: cannot save %s: %s' % (self.cfg.state_file, e))

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
        """Publish the merged map (latched) when it changed since the last one sent: its cells,
        its geometry, or a robot's placement. An unchanged merge sends nothing: the latched
        topic already holds it for every subscriber, late ones included, and resending a whole
        grid at ``merge_rate`` would load every remote subscriber's link for no news."""
        grid = self._ready
        if grid is None:
            return
        sent = self._sent
        if sent is not None and grid is sent[0]:
            return   # compose() returns the very same grid while nothing moved or changed
        placed = {r: pl.T.tobytes() for r, pl in self.merger.placements().items()}
        if sent is not None and placed == sent[1] and same_grid(grid, sent[0]):
            self._sent = (grid, placed)   # recomposed, but to the same cells
            return
        now = rospy.Time.now()
        self._map_pub.publish(grid_to_msg(grid, now, self.cfg.merged_map_frame))
        self._meta_pub.publish(metadata(grid, now))
        self._sent = (grid, placed)

    def _publish_markers(self, _event) -> None:
        """The rviz markers (latched), sent again only when a placement or a kept link changed."""
        placements, links = self.merger.placements(), list(self.merger.links().values())
        key = markers_key(placements, links)
        if key == self._markers_key:
            return
        # stamp 0: a placement is a pose between frames, not of a moment; rviz draws it with
        # the latest TF whatever its fixed frame
        self._markers_pub.publish(markers_msg(placements, links, self.cfg.merged_map_frame, rospy.Time(0),
                                              self.cfg.min_agreement))
        self._markers_key = key

    def _publish_poses(self, _event) -> None:
        """Per placed robot, its map frame's pose in the merged frame with the placement's
        covariance on ``/<robot>/map_merge/pose`` (latched), sent when the placement or its
        covariance changed. A robot no longer placed gets nothing new (its TF stops; /diagnostics
        says it is not merged)."""
        for robot, pl in self.merger.placements().items():
            cov = pl.cov   # read once: the estimation thread sets it anew in place
            key = (pl.T.tobytes(), None if cov is None else np.asarray(cov).tobytes(), pl.via)
            if self._pose_keys.get(robot) == key:
                continue
            pub = self._pose_pubs.get(robot)
            if pub is None:
                pub = self._pose_pubs[robot] = rospy.Publisher(
                    '/%s/map_merge/pose' % robot, PoseWithCovarianceStamped, queue_size=1, latch=True)
            pub.publish(pose_with_covariance_msg(pl.T, cov, self.cfg.merged_map_frame, rospy.Time.now(),
                                                 exact=not pl.via))
            self._pose_keys[robot] = key

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
            self._tf_pub.publish(TFMessage(out))

    def _update_diagnostics(self, _event) -> None:
        """Give every robot seen a status of its own, then let the updater publish (it does at
        ~diagnostic_period)."""
        for robot in self.merger.status():
            if robot not in self._diag_robots:
                self._diag_robots.add(robot)
                self._updater.add(robot, functools.partial(self._robot_diagnostic, robot))
        self._updater.update()

    def _robot_diagnostic(self, robot: str, stat):
        st = self.merger.status().get(robot)
        if st is None:   # (robots are never forgotten by the node: kept for completeness)
            stat.summary(stat.WARN, 'no longer known')
            stat.hardware_id = robot
            return stat
        return robot_diagnostic(robot, st, bool(self._gone.get(robot)), time.time(), stat,
                                self.cfg.max_position_sigma, self.cfg.stale_map_timeout)

    def _node_diagnostic(self, stat):
        now = time.time()
        waited = now - self._started
        # robots of ~robots that never sent a map, once that is as long as a stopped map's
        silent = {r: waited for r in self.cfg.robots} if (
            self.cfg.stale_map_timeout > 0 and waited > self.cfg.stale_map_timeout) else {}
        return node_diagnostic(self.merger.status(), self._gone, self._est_seconds, self._est_error,
                               len(self.merger.frames()), len(self.merger.placements()), stat,
                               now, self.cfg.stale_map_timeout, silent)

    def _get_map(self, _req) -> GetMapResponse:
        """The merged map as /map has it now (gmapping's ``dynamic_map``); an error before
        the reference robot's first map arrived."""
        grid = self._ready
        if grid is None:
            raise rospy.ServiceException('no merged map yet (no map of the reference robot received)')
        msg = grid_to_msg(grid, rospy.Time.now(), self.cfg.merged_map_frame)
        msg.data = msg.data.tolist()   # the service's response is a plain (not numpy) message
        return GetMapResponse(map=msg)

    def _reset(self, _req) -> TriggerResponse:
        self.merger.reset()
        rospy.logwarn('multi_map_merge: all transforms forgotten (reset service)')
        return TriggerResponse(True, 'all transforms forgotten')


NODE_NAME = 'map_merge'


def workers_before_init(argv=None) -> int:
    """``~workers`` as the node will read it, read before ``rospy.init_node`` (which starts
    threads): from a ``_workers:=N`` argument, else from the parameter server (XML-RPC calls, no
    thread; the node's name and namespace from ``__name:=``, ``__ns:=`` or ROS_NAMESPACE, as rospy
    resolves them). 0 (one per core) when it is not set, cannot be read within 2 s or is invalid
    (load_params says why later). The pool must be forked now: a pool of another size started
    once threads run comes from a forkserver, which imports OpenCV again (about 100 MB more for
    the node's tree on the house maps)."""
    import socket

    import rosgraph
    import rosgraph.names
    import yaml
    argv = sys.argv if argv is None else argv
    value = None
    for a in argv:
        if a.startswith('_workers:='):
            try:
                value = yaml.safe_load(a.split(':=', 1)[1])
            except yaml.YAMLError:
                value = a.split(':=', 1)[1]
    if value is None:
        mappings = rosgraph.names.load_mappings(argv)
        name = rosgraph.names.ns_join(rosgraph.names.get_ros_namespace(argv=argv),
                                      mappings.get('__name', NODE_NAME))
        old = socket.getdefaulttimeout()
        socket.setdefaulttimeout(2.0)
        try:
            value = rosgraph.Master(name).getParam(rosgraph.names.ns_join(name, 'workers'))
        except Exception:   # not set (MasterError), no master yet (rosrun before roscore), unreachable
            return 0
        finally:
            socket.setdefaulttimeout(old)
    return resolve_params({'workers': value}).config.workers


def run_merge_node(argv: Optional[List[str]] = None) -> None:
    """``map_merge_node [ROS remappings]``: the live merger. It discovers the robots' maps
    (/<robot>/map matching ~robot_namespace_pattern, or the robots of ~robots), places every robot's
    map in the reference robot's frame and publishes the merged /map (~merged_map_topic), the TF
    map -> <robot>/map of every merged robot, /diagnostics and rviz markers. It is configured by
    ROS parameters, not options: the private parameters (~estimation_rate, ~reference_robot,
    ~initial_poses, ...; m-explore's names are read too) and its topics, services and TF are
    listed in the README's tables (config/map_merge.yaml holds the defaults, and
    `roslaunch multi_map_merge map_merge.launch` loads it). Usually started by a launch file:

        roslaunch multi_map_merge map_merge.launch [robots:="tb3_0 tb3_1"] [reference_robot:=tb3_0]
        rosrun multi_map_merge map_merge_node _estimation_rate:=0.5 __name:=map_merge"""
    from ..cli.args import parser
    args = rospy.myargv(sys.argv if argv is None else argv)[1:]
    # before the workers fork and rospy starts: --help starts nothing
    parser('map_merge_node', run_merge_node.__doc__).parse_args(args)
    # the estimation workers forked before rospy starts its threads: they share the node's
    # memory (core/workers.py)
    start_pool(workers_before_init())
    rospy.init_node(NODE_NAME)
    res = load_params()
    MergeNode(res.config, res.library['diagnostic_period'], res.library_given.get('diagnostic_period', 1.0))
    rospy.spin()
