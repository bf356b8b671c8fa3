"""The priors a robot is given through ROS, converted to plain numbers and handed to the merger,
which relates their frames (:mod:`core.priors`, :meth:`MapMerger.set_prior_in_merged_frame`):

- ``/<robot>/map_merge/prior`` (geometry_msgs/PoseWithCovarianceStamped, what rviz's 2D Pose
  Estimate publishes): where the robot's map frame origin (its start pose) lies in the merged
  frame, or in a frame TF relates to it; ``/<robot>/map_merge/clear_prior`` (std_msgs/Empty)
  removes it.
- m-explore's ``/<robot>/map_merge/init_pose_{x,y,yaw}`` parameters (metres, radians: the robot's
  map frame in a common world frame), for a robot ``initial_poses`` does not list, only under
  ``~known_init_poses`` (off by default, as in m-explore). ROBOTIS's Gazebo launch file writes
  spawn positions there while every robot's map is in the world frame: the merger tells that
  from the grids (:meth:`MapMerger.check_spawn_poses`).
"""
from __future__ import annotations

import math
import threading
from typing import Dict, List

import numpy as np
import rospy
from geometry_msgs.msg import PoseWithCovarianceStamped
from std_msgs.msg import Empty

from ..core.merger import MapMerger
from ..core.priors import PriorOfReference, PriorRefused, pose_of
from ..core.transforms import se2, xyyaw
from ..node_config import NodeConfig
from .convert import quaternion_yaw


class PriorInputs:
    """Every robot's prior topics and parameters (see the module docstring), for ``merger``."""

    def __init__(self, merger: MapMerger, config: NodeConfig):
        self.merger = merger
        self.cfg = config
        self._subs: Dict[str, list] = {}
        self._lock = threading.Lock()
        # tf2_ros (its C++ bindings add to the node's memory, docs/measurements.md) is loaded only
        # on the first prior given in a frame other than the merged one
        self._tf_buffer = None

    def add_robot(self, robot: str) -> None:
        """Read ``robot``'s init_pose_* (under ``~known_init_poses``), then subscribe its prior
        topics."""
        with self._lock:
            if robot in self._subs:
                return
            self._subs[robot] = []
        self._read_init_pose(robot)
        subs = [rospy.Subscriber('/%s/map_merge/prior' % robot, PoseWithCovarianceStamped,
                                 self._on_prior, callback_args=robot, queue_size=1),
                rospy.Subscriber('/%s/map_merge/clear_prior' % robot, Empty,
                                 self._on_clear_prior, callback_args=robot, queue_size=1)]
        with self._lock:
            self._subs[robot] = subs

    def _in_merged_frame(self, msg) -> np.ndarray:
        """The 3x3 pose of a PoseWithCovarianceStamped in the merged frame (through TF when it
        is given in another frame); ValueError saying why not."""
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        T = pose_of(p.x, p.y, q.x, q.y, q.z, q.w)
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
            T = self._in_merged_frame(msg)
            events = self.merger.set_prior_in_merged_frame(robot, T)
        except PriorOfReference as e:
            rospy.logwarn('multi_map_merge: ignoring the prior of %s on %s: %s', robot, topic, e)
            return
        except ValueError as e:   # PriorRefused too
            rospy.logerr('multi_map_merge: ignoring the prior of %s on %s: %s', robot, topic, e)
            return
        for event in events:
            rospy.logwarn('multi_map_merge: %s', event)
        x, y, yaw = xyyaw(T)
        given = msg.header.frame_id
        rospy.loginfo('multi_map_merge: prior of %s from %s: its map frame at x=%.3f m y=%.3f m yaw=%.2f deg '
                      'in %s%s; links contradicting it by more than %.2f m or %.1f deg are rejected%s',
                      robot, topic, x, y, math.degrees(yaw), self.cfg.merged_map_frame,
                      ' (given in %s)' % given if given.lstrip('/') not in
                      ('', self.cfg.merged_map_frame.lstrip('/')) else '',
                      self.cfg.initial_pose_tolerance[0], math.degrees(self.cfg.initial_pose_tolerance[1]),
                      ', and it is placed there while no link places it (~trust_initial_poses)'
                      if self.cfg.trust_initial_poses else '')

    def _on_clear_prior(self, _msg, robot: str) -> None:
        if not self.merger.clear_prior(robot):
            rospy.loginfo('multi_map_merge: /%s/map_merge/clear_prior: %s has no prior', robot, robot)
            return
        rospy.loginfo('multi_map_merge: prior of %s cleared (/%s/map_merge/clear_prior): its pairs are '
                      'estimated again without it', robot, robot)

    def _read_init_pose(self, robot: str) -> None:
        if not self.merger.wants_init_pose(robot):
            return
        names = ['/%s/map_merge/init_pose_%s' % (robot, k) for k in ('x', 'y', 'yaw')]
        try:
            if not all(rospy.has_param(n) for n in names):
                return
            pose: List[float] = [float(rospy.get_param(n)) for n in names]
        except (KeyError, TypeError, ValueError) as e:
            rospy.logerr('multi_map_merge: ignoring the initial pose of %s: %s', robot, e)
            return
        except Exception as e:   # the master gone for a moment
            rospy.logwarn('multi_map_merge: could not read the initial pose of %s: %s', robot, e)
            return
        try:
            shared = self.merger.add_init_pose(robot, pose)
        except PriorRefused as e:
            rospy.logerr('multi_map_merge: ignoring the initial pose of %s: %s', robot, e)
            return
        line = ('multi_map_merge: initial pose of %s from /%s/map_merge/init_pose_*: x=%.3f m y=%.3f m '
                'yaw=%.2f deg' % (robot, robot, pose[0], pose[1], math.degrees(pose[2])))
        if shared:
            line += (", a spawn pose in the frame the robots' maps share (as said above): its prior "
                     "is [0, 0, 0]")
        rospy.loginfo(line)

    def check_spawn_poses(self) -> None:
        """Before each estimation cycle: whether the init_pose_* priors are spawn poses of robots
        whose maps share one frame (:meth:`MapMerger.check_spawn_poses`); one warning when they
        are, saying what to change."""
        found = self.merger.check_spawn_poses()
        if found is None:
            return
        changed, verdict, events = found
        for event in events:
            rospy.logwarn('multi_map_merge: %s', event)
        rospy.logwarn(
            'multi_map_merge: ~known_init_poses: the init_pose_* of %s are spawn poses of robots whose maps '
            'share one frame, not the poses of their map frames (ROBOTIS\'s Gazebo set-up: every gmapping map '
            'starts in Gazebo\'s world frame): %s; merging with [0, 0, 0] as the prior of each. To say so in '
            'your launch file: set known_init_poses false (the maps alone place the robots) or every '
            'init_pose_x, _y, _yaw 0, and drop its static_transform_publishers of %s -> <robot>/map (this node '
            'broadcasts them)', ', '.join(changed), verdict.message(), self.cfg.merged_map_frame)
