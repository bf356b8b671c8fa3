"""What the node publishes of the placements (the merger's :meth:`MapMerger.placements`): the
TF ``merged_map_frame -> <robot>/map`` of every placed robot at ``tf_rate``, and, at
``merge_rate`` when they change, its pose with covariance on ``/<robot>/map_merge/pose`` and the
rviz markers (where each robot started and the kept links) on ``~markers``."""
from __future__ import annotations

from typing import Dict

import rospy
from geometry_msgs.msg import PoseWithCovarianceStamped
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from ..core.merger import MapMerger
from ..node_config import NodeConfig
from .convert import pose_with_covariance_msg, transform_msg
from .markers import markers_key, markers_msg
from .pose_changes import PoseChanges, tf_children


class PlacementOutputs:
    """The publishers of the placements of ``merger`` (see the module docstring)."""

    def __init__(self, merger: MapMerger, config: NodeConfig):
        self.merger = merger
        self.cfg = config
        # /tf as tf2_ros's TransformBroadcaster sends it (it is this publisher), without importing
        # tf2_ros, whose C++ bindings add to the node's memory (docs/measurements.md)
        self._tf_pub = rospy.Publisher('/tf', TFMessage, queue_size=100)
        self._last_tf_stamp = None
        # rviz: where each robot started and the kept links (latched, sent when they change)
        self._markers_pub = rospy.Publisher('~markers', MarkerArray, queue_size=1, latch=True)
        self._markers_key = None
        # /<robot>/map_merge/pose (latched, made as robots are placed) and what each last sent
        self._pose_pubs: Dict[str, rospy.Publisher] = {}
        self._pose_changes = PoseChanges()

    def start(self) -> None:
        """Publish from now on, each at its rate."""
        rospy.Timer(rospy.Duration(1.0 / self.cfg.merge_rate), self._publish_markers)
        rospy.Timer(rospy.Duration(1.0 / self.cfg.merge_rate), self._publish_poses)
        rospy.Timer(rospy.Duration(1.0 / self.cfg.tf_rate), self._publish_tf)

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
        for robot, pl, cov in self._pose_changes.due(self.merger.placements()):
            pub = self._pose_pubs.get(robot)
            if pub is None:
                pub = self._pose_pubs[robot] = rospy.Publisher(
                    '/%s/map_merge/pose' % robot, PoseWithCovarianceStamped, queue_size=1, latch=True)
            pub.publish(pose_with_covariance_msg(pl.T, cov, self.cfg.merged_map_frame, rospy.Time.now(),
                                                 exact=not pl.via))

    def _publish_tf(self, _event) -> None:
        frames = self.merger.frames()
        now = rospy.Time.now()
        # On a bag's clock two timer ticks can share a stamp: tf2 would warn of repeated data
        if now == self._last_tf_stamp:
            return
        self._last_tf_stamp = now
        out = [transform_msg(T, self.cfg.merged_map_frame, child, now)
               for T, child in tf_children(self.merger.placements(), frames, self.cfg.merged_map_frame)]
        if out:
            self._tf_pub.publish(TFMessage(out))
