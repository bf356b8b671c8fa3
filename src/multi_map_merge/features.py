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

_MARGIN = 40  # cells of unknown around the known box: AKAZE drops keypoints whose
# descriptor window leaves the image, so a tight crop loses the walls at the border (measured:
# 73 features on a tb3_house map with 8 cells, 170 with 40, 181 on the whole 608x384 canvas).


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
        max_features: keep at most this many, the strongest (matching cost grows with the
            product of two maps' feature counts); 0 keeps all.
    """

    def __init__(self, threshold: float = 0.0003, max_features: int = 2000):
        self._akaze = cv2.AKAZE_create(threshold=threshold)
        self._max = int(max_features)

    def __call__(self, levels: np.ndarray) -> Features:
        """Features of a grid given its levels array (see :func:`grid.classify`)."""
        box = known_bbox(levels, 0)
        if box is None:
            return empty_features()
        r0, r1, c0, c1 = box
        h, w = levels.shape
        a0, a1, b0, b1 = max(0, r0 - _MARGIN), min(h, r1 + _MARGIN), max(0, c0 - _MARGIN), min(w, c1 + _MARGIN)
        # where the grid itself ends before the margin, pad with unknown
        img = cv2.copyMakeBorder(to_image(levels[a0:a1, b0:b1]), a0 - (r0 - _MARGIN), (r1 + _MARGIN) - a1,
                                 b0 - (c0 - _MARGIN), (c1 + _MARGIN) - b1, cv2.BORDER_CONSTANT, value=127)
        kps, desc = self._akaze.detectAndCompute(img, None)
        if desc is None or not kps:
            return empty_features()
        if self._max and len(kps) > self._max:
            strongest = np.argsort([-kp.response for kp in kps], kind='stable')[:self._max]
            kps = [kps[i] for i in strongest]
            desc = desc[strongest]
        pts = np.array([kp.pt for kp in kps], np.float32) + np.array([c0 - _MARGIN, r0 - _MARGIN], np.float32)
        return Features(pts, desc, int(np.count_nonzero(levels)))
