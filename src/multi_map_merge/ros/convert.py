"""Messages <-> the core's types: OccupancyGrid <-> :class:`Grid`, 3x3 poses <-> TF, a
placement and its covariance -> PoseWithCovarianceStamped.

Grids travel as ``rospy.numpy_msg`` messages: plain rospy packs ``int8[] data`` one element at
a time (about 170 ms for a 2000x2000 grid), numpy_msg sends the same bytes in about 1 ms.
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np
import rospy
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from map_msgs.msg import OccupancyGridUpdate
from nav_msgs.msg import MapMetaData, OccupancyGrid
from rospy.numpy_msg import numpy_msg

from ..core import priors
from ..core.grid import Grid
from ..core.transforms import xyyaw
from .map_input import grid_of

NumpyGrid = numpy_msg(OccupancyGrid)

# indices of x, y, yaw in a ROS 6x6 pose covariance, whose order is (x, y, z, roll, pitch, yaw)
POSE_COV_INDEX = (0, 1, 5)
# covariance[0] of a pose whose covariance is not known (sensor_msgs' convention for "no
# estimate", e.g. sensor_msgs/Imu): the other 35 elements are then 0
UNKNOWN_COVARIANCE = -1.0
NumpyGridUpdate = numpy_msg(OccupancyGridUpdate)


def quaternion_yaw(q) -> float:
    """Yaw (radians) of a geometry_msgs/Quaternion (planar part only)."""
    return priors.quaternion_yaw(q.x, q.y, q.z, q.w)


def set_yaw(q, yaw: float) -> None:
    """Set a geometry_msgs/Quaternion (x and y left 0) to the rotation of ``yaw`` radians about z."""
    q.z = math.sin(yaw / 2.0)
    q.w = math.cos(yaw / 2.0)


def grid_from_msg(msg, max_cells: int) -> Grid:
    """Validated Grid from an OccupancyGrid (numpy_msg, or plain as rosbag reads it); raises
    GridError with the reason (:func:`.map_input.grid_of`)."""
    return grid_of(msg.info, msg.header.frame_id, msg.header.stamp.to_sec(), msg.data, max_cells)


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
    set_yaw(info.origin.orientation, grid.origin[2])
    return info


def transform_msg(T: np.ndarray, parent: str, child: str, stamp: rospy.Time) -> TransformStamped:
    """TransformStamped ``parent -> child`` from the 3x3 pose of child in parent (metres)."""
    x, y, yaw = xyyaw(T)
    t = TransformStamped()
    t.header.stamp = stamp
    t.header.frame_id = parent
    t.child_frame_id = child
    t.transform.translation.x, t.transform.translation.y = x, y
    set_yaw(t.transform.rotation, yaw)
    return t


def pose_with_covariance_msg(T: np.ndarray, cov: Optional[np.ndarray], frame: str, stamp: rospy.Time,
                             exact: bool = False) -> PoseWithCovarianceStamped:
    """PoseWithCovarianceStamped of the 3x3 pose ``T`` (a robot's map frame in ``frame``) and its
    3x3 covariance of (x, y, yaw) (metres^2, radians^2), placed at rows/columns 0, 1, 5 of the
    6x6 (x, y, z, roll, pitch, yaw), cross terms included (symmetrised). z, roll and pitch get variance 0: a
    map frame lies in the merged frame's plane by construction (its TF says z = roll = pitch =
    0), the platform constraint robot_localization's docs fuse as an exact 0, and what amcl's
    ``amcl_pose`` leaves there. ``cov`` None: ``exact`` (the reference, whose map frame is the
    merged frame) gives an all-zero covariance; otherwise it is unknown: covariance[0] =
    UNKNOWN_COVARIANCE (-1), the rest 0."""
    m = PoseWithCovarianceStamped()
    m.header.stamp = stamp
    m.header.frame_id = frame
    x, y, yaw = xyyaw(T)
    m.pose.pose.position.x, m.pose.pose.position.y = float(x), float(y)
    set_yaw(m.pose.pose.orientation, yaw)
    c = np.zeros((6, 6))
    if cov is not None:
        c3 = np.asarray(cov, float).reshape(3, 3)
        # the core's covariance is a numerical inverse, symmetric only to its last bits
        c[np.ix_(POSE_COV_INDEX, POSE_COV_INDEX)] = (c3 + c3.T) / 2.0
    elif not exact:
        c[0, 0] = UNKNOWN_COVARIANCE
    m.pose.covariance = [float(v) for v in c.ravel()]
    return m


def covariance_of(msg) -> Optional[np.ndarray]:
    """The 3x3 covariance of (x, y, yaw) of a PoseWithCovarianceStamped, as
    :func:`pose_with_covariance_msg` wrote it; None when it says unknown (-1 first)."""
    c = np.asarray(msg.pose.covariance, float).reshape(6, 6)
    if c[0, 0] < 0:
        return None
    return c[np.ix_(POSE_COV_INDEX, POSE_COV_INDEX)]
