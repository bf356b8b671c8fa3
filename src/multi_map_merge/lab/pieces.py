"""Robots' maps cut out of one real map, each in its own frame, with the answer known.

Used by tests, the demo and the benchmark: a piece of a ground-truth map is moved into a new
map frame by a pose we choose, so the merger's estimate can be scored against that pose.
"""
from __future__ import annotations

import math
from typing import List, Sequence, Tuple

import cv2
import numpy as np

from ..core.grid import Grid, known_bbox, levels_to_values
from ..core.transforms import cell_to_metric, se2


def cut_piece(world: Grid, rect: Tuple[int, int, int, int], pose: Sequence[float],
              frame_id: str = '', margin_cells: int = 20) -> Tuple[Grid, np.ndarray]:
    """Cut ``rect`` = (row0, row1, col0, col1) (cells, half-open) out of ``world`` and express
    it in a new frame k whose pose in the world frame is ``pose`` = (x, y, yaw) (m, rad).

    Returns (grid of the piece in frame k, T_world_k 3x3). The grid is axis-aligned in frame
    k, big enough for the piece plus ``margin_cells`` of unknown, with its origin at a
    multiple of the resolution as gmapping does."""
    r0, r1, c0, c1 = rect
    lv = np.zeros_like(world.levels())
    lv[r0:r1, c0:c1] = world.levels()[r0:r1, c0:c1]
    res = world.resolution
    T = se2(*pose)
    W_w = cell_to_metric(res, world.origin)
    corners = np.array([[c0, r0], [c1, r0], [c0, r1], [c1, r1]], np.float64) - 0.5
    mw = (W_w[:2, :2] @ corners.T).T + W_w[:2, 2]
    Tinv = np.linalg.inv(T)
    mk = (Tinv[:2, :2] @ mw.T).T + Tinv[:2, 2]
    x0 = math.floor(mk[:, 0].min() / res) * res - margin_cells * res
    y0 = math.floor(mk[:, 1].min() / res) * res - margin_cells * res
    w = int(math.ceil((mk[:, 0].max() - x0) / res)) + margin_cells
    h = int(math.ceil((mk[:, 1].max() - y0) / res)) + margin_cells
    origin = (round(x0, 6), round(y0, 6), 0.0)
    M = np.linalg.inv(W_w) @ T @ cell_to_metric(res, origin)  # cells of k -> cells of world
    out = cv2.warpAffine(lv, M[:2], (w, h), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return Grid(levels_to_values(out), res, origin, frame_id), T


def split_rects(world: Grid, n: int, overlap: float = 0.35) -> List[Tuple[int, int, int, int]]:
    """n overlapping rectangles tiling the known part of ``world`` (a grid of ceil(sqrt n)
    columns), each grown by ``overlap`` of its size so neighbours share structure."""
    box = known_bbox(world.levels())
    if box is None:
        raise ValueError('world map has no known cell')
    r0, r1, c0, c1 = box
    cols = int(math.ceil(math.sqrt(n)))
    rows = int(math.ceil(n / cols))
    out = []
    for k in range(n):
        i, j = k % cols, k // cols
        ch = (c1 - c0) / cols
        rh = (r1 - r0) / rows
        a0 = c0 + i * ch - overlap * ch
        a1 = c0 + (i + 1) * ch + overlap * ch
        b0 = r0 + j * rh - overlap * rh
        b1 = r0 + (j + 1) * rh + overlap * rh
        out.append((max(r0, int(b0)), min(r1, int(b1)), max(c0, int(a0)), min(c1, int(a1))))
    return out


def halves(world: Grid, y: float, strip: float, poses: Sequence[Sequence[float]],
           frames: Sequence[str] = ('', '')) -> List[Tuple[Grid, np.ndarray]]:
    """Two robots' maps of a building split at the line ``y`` (metres, world frame, a yaw-0
    world grid): the first above it, the second below, each reaching ``strip`` metres beyond
    it (they share a strip 2 * ``strip`` wide), at ``poses`` as :func:`cut_piece`. On a
    building of two look-alike halves (the Turtlebot3 double house, split where the robots
    started) the features place one half on the other. Returns [(grid, T_world_k)] x 2."""
    box = known_bbox(world.levels())
    if box is None:
        raise ValueError('world map has no known cell')
    r0, r1, c0, c1 = box
    mid = int(round((y - world.origin[1]) / world.resolution))
    k = int(round(strip / world.resolution))
    return [cut_piece(world, (max(r0, mid - k), r1, c0, c1), poses[0], frames[0]),
            cut_piece(world, (r0, min(r1, mid + k), c0, c1), poses[1], frames[1])]


def in_world_frame(world: Grid, box: Sequence[float], extent: Sequence[float] = (-10.0, -10.0, 10.0, 10.0),
                   frame_id: str = '') -> Grid:
    """A robot's map in the world's own frame, as ROBOTIS's Gazebo robots make theirs (the
    diff-drive plugin's odometry is the world pose, and gmapping starts its map frame on the
    odometry frame): a grid over ``extent`` (xmin, ymin, xmax, ymax, metres: gmapping's xmin,
    ymin, xmax, ymax; multiples of the resolution) at the world's resolution, holding the world
    (a yaw-0 grid whose origin lies on the same lattice) within ``box`` (x0, x1, y0, y1,
    metres) and unknown elsewhere."""
    res = world.resolution
    xmin, ymin, xmax, ymax = extent
    w, h = int(round((xmax - xmin) / res)), int(round((ymax - ymin) / res))
    off_c = int(round((xmin - world.origin[0]) / res))
    off_r = int(round((ymin - world.origin[1]) / res))
    x0, x1, y0, y1 = box
    c0, c1 = max(0, int(round((x0 - xmin) / res))), min(w, int(round((x1 - xmin) / res)))
    r0, r1 = max(0, int(round((y0 - ymin) / res))), min(h, int(round((y1 - ymin) / res)))
    # the world's cells there (those outside the world stay unknown)
    wr0, wr1 = max(r0 + off_r, 0), min(r1 + off_r, world.height)
    wc0, wc1 = max(c0 + off_c, 0), min(c1 + off_c, world.width)
    out = np.zeros((h, w), np.uint8)
    if wr1 > wr0 and wc1 > wc0:
        out[wr0 - off_r:wr1 - off_r, wc0 - off_c:wc1 - off_c] = world.levels()[wr0:wr1, wc0:wc1]
    return Grid(levels_to_values(out), res, (float(xmin), float(ymin), 0.0), frame_id)


def random_poses(n: int, seed: int, max_offset: float = 5.0,
                 max_yaw: float = math.pi) -> List[Tuple[float, float, float]]:
    """n poses (x, y, yaw): offsets up to ``max_offset`` metres, yaw up to ``max_yaw`` rad."""
    rng = np.random.default_rng(seed)
    return [(float(rng.uniform(-max_offset, max_offset)), float(rng.uniform(-max_offset, max_offset)),
             float(rng.uniform(-max_yaw, max_yaw))) for _ in range(n)]


def pieces_windows(world: Grid, n: int, frac: float = 0.6, seed: int = 0) -> List[Tuple[Grid, np.ndarray]]:
    """n world-sized robots: random windows of ``frac`` of the world each (all pairs overlap,
    the worst case for estimation), each at a random pose: [(grid, T_world_k)]."""
    rng = np.random.default_rng(seed)
    r0, r1, c0, c1 = known_bbox(world.levels())
    h, w = int((r1 - r0) * frac), int((c1 - c0) * frac)
    out = []
    for p in random_poses(n, seed + 1):
        a = int(rng.integers(r0, r1 - h + 1))
        b = int(rng.integers(c0, c1 - w + 1))
        out.append(cut_piece(world, (a, a + h, b, b + w), p))
    return out


def bad_grids(rng: np.random.Generator, n: int):
    """n (data, width, height, resolution, origin) tuples, each wrong in at least one way: what
    fuzzing the grid checks and the node feeds on."""
    for _ in range(n):
        w, h = int(rng.integers(1, 60)), int(rng.integers(1, 60))
        data = rng.integers(-1, 101, w * h).astype(np.int16)
        res, origin = 0.05, [0.0, 0.0, 0.0]
        kind = rng.integers(0, 8)
        if kind == 0:
            data = data[:int(rng.integers(0, w * h))]                   # truncated
        elif kind == 1:
            data = np.concatenate([data, rng.integers(-1, 101, int(rng.integers(1, 50)))])
        elif kind == 2:
            w = 0 if rng.random() < 0.5 else w
            h = 0 if w else h                                            # an empty side
            data = data[:w * h] if w * h else data
        elif kind == 3:
            res = float(rng.choice([0.0, -0.05, np.nan, np.inf, -np.inf]))
        elif kind == 4:
            origin[int(rng.integers(0, 3))] = float(rng.choice([np.nan, np.inf, -np.inf]))
        elif kind == 5:
            data[int(rng.integers(0, w * h))] = int(rng.choice([-2, -128, 101, 127]))
        elif kind == 6:
            w, h = 100000, 100000                                       # absurd size
        else:
            data = rng.integers(-128, 128, int(rng.integers(0, 3 * w * h + 1)))
            if data.size == w * h and data.min() >= -1 and data.max() <= 100:
                data = data[:-1] if data.size else data
        yield data, w, h, res, origin
