"""Does a map bend across a link's overlap: two halves of the overlap, each fitted on its own.

A link is one rigid pose fitted on a pair's whole overlap, and its covariance
(:mod:`covariance`) says how well the walls pin that pose. A gmapping map bends: its far parts
sit a little turned and shifted against its near parts, so the walls of one half of an overlap
want another pose than the walls of the other half, and a robot placed by the link fits its
partner well near the overlap's centre and worse away from it. Nothing in the walls' own
likelihood says so. Here the child's wall cells that land on the parent's known cells are split
across the overlap's long axis at its median, each half is fitted by ICP from the link's pose
(:func:`refine.refine`), and the pose between the two fits is the *bend*: (dx, dy, dyaw) about
the overlap's centre. Half of it is how far each half's own pose lies from the link's. A map's
far parts lie further from the overlap than the halves' centres, and bend further: the model
error is half the bend scaled by :data:`BEND_SCALE` and by how much further the two maps' walls
spread than the overlap's (``reach``: the root-mean-square distance of every wall cell of both
maps from their centre over that of the overlap's walls, at least 1), in both position axes
alike (how a map bends far from the overlap is not the direction its halves disagree in here)
and in the turn; in the terms of :func:`covariance.pinning`'s covariance (the parent's cells,
turns about the pivot), to which it is added.

The bend's size in metres is how far a wall cell of the overlap lands apart under the two fits
(the largest over the overlap's wall cells): what ``/diagnostics`` reports above
:data:`REPORT_BEND`.

Frames: points are cells (col, row) of the child's grid, poses 3x3 matrices of the child's
cells -> the parent's cells, as in :mod:`pair`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .refine import WallField, refine
from .transforms import apply, inverse

# each half needs this many wall cells for its own fit
MIN_HALF_POINTS = 60
# the overlap's walls must spread this far along its long axis (cells) for halves to differ
MIN_SPREAD_CELLS = 20.0
# ICP's first pairing distance for a half (cells): from the link's pose, a half of a bent overlap lies a few cells off
HALF_GATE = 3.0
# the model error added to a link's covariance: (BEND_SCALE * reach * half the bend)^2
BEND_SCALE = 2.0
# cells two halves of a map that does not bend land apart anyway (their fits on a lattice): only
# a bend beyond it is model error
NOISE_CELLS = 1.0
# a bend (metres, the largest distance between the halves' fits over the overlap) reported on
# /diagnostics from this size
REPORT_BEND = 0.2


@dataclass
class Bend:
    """How two halves of an overlap disagree about the link's pose.

    Attributes:
        d: (3,) the pose from one half's fit to the other's: dx, dy (parent's cells), dyaw
            (radians) about ``centre``.
        centre: (2,) the pivot of the turn, in the parent's cells.
        metres: the largest distance (m) a wall cell of the overlap lands apart under the two
            halves' fits.
        cells: the same in the parent's cells.
        reach: how much further the two maps' walls spread than the overlap's (>= 1).
    """

    d: np.ndarray
    centre: np.ndarray
    metres: float
    cells: float
    reach: float = 1.0

    def cov_cells(self) -> np.ndarray:
        """The model error's covariance (3x3 of dx, dy cells, dyaw radians about ``centre``):
        of the bend beyond :data:`NOISE_CELLS`, in position and turn alike."""
        beyond = max(0.0, 1.0 - NOISE_CELLS / self.cells) if self.cells > 0 else 0.0
        k = BEND_SCALE * self.reach * 0.5 * beyond
        return np.diag([(k * self.cells) ** 2] * 2 + [(k * self.d[2]) ** 2])


def rms_spread(points: np.ndarray) -> float:
    """Root-mean-square distance of ``points`` ((N, 2)) from their centre (their units)."""
    if points.shape[0] == 0:
        return 0.0
    return float(np.sqrt(((points - points.mean(axis=0)) ** 2).sum(axis=1).mean()))


def across_halves(field: WallField, child_points: np.ndarray, A: np.ndarray, resolution: float,
                  pivot: Optional[np.ndarray] = None, spread_cells: float = 0.0) -> Optional[Bend]:
    """The bend of the link ``A`` (child's cells -> parent's cells) over the child's wall cells
    ``child_points`` ((N, 2) col, row) that land on the parent's known cells; ``field``: the
    parent's walls, ``resolution``: metres per cell, ``pivot``: the parent's cell the turn is
    taken about (default: the overlap's wall centre under ``A``), ``spread_cells``: how far the
    two maps' walls spread (:func:`rms_spread`, cells; 0: as far as the overlap's). None when the
    overlap is too small or too narrow to split, or a half does not fit (too few of its walls
    pair up)."""
    if child_points.shape[0] < 2 * MIN_HALF_POINTS:
        return None
    mapped = apply(A, child_points)
    centre = mapped.mean(axis=0) if pivot is None else np.asarray(pivot, np.float64)
    q = mapped - mapped.mean(axis=0)
    # the long axis of the overlap's walls: the principal direction of their spread
    _, _, vt = np.linalg.svd(q, full_matrices=False)
    along = q @ vt[0]
    if float(along.max() - along.min()) < MIN_SPREAD_CELLS:
        return None
    cut = float(np.median(along))
    fits = []
    for half in (along <= cut, along > cut):
        if int(half.sum()) < MIN_HALF_POINTS:
            return None
        A_half = refine(field, child_points[half], A, max_distance=HALF_GATE)
        if A_half is None:
            return None
        fits.append(A_half)
    D = fits[1] @ inverse(fits[0])
    d = np.array([*(apply(D, centre[None, :])[0] - centre), math.atan2(D[1, 0], D[0, 0])])
    apart = float(np.hypot(*(apply(fits[1], child_points) - apply(fits[0], child_points)).T).max())
    reach = max(1.0, spread_cells / max(rms_spread(mapped), 1.0))
    return Bend(d, centre, apart * resolution, apart, reach)
