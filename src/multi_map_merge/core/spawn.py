"""m-explore's per-robot priors read against the grids: are they spawn poses of robots whose
maps share one frame?

ROBOTIS's Gazebo multi-robot launch (turtlebot3_gazebo ``multi_map_merge.launch``) writes each
robot's spawn position to ``/<robot>/map_merge/init_pose_*`` and sets ``known_init_poses``. In
m-explore's meaning those are the poses of the robots' map frames in a common frame; but in
Gazebo every robot's odometry starts in the world frame (the diff-drive plugin's
``odometrySource world``) and gmapping starts its map frame on the odometry frame, so every
robot's map is in the world frame: the map frames coincide, and the values are where the robots
stand in that shared frame. Read as priors they reject the right link (``contradicts initial
poses``).

The grids tell the two meanings apart. Maps that share one frame agree with each other where
they are (at identity) wherever they overlap, and each robot's spawn point is free space of its
own map (the robot stood there when its map began). :func:`spawn_poses_in_one_frame` checks
both; when they hold and the priors would place the maps elsewhere, the priors mean spawn
poses, and the maps' own frames (all ``[0, 0, 0]``) are the priors to use.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .config import MergeConfig
from .grid import FREE, UNKNOWN, Grid
from .transforms import inverse, pose_distance, se2, within_tolerance
from .verify import pose_on_grids

#: agreement at identity below which two overlapping maps are not in one frame. Measured on the
#: AWS small house: the four real gmapping maps of make accuracy's seed 2 in their own
#: frames (starts within 1 m, headings 85-260 degrees apart) agree 0.06-0.32 at identity; the
#: same maps carried into the world frame by their true starts, 0.78-1.00 (gmapping's drift);
#: pieces of the house map in the world frame, moved 0.2 m or turned 3 degrees, 0.67-0.83
NOT_ONE_FRAME = 0.5

#: metres around a spawn point that must be free space of the robot's own map (a Turtlebot3
#: Burger is 0.1 m in radius; gmapping clears the cells under it with its first scans)
SPAWN_RADIUS = 0.15


@dataclass
class SharedFrame:
    """The verdict of :func:`spawn_poses_in_one_frame`.

    Attributes:
        robots: the robots whose priors are spawn poses (every robot given to it).
        pairs: (a, b, agreement at identity, overlap cells, metres the priors put b's map
            frame from a's) of each pair whose maps overlap at identity.
    """

    robots: List[str]
    pairs: List[Tuple[str, str, float, int, float]]

    def message(self) -> str:
        a, b, agr, ovl, off = max(self.pairs, key=lambda p: p[3])
        return ('the maps of %s and %s agree where they are (agreement %.2f over %d cells at identity), not %.2f m '
                'apart as their init_pose_* would put them, and every robot\'s init_pose_* is free space of its own map'
                % (a, b, agr, ovl, off))


def spawn_point_free(config: MergeConfig, grid: Grid, x: float, y: float,
                     radius: float = SPAWN_RADIUS) -> bool:
    """(x, y), metres in ``grid``'s frame, is free space of ``grid``: at least half of the
    cells within ``radius`` are known, and every known one of them is free."""
    if abs(grid.origin[2]) > 1e-9:   # a rotated grid: carry the point into its axes
        c, s = math.cos(grid.origin[2]), math.sin(grid.origin[2])
        dx, dy = x - grid.origin[0], y - grid.origin[1]
        gx, gy = c * dx + s * dy, -s * dx + c * dy
    else:
        gx, gy = x - grid.origin[0], y - grid.origin[1]
    res = grid.resolution
    col, row = gx / res, gy / res
    n = max(1, int(math.ceil(radius / res)))
    r0, c0 = int(math.floor(row)) - n, int(math.floor(col)) - n
    r1, c1 = r0 + 2 * n + 1, c0 + 2 * n + 1
    if r0 < 0 or c0 < 0 or r1 > grid.height or c1 > grid.width:
        return False
    lv = grid.levels(config.free_thresh, config.occupied_thresh)[r0:r1, c0:c1]
    rr, cc = np.mgrid[r0:r1, c0:c1]
    near = ((rr + 0.5 - row) ** 2 + (cc + 0.5 - col) ** 2) <= (radius / res) ** 2
    cells = lv[near]
    known = cells != UNKNOWN
    return known.sum() * 2 >= cells.size and bool(np.all(cells[known] == FREE))


def spawn_poses_in_one_frame(config: MergeConfig, grids: Dict[str, Grid],
                             priors: Dict[str, Sequence[float]]) -> Optional[SharedFrame]:
    """A :class:`SharedFrame` when the ``priors`` (robot -> [x, y, yaw], m-explore's
    ``init_pose_*``) of the robots of ``grids`` are spawn poses in one frame that all their maps
    share, not the poses of their map frames; None when the grids do not say so (yet).

    It says so when every robot of ``priors`` has a grid, its spawn point (x, y) is free space
    of that grid (:func:`spawn_point_free`), at least one pair whose priors put their map frames
    apart (beyond ``initial_pose_tolerance``) verifies at identity on the grids (agreement >=
    ``min_agreement`` over >= ``min_overlap_cells``) and not where the priors put it, and no pair
    overlapping at identity plainly disagrees there (agreement < :data:`NOT_ONE_FRAME`: maps
    in frames of their own; between that and ``min_agreement``: one frame and gmapping's
    drift, or not; neither for nor against)."""
    names = sorted(priors)
    if len(names) < 2 or any(n not in grids for n in names):
        return None
    pairs = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            P = inverse(se2(*priors[a])) @ se2(*priors[b])
            d, ang = pose_distance(P, np.eye(3))
            agr, ovl = pose_on_grids(config, grids[a], grids[b], np.eye(3))
            if ovl < config.min_overlap_cells:
                continue   # they do not overlap at identity: nothing to say
            if agr < NOT_ONE_FRAME:
                return None   # overlapping at identity and disagreeing: not one frame
            if agr < config.min_agreement or within_tolerance(d, ang, config.initial_pose_tolerance):
                continue   # no evidence either way; or the priors say identity too
            agr_p, ovl_p = pose_on_grids(config, grids[a], grids[b], P)
            if ovl_p >= config.min_overlap_cells and agr_p >= config.min_agreement:
                return None   # the priors' placement verifies as well: nothing to correct
            pairs.append((a, b, agr, ovl, d))
    if not pairs:
        return None
    if not all(spawn_point_free(config, grids[n], priors[n][0], priors[n][1]) for n in names):
        return None
    return SharedFrame(names, pairs)
