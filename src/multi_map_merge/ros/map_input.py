"""A robot's map as a node takes it in, the same for the ROS 1 and the ROS 2 node (no ROS in
here: each node passes its messages' parts and its own log functions).

- A map message becomes a validated :class:`~multi_map_merge.core.grid.Grid` (:func:`grid_of`):
  sizes, resolution, origin and cell values checked by the core, the origin's quaternion too.
- A map refused is logged once per robot and reason (not once per message) and shown in the
  merger's status; the next valid map is logged as such.
- A robot's map frame must be its own: a map in the merged frame, or in "map" (a bag recorded by
  a lone robot), is taken as ``<robot>/map``, with one warning.
- A map update (``map_msgs/OccupancyGridUpdate``) applies to the robot's last full map.
- A restart the merger detects, and the choice of the reference robot, are logged.
"""
from __future__ import annotations

import array
import math
import threading
from typing import Any, Callable, Dict, NamedTuple, Optional

import numpy as np

from ..core.grid import Grid, GridError, apply_update, make_grid
from ..core.merger import MapMerger
from ..core.priors import quaternion_yaw


class Log(NamedTuple):
    """A node's log lines by level: each takes one finished line."""
    error: Callable[[str], None]
    warning: Callable[[str], None]
    info: Callable[[str], None]


def grid_of(info: Any, frame_id: str, stamp: float, data: Any, max_cells: int) -> Grid:
    """The validated Grid of an OccupancyGrid's parts (ROS 1's or ROS 2's ``info``, its
    header's frame and stamp in seconds, its cells); raises GridError with the reason. Cells
    given as bytes or an array.array (a bag's plain message, ROS 2's) are viewed, not copied."""
    o = info.origin
    q = (o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w)
    # atan2 of infinities is finite, so the quaternion itself must be checked. An all-zero
    # quaternion is what an unset orientation looks like in ROS: taken as yaw 0.
    if not all(math.isfinite(v) for v in q):
        raise GridError('origin orientation is not finite: %r' % (q,))
    cells = np.frombuffer(data, np.int8) if isinstance(data, (bytes, bytearray, array.array)) else np.asarray(data)
    return make_grid(cells, int(info.width), int(info.height), float(info.resolution),
                     (float(o.position.x), float(o.position.y), quaternion_yaw(*q)), frame_id, stamp, max_cells)


class MapInput:
    """Every robot's map into ``merger`` (see the module docstring). ``latest``: the last
    accepted grid per robot, as it came (what an update applies to, and what the health check
    reads)."""

    def __init__(self, merger: MapMerger, merged_map_frame: str, max_cells: int, log: Log):
        self.merger = merger
        self.max_cells = max_cells
        self.log = log
        self.latest: Dict[str, Grid] = {}
        self._merged_frame = merged_map_frame.lstrip('/')
        self._refused: Dict[str, str] = {}         # robot -> the reason last logged
        self._frame_warned: Dict[str, str] = {}    # robot -> the foreign frame last warned of
        self._reference_logged: Optional[tuple] = None
        self._reference_lock = threading.Lock()

    def on_map(self, robot: str, read: Callable[[], Grid]) -> None:
        """A full map of ``robot``: ``read()`` makes its grid (:func:`grid_of`) or raises."""
        try:
            grid = read()
        except (GridError, ValueError, TypeError) as e:
            self.refuse(robot, str(e))
            return
        self.accept(robot, grid)

    def on_update(self, robot: str, x: int, y: int, width: int, height: int, data: Any) -> None:
        """A map update of ``robot`` (cells at ``x``, ``y``, ``width`` x ``height``)."""
        base = self.latest.get(robot)
        if base is None:
            return   # an update before any full map has nothing to apply to
        try:
            grid = apply_update(base, int(x), int(y), int(width), int(height), np.asarray(data))
        except (GridError, ValueError, TypeError) as e:
            self.refuse(robot, 'map_updates: %s' % e)
            return
        self.accept(robot, grid)

    def refuse(self, robot: str, reason: str) -> None:
        if self._refused.get(robot) != reason:
            self.log.error('ignoring map of %s: %s' % (robot, reason))
            self._refused[robot] = reason
        self.merger.report_error(robot, reason)

    def accept(self, robot: str, grid: Grid) -> None:
        frame = grid.frame_id.lstrip('/')
        if not frame or frame in (self._merged_frame, 'map'):
            own = '%s/map' % robot
            if frame and self._frame_warned.get(robot) != frame:
                self.log.warning('map of %s is in frame "%s", not one of its own: publishing its TF as %s'
                                 % (robot, grid.frame_id, own))
                self._frame_warned[robot] = frame
            grid.frame_id = own
        if robot in self._refused:
            self.log.info('map of %s is valid again' % robot)
            del self._refused[robot]
        self.latest[robot] = grid
        event = self.merger.update_map(robot, grid)
        if event:   # a restart (gmapping's or slam_toolbox's reset): the core forgets its links
            self.log.warning(event)
        self.log_reference()

    def log_reference(self) -> None:
        """One info line when the reference robot is chosen, changes, or is fixed."""
        choice = self.merger.reference_choice()
        with self._reference_lock:
            key = (choice.robot, choice.fixed)
            if key == self._reference_logged or not choice.robot:
                return
            self._reference_logged = key
        self.log.info(choice.message())
