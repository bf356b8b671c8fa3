"""Occupancy grids as numpy arrays, and their image form.

A :class:`Grid` keeps the cells in OccupancyGrid order: ``data[row, col]`` with row 0 at the
grid's origin (lowest y in the map frame) and columns along +x. We never flip rows inside the
pipeline: feature detection, estimation and compositing all work in this order, so a cell index
maps to metres by a proper rotation (determinant +1) and a rigid image transform is a rigid
metric one. The only row flip is at the edge, when a map_server ``.pgm`` (row 0 = top) is read
or written, and when a picture is drawn for people (see :mod:`multi_map_merge.core.mapio`).

Cell values follow nav_msgs/OccupancyGrid: -1 unknown, 0..100 occupancy probability in percent.
They are classified with two thresholds (percent, as in map_server's ``free_thresh`` and
``occupied_thresh``, default 19.6 and 65):

- ``v < 0``                   -> UNKNOWN
- ``0 <= v <= free_thresh``   -> FREE
- ``v >= occupied_thresh``    -> OCCUPIED
- anything in between         -> UNKNOWN (gmapping's "not sure yet": better not to match on it)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Tuple

import cv2
import numpy as np

# Levels, ordered by compositing priority: Occupied > Free > Unknown, so np.maximum merges.
UNKNOWN = 0
FREE = 1
OCCUPIED = 2

# Image form for features (the paper: occupied black, free white, unknown gray).
IMAGE_VALUES = np.array([127, 255, 0], dtype=np.uint8)  # indexed by level

DEFAULT_FREE_THRESH = 19.6   # percent
DEFAULT_OCC_THRESH = 65.0    # percent


class GridError(ValueError):
    """A grid that cannot be used; the message says why."""


@dataclass
class Grid:
    """One occupancy grid.

    Attributes:
        data: int8 array (height, width), OccupancyGrid values (-1, 0..100), row 0 at the origin.
        resolution: metres per cell.
        origin: (x, y, yaw) of cell (0, 0)'s outer corner in ``frame_id``; metres, radians.
        frame_id: the frame the grid is expressed in, e.g. ``tb3_1/map``.
        stamp: seconds (the message stamp), informational.
    """

    data: np.ndarray
    resolution: float
    origin: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    frame_id: str = ''
    stamp: float = 0.0
    _levels: Optional[np.ndarray] = field(default=None, repr=False, compare=False)
    _box: Optional[tuple] = field(default=None, repr=False, compare=False)
    _known: Optional[tuple] = field(default=None, repr=False, compare=False)

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    def levels(self, free_thresh: float = DEFAULT_FREE_THRESH,
               occ_thresh: float = DEFAULT_OCC_THRESH) -> np.ndarray:
        """uint8 array of UNKNOWN/FREE/OCCUPIED per cell (cached for the default thresholds)."""
        default = free_thresh == DEFAULT_FREE_THRESH and occ_thresh == DEFAULT_OCC_THRESH
        if default and self._levels is not None:
            return self._levels
        lv = classify(self.data, free_thresh, occ_thresh)
        if default:
            self._levels = lv
        return lv


    def known_box(self, free_thresh: float = DEFAULT_FREE_THRESH,
                  occ_thresh: float = DEFAULT_OCC_THRESH) -> Optional[Tuple[int, int, int, int]]:
        """:func:`known_bbox` of the levels, grown by one cell (cached for the default
        thresholds: grids are not modified once made)."""
        if free_thresh != DEFAULT_FREE_THRESH or occ_thresh != DEFAULT_OCC_THRESH:
            return known_bbox(self.levels(free_thresh, occ_thresh), 1)
        if self._box is None:
            self._box = (known_bbox(self.levels(), 1),)
        return self._box[0]

    def known_values(self, free_thresh: float = DEFAULT_FREE_THRESH,
                     occ_thresh: float = DEFAULT_OCC_THRESH) -> Optional[Tuple[Tuple[int, int, int, int], np.ndarray]]:
        """(:meth:`known_box`, :func:`known_values` in it) of the levels; None when nothing is
        known (cached for the default thresholds)."""
        if free_thresh != DEFAULT_FREE_THRESH or occ_thresh != DEFAULT_OCC_THRESH:
            box = self.known_box(free_thresh, occ_thresh)
            return None if box is None else (box, known_values(self.levels(free_thresh, occ_thresh), box))
        if self._known is None:
            box = self.known_box()
            self._known = (None if box is None else (box, known_values(self.levels(), box)),)
        return self._known[0]


def classify(data: np.ndarray, free_thresh: float = DEFAULT_FREE_THRESH,
             occ_thresh: float = DEFAULT_OCC_THRESH) -> np.ndarray:
    """OccupancyGrid values -> levels (see module docstring for the thresholds)."""
    d = data.astype(np.int16, copy=False)
    lv = np.zeros(d.shape, np.uint8)
    lv[(d >= 0) & (d <= free_thresh)] = FREE
    lv[d >= occ_thresh] = OCCUPIED
    return lv


_VALUES_LUT = np.zeros(256, np.uint8)
_VALUES_LUT[:3] = np.array([-1, 0, 100], np.int8).view(np.uint8)


def levels_to_values(levels: np.ndarray) -> np.ndarray:
    """Levels -> OccupancyGrid int8 values: -1 unknown, 0 free, 100 occupied."""
    import cv2  # cv2.LUT is about 10x faster than numpy fancy indexing on big grids
    # A slice of a grid goes in as it is (OpenCV takes its row stride): no copy first.
    strided_ok = levels.dtype == np.uint8 and levels.strides[-1] == 1
    lv = levels if strided_ok else np.ascontiguousarray(levels, np.uint8)
    return cv2.LUT(lv, _VALUES_LUT).view(np.int8).reshape(levels.shape)   # 1-D in: 1-D out


def known_values(levels: np.ndarray, box: Tuple[int, int, int, int]) -> np.ndarray:
    """OccupancyGrid values (contiguous int8: -1 unknown, 0 free, 100 occupied) of the levels in
    ``box`` (rows r0:r1, cols c0:c1, half-open): the part of a map that compositing warps."""
    r0, r1, c0, c1 = box
    return levels_to_values(levels[r0:r1, c0:c1])


_IMAGE_LUT = np.zeros(256, np.uint8)
_IMAGE_LUT[:IMAGE_VALUES.size] = IMAGE_VALUES


def to_image(levels: np.ndarray) -> np.ndarray:
    """Levels -> uint8 image for feature detection: occupied 0, free 255, unknown 127."""
    # (OpenCV's table lookup: a fifth of the cost of numpy's fancy indexing)
    return cv2.LUT(np.ascontiguousarray(levels, np.uint8), _IMAGE_LUT)


def known_bbox(levels: np.ndarray, margin: int = 0) -> Optional[Tuple[int, int, int, int]]:
    """(row0, row1, col0, col1), half-open, of the known cells grown by ``margin`` cells;
    None when nothing is known. gmapping publishes a big canvas that is mostly unknown, and
    the cost of features grows with the image, so work happens inside this box."""
    rows = np.flatnonzero(levels.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(levels.any(axis=0))
    h, w = levels.shape
    return (max(0, int(rows[0]) - margin), min(h, int(rows[-1]) + 1 + margin),
            max(0, int(cols[0]) - margin), min(w, int(cols[-1]) + 1 + margin))


def validate(data: np.ndarray, width: int, height: int, resolution: float,
             origin: Tuple[float, float, float], max_cells: int) -> None:
    """Raise GridError with the reason when a grid cannot be merged.

    Args:
        data: the flat or 2-D cell array as received.
        width, height: cells, as the message declares them.
        resolution: metres per cell.
        origin: (x, y, yaw) metres, radians.
        max_cells: upper bound on width*height (memory guard against absurd sizes).
    """
    if width <= 0 or height <= 0:
        raise GridError('empty grid: width=%d height=%d' % (width, height))
    if width * height > max_cells:
        raise GridError('grid too large: %dx%d = %d cells > max_cells %d'
                        % (width, height, width * height, max_cells))
    if data.size != width * height:
        raise GridError('data length %d != width*height = %d*%d = %d'
                        % (data.size, width, height, width * height))
    if not (isinstance(resolution, (int, float)) and math.isfinite(resolution) and resolution > 0):
        raise GridError('resolution must be a positive finite number of metres, got %r' % (resolution,))
    if not all(math.isfinite(float(v)) for v in origin):
        raise GridError('origin is not finite: %r' % (tuple(origin),))
    if data.size:
        d = data.astype(np.int16, copy=False)
        lo, hi = int(d.min()), int(d.max())
        if lo < -1 or hi > 100:
            raise GridError('cell values outside -1..100 (min %d, max %d)' % (lo, hi))


def make_grid(data, width: int, height: int, resolution: float,
              origin: Tuple[float, float, float], frame_id: str = '', stamp: float = 0.0,
              max_cells: int = 25_000_000) -> Grid:
    """Validate and build a Grid from OccupancyGrid fields (data flat, row-major)."""
    arr = np.asarray(data)
    if arr.dtype != np.int8:
        arr = arr.astype(np.int16)
    validate(arr, int(width), int(height), float(resolution), tuple(origin), max_cells)
    arr = arr.astype(np.int8, copy=False).reshape(int(height), int(width))
    return Grid(arr, float(resolution), tuple(float(v) for v in origin), frame_id, stamp)


def same_grid(a: Grid, b: Grid) -> bool:
    """True when two grids are the same map: geometry (size, resolution, origin), frame and
    every cell."""
    return (a.data.shape == b.data.shape and a.resolution == b.resolution and a.origin == b.origin
            and a.frame_id == b.frame_id and np.array_equal(a.data, b.data))


def rescale(grid: Grid, resolution: float) -> Grid:
    """Resample ``grid`` to ``resolution`` metres per cell (same frame and origin corner).

    Downsampling keeps the highest-priority level in each block (a wall never disappears);
    upsampling repeats cells. Maps of a different resolution are rescaled, not rejected."""
    if abs(grid.resolution - resolution) < 1e-9:
        return grid
    f = grid.resolution / resolution          # new cells per old cell
    lv = grid.levels()
    if f < 1:
        import cv2
        # Max-pool each target cell's block of source cells: the block of target row i starts
        # at source row floor(i / f) (both grids share the origin corner), so the dilation
        # anchored at (0, 0) is sampled at block starts, and the target covers every source
        # cell (ceil), or the first/last rows' walls would vanish and the rest shift a cell.
        h = max(1, int(math.ceil(grid.height * f - 1e-9)))
        w = max(1, int(math.ceil(grid.width * f - 1e-9)))
        rows = np.minimum(np.floor(np.arange(h) / f + 1e-9), grid.height - 1).astype(int)
        cols = np.minimum(np.floor(np.arange(w) / f + 1e-9), grid.width - 1).astype(int)
        k = int(math.ceil(1 / f - 1e-9))
        dil = cv2.dilate(lv, np.ones((k, k), np.uint8), anchor=(0, 0))
        out = dil[rows][:, cols]
    else:
        # upsampling: the source cell containing each target cell's centre
        h = max(1, int(round(grid.height * f)))
        w = max(1, int(round(grid.width * f)))
        rows = np.minimum((np.arange(h) + 0.5) / f, grid.height - 1e-6).astype(int)
        cols = np.minimum((np.arange(w) + 0.5) / f, grid.width - 1e-6).astype(int)
        out = lv[rows][:, cols]
    return Grid(levels_to_values(out), float(resolution), grid.origin, grid.frame_id, grid.stamp)


def apply_update(grid: Grid, x: int, y: int, width: int, height: int, data) -> Grid:
    """A copy of ``grid`` with the rectangle of an OccupancyGridUpdate written in.

    Args:
        x, y: cells, column and row of the rectangle's first cell (OccupancyGrid order).
        width, height: cells.
        data: flat row-major values of the rectangle (-1, 0..100).
    Raises GridError when the rectangle does not fit or the data does not match it.
    """
    arr = np.asarray(data)
    if width < 0 or height < 0 or x < 0 or y < 0 or x + width > grid.width or y + height > grid.height:
        raise GridError('update %dx%d at (%d, %d) does not fit the %dx%d grid'
                        % (width, height, x, y, grid.width, grid.height))
    if arr.size != width * height:
        raise GridError('update data length %d != width*height = %d' % (arr.size, width * height))
    if arr.size:
        d = arr.astype(np.int16, copy=False)
        if int(d.min()) < -1 or int(d.max()) > 100:
            raise GridError('update values outside -1..100')
    out = grid.data.copy()
    out[y:y + height, x:x + width] = arr.astype(np.int8, copy=False).reshape(height, width)
    return Grid(out, grid.resolution, grid.origin, grid.frame_id, grid.stamp)
