"""Step (4) (docs/design.md), beyond the paper: verification of a transform on the grids.

An inlier ratio alone can be high for a confident wrong match on repetitive structure, so a
transform is also scored by how the two grids agree under it: walls landing on walls, not on
free space.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np

from .config import MergeConfig
from .grid import FREE, OCCUPIED, Grid, known_bbox
from .transforms import apply, pose_to_image, se2


@dataclass
class Walls:
    """What verification needs of a grid, derived once per grid (a pair verifies many
    hypotheses against the same parent): boolean (rows, cols) masks over its levels.

    Attributes:
        known: cells known (free or occupied).
        occupied: occupied cells.
        near: cells within ``tolerance`` cells (a square) of an occupied one.
        free_far: free cells farther than that from any occupied one.
    """

    known: np.ndarray
    occupied: np.ndarray
    near: np.ndarray
    free_far: np.ndarray

    @classmethod
    def of(cls, levels: np.ndarray, tolerance: int) -> 'Walls':
        occ = levels == OCCUPIED
        k = np.ones((2 * tolerance + 1, 2 * tolerance + 1), np.uint8)
        near = cv2.dilate(occ.view(np.uint8), k) > 0
        return cls(levels > 0, occ, near, (levels == FREE) & ~near)

    def window(self, r0: int, r1: int, c0: int, c1: int) -> 'Walls':
        return Walls(*(m[r0:r1, c0:c1] for m in (self.known, self.occupied, self.near, self.free_far)))


def agreement(lv_dst: np.ndarray, lv_src: np.ndarray, A: np.ndarray,
              tolerance: int, boxes: Optional[Tuple] = None,
              walls_dst: Optional[Walls] = None) -> Tuple[float, int]:
    """Verification of ``A`` (cells of src -> cells of dst) on the grids themselves.

    Returns (agreement 0..1, overlap in cells). An occupied cell of either grid that lands on
    a known cell of the other agrees if the other has an occupied cell within ``tolerance``
    cells, and counts against ``A`` if it lands on free space there.

    ``boxes``: (known box of dst, known box of src), as :func:`grid.known_bbox` with no
    margin, and ``walls_dst``: ``Walls.of(lv_dst, tolerance)``, when the caller has them (a
    pair scores many hypotheses on the same grids).
    """
    agree, conflict, overlap = agreement_counts(lv_dst, lv_src, A, tolerance, boxes, walls_dst)
    if agree + conflict == 0:
        return 0.0, overlap
    return agree / float(agree + conflict), overlap


def agreement_counts(lv_dst: np.ndarray, lv_src: np.ndarray, A: np.ndarray,
                     tolerance: int, boxes: Optional[Tuple] = None,
                     walls_dst: Optional[Walls] = None) -> Tuple[int, int, int]:
    """:func:`agreement`'s counts: (occupied cells that agree, occupied cells that land on
    free space, overlap in cells); what sums over several overlaps (:mod:`joint`)."""
    box_d, box_s = boxes if boxes is not None else (known_bbox(lv_dst), known_bbox(lv_src))
    if box_d is None or box_s is None:
        return 0, 0, 0
    # Only where src's known box lands (grown by the tolerance, for the dilation) can anything
    # be counted: on partial overlaps that is a small part of dst's box.
    m = tolerance + 1
    sr0, sr1, sc0, sc1 = box_s
    corners = apply(A, np.array([[sc0, sr0], [sc1 - 1, sr0], [sc0, sr1 - 1], [sc1 - 1, sr1 - 1]], np.float64))
    r0 = max(box_d[0] - m, int(math.floor(corners[:, 1].min())) - m, 0)
    r1 = min(box_d[1] + m, int(math.ceil(corners[:, 1].max())) + 1 + m, lv_dst.shape[0])
    c0 = max(box_d[2] - m, int(math.floor(corners[:, 0].min())) - m, 0)
    c1 = min(box_d[3] + m, int(math.ceil(corners[:, 0].max())) + 1 + m, lv_dst.shape[1])
    if r1 <= r0 or c1 <= c0:
        return 0, 0, 0
    shift = se2(-c0, -r0, 0.0)
    M = (shift @ A)[:2]
    warped = cv2.warpAffine(lv_src, M, (c1 - c0, r1 - r0), flags=cv2.INTER_NEAREST,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    # (the window is dst's known box grown by the tolerance and a cell, so dst's walls within
    # it are the same whether derived on the window or on the whole grid)
    ref = walls_dst.window(r0, r1, c0, c1) if walls_dst is not None else Walls.of(lv_dst[r0:r1, c0:c1], tolerance)
    w = Walls.of(warped, tolerance)
    overlap = int(np.count_nonzero(ref.known & w.known))
    if overlap == 0:
        return 0, 0, 0
    agree = np.count_nonzero(ref.occupied & w.near) + np.count_nonzero(w.occupied & ref.near)
    conflict = np.count_nonzero(ref.occupied & w.free_far) + np.count_nonzero(w.occupied & ref.free_far)
    return int(agree), int(conflict), overlap


def pose_on_grids(config: MergeConfig, parent: Grid, child: Grid, T: np.ndarray) -> Tuple[float, int]:
    """:func:`agreement` of a link ``T`` (metres of ``child``'s frame -> ``parent``'s frame) on
    the two grids, classified at the configured thresholds: (agreement 0..1, overlap cells)."""
    A = pose_to_image(T, parent.resolution, parent.origin, child.resolution, child.origin)
    return agreement(parent.levels(config.free_thresh, config.occupied_thresh),
                     child.levels(config.free_thresh, config.occupied_thresh), A, config.agreement_tolerance)
