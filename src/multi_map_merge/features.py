"""Step 1-2a of the paper: a grid becomes an image, AKAZE finds features in it.

Features are computed on the known part of the grid only (its bounding box plus a margin):
gmapping publishes a large canvas that is mostly unknown, and AKAZE's cost grows with the
image, while unknown space has nothing to find.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .grid import known_bbox, to_image

_MARGIN = 8  # cells around the known box, so features at the border see their surroundings


@dataclass
class Features:
    """AKAZE keypoints of one grid.

    Attributes:
        points: (N, 2) float32 keypoint positions in the grid's cell coordinates (col, row).
        descriptors: (N, 61) uint8 binary AKAZE descriptors (matched with Hamming distance).
        known_cells: number of known cells in the grid (size of what was described).
    """

    points: np.ndarray
    descriptors: np.ndarray
    known_cells: int

    def __len__(self) -> int:
        return int(self.points.shape[0])


def empty_features() -> Features:
    return Features(np.zeros((0, 2), np.float32), np.zeros((0, 61), np.uint8), 0)


class FeatureExtractor:
    """AKAZE on the image form of a grid (occupied black, free white, unknown gray).

    Args:
        threshold: AKAZE detector response threshold; lower finds more (and weaker) features.
        upscale_below_cells: known boxes smaller than this many cells are described at 2x.
    """

    def __init__(self, threshold: float = 0.001, upscale_below_cells: int = 250_000):
        self._akaze = cv2.AKAZE_create(threshold=threshold)
        self._small = int(upscale_below_cells)

    def __call__(self, levels: np.ndarray) -> Features:
        """Features of a grid given its levels array (see :func:`grid.classify`)."""
        box = known_bbox(levels, _MARGIN)
        if box is None:
            return empty_features()
        r0, r1, c0, c1 = box
        img = to_image(levels[r0:r1, c0:c1])
        # A small map (a house at 5 cm) has too few cells for AKAZE's coarser octaves to find
        # enough features; describing it at twice the size recovers them (measured on the AWS
        # small house: 30 of 30 pieces placed instead of 15).
        up = 2 if img.size < self._small else 1
        if up > 1:
            img = cv2.resize(img, None, fx=up, fy=up, interpolation=cv2.INTER_NEAREST)
        kps, desc = self._akaze.detectAndCompute(img, None)
        if desc is None or not kps:
            return empty_features()
        # back to cell centres: pixel p of the upscaled image covers cell (p + 0.5) / up - 0.5
        pts = (np.array([kp.pt for kp in kps], np.float32) + 0.5) / up - 0.5
        pts += np.array([c0, r0], np.float32)
        return Features(pts, desc, int(np.count_nonzero(levels)))
