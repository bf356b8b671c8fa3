"""Step (5) (docs/design.md): warp every placed map into the merged frame and composite them.

The merged canvas is axis-aligned in the merged frame on the reference map's cell lattice, so
the reference is copied without resampling. It grows to cover every merged map (not only the
reference). Where maps overlap, Occupied > Free > Unknown. Maps are warped and composited as
classified OccupancyGrid values (-1 unknown, 0 free, 100 occupied), whose order is that
priority: compositing is an element-wise maximum, and the merged grid is published as it is.

Each map is warped into a *patch* of the lattice covering its known cells only, and the patch
is cached: a robot whose map and pose did not change is not warped again.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

import cv2
import numpy as np

from .grid import Grid
from .transforms import apply, cell_to_metric, inverse, se2


@dataclass
class Patch:
    """A map warped onto the merged lattice: int8 OccupancyGrid values (-1/0/100); values[j, i]
    is lattice cell (i0 + i, j0 + j)."""

    i0: int
    j0: int
    values: np.ndarray


@dataclass
class Lattice:
    """Cells of the merged canvas: cell (i, j) has its centre at
    ``(x0 + (i + 0.5) * res, y0 + (j + 0.5) * res)`` metres in the merged frame."""

    resolution: float
    x0: float
    y0: float

    def key(self) -> Tuple[float, float, float]:
        return (self.resolution, self.x0, self.y0)


def lattice_for(reference: Grid) -> Lattice:
    """The lattice of the reference map's cells (exact when its origin has no yaw)."""
    ox, oy, _ = reference.origin
    return Lattice(reference.resolution, ox, oy)


def warp_patch(known: np.ndarray, box: Tuple[int, int, int, int], resolution: float, origin,
               T_merged_k: np.ndarray, lattice: Lattice, max_cells: int) -> Optional[Patch]:
    """Warp one map's known part onto ``lattice`` by the pose ``T_merged_k`` (metres, frame k ->
    merged frame).

    ``known``: int8 OccupancyGrid values (-1/0/100) of the map's cells in ``box`` (rows r0:r1,
    cols c0:c1 of its grid, half-open: :func:`grid.known_values`); the grid has ``resolution``
    metres per cell and ``origin`` in its frame k.
    Returns None when the patch would exceed ``max_cells``."""
    r0, r1, c0, c1 = box
    W_k = cell_to_metric(resolution, origin)
    cells_to_merged = T_merged_k @ W_k   # cells of k -> metres in the merged frame
    shift = _lattice_shift(cells_to_merged, lattice)
    if shift is not None:
        # The map's cells are lattice cells (the reference, or a map placed at a whole-cell
        # offset with no rotation): no resampling. The patch shares the map's array.
        if (r1 - r0) * (c1 - c0) > max_cells:
            return None
        return Patch(shift[0] + c0, shift[1] + r0, known)
    corners = np.array([[c0 - 0.5, r0 - 0.5], [c1 - 0.5, r0 - 0.5],
                        [c0 - 0.5, r1 - 0.5], [c1 - 0.5, r1 - 0.5]], np.float64)
    m = apply(cells_to_merged, corners)
    res = lattice.resolution
    i0 = int(math.floor((m[:, 0].min() - lattice.x0) / res))
    i1 = int(math.ceil((m[:, 0].max() - lattice.x0) / res))
    j0 = int(math.floor((m[:, 1].min() - lattice.y0) / res))
    j1 = int(math.ceil((m[:, 1].max() - lattice.y0) / res))
    w, h = i1 - i0, j1 - j0
    if w <= 0 or h <= 0 or w * h > max_cells:
        return None
    W_patch = cell_to_metric(res, (lattice.x0 + i0 * res, lattice.y0 + j0 * res, 0.0))
    M = inverse(W_k) @ inverse(T_merged_k) @ W_patch   # patch cells -> cells of k
    M = se2(-c0, -r0, 0.0) @ M
    # warpAffine takes no int8: as uint8, -1 is 255, the border value, so a lattice cell
    # sampled outside the map stays unknown.
    out = cv2.warpAffine(known.view(np.uint8), M[:2], (w, h),
                         flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=255)
    return Patch(i0, j0, out.view(np.int8))


def _lattice_shift(M: np.ndarray, lattice: Lattice) -> Optional[Tuple[int, int]]:
    """(di, dj) when ``M`` (cells of a map -> metres in the merged frame) puts cell (c, r) at
    lattice cell (c + di, r + dj) exactly; None when it rotates, scales or shifts by part of a
    cell."""
    res = lattice.resolution
    L = M / res
    if abs(L[0, 0] - 1) > 1e-9 or abs(L[1, 1] - 1) > 1e-9 or abs(L[0, 1]) > 1e-9 or abs(L[1, 0]) > 1e-9:
        return None
    # cell (0, 0)'s centre lands at lattice coordinates (fi + 0.5, fj + 0.5)
    fi = (M[0, 2] - lattice.x0) / res - 0.5
    fj = (M[1, 2] - lattice.y0) / res - 0.5
    di, dj = round(fi), round(fj)
    if abs(fi - di) > 1e-6 or abs(fj - dj) > 1e-6:
        return None
    return int(di), int(dj)


def composite(patches, lattice: Lattice, frame_id: str, max_cells: int) -> Optional[Grid]:
    """Element-wise maximum of the patches on one canvas covering all of them.

    Returns the merged Grid (OccupancyGrid values -1/0/100) or None without patches."""
    patches = [p for p in patches if p is not None]
    if not patches:
        return None
    i0 = min(p.i0 for p in patches)
    j0 = min(p.j0 for p in patches)
    i1 = max(p.i0 + p.values.shape[1] for p in patches)
    j1 = max(p.j0 + p.values.shape[0] for p in patches)
    if (i1 - i0) * (j1 - j0) > max_cells:
        raise ValueError('merged canvas %dx%d exceeds max_cells %d' % (i1 - i0, j1 - j0, max_cells))
    canvas = np.full((j1 - j0, i1 - i0), -1, np.int8)
    for p in patches:
        h, w = p.values.shape
        view = canvas[p.j0 - j0:p.j0 - j0 + h, p.i0 - i0:p.i0 - i0 + w]
        cv2.max(view, p.values, dst=view)   # in place (a view of the canvas), twice numpy's speed
    res = lattice.resolution
    origin = (lattice.x0 + i0 * res, lattice.y0 + j0 * res, 0.0)
    return Grid(canvas, res, origin, frame_id, 0.0)
