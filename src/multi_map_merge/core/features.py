"""Step (1) (docs/design.md): a grid becomes an image, AKAZE finds features in it.

Features are computed on the known part of the grid only (its bounding box plus a margin):
gmapping publishes a large canvas that is mostly unknown, and AKAZE's cost grows with the
image, while unknown space has nothing to find.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np

from .grid import UNKNOWN, known_bbox, to_image

_MARGIN = 32  # cells of unknown around the known box: AKAZE drops keypoints whose
# descriptor window leaves the image, so a tight crop loses the walls at the border.


@dataclass
class Features:
    """AKAZE keypoints of one grid.

    Attributes:
        points: (N, 2) float32 keypoint positions in the grid's cell coordinates (col, row).
        descriptors: (N, 61) uint8 binary AKAZE descriptors (matched with Hamming distance).
        known_cells: number of known cells in the grid (size of what was described).
        factor: the image described had one pixel per ``factor`` x ``factor`` cells.
    """

    points: np.ndarray
    descriptors: np.ndarray
    known_cells: int
    factor: int = 1

    def __len__(self) -> int:
        return int(self.points.shape[0])


def empty_features() -> Features:
    return Features(np.zeros((0, 2), np.float32), np.zeros((0, 61), np.uint8), 0)


class FeatureExtractor:
    """AKAZE on the image form of a grid (occupied black, free white, unknown gray).

    Args:
        threshold: AKAZE detector response threshold; lower finds more (and weaker) features.
        max_features: keep at most this many, the strongest (matching cost grows with the
            product of two maps' feature counts); 0 keeps all.
        detect_cells: a known area larger than this many cells is described on a coarser
            image (integer factor, max-pooled so walls survive); 0 never coarsens. AKAZE's
            cost grows with the image, and the grid refinement after RANSAC restores the
            full resolution's precision.
    """

    def __init__(self, threshold: float = 0.0003, max_features: int = 2000,
                 detect_cells: int = 0):
        # Two octaves, not OpenCV's four: on occupancy images the coarser octaves (blobs of
        # 6-13 cells) yield next to no keypoint at this threshold, and building them costs
        # time. (Fewer layers per octave would save more but lose features small maps need.)
        self._akaze = cv2.AKAZE_create(threshold=threshold, nOctaves=2)
        self._max = int(max_features)
        self._cells = int(detect_cells)

    def __call__(self, levels: np.ndarray, factor: Optional[int] = None) -> Features:
        """Features of a grid given its levels array (see :func:`grid.classify`), described
        at ``factor`` cells per pixel, or at the factor its known area calls for."""
        box = known_bbox(levels, 0)
        if box is None:
            return empty_features()
        r0, r1, c0, c1 = box
        h, w = levels.shape
        # The window described: the known box and a margin, padded with unknown where the
        # grid ends first. It is set by the known cells alone, not by the array's extent, so
        # a map's crop and its whole canvas give the same features (and pool alike).
        A0, A1, B0, B1 = r0 - _MARGIN, r1 + _MARGIN, c0 - _MARGIN, c1 + _MARGIN
        a0, a1, b0, b1 = max(0, A0), min(h, A1), max(0, B0), min(w, B1)
        lv = levels[a0:a1, b0:b1]
        if (a0, a1, b0, b1) != (A0, A1, B0, B1):
            lv = cv2.copyMakeBorder(lv, a0 - A0, A1 - a1, b0 - B0, B1 - b1, cv2.BORDER_CONSTANT, value=UNKNOWN)
        f = self.factor(box) if factor is None else int(factor)
        if f > 1:
            lv = _maxpool(lv, f)
        img = to_image(lv)
        kps, desc = self._akaze.detectAndCompute(img, None)
        if desc is None or not kps:
            return empty_features()
        if self._max and len(kps) > self._max:
            strongest = np.argsort([-kp.response for kp in kps], kind='stable')[:self._max]
            kps = [kps[i] for i in strongest]
            desc = desc[strongest]
        pts = np.array([kp.pt for kp in kps], np.float32)
        pts = (pts + 0.5) * f - 0.5                          # pooled pixel -> cell centres
        pts += np.array([B0, A0], np.float32)                # window -> grid cells
        return Features(pts, desc, int(np.count_nonzero(levels)), f)

    def factor(self, box: Tuple[int, int, int, int]) -> int:
        """Cells per pixel of the image a known box (rows, cols, half-open) is described on."""
        return coarsening(box, self._cells)


def coarsening(box: Optional[Tuple[int, int, int, int]], cells: int) -> int:
    """The integer factor that brings a box (rows, cols, half-open) under ``cells`` pixels;
    1 when it is under already, when ``cells`` is 0 or there is no box."""
    if box is None or not cells:
        return 1
    area = (box[1] - box[0]) * (box[3] - box[2])
    return int(np.ceil(np.sqrt(area / float(cells)))) if area > cells else 1


def _maxpool(levels: np.ndarray, f: int) -> np.ndarray:
    """Levels pooled by an integer factor, keeping the highest level (a wall wins a block)."""
    h, w = levels.shape
    H, W = -(-h // f), -(-w // f)
    padded = np.zeros((H * f, W * f), levels.dtype)
    padded[:h, :w] = levels
    # the rows of each block, then its columns, by elementwise maxima of strided views: numpy
    # reduces a (H, f, W, f) view over axes (1, 3) element by element, 30x slower
    rows = padded[0::f].copy()
    for k in range(1, f):
        np.maximum(rows, padded[k::f], out=rows)
    pooled = rows[:, 0::f].copy()
    for k in range(1, f):
        np.maximum(pooled, rows[:, k::f], out=pooled)
    return pooled
