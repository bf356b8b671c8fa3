"""Robots' maps cut from a real building along its real drive, each in its own frame, with the
answer known (issue 22's sweeps).

The ground-truth maps of ``../shared/data/ground_truth`` were rasterised from the CARMEN logs'
corrected poses, in the log's frame, so a log's poses say where a robot drove and its scans
what it saw. A robot's map is the ground-truth map where the robot's scans of a part of the
drive reached (each scan's fan of beams, filled), moved into a frame of its own by a chosen
pose (:func:`synth.cut_piece`):

- :func:`chain`: the drive cut into n consecutive stretches (equal distance driven), each
  grown by ``overlap`` of its length at both ends, so each robot overlaps only its
  neighbours: a robot's placement is a chain of links through the team.
- :func:`flood`: every robot starts at a common place (the drive's first pose) and holds the
  scans taken within ``start_radius`` of it plus those taken in one sector of directions
  from it (n sectors, each grown by ``sector_overlap`` radians on both sides): a team
  spreading out from where it was dropped.
"""
from __future__ import annotations

import math
import os
from typing import List, Tuple

import cv2
import numpy as np

from ..core.grid import UNKNOWN, Grid, known_bbox, levels_to_values
from ..core.mapio import load_map
from ..core.transforms import cell_to_metric, inverse
from .simulate import read_carmen
from .synth import cut_piece, random_poses

# metres: how far a robot's map reaches from its drive (an LDS-02 sees 8 m; the ground-truth
# maps were rasterised from beams up to 20 m, so a robot's map is always part of them)
MAX_RANGE = 8.0


def buildings(data: str) -> List[str]:
    """Names of the ground-truth buildings with a CARMEN log in ``data`` (../shared/data)."""
    gt = os.path.join(data, 'ground_truth')
    names = sorted(f[:-len('_gt.yaml')] for f in os.listdir(gt) if f.endswith('_gt.yaml'))
    return [n for n in names if os.path.exists(os.path.join(data, 'carmen', n + '-corrected.log.gz'))]


def load(data: str, name: str, cache: str = '') -> Tuple[Grid, np.ndarray, np.ndarray, np.ndarray]:
    """(ground-truth map, poses (N, 3), ranges (N, beams), beam angles) of a building; the log
    parsed once into ``cache`` (a directory) when given."""
    world = load_map(os.path.join(data, 'ground_truth', name + '_gt.yaml'))
    f = os.path.join(cache, name + '.npz') if cache else ''
    if f and os.path.exists(f):
        z = np.load(f)
        return world, z['poses'], z['ranges'], z['angles']
    log = read_carmen(os.path.join(data, 'carmen', name + '-corrected.log.gz'))
    out = (log.poses, log.ranges, log.angles)
    if f:
        os.makedirs(cache, exist_ok=True)
        np.savez(f, poses=out[0], ranges=out[1], angles=out[2])
    return (world,) + out


def travelled(poses: np.ndarray) -> np.ndarray:
    """Distance driven (m) at every pose, from the first."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))])


def seen(world: Grid, poses: np.ndarray, ranges: np.ndarray, angles: np.ndarray,
         every: float = 0.25) -> np.ndarray:
    """Boolean mask over ``world``'s cells reached by the scans taken at ``poses`` (one scan per
    ``every`` metres driven or 10 degrees turned), beams cut at MAX_RANGE, walls at the beams'
    ends included."""
    mask = np.zeros(world.data.shape, np.uint8)
    Winv = inverse(cell_to_metric(world.resolution, world.origin))
    last = None
    for p, r in zip(poses, ranges):
        if last is not None and math.hypot(p[0] - last[0], p[1] - last[1]) < every \
                and abs(math.remainder(p[2] - last[2], 2 * math.pi)) < math.radians(10):
            continue
        last = p
        rr = np.minimum(np.where(r > 0, r, MAX_RANGE), MAX_RANGE)   # (no return: open space)
        a = p[2] + angles
        pts = np.stack([p[0] + rr * np.cos(a), p[1] + rr * np.sin(a)], 1)
        pts = np.vstack([p[None, :2], pts]) @ Winv[:2, :2].T + Winv[:2, 2]
        cv2.fillPoly(mask, [np.rint(pts).astype(np.int32)], 1)
    # a beam ends on the wall's near face: the wall's cells are a cell or two beyond
    return cv2.dilate(mask, np.ones((5, 5), np.uint8)) > 0


def masked_piece(world: Grid, mask: np.ndarray, pose, frame_id: str = '') -> Tuple[Grid, np.ndarray]:
    """The world's cells under ``mask`` as a robot's map in a frame at ``pose`` (x, y, yaw in
    the world frame): (grid, T_world_k), as :func:`synth.cut_piece`."""
    lv = world.levels().copy()
    lv[~mask] = UNKNOWN
    box = known_bbox(lv)
    if box is None:
        raise ValueError('the drive saw nothing of the map')
    return cut_piece(Grid(levels_to_values(lv), world.resolution, world.origin, world.frame_id), box, pose, frame_id)


def chain(world: Grid, poses: np.ndarray, ranges: np.ndarray, angles: np.ndarray, n: int,
          seed: int, overlap: float = 0.15) -> List[Tuple[Grid, np.ndarray]]:
    """n robots, each the scans of one stretch of the drive (see the module docstring), at
    random poses: [(grid, T_world_k)] in the drive's order."""
    s = travelled(poses)
    L = s[-1] / n
    out = []
    for k, pose in enumerate(random_poses(n, seed)):
        sel = (s >= (k - overlap) * L) & (s <= (k + 1 + overlap) * L)
        out.append(masked_piece(world, seen(world, poses[sel], ranges[sel], angles), pose, 'r%d' % k))
    return out


def flood(world: Grid, poses: np.ndarray, ranges: np.ndarray, angles: np.ndarray, n: int,
          seed: int, start_radius: float = 3.0, sector_overlap: float = math.radians(15)
          ) -> List[Tuple[Grid, np.ndarray]]:
    """n robots spreading out from the drive's first pose, one sector of directions each (see
    the module docstring), at random poses: [(grid, T_world_k)]."""
    d = poses[:, :2] - poses[0, :2]
    dist = np.hypot(d[:, 0], d[:, 1])
    ang = np.arctan2(d[:, 1], d[:, 0])
    width = 2 * math.pi / n
    out = []
    for k, pose in enumerate(random_poses(n, seed)):
        mid = -math.pi + (k + 0.5) * width
        off = np.abs(np.remainder(ang - mid + math.pi, 2 * math.pi) - math.pi)
        sel = (dist <= start_radius) | (off <= 0.5 * width + sector_overlap)
        out.append(masked_piece(world, seen(world, poses[sel], ranges[sel], angles), pose, 'r%d' % k))
    return out
