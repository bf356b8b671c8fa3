"""Priors and their frames, as plain numbers (no ROS).

A *prior* is ``[x, y, yaw]`` (metres, radians): the pose of a robot's map frame (its start pose)
in one frame common to all priors, the *priors' frame* (``initial_poses``' meaning). That frame
need not be the merged frame: the merged frame is the reference robot's map frame, which lies
in the priors' frame at the reference's own prior. Only the priors of two robots relative to
each other (:func:`relative_pose`) say anything about the pair.

A prior given while running (rviz's 2D Pose Estimate on ``/<robot>/map_merge/prior``) is a pose
in the merged frame; :func:`in_priors_frame` carries it into the priors' frame.
"""
from __future__ import annotations

import math
from typing import Dict, List, Optional, Tuple

import numpy as np

from .transforms import inverse, se2, xyyaw

Priors = Dict[str, List[float]]


class PriorRefused(ValueError):
    """A prior that cannot be used; its text says why, for people."""


class PriorOfReference(PriorRefused):
    """A prior given to the reference robot: its map frame is the merged frame, so it says
    nothing (a mistake rather than bad data)."""


def quaternion_yaw(qx: float, qy: float, qz: float, qw: float) -> float:
    """Yaw (radians) of a rotation given as a quaternion (x, y, z, w): its planar part only."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


def pose_of(x: float, y: float, qx: float, qy: float, qz: float, qw: float) -> np.ndarray:
    """The 3x3 planar pose of position (x, y) (metres) and orientation quaternion
    (qx, qy, qz, qw), in the frame they are given in. PriorRefused when a number is not
    finite or the quaternion is zero (no rotation)."""
    values = [x, y, qx, qy, qz, qw]
    if not all(math.isfinite(v) for v in values):
        raise PriorRefused('not finite: %s' % values)
    if qx * qx + qy * qy + qz * qz + qw * qw < 1e-6:
        raise PriorRefused('its orientation is not a rotation (a zero quaternion)')
    return se2(x, y, quaternion_yaw(qx, qy, qz, qw))


def relative_pose(priors: Priors, parent: str, child: str) -> Optional[np.ndarray]:
    """The 3x3 pose of ``child``'s map frame in ``parent``'s that their priors give (metres
    of ``child``'s frame -> ``parent``'s); None when either has none."""
    if parent not in priors or child not in priors:
        return None
    return inverse(se2(*priors[parent])) @ se2(*priors[child])


def in_priors_frame(robot: str, T: np.ndarray, reference: str,
                    priors: Priors) -> Tuple[List[float], bool]:
    """``robot``'s prior ``[x, y, yaw]`` in the priors' frame, from ``T``, the 3x3 pose of its
    map frame in the merged frame (the ``reference``'s map frame), given the ``priors`` in use;
    and whether the reference must be given ``[0, 0, 0]`` first (no prior has been given to
    another robot yet: the merged frame becomes the priors' frame).

    PriorOfReference when ``robot`` is the reference (its map frame is the merged frame);
    PriorRefused when
    other robots have priors but the reference has none: their frame cannot be related to the
    merged frame."""
    if robot == reference:
        raise PriorOfReference("%s is the reference, its map frame is the merged frame (give the other "
                           "robots' priors)" % robot)
    if reference in priors:
        return list(xyyaw(se2(*priors[reference]) @ T)), False
    if any(r != robot for r in priors):
        raise PriorRefused('the other priors (%s) are in a frame of their own and the reference %s has '
                           'none, so a pose in the merged frame cannot be related to them; give %s a '
                           'prior in ~initial_poses' % (', '.join(sorted(priors)), reference, reference))
    return list(xyyaw(T)), True
