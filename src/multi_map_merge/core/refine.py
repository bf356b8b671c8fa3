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
    """Nearest occupied cell of a grid for any cell of its known box (built once per grid)."""

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
        src = np.where(occ, 0, 255).astype(np.uint8)
        dist, labels = cv2.distanceTransformWithLabels(
            src, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
        # Labels number the zero (occupied) pixels in raster order, from 1.
        rr, cc = np.nonzero(occ)
        # flat per-cell tables with one extra entry past the end for points outside the box
        # (no wall: infinitely far, label 0), and the wall cell of each label (grid's cells)
        self.dist_flat = np.append(dist.ravel(), np.float32(np.inf))
        self.labels_flat = np.append(labels.ravel(), 0).astype(np.int32)
        self.wall_x = np.append(np.float64(-1.0), cc + float(c0))
        self.wall_y = np.append(np.float64(-1.0), rr + float(r0))
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
            lab = field.labels_flat.take(idx.take(sel))
            step = rigid_from_xy(px.take(sel), py.take(sel), field.wall_x.take(lab), field.wall_y.take(lab))
            cur = step @ cur
            if abs(step[0, 2]) < 0.01 and abs(step[1, 2]) < 0.01 and abs(step[1, 0]) < 1e-4:
                break
    return cur
