"""What the ROS 2 node publishes of the merger's placements and state, as the ROS 1 node's
:mod:`~multi_map_merge.ros.placement_outputs` and :mod:`~multi_map_merge.ros.health` do: the TF
``merged_map_frame -> <robot>/map`` of every placed robot at ``tf_rate``, each placement with its
covariance on ``/<robot>/map_merge/pose`` (transient-local, sent when it changes), and
/diagnostics (the node's status and one per robot, the ROS 1 node's texts:
:mod:`multi_map_merge.ros.diagnostics`) every ``diagnostic_period`` seconds; robots whose map
publisher went away (vanished) or whose maps stopped (stale) logged once each."""
from __future__ import annotations

import time
from typing import Callable, Dict, Optional

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from tf2_msgs.msg import TFMessage

from multi_map_merge.core.merger import MapMerger
from multi_map_merge.node_config import NodeConfig
from multi_map_merge.ros.diagnostics import node_diagnostic, robot_diagnostic, stale_maps
from multi_map_merge.ros.pose_changes import PoseChanges, tf_children

from .convert import pose_with_covariance_msg, transform_msg

#: a latest-value topic as map servers publish theirs: late subscribers get the last message
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class PlacementOutputs:
    """TF and ``/<robot>/map_merge/pose`` of ``merger``'s placements, published by ``node``."""

    def __init__(self, node: Node, merger: MapMerger, config: NodeConfig):
        self.node = node
        self.merger = merger
        self.cfg = config
        # /tf as tf2_ros's TransformBroadcaster publishes it (depth 100, volatile, reliable)
        self._tf_pub = node.create_publisher(TFMessage, '/tf', 100)
        self._last_tf_stamp = None
        self._pose_pubs: Dict[str, object] = {}
        self._pose_changes = PoseChanges()

    def publish_tf(self) -> None:
        frames = self.merger.frames()
        now = self.node.get_clock().now()
        # on a simulated clock two timer ticks can share a stamp: tf2 would warn of repeated data
        if now == self._last_tf_stamp:
            return
        self._last_tf_stamp = now
        stamp = now.to_msg()
        out = [transform_msg(T, self.cfg.merged_map_frame, child, stamp)
               for T, child in tf_children(self.merger.placements(), frames, self.cfg.merged_map_frame)]
        if out:
            self._tf_pub.publish(TFMessage(transforms=out))

    def publish_poses(self) -> None:
        """Per placed robot, its map frame's pose in the merged frame with the placement's
        covariance, sent when either changed."""
        for robot, pl, cov in self._pose_changes.due(self.merger.placements()):
            pub = self._pose_pubs.get(robot)
            if pub is None:
                pub = self._pose_pubs[robot] = self.node.create_publisher(
                    PoseWithCovarianceStamped, '/%s/map_merge/pose' % robot, LATCHED)
            pub.publish(pose_with_covariance_msg(pl.T, cov, self.cfg.merged_map_frame,
                                                 self.node.get_clock().now().to_msg(), exact=not pl.via))


class NodeHealth:
    """Vanished and stale robots in the log, and /diagnostics (see the module docstring)."""

    def __init__(self, node: Node, merger: MapMerger, config: NodeConfig,
                 publishers_of: Callable[[str], int]):
        self.node = node
        self.merger = merger
        self.cfg = config
        self._publishers_of = publishers_of   # topic -> how many publishers it has
        self.gone: Dict[str, bool] = {}
        self._stale: set = set()
        self._started = time.time()   # (wall seconds: how long a robot of robots has been silent)
        self.est_seconds = 0.0
        self.est_error: Optional[BaseException] = None
        self._pub = node.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._name = node.get_name()

    def estimated(self, seconds: float, error: Optional[BaseException]) -> None:
        """An estimation cycle took ``seconds`` and raised ``error`` (None: it did not)."""
        self.est_error = error
        self.est_seconds = seconds

    def watch(self, map_topics: Dict[str, str], with_map) -> None:
        """Log a robot whose map publisher went away, or whose maps stopped, and its return
        (``map_topics``: robot -> its map topic; ``with_map``: robots a map of which was
        accepted). Its last map and transform stay in the merge."""
        log = self.node.get_logger()
        for robot, topic in map_topics.items():
            gone = robot in with_map and self._publishers_of(topic) == 0
            if gone and not self.gone.get(robot):
                log.warning('robot %s vanished (no publisher of %s): keeping its last map and transform'
                            % (robot, topic))
            elif not gone and self.gone.get(robot):
                log.info('robot %s is back' % robot)
            self.gone[robot] = gone
        stale = stale_maps(self.merger.status(), self.gone, time.time(), self.cfg.stale_map_timeout)
        for robot, age in sorted(stale.items()):
            if robot not in self._stale:
                log.warning('no map of robot %s for %.0f s (over stale_map_timeout, %g s), though %s still has '
                            'a publisher: keeping its last map and transform'
                            % (robot, age, self.cfg.stale_map_timeout, map_topics.get(robot, 'its map topic')))
        for robot in sorted(self._stale - set(stale)):
            if not self.gone.get(robot):
                log.info('maps of robot %s arrive again' % robot)
        self._stale = set(stale)

    def publish(self) -> None:
        """/diagnostics: the node's status, then one per robot (named as diagnostic_updater
        names them, ``<node>: <task>``)."""
        now = time.time()
        status = self.merger.status()
        waited = now - self._started
        silent = {r: waited for r in self.cfg.robots} if (
            self.cfg.stale_map_timeout > 0 and waited > self.cfg.stale_map_timeout) else {}
        own = node_diagnostic(status, self.gone, self.est_seconds, self.est_error, len(self.merger.frames()),
                              len(self.merger.placements()), None, now, self.cfg.stale_map_timeout, silent)
        own.name, own.hardware_id = '%s: node' % self._name, self._name
        out = [own]
        for robot, st in sorted(status.items()):
            s = robot_diagnostic(robot, st, bool(self.gone.get(robot)), now,
                                 stale_map_timeout=self.cfg.stale_map_timeout)
            s.name = '%s: %s' % (self._name, robot)
            out.append(s)
        msg = DiagnosticArray(status=out)
        msg.header.stamp = self.node.get_clock().now().to_msg()
        self._pub.publish(msg)
