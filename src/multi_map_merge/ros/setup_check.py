"""What the set-up around the node needs, checked at its start: ROS-free, so unit-tested without a
master (the node reads the installed package's version and the TF messages' senders).

- ``robot_state_publisher`` 1.15.0 dropped ``tf_prefix`` and 1.15.2 restored it: with 1.15.0 or
  1.15.1 every robot publishes the same unprefixed frames (``base_footprint``, ``base_scan``),
  and nothing says so.
- Another node broadcasting ``<merged frame> -> <robot>/map`` (ROBOTIS's Gazebo
  ``multi_map_merge.launch`` keeps identity ``static_transform_publisher`` s for
  ``map -> tb3_N/map``) fights the transform this node publishes: rviz and move_base see the two
  alternate.
"""
from __future__ import annotations

import re
from typing import Optional, Tuple

#: robot_state_publisher's first version with tf_prefix back (1.15.0 and 1.15.1 dropped it)
RSP_TF_PREFIX_VERSION = (1, 15, 2)


def version_tuple(version: str) -> Optional[Tuple[int, ...]]:
    """'1.15.2' -> (1, 15, 2); None when it does not start with dotted numbers."""
    m = re.match(r'^\s*(\d+(?:\.\d+)*)', version or '')
    return tuple(int(p) for p in m.group(1).split('.')) if m else None


def rsp_version_warning(version: Optional[str]) -> Optional[str]:
    """One line when ``robot_state_publisher`` ``version`` has no ``tf_prefix`` (older than
    1.15.2), else None (also when its version is unknown: not installed here, e.g. a base
    station whose robots run it)."""
    v = version_tuple(version or '')
    if v is None or v >= RSP_TF_PREFIX_VERSION:
        return None
    return ('robot_state_publisher %s is older than 1.15.2: 1.15.0 dropped tf_prefix (1.15.2 restored '
            'it), so a robot_state_publisher of this version publishes every robot\'s frames without '
            'its <robot>/ prefix; install 1.15.2 or later' % version.strip())


def foreign_robot_map_tf(parent: str, child: str, authority: str, merged_frame: str, own_node: str,
                         is_robot_map_frame) -> bool:
    """True when a transform ``parent -> child`` sent by node ``authority`` is one this node
    publishes, merged frame -> a robot's map frame, sent by another node.
    ``is_robot_map_frame(child)`` says whether ``child`` is (or would be) a robot's map frame."""
    if parent.lstrip('/') != merged_frame.lstrip('/'):
        return False
    if authority.strip() in ('', own_node):
        return False
    return bool(is_robot_map_frame(child.lstrip('/')))


def foreign_tf_warning(parent: str, child: str, authority: str, static: bool) -> str:
    return ('node %s publishes the TF %s -> %s%s, which this node publishes (the robot\'s placement): '
            'the two fight (rviz and move_base see them alternate); stop it (e.g. the identity '
            'static_transform_publishers of ROBOTIS\'s turtlebot3_gazebo multi_map_merge.launch)'
            % (authority, parent.lstrip('/'), child.lstrip('/'), ' (on /tf_static)' if static else ''))
