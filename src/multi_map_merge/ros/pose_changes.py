"""What both nodes (ROS 1's and ROS 2's) send of the placements, decided the same way (no ROS in
here): a robot's pose on ``/<robot>/map_merge/pose`` only when its placement changed, and the TF
of every placed robot whose map frame is its own."""
from __future__ import annotations

from typing import Dict, List, Mapping, Optional, Tuple

import numpy as np

from ..core.placement import Placement


class PoseChanges:
    """The placements to send again: those whose pose, covariance or way of placing (``via``)
    changed since they were last returned by :meth:`due`."""

    def __init__(self):
        self._sent: Dict[str, tuple] = {}

    def due(self, placements: Mapping[str, Placement]) -> List[Tuple[str, Placement, Optional[np.ndarray]]]:
        """(robot, placement, its covariance or None) of each changed placement; each is taken
        as sent. The covariance is read once: the estimation thread sets it anew in place."""
        out = []
        for robot, pl in placements.items():
            cov = pl.cov
            key = (pl.T.tobytes(), None if cov is None else np.asarray(cov).tobytes(), pl.via)
            if self._sent.get(robot) != key:
                self._sent[robot] = key
                out.append((robot, pl, cov))
        return out


def tf_children(placements: Mapping[str, Placement], frames: Mapping[str, str],
                merged_map_frame: str) -> List[Tuple[np.ndarray, str]]:
    """(T_merged_child, child frame) of every placed robot whose map frame is known and is not
    the merged frame itself (the reference's map in the merged frame needs no TF)."""
    return [(pl.T, frames[robot]) for robot, pl in placements.items()
            if frames.get(robot) and frames[robot] != merged_map_frame]
