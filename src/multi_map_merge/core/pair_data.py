"""One pair's data (steps (1)-(4), :mod:`pair`): each robot's side of a pair as a worker takes it
(:class:`PairInput`: the known crop of its levels, their features), what a worker derives from a
side once per map version (cached per process, :mod:`cache`: its known box and centre, wall
field, walls, wall points, features at another scale), and the pair's result (:class:`PairResult`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np

from . import cache, verify
from .config import MergeConfig
from .features import FeatureExtractor, Features, coarsening
from .grid import known_bbox
from .refine import WALL_FIELD_MARGIN, WallField, occupied_points
from .transforms import se2


@dataclass
class PairResult:
    """One pair's result: the transform between two grids (cells of the child -> cells of the
    parent) and how well it is supported.

    Attributes:
        A: 3x3 rigid matrix, cell coordinates of the child's grid -> of the parent's grid.
        matches: number of matches that passed the ratio test (N_inlier + N_outlier).
        inliers: RANSAC inliers N_inlier.
        inlier_ratio: the paper's reliability, 0..1: inliers among the matches.
        agreement: verification score 0..1: of the occupied cells that land on known cells of
            the other grid, the fraction that meet an occupied cell there (within tolerance)
            rather than a free one.
        overlap: cells known in both grids under ``A``.
        accepted: passed every gate (min inliers, min overlap, min agreement).
        reason: why it was rejected, '' when accepted.
        runner_up: the best clearly different placement that also passed every gate, as
            (agreement, metres, degrees from this one); None when there was none.
        stamp: seconds (time.time()) when the merger received it; 0 until then.
        cov: of an accepted estimate, 3x3 covariance of (x, y, yaw) of the link's pose (the
            child's map frame in the parent's): metres^2 / radians^2, x, y in the parent's
            frame (:mod:`covariance`, with the model error of :mod:`bend` added); None when not
            computed.
        bend: of an accepted estimate, metres two halves of the overlap land apart under their
            own fits (:mod:`bend`); 0 when not measured.
        centre: of an accepted estimate, the centre (x, y) of the child's walls on the parent's
            known cells, metres in the parent's map frame: where the link was fitted, whose
            distance from each map's origin is what the maps drifted on the way (:mod:`drift`);
            None when not computed.
        parent_turn, child_turn: of an accepted estimate, radians each map turned between its
            frame's origin and the overlap, read off its walls' direction (:func:`drift.turn`);
            None where its walls do not tell.
        few_evidence: refused only for too little evidence (fewer than ``few_inliers`` RANSAC
            inliers, agreeing below ``few_inliers_min_agreement``), every other gate passed: a
            link that another such link can corroborate (:mod:`corroborate`).
        tracked: the kept link followed onto new maps (:func:`track_pair`), not a feature
            match: its ``matches``, ``inliers`` and ``inlier_ratio`` are zero.
        pin_deferred: accepted, and its covariance search (with the pose it may correct, and
            ``cov``, ``bend``, ``centre``, the turns) left for later (:func:`pair.pin_later`).
    """

    A: Optional[np.ndarray]
    matches: int = 0
    inliers: int = 0
    inlier_ratio: float = 0.0
    agreement: float = 0.0
    overlap: int = 0
    accepted: bool = False
    reason: str = ''
    runner_up: Optional[Tuple[float, float, float]] = None
    stamp: float = 0.0
    cov: Optional[np.ndarray] = None
    bend: float = 0.0
    centre: Optional[Tuple[float, float]] = None
    few_evidence: bool = False
    parent_turn: Optional[float] = None
    child_turn: Optional[float] = None
    tracked: bool = False
    pin_deferred: bool = False


@dataclass
class PairInput:
    """One robot's side of a pair: the known part of its working-resolution grid's levels and
    their features. ``levels`` is a crop: its cell (c, r) is cell (c + offset[0], r + offset[1])
    of the grid whose ``origin`` is given. (A gmapping canvas is mostly unknown; the crop is
    what is worth sending to a worker process, once per pair.)"""

    name: str
    version: int
    levels: np.ndarray            # uint8 levels (grid.UNKNOWN/FREE/OCCUPIED), OccupancyGrid order
    resolution: float             # metres per cell
    origin: Tuple[float, float, float]   # of the whole grid
    features: Optional[Features]  # positions in the crop's cells; None where only tracked (track_pair)
    owner: str = ''               # the merger it comes from: (owner, name, version) is unique
    offset: Tuple[int, int] = (0, 0)     # (col, row) of the crop's cell (0, 0) in the grid


# Unknown cells kept around the known box in a crop: the wall field looks this far beyond the
# known cells (a wall point landing just outside the parent's map still finds its wall), so a
# pair estimated on crops is the pair estimated on the whole grids.
CROP_MARGIN = WALL_FIELD_MARGIN


def crop_known(levels: np.ndarray, box: Optional[Tuple[int, int, int, int]]) -> Tuple[np.ndarray, Tuple[int, int]]:
    """(levels of ``box`` (rows, cols, half-open; the known cells' box) grown by CROP_MARGIN
    within the grid, its (col, row) offset); the whole grid when nothing is known."""
    if box is None:
        return levels, (0, 0)
    h, w = levels.shape
    r0, r1 = max(0, box[0] - CROP_MARGIN), min(h, box[1] + CROP_MARGIN)
    c0, c1 = max(0, box[2] - CROP_MARGIN), min(w, box[3] + CROP_MARGIN)
    return np.ascontiguousarray(levels[r0:r1, c0:c1]), (c0, r0)


def grid_cells(A: np.ndarray, pa: PairInput, ch: PairInput) -> np.ndarray:
    """A transform between the crops' cells as one between the grids' cells."""
    return se2(pa.offset[0], pa.offset[1], 0.0) @ A @ se2(-ch.offset[0], -ch.offset[1], 0.0)


def crop_cells(A: np.ndarray, pa: PairInput, ch: PairInput) -> np.ndarray:
    """A transform between the grids' cells as one between the crops' cells (:func:`grid_cells`
    undone)."""
    return se2(-pa.offset[0], -pa.offset[1], 0.0) @ A @ se2(ch.offset[0], ch.offset[1], 0.0)


def compute_features(config: MergeConfig, levels: np.ndarray, factor: Optional[int] = None) -> Features:
    """(1) AKAZE features of a grid's levels, with the configured extractor (at ``factor``
    cells per pixel, or the one the map's known area calls for)."""
    key = (config.akaze_threshold, config.max_features, config.feature_cells)
    return cache.extractor(key, FeatureExtractor)(levels, factor)


def describe_version(config: MergeConfig, levels: np.ndarray, owner: str, name: str, version: int) -> Features:
    """(1) features of version ``version`` of robot ``name``'s map (of merger ``owner``), as
    :func:`compute_features`; what this process derived from the map's former versions is
    dropped first: it is stale, and a description is a worker's largest working set (AKAZE's
    scale space), so the two should not be held at once."""
    cache.forget_other_versions(owner, name, version)
    return compute_features(config, levels)


DESCRIBED_AT_MOST = 16   # x feature_cells: the largest image a map is described on to match a finer one


def at_one_scale(config: MergeConfig, pa: PairInput, ch: PairInput) -> Tuple[Features, Features]:
    """The pair's features described at one scale (parent's, child's). A map whose known area
    is large is described on a coarser image (``feature_cells``), and keypoints of images at
    different scales do not match. The coarser map is described again at the finer map's
    factor (cached per process): the other way, a small map pooled by the big one's factor
    keeps too few keypoints ..."""
    coarser = pa if pa.features.factor >= ch.features.factor else ch
    # ... but on an image of at most DESCRIBED_AT_MOST x feature_cells pixels: a whole big
    # building at full resolution would cost a worker seconds and hundreds of MB.
    f = max(min(pa.features.factor, ch.features.factor),
            coarsening(known_of(coarser)[0], DESCRIBED_AT_MOST * config.feature_cells))

    def at(p: PairInput) -> Features:
        if p.features.factor == f:
            return p.features
        return cache.derived('features/%d' % f, p, lambda p: compute_features(config, p.levels, f))
    return at(pa), at(ch)


def known_of(p: PairInput) -> tuple:
    """(known box, known centre) of a map."""
    def make(p):
        box = known_bbox(p.levels)
        return box, known_centre(p.levels, box)
    return cache.derived('known', p, make)


def wall_field_of(p: PairInput) -> WallField:
    """Nearest walls of a map (needed where it is a pair's parent only)."""
    return cache.derived('field', p, lambda p: WallField(p.levels))


def walls_of(p: PairInput, tolerance: int) -> verify.Walls:
    """A map's walls for verification (needed where it is a pair's parent only)."""
    return cache.derived('walls/%d' % tolerance, p, lambda p: verify.Walls.of(p.levels, tolerance))


def wall_points_of(p: PairInput) -> np.ndarray:
    """Wall cells of a map (ICP source points, where it is a pair's child)."""
    return cache.derived('points', p, lambda p: occupied_points(p.levels, known_of(p)[0]))


def known_centre(levels: np.ndarray, box) -> Optional[np.ndarray]:
    """(1, 2) centre (col, row) of a grid's known cells (all inside ``box``, the grid's
    :func:`known_bbox`); None when it has none."""
    if box is None:
        return None
    r0, r1, c0, c1 = box
    # image moments of the known mask: a third of the cost of averaging its cells' indices
    mo = cv2.moments((levels[r0:r1, c0:c1] > 0).view(np.uint8), True)
    if mo['m00'] <= 0:
        return None
    return np.array([[mo['m10'] / mo['m00'] + c0, mo['m01'] / mo['m00'] + r0]])
