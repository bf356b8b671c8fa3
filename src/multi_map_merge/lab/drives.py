"""Robots' maps cut from a real building along its real drive, each in its own frame, with the
answer known (for the sweeps that calibrate how well a link is pinned, bench/tools/pinning_sweep.py).

The ground-truth maps of ``../shared/data/ground_truth`` were rasterised from the CARMEN logs'
corrected poses, in the log's frame, so a log's poses say where a robot drove and its scans
what it saw. A robot's map is the ground-truth map where the robot's scans of a part of the
drive reached (each scan's fan of beams, filled), moved into a frame of its own by a chosen
pose (:func:`pieces.cut_piece`):

- :func:`chain`: the drive cut into n consecutive stretches (equal distance driven), each
  grown by ``overlap`` of its length at both ends, so each robot overlaps only its
  neighbours: a robot's placement is a chain of links through the team.
- :func:`flood`: every robot starts at a common place (the drive's first pose) and holds the
  scans taken within ``start_radius`` of it plus those taken in one sector of directions
  from it (n sectors, each grown by ``sector_overlap`` radians on both sides): a team
  spreading out from where it was dropped.

The two AWS maps (``aws/small_house``, ``aws/bookstore``) have no log: :func:`planned_drive`
gives them one, a tour of their free space (the robot kept ``CLEARANCE`` from walls, driven
to the nearest place not yet visited on a 1.5 m lattice, poses every 0.2 m facing the way
it goes) with its scans simulated by ray casting on the map. A real drive comes back to
places it saw; so does the tour, when it crosses the building to its next unvisited place.
"""
from __future__ import annotations

import math
import os
from typing import List, Tuple

import cv2
import numpy as np

from ..core.grid import FREE, UNKNOWN, Grid, known_bbox, levels_to_values
from ..core.mapio import load_map
from ..core.transforms import cell_to_metric, inverse
from .pieces import cut_piece, random_poses
from .simulate import read_carmen

# metres: how far a robot's map reaches from its drive (an LDS-02 sees 8 m; the ground-truth
# maps were rasterised from beams up to 20 m, so a robot's map is always part of them)
MAX_RANGE = 8.0


# the AWS worlds' maps, which have no log: name -> map under ``data``; driven by planned_drive
AWS = {'aws-small_house': 'aws/small_house/map.yaml', 'aws-bookstore': 'aws/bookstore/map.yaml'}
CLEARANCE = 0.25        # m: a planned drive keeps this far from walls and unknown
LATTICE = 1.5           # m: a planned drive visits a place every LATTICE in both directions
STEP = 0.2              # m: a planned drive's poses, this far apart


def buildings(data: str, planned: bool = True) -> List[str]:
    """Names of the ground-truth buildings with a CARMEN log in ``data`` (../shared/data), and
    (``planned``) the AWS maps there, driven by :func:`planned_drive`."""
    gt = os.path.join(data, 'ground_truth')
    names = sorted(f[:-len('_gt.yaml')] for f in os.listdir(gt) if f.endswith('_gt.yaml'))
    out = [n for n in names if os.path.exists(os.path.join(data, 'carmen', n + '-corrected.log.gz'))]
    return out + [n for n, f in sorted(AWS.items()) if planned and os.path.exists(os.path.join(data, f))]


def load(data: str, name: str, cache: str = '') -> Tuple[Grid, np.ndarray, np.ndarray, np.ndarray]:
    """(ground-truth map, poses (N, 3), ranges (N, beams), beam angles) of a building; the log
    parsed (or the drive planned) once into ``cache`` (a directory) when given."""
    world = load_map(os.path.join(data, AWS[name] if name in AWS else
                                  os.path.join('ground_truth', name + '_gt.yaml')))
    f = os.path.join(cache, name + '.npz') if cache else ''
    if f and os.path.exists(f):
        z = np.load(f)
        return world, z['poses'], z['ranges'], z['angles']
    if name in AWS:
        out = planned_drive(world)
    else:
        log = read_carmen(os.path.join(data, 'carmen', name + '-corrected.log.gz'))
        out = (log.poses, log.ranges, log.angles)
    if f:
        os.makedirs(cache, exist_ok=True)
        np.savez(f, poses=out[0], ranges=out[1], angles=out[2])
    return (world,) + out


def planned_drive(world: Grid, beams: int = 181, max_range: float = 12.0
                  ) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A drive through ``world``'s free space, for a map with no log (see the module
    docstring): (poses (N, 3) in the map's frame, ranges (N, beams), beam angles), the ranges
    ray cast on the map over 180 degrees, 0 where nothing is hit within ``max_range``."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra
    lv = world.levels()
    res = world.resolution
    clear = int(math.ceil(CLEARANCE / res))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * clear + 1, 2 * clear + 1))
    ok = cv2.erode((lv == FREE).astype(np.uint8), k) > 0
    # the largest connected part of the free space
    n_cc, lab = cv2.connectedComponents(ok.astype(np.uint8), connectivity=8)
    if n_cc < 2:
        raise ValueError('no free space %.2f m clear of walls' % CLEARANCE)
    ok = lab == 1 + int(np.argmax(np.bincount(lab[lab > 0].ravel())[1:]))
    rc = np.argwhere(ok)
    idx = -np.ones(lv.shape, np.int64)
    idx[ok] = np.arange(len(rc))
    rows, cols, w = [], [], []
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        r2, c2 = rc[:, 0] + dr, rc[:, 1] + dc
        inside = (r2 >= 0) & (r2 < lv.shape[0]) & (c2 >= 0) & (c2 < lv.shape[1])
        j = np.full(len(rc), -1)
        j[inside] = idx[r2[inside], c2[inside]]
        keep = j >= 0
        rows.append(np.nonzero(keep)[0])
        cols.append(j[keep])
        w.append(np.full(int(keep.sum()), math.hypot(dr, dc)))
    rows, cols, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
    G = csr_matrix((np.concatenate([w, w]), (np.concatenate([rows, cols]), np.concatenate([cols, rows]))),
                   shape=(len(rc), len(rc)))
    # places to visit: the free cell nearest each node of a lattice
    lat = max(1, int(round(LATTICE / res)))
    cell = (rc[:, 0] // lat) * (lv.shape[1] // lat + 1) + rc[:, 1] // lat
    centre = np.abs(rc % lat - lat // 2).sum(1)
    order = np.lexsort((centre, cell))
    todo = set(order[np.r_[True, cell[order][1:] != cell[order][:-1]]].tolist())
    # start at the place nearest the free space's centroid; always on to the nearest unvisited
    here = min(todo, key=lambda i: float(np.hypot(*(rc[i] - rc.mean(0)))))
    todo.discard(here)
    path = [here]
    while todo:
        dist, pred = dijkstra(G, indices=here, return_predecessors=True)
        cand = [i for i in todo if np.isfinite(dist[i])]
        if not cand:
            break
        nxt = min(cand, key=lambda i: dist[i])
        leg = [nxt]
        while leg[-1] != here:
            leg.append(pred[leg[-1]])
        path += leg[-2::-1]
        # places passed on the way count as visited
        todo -= set(leg)
        here = nxt
        todo.discard(here)
    xy = cell_to_metric(res, world.origin) @ np.vstack([rc[path][:, ::-1].T.astype(np.float64),
                                                      np.ones(len(path))])
    xy = xy[:2].T
    s = travelled(np.hstack([xy, np.zeros((len(xy), 1))]))
    at = np.searchsorted(s, np.arange(0.0, s[-1], STEP))
    xy = xy[np.unique(at)]
    d = np.diff(xy, axis=0)
    yaw = np.arctan2(d[:, 1], d[:, 0])
    poses = np.column_stack([xy, np.append(yaw, yaw[-1:])])
    angles = np.linspace(-math.pi / 2, math.pi / 2, beams)
    return poses, cast(lv != FREE, world, poses, angles, max_range), angles


def cast(blocked: np.ndarray, world: Grid, poses: np.ndarray, angles: np.ndarray,
         max_range: float) -> np.ndarray:
    """Ranges (N, beams) from ``poses`` to the first ``blocked`` cell of ``world``'s grid (m,
    to the cell's near side within half a cell), 0 where none is within ``max_range``."""
    res = world.resolution
    Winv = inverse(cell_to_metric(res, world.origin))
    r = np.arange(0.5 * res, max_range, 0.5 * res)
    h, w = blocked.shape
    out = np.zeros((len(poses), len(angles)), np.float32)
    for k, p in enumerate(poses):
        a = p[2] + angles
        x = p[0] + np.cos(a)[:, None] * r
        y = p[1] + np.sin(a)[:, None] * r
        c = np.rint(Winv[0, 0] * x + Winv[0, 1] * y + Winv[0, 2]).astype(np.int64)
        rr = np.rint(Winv[1, 0] * x + Winv[1, 1] * y + Winv[1, 2]).astype(np.int64)
        hit = (c < 0) | (c >= w) | (rr < 0) | (rr >= h)
        hit[~hit] = blocked[rr[~hit], c[~hit]]
        first = np.argmax(hit, axis=1)
        out[k] = np.where(hit[np.arange(len(angles)), first], r[first], 0.0)
    return out


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
    the world frame): (grid, T_world_k), as :func:`pieces.cut_piece`."""
    lv = world.levels().copy()
    lv[~mask] = UNKNOWN
    box = known_bbox(lv)
    if box is None:
        raise ValueError('the drive saw nothing of the map')
    return cut_piece(Grid(levels_to_values(lv), world.resolution, world.origin, world.frame_id), box, pose, frame_id)


def chain(world: Grid, poses: np.ndarray, ranges: np.ndarray, angles: np.ndarray, n: int,
          seed: int, overlap: float = 0.15, strict: bool = False) -> List[Tuple[Grid, np.ndarray]]:
    """n robots, each the scans of one stretch of the drive (see the module docstring), at
    random poses: [(grid, T_world_k)] in the drive's order.

    A drive that comes back to a place it saw (a loop, a corridor driven both ways) makes
    stretches far apart in the drive overlap too: the chain is then not only a chain. With
    ``strict``, a robot keeps only the cells that no stretch other than itself and its two
    neighbours saw, so robots overlap their neighbours only (the places seen again are in no
    robot's map but one or two consecutive ones); a stretch left with nothing is no robot
    (fewer than n, renumbered in the drive's order)."""
    s = travelled(poses)
    L = s[-1] / n
    masks = []
    for k in range(n):
        sel = (s >= (k - overlap) * L) & (s <= (k + 1 + overlap) * L)
        masks.append(seen(world, poses[sel], ranges[sel], angles))
    if strict:
        count = np.zeros(world.data.shape, np.int32)
        for m in masks:
            count += m
        kept = []
        for k, m in enumerate(masks):
            near = sum(masks[j].astype(np.int32) for j in range(max(0, k - 1), min(n, k + 2)))
            kept.append(m & (count == near))     # seen by no stretch beyond its neighbours
        masks = kept
        # a stretch all of whose cells other stretches saw too has no map left: no robot
        kept = [(m, pose) for m, pose in zip(masks, random_poses(n, seed)) if known_bbox(
            np.where(m, world.levels(), UNKNOWN)) is not None]
        return [masked_piece(world, m, pose, 'r%d' % k) for k, (m, pose) in enumerate(kept)]
    return [masked_piece(world, m, pose, 'r%d' % k)
            for k, (m, pose) in enumerate(zip(masks, random_poses(n, seed)))]


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
