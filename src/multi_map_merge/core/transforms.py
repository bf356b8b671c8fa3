"""SE(2) maths between grid cells, map frames and the merged frame.

Conventions (used everywhere in the package):

- Homogeneous 3x3 matrices act on column vectors ``[x, y, 1]``.
- *Cell coordinates* of a grid are continuous ``(col, row)`` with the centre of cell
  ``data[r, c]`` at ``(c, r)``: OpenCV's pixel-centre convention, in OccupancyGrid row order
  (row 0 at the origin, no flip; see :mod:`multi_map_merge.core.grid`).
- ``cell_to_metric(resolution, origin)`` (``W``) maps a grid's cell coordinates to metres in its
  ``frame_id``.
- An *image transform* ``A`` maps cell coordinates of one grid to cell coordinates of another
  (here: robot map -> reference map). Estimation produces it.
- A *pose* ``T_ref_k`` is the SE(2) pose of frame k expressed in frame ref: it maps metres in
  frame k to metres in frame ref. This is what tf2 broadcasts as ``ref -> k``
  (parent ``ref``, child ``k``).

Because cell order equals frame order (no flip), ``T_ref_k = W_ref @ A @ inv(W_k)`` is rigid
whenever ``A`` is rigid and both grids share a resolution.
"""
from __future__ import annotations

import math
from typing import Sequence, Tuple

import numpy as np


def se2(x: float, y: float, yaw: float) -> np.ndarray:
    """3x3 homogeneous matrix of a pose: metres, radians."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def xyyaw(T: np.ndarray) -> Tuple[float, float, float]:
    """(x, y, yaw) of a 3x3 rigid matrix: metres, radians in (-pi, pi]."""
    return float(T[0, 2]), float(T[1, 2]), float(math.atan2(T[1, 0], T[0, 0]))


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 affine matrix (last row 0 0 1), in closed form: LAPACK's general
    inverse costs far more for 3x3 (and stalls on a busy machine's BLAS threads)."""
    a, b, c = T[0]
    d, e, f = T[1]
    det = a * e - b * d
    if T[2, 0] != 0.0 or T[2, 1] != 0.0 or T[2, 2] != 1.0 or det == 0.0:
        return np.linalg.inv(T)
    return np.array([[e / det, -b / det, (b * f - c * e) / det],
                     [-d / det, a / det, (c * d - a * f) / det],
                     [0.0, 0.0, 1.0]])


def to3x3(A: np.ndarray) -> np.ndarray:
    """2x3 affine (OpenCV style) -> 3x3 homogeneous."""
    if A.shape == (3, 3):
        return A
    return np.vstack([A, [0.0, 0.0, 1.0]])


def cell_to_metric(resolution: float, origin: Sequence[float]) -> np.ndarray:
    """3x3 matrix: cell coordinates (col, row, centres at integers) -> metres in the grid frame.

    The origin is the pose of cell (0, 0)'s outer corner, so cell (c, r)'s centre lies at
    ``origin ⊕ ((c + 0.5) * res, (r + 0.5) * res)``.
    """
    ox, oy, oyaw = float(origin[0]), float(origin[1]), float(origin[2])
    S = np.array([[resolution, 0.0, 0.5 * resolution],
                  [0.0, resolution, 0.5 * resolution],
                  [0.0, 0.0, 1.0]])
    return se2(ox, oy, oyaw) @ S


def image_to_pose(A: np.ndarray, res_ref: float, origin_ref: Sequence[float],
                  res_k: float, origin_k: Sequence[float]) -> np.ndarray:
    """Image transform (cells of map k -> cells of the reference) -> pose T_ref_k (metres).

    ``res_k`` is the resolution of the grid ``A`` was estimated on (after any rescaling).
    """
    return cell_to_metric(res_ref, origin_ref) @ to3x3(A) @ inverse(cell_to_metric(res_k, origin_k))


def pose_to_image(T_ref_k: np.ndarray, res_ref: float, origin_ref: Sequence[float],
                  res_k: float, origin_k: Sequence[float]) -> np.ndarray:
    """Inverse of :func:`image_to_pose`: 3x3 cells-of-k -> cells-of-ref."""
    return inverse(cell_to_metric(res_ref, origin_ref)) @ T_ref_k @ cell_to_metric(res_k, origin_k)


def rigid_from_points(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Least-squares rigid 3x3 (rotation + translation, det +1) with dst ~ R src + t, for
    (N, 2) point arrays."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    return rigid_from_xy(src[:, 0], src[:, 1], dst[:, 0], dst[:, 1])


def rigid_from_xy(sx: np.ndarray, sy: np.ndarray, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """:func:`rigid_from_points` of points given as coordinate arrays (N,) (src x, y; dst x, y).

    In 2D the best rotation has a closed form (the angle of the cross-covariance), no SVD:
    this runs inside RANSAC and ICP loops hundreds of times per pair, so the sums are dot
    products of 1-D arrays (numpy's column sums of an (N, 2) array cost several times more)."""
    n = sx.shape[0]
    ssx, ssy, sdx, sdy = sx.sum(), sy.sum(), dx.sum(), dy.sum()
    th = math.atan2(*rigid_fit_angle(n, ssx, ssy, sdx, sdy, sx @ dx, sx @ dy, sy @ dx, sy @ dy))
    c, s = math.cos(th), math.sin(th)
    tx, ty = rigid_fit_translation(n, c, s, ssx, ssy, sdx, sdy)
    return np.array([[c, -s, tx], [s, c, ty], [0.0, 0.0, 1.0]])


def rigid_fit_angle(n, ssx, ssy, sdx, sdy, sxdx, sxdy, sydx, sydy):
    """(y, x) whose atan2 is the rotation of the least-squares rigid fit dst ~ R src + t over n
    point pairs, from the sums of src x, y, dst x, y and of the products sx dx, sx dy, sy dx,
    sy dy: the cross-covariance about the means. Scalars, or arrays for many fits at once."""
    kxx = sxdx - ssx * sdx / n
    kxy = sxdy - ssx * sdy / n
    kyx = sydx - ssy * sdx / n
    kyy = sydy - ssy * sdy / n
    return kxy - kyx, kxx + kyy


def rigid_fit_translation(n, c, s, ssx, ssy, sdx, sdy):
    """(tx, ty) of that fit once its rotation (cos ``c``, sin ``s``) is known: the dst mean
    minus the rotated src mean. Scalars or arrays, as :func:`rigid_fit_angle`."""
    msx, msy, mdx, mdy = ssx / n, ssy / n, sdx / n, sdy / n
    return mdx - (c * msx - s * msy), mdy - (s * msx + c * msy)


def apply(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 3x3 transform to an (N, 2) array of points."""
    return pts @ T[:2, :2].T + T[:2, 2]


def pose_distance(T1: np.ndarray, T2: np.ndarray) -> Tuple[float, float]:
    """(translation distance in metres, |yaw difference| in radians) between two poses."""
    x1, y1, a1 = xyyaw(T1)
    x2, y2, a2 = xyyaw(T2)
    return math.hypot(x1 - x2, y1 - y2), abs(float(wrap_angle(a1 - a2)))


def within(T1: np.ndarray, T2: np.ndarray, tolerance: Tuple[float, float]) -> bool:
    """Whether two poses are within ``tolerance`` (metres, radians) of each other: their
    translations at most ``tolerance[0]`` apart and their yaws at most ``tolerance[1]``."""
    d, a = pose_distance(T1, T2)
    return within_tolerance(d, a, tolerance)


def within_tolerance(distance: float, angle: float, tolerance: Tuple[float, float]) -> bool:
    """Whether a ``distance`` (metres) and an ``angle`` (radians, its magnitude) between two
    poses are within ``tolerance`` (metres, radians): :func:`within` once they are measured."""
    return distance <= tolerance[0] and angle <= tolerance[1]


def wrap_angle(a):
    """Angle(s) in radians folded into [-pi, pi) (scalars or arrays)."""
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def turn_between(A: np.ndarray, B: np.ndarray) -> float:
    """|angle| in radians (0..pi) between the rotations of two 3x3 rigid transforms."""
    return abs(float(wrap_angle(math.atan2(A[1, 0], A[0, 0]) - math.atan2(B[1, 0], B[0, 0]))))


# ---- poses as arrays of (x, y, yaw), for trajectories
def compose(p: np.ndarray, d: np.ndarray) -> np.ndarray:
    """p ⊕ d for arrays of (x, y, yaw): d expressed in p's frame."""
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    return np.stack([p[..., 0] + c * d[..., 0] - s * d[..., 1],
                     p[..., 1] + s * d[..., 0] + c * d[..., 1],
                     wrap_angle(p[..., 2] + d[..., 2])], axis=-1)


def relative(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a^-1 ⊕ b: pose b seen from pose a."""
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    dx, dy = b[..., 0] - a[..., 0], b[..., 1] - a[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, wrap_angle(b[..., 2] - a[..., 2])], axis=-1)
