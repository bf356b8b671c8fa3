"""ROS 2 messages <-> the core's types: nav_msgs/OccupancyGrid <-> :class:`Grid`, 3x3 poses <->
TransformStamped and PoseWithCovarianceStamped. The ROS 1 node's :mod:`multi_map_merge.ros.convert`
for rclpy's messages.

rclpy holds ``int8[] data`` as an ``array.array('b')``: a grid's cells are viewed by numpy and
sent back as one ``array.array`` made from their bytes, never element by element (rclpy checks
every element of any other sequence, about 1 s for a 2000 x 2000 grid).
"""
from __future__ import annotations

import array
import math
from typing import Optional

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from nav_msgs.msg import MapMetaData, OccupancyGrid

from multi_map_merge.core import priors
from multi_map_merge.core.grid import Grid
from multi_map_merge.core.transforms import xyyaw
from multi_map_merge.ros.map_input import grid_of

# indices of x, y, yaw in a ROS 6x6 pose covariance, whose order is (x, y, z, roll, pitch, yaw)
POSE_COV_INDEX = (0, 1, 5)
# covariance[0] of a pose whose covariance is not known (sensor_msgs' convention), as ROS 1's node
UNKNOWN_COVARIANCE = -1.0


def quaternion_yaw(q) -> float:
    """Yaw (radians) of a geometry_msgs/Quaternion (planar part only)."""
    return priors.quaternion_yaw(q.x, q.y, q.z, q.w)


def set_yaw(q, yaw: float) -> None:
    """Set a geometry_msgs/Quaternion to the rotation of ``yaw`` radians about z."""
    q.x, q.y = 0.0, 0.0
    q.z = math.sin(yaw / 2.0)
    q.w = math.cos(yaw / 2.0)


def stamp_seconds(stamp: Time) -> float:
    """A builtin_interfaces/Time in seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


def grid_from_msg(msg: OccupancyGrid, max_cells: int) -> Grid:
    """Validated Grid of an OccupancyGrid (its cells viewed, not copied); raises GridError with
    the reason (the core's checks: sizes, resolution, origin, cell values;
    :func:`multi_map_merge.ros.map_input.grid_of`, as the ROS 1 node reads its maps)."""
    return grid_of(msg.info, msg.header.frame_id, stamp_seconds(msg.header.stamp), msg.data, max_cells)


def metadata(grid: Grid, stamp: Time) -> MapMetaData:
    """The MapMetaData of a Grid (resolution in m/cell, origin in its frame)."""
    info = MapMetaData()
    info.map_load_time = stamp
    info.resolution = float(grid.resolution)
    info.width, info.height = int(grid.width), int(grid.height)
    info.origin.position.x, info.origin.position.y = float(grid.origin[0]), float(grid.origin[1])
    set_yaw(info.origin.orientation, float(grid.origin[2]))
    return info


def grid_to_msg(grid: Grid, stamp: Time, frame_id: Optional[str] = None) -> OccupancyGrid:
    """OccupancyGrid of a Grid, its cells passed as one array.array (see the module docstring)."""
    msg = OccupancyGrid()
    msg.header.stamp = stamp
    msg.header.frame_id = frame_id if frame_id is not None else grid.frame_id
    msg.info = metadata(grid, stamp)
    msg.data = array.array('b', np.ascontiguousarray(grid.data, dtype=np.int8).tobytes())
    return msg


def transform_msg(T: np.ndarray, parent: str, child: str, stamp: Time) -> TransformStamped:
    """TransformStamped ``parent -> child`` from the 3x3 pose of child in parent (metres)."""
    x, y, yaw = xyyaw(T)
    t = TransformStamped()
    t.header.stamp = stamp
    t.header.frame_id = parent
    t.child_frame_id = child
    t.transform.translation.x, t.transform.translation.y = float(x), float(y)
    set_yaw(t.transform.rotation, float(yaw))
    return t


def pose_with_covariance_msg(T: np.ndarray, cov: Optional[np.ndarray], frame: str, stamp: Time,
                             exact: bool = False) -> PoseWithCovarianceStamped:
    """PoseWithCovarianceStamped of the 3x3 pose ``T`` (a robot's map frame in ``frame``) and its
    3x3 covariance of (x, y, yaw) (m^2, rad^2) at rows/columns 0, 1, 5 of the 6x6; as the ROS 1
    node's: ``cov`` None is exact (all 0) for the reference, else unknown (covariance[0] = -1)."""
    m = PoseWithCovarianceStamped()
    m.header.stamp = stamp
    m.header.frame_id = frame
    x, y, yaw = xyyaw(T)
    m.pose.pose.position.x, m.pose.pose.position.y = float(x), float(y)
    set_yaw(m.pose.pose.orientation, float(yaw))
    c = np.zeros((6, 6))
    if cov is not None:
        c3 = np.asarray(cov, float).reshape(3, 3)
        c[np.ix_(POSE_COV_INDEX, POSE_COV_INDEX)] = (c3 + c3.T) / 2.0
    elif not exact:
        c[0, 0] = UNKNOWN_COVARIANCE
    m.pose.covariance = c.ravel().astype(float)
    return m
