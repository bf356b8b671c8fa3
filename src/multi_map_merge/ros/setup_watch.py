"""The node's watch on the set-up around it (the checks themselves: :mod:`setup_check`): at
start, one warning when robot_state_publisher has no tf_prefix (older than 1.15.2), and one per
frame when another node broadcasts merged frame -> a robot's map frame, the TF the node
publishes (its sender is the messages' callerid, tf's authority)."""
from __future__ import annotations

import fnmatch

import rospy
from tf2_msgs.msg import TFMessage

from ..core.merger import MapMerger
from ..node_config import NodeConfig
from .setup_check import foreign_robot_map_tf, foreign_tf_warning, rsp_version_warning

#: seconds after start during which /tf is read for other senders of the node's transforms
TF_CHECK_SECONDS = 60.0


class SetupWatch:
    """/tf_static is watched for the node's life (latched, seldom sent); /tf for
    TF_CHECK_SECONDS after start only, as every robot's TF at 50 Hz would cost this Python node
    a core."""

    def __init__(self, merger: MapMerger, config: NodeConfig):
        self.merger = merger
        self.cfg = config
        try:
            import rospkg
            version = rospkg.RosPack().get_manifest('robot_state_publisher').version
        except Exception:   # not installed here (it runs on the robots): nothing to say
            version = None
        line = rsp_version_warning(version)
        if line:
            rospy.logwarn('multi_map_merge: %s', line)
        self._warned: set = set()
        rospy.Subscriber('/tf_static', TFMessage, self._on_tf, callback_args=True, queue_size=10)
        sub = rospy.Subscriber('/tf', TFMessage, self._on_tf, callback_args=False, queue_size=100)
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

    def _on_tf(self, msg, static: bool) -> None:
        authority = getattr(msg, '_connection_header', {}).get('callerid', '')
        for t in msg.transforms:
            parent, child = t.header.frame_id, t.child_frame_id
            key = (parent.lstrip('/'), child.lstrip('/'), authority)
            if key in self._warned or not foreign_robot_map_tf(
                    parent, child, authority, self.cfg.merged_map_frame, rospy.get_name(),
                    self._is_robot_map_frame):
                continue
            self._warned.add(key)
            rospy.logwarn('multi_map_merge: %s', foreign_tf_warning(parent, child, authority, static))
