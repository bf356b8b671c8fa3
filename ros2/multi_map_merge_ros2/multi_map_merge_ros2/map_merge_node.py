"""``map_merge_node [--ros-args ...]``: the ROS 2 merger node (:class:`.node.MergeNode`). It
discovers the robots' maps (/<robot>/map matching robot_namespace_pattern, or the robots of
``robots``), places every robot's map in the reference robot's frame and publishes the merged
/map (transient-local), the TF map -> <robot>/map of every placed robot, /<robot>/map_merge/pose
and /diagnostics. Configured by ROS 2 parameters (``ros2 param describe map_merge <name>``, or
the README's table), e.g.:

    python3 -m multi_map_merge_ros2.map_merge_node --ros-args -p robots:="['tb3_0', 'tb3_1']"
    ros2 run multi_map_merge_ros2 map_merge_node --ros-args -p estimation_rate:=1.0 -p use_sim_time:=true
"""
from __future__ import annotations

import sys
from typing import List, Optional


def main(argv: Optional[List[str]] = None) -> int:
    argv = list(sys.argv if argv is None else argv)
    ros_args = argv.index('--ros-args') if '--ros-args' in argv else len(argv)
    if any(a in ('-h', '--help') for a in argv[1:ros_args]):
        print(__doc__)
        return 0
    # the estimation workers forked before rclpy starts its threads (as the ROS 1 node does)
    from multi_map_merge.core.workers import start_pool

    from .parameters import workers_from_argv
    start_pool(workers_from_argv(argv))
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from .node import MergeNode
    rclpy.init(args=argv)
    node = MergeNode()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
