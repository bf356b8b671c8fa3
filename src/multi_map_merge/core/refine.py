"""Refinement on the grids themselves (beyond the paper).

Feature positions are only as precise as AKAZE's keypoints on a blocky image, so the RANSAC
transform is often a cell or two off. This aligns the occupied cells of the source grid to
the occupied cells of the destination grid by ICP (point-to-point, trimmed at ``max_distance``
cells), starting from the RANSAC transform. Nearest occupied cells come from one distance
transform of the destination grid, so each iteration costs one lookup per source wall cell.
"""
from __future__ import annotations

from typing import Optional, Tuple

import cv2
import numpy as np

from .grid import OCCUPIED, known_bbox
from .transforms import rigid_from_xy

WALL_FIELD_MARGIN = 4   # cells beyond the known box where nearest walls are still looked up


class WallField:
    """Nearest occupied cell of a grid for any cell of its known box (built once per grid).

    Attributes:
        dist_flat: float32 distance (cells) to the nearest wall of each cell of the box, row
            major, plus one entry past the end (infinite) for points outside the box.
        dx_flat, dy_flat: int8 offset (cells) from each cell to that wall; exact within
            OFFSET_REACH cells, which is all ICP looks at (its gates are a few cells).
        offset: (col, row) of the box's first cell in the grid; shape: the box's (rows, cols).
    """

    OFFSET_REACH = 127

    def __init__(self, levels: np.ndarray, margin: int = WALL_FIELD_MARGIN):
        box = known_bbox(levels, margin)
        self.ok = box is not None
        if not self.ok:
            return
        r0, r1, c0, c1 = box
        self.offset = np.array([c0, r0], np.float64)
        occ = levels[r0:r1, c0:c1] == OCCUPIED
        self.ok = bool(occ.any())
        if not self.ok:
            return
        h, w = occ.shape
        # (each array made once and worked on in place: a parent's field is built in every
        # worker that aligns a pair of it, and a worker's fresh pages cost more than its sums)
        src = cv2.compare(levels[r0:r1, c0:c1], OCCUPIED, cv2.CMP_NE)   # walls 0, else 255
        dist = np.empty(h * w + 1, np.float32)
        dist[-1] = np.inf                       # the entry for points outside the box
        img, labels = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 5, dst=dist[:-1].reshape(h, w),
                                                      labelType=cv2.DIST_LABEL_PIXEL)
        if not np.shares_memory(img, dist):     # (OpenCV wrote elsewhere after all)
            dist[:-1] = img.reshape(-1)
        del src, img
        # Labels number the zero (occupied) pixels in raster order, from 1. A cell keeps the
        # offset to its wall, 2 bytes instead of a 4-byte label (memory per parent map): each
        # cell's wall is looked up once, its (col, row) packed in one integer.
        rr, cc = np.nonzero(occ)
        shift, dtype = (16, np.int32) if max(h, w) < 1 << 15 else (32, np.int64)
        wall = cc.astype(dtype)
        wall <<= shift
        wall |= rr
        lab = labels.reshape(-1).astype(np.intp)
        del labels
        lab -= 1
        near = wall.take(lab).reshape(h, w)            # each cell's nearest wall, packed
        del lab
        reach = self.OFFSET_REACH
        dx = near >> shift
        dx -= np.arange(w, dtype=dtype)[None, :]
        near &= (1 << shift) - 1                       # (near becomes dy)
        near -= np.arange(h, dtype=dtype)[:, None]
        offsets = []
        for d in (dx, near):
            np.clip(d, -reach, reach, out=d)
            out = np.empty(h * w + 1, np.int8)
            out[-1] = 0
            out[:-1] = d.reshape(-1)
            offsets.append(out)
        self.dx_flat, self.dy_flat = offsets
        self.dist_flat = dist
        self.shape = occ.shape

    def index(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Flat table index of the cells nearest to points (x, y) (cells; the past-the-end
        entry for points outside the box)."""
        h, w = self.shape
        ix = np.rint(x - self.offset[0]).astype(np.int64)
        iy = np.rint(y - self.offset[1]).astype(np.int64)
        # unsigned compare: negative coordinates wrap to huge values and fail too
        valid = (ix.astype(np.uint64) < w) & (iy.astype(np.uint64) < h)
        return np.where(valid, iy * w + ix, h * w)

    def walls(self, idx: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """(x, y) grid cells of the walls nearest to the cells of flat indices ``idx`` (inside
        the box, within OFFSET_REACH cells of a wall)."""
        iy, ix = np.divmod(idx, self.shape[1])
        return (ix + self.dx_flat.take(idx) + self.offset[0], iy + self.dy_flat.take(idx) + self.offset[1])


def occupied_points(levels: np.ndarray, box: Optional[Tuple[int, int, int, int]] = None,
                    max_points: int = 4000) -> np.ndarray:
    """(N, 2) cell coordinates (col, row) of occupied cells in raster order, evenly thinned to
    ``max_points``. ``box``: the grid's known box (:func:`grid.known_bbox`), when the caller
    has it: every occupied cell lies inside it, and searching it only is cheaper."""
    r0, c0 = 0, 0
    if box is not None:
        r0, r1, c0, c1 = box
        levels = levels[r0:r1, c0:c1]
    rr, cc = np.nonzero(levels == OCCUPIED)
    pts = np.empty((rr.size, 2), np.float64)
    pts[:, 0] = cc + c0
    pts[:, 1] = rr + r0
    if pts.shape[0] > max_points:
        pts = np.ascontiguousarray(pts[:: int(np.ceil(pts.shape[0] / max_points))])
    return pts


def refine(field: WallField, src_pts: np.ndarray, A: np.ndarray, max_distance: float = 3.0,
           iterations: int = 20, min_pairs: int = 30) -> Optional[np.ndarray]:
    """ICP of the source's wall cells onto the destination's walls; returns the refined 3x3
    (cells of src -> cells of dst), or None when too few walls pair up to say anything.

    The pairing distance shrinks from ``max_distance`` to one cell: a fixed wide gate biases
    the result towards wherever the most walls lie within it (on partial maps, walls seen
    only by one robot pair with unrelated walls 2-3 cells away and pull the estimate by a
    degree or more); the last, tight stage keeps only walls that really coincide."""
    if not field.ok or src_pts.shape[0] < min_pairs:
        return None
    cur = A.copy()
    # (the field knows each cell's wall within OFFSET_REACH cells only)
    max_distance = min(max_distance, float(field.OFFSET_REACH))
    gates = [max_distance] + [g for g in (4.0, 3.0, 2.0, 1.5, 1.0) if g < max_distance]
    # the wide gates only bring the walls within reach: a third of the points does that as
    # well (most iterations happen there); the tight gates that set the result use them all
    coarse = src_pts[::3] if src_pts.shape[0] >= 30 * min_pairs else src_pts
    # x and y as separate contiguous arrays: each iteration is then a few passes over them
    xy_all = (np.ascontiguousarray(src_pts[:, 0]), np.ascontiguousarray(src_pts[:, 1]))
    xy_coarse = (np.ascontiguousarray(coarse[:, 0]), np.ascontiguousarray(coarse[:, 1]))
    for k, gate in enumerate(gates):
        x, y = xy_coarse if gate > 1.5 else xy_all
        need = min_pairs * x.size // src_pts.shape[0]   # the same share of the walls
        for _ in range(iterations):
            px = cur[0, 0] * x + cur[0, 1] * y + cur[0, 2]
            py = cur[1, 0] * x + cur[1, 1] * y + cur[1, 2]
            idx = field.index(px, py)
            # (outside the box the distance is infinite; take() beats boolean indexing 4x)
            sel = np.flatnonzero(field.dist_flat.take(idx) <= gate)
            if sel.size < need:
                return cur if k > 0 else None
            wx, wy = field.walls(idx.take(sel))
            step = rigid_from_xy(px.take(sel), py.take(sel), wx, wy)
            cur = step @ cur
            if abs(step[0, 2]) < 0.01 and abs(step[1, 2]) < 0.01 and abs(step[1, 0]) < 1e-4:
                break
    return cur
