"""How well a link is pinned: a correlative search of the wall likelihood around a link's pose,
pure numpy / OpenCV.

An inlier ratio or a wall agreement of 0.99 says the walls meet; it does not say in which
directions they could slide. Through a corridor the walls pin the pose across it and hardly
along it. This scores the child's wall cells against the parent's walls over a window of
rotations and translations around the link (Olson's correlative scan matching, on the grids):
the cost of a pose is the mean over the child's wall cells of the squared distance (cells,
truncated at ``TRUNCATE``) to the parent's nearest wall, and the pose's likelihood
``exp(-(cost - best cost) / TEMPERATURE)``. The likelihood's moments over the window give the
covariance: wide along a corridor, narrow across it, narrow in both at a corner.

Two resolutions, for speed: a coarse window (``COARSE``: +-12 cells in steps of 2, +-2 degrees
in steps of 1) with a third of the wall cells, then a fine one around its best pose (+-3 cells
in steps of 1, +-0.75 degree in steps of 0.25). The covariance is the fine window's when the
coarse likelihood lies within it, else the coarse one's (a weakly pinned direction).

Frames: perturbations are searched in the parent's cells (a translation, and a turn about the
centre of the child's walls); :func:`metric_covariance` turns them into the covariance of
(x, y, yaw) of the link's pose ``T`` (child's map frame in the parent's map frame: x, y in
metres of the parent's frame, yaw in radians).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import cv2
import numpy as np

from .grid import OCCUPIED, UNKNOWN, known_bbox
from .transforms import cell_to_metric, se2

TRUNCATE = 3.0          # cells: a wall farther than this from any wall costs as much as this
# the likelihood's temperature (cost units: cells^2 of mean squared distance): calibrated on the
# chain and flood-out sweeps of bench/tools/pinning_sweep.py so that the true pose lies within the 95%
# ellipse in at least 95% of links (docs/measurements.md)
TEMPERATURE = 0.05
MAX_POINTS = 800        # wall cells scored (evenly thinned)
MIN_POINTS = 30
# (half-width cells, step cells, half-width degrees, step degrees, share of the points)
COARSE = (12, 2, 2.0, 1.0, 3)
FINE = (3, 1, 0.75, 0.25, 1)
# search(): the coarse window's steps (cells, degrees) and how many of its best poses are
# searched finely
SEARCH_STEP = (2, 0.5)
SEARCH_CANDIDATES = 8
# mean cost (cells^2) by which a pose found by the search must beat the given one to replace it
BETTER_COST = 0.02
# floors of the reported standard deviations (cells, degrees), beside the window's quantisation
# (calibrated with TEMPERATURE)
FLOOR_CELLS = 0.1
FLOOR_DEG = 0.02
# the cost table holds costs as uint16 steps of 1/COST_SCALE cells^2 (TRUNCATE^2 fits in 16 bits):
# half the memory of float32, and summing it is faster; a step is far below TEMPERATURE
COST_SCALE = math.floor(65535 / TRUNCATE ** 2)


@dataclass
class Pinning:
    """Result of :func:`pinning`.

    Attributes:
        A: 3x3 best pose found (cells of the child -> cells of the parent).
        cov: 3x3 covariance of the perturbation (dx, dy in the parent's cells, dyaw radians
            about ``centre``) around the given pose, i.e. second moments about it (so an
            offset of the likelihood's mass from the given pose is counted in).
        cov_best: the same about ``A`` (the best pose).
        centre: (2,) the child's wall centre in the parent's cells (the turns' pivot).
        cost: mean truncated squared distance at the given pose (cells^2).
        cost_best: the same at ``A``.
        points: the child's wall cells scored ((N, 2) col, row in the child's cells).
    """

    A: np.ndarray
    cov: np.ndarray
    cov_best: np.ndarray
    centre: np.ndarray
    cost: float
    cost_best: float
    points: np.ndarray


class CostField:
    """Truncated squared distance to the nearest wall of a grid's levels, over its known box
    padded by the search window (built once per parent grid), in uint16 steps of
    1/``COST_SCALE`` cells^2. ``dist``, ``offset``: the distances to the nearest wall over a
    part of the grid holding its known box and that part's (col, row) offset, when the caller
    has them (:class:`refine.WallField`). ``levels`` is kept by reference (which cells are
    known), not copied."""

    def __init__(self, levels: np.ndarray, dist: Optional[np.ndarray] = None,
                 offset: Tuple[int, int] = (0, 0), pad: int = COARSE[0] + FINE[0] + 4):
        self.levels = levels
        self.ok = dist is not None
        if dist is None:
            box = known_bbox(levels)
            self.ok = box is not None
            if not self.ok:
                return
            r0, r1, c0, c1 = box
            occ = levels[r0:r1, c0:c1] == OCCUPIED
            self.ok = bool(occ.any())
            if not self.ok:
                return
            dist = cv2.distanceTransform(np.where(occ, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)
            offset = (c0, r0)
        cost = np.rint(np.minimum(dist, np.float32(TRUNCATE)) ** 2 * np.float32(COST_SCALE)).astype(np.uint16)
        self.big = int(round(TRUNCATE ** 2 * COST_SCALE))
        self.cost = cv2.copyMakeBorder(cost, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=self.big)
        self.flat = self.cost.ravel()
        self.offset = np.array([offset[0] - pad, offset[1] - pad], np.float64)   # cell (0, 0) of the table

    def flat_index(self, pts: np.ndarray, margin: int) -> Tuple[np.ndarray, np.ndarray]:
        """(flat index of each point's cell, mask of points at least ``margin`` cells inside)."""
        h, w = self.cost.shape
        ix = np.rint(pts[:, 0] - self.offset[0]).astype(np.int64)
        iy = np.rint(pts[:, 1] - self.offset[1]).astype(np.int64)
        ok = (ix >= margin) & (ix < w - margin) & (iy >= margin) & (iy < h - margin)
        return iy * w + ix, ok


def _wall_points(levels: np.ndarray, max_points: int) -> np.ndarray:
    rr, cc = np.nonzero(levels == OCCUPIED)
    pts = np.stack([cc, rr], 1).astype(np.float64)
    if pts.shape[0] > max_points:
        pts = pts[:: int(math.ceil(pts.shape[0] / float(max_points)))]
    return pts


def _search(field: CostField, q: np.ndarray, centre: np.ndarray, half: int, step: int,
            half_deg: float, step_deg: float, around: Tuple[float, float, float]):
    """Mean cost over a window of poses: (costs (n_yaw, n_y, n_x), offsets x, y cells, yaws rad).
    A pose moves point ``q`` (relative to ``centre``) to R(yaw) q + centre + (x, y)."""
    ax, ay, ath = around
    offs = np.arange(-half, half + 1, step, dtype=np.float64)
    xs, ys = offs + round(ax), offs + round(ay)
    yaws = ath + np.radians(np.arange(-half_deg, half_deg + 1e-9, step_deg))
    h, w = field.cost.shape
    dxy = (ys[:, None].astype(np.int64) * w + xs[None, :].astype(np.int64)).ravel()
    out = np.empty((yaws.size, dxy.size))
    reach = int(max(abs(xs).max(), abs(ys).max())) + 1
    for i, th in enumerate(yaws):
        c, s = math.cos(th), math.sin(th)
        p = np.empty_like(q)
        p[:, 0] = c * q[:, 0] - s * q[:, 1] + centre[0]
        p[:, 1] = s * q[:, 0] + c * q[:, 1] + centre[1]
        idx, ok = field.flat_index(p, reach)
        # points that a shift could carry off the table cost the truncation everywhere
        n_out = int(q.shape[0] - ok.sum())
        idx = idx[ok]
        out[i] = field.flat.take(idx[None, :] + dxy[:, None]).sum(axis=1, dtype=np.uint32) + n_out * field.big
    out /= q.shape[0] * COST_SCALE
    return out.reshape(yaws.size, ys.size, xs.size), xs, ys, yaws


def _mode(costs: np.ndarray, xs, ys, yaws) -> Tuple[float, float, float]:
    """The least-cost pose of a window; of equal costs (a corridor), the one nearest the given
    pose."""
    TH, Y, X = np.meshgrid(yaws, ys, xs, indexing='ij')
    k = np.unravel_index(int(np.argmin(costs + 1e-9 * (X ** 2 + Y ** 2 + (TH * 100.0) ** 2))), costs.shape)
    return float(xs[k[2]]), float(ys[k[1]]), float(yaws[k[0]])


def _moments(costs: np.ndarray, xs, ys, yaws, about: Sequence[float]) -> Tuple[np.ndarray, float]:
    """(second moments of the likelihood about ``about`` (x, y cells, yaw rad), its mass
    within ... (the normalised weights' sum: 1))."""
    wgt = np.exp(-(costs - costs.min()) / TEMPERATURE)
    wgt /= wgt.sum()
    TH, Y, X = np.meshgrid(yaws, ys, xs, indexing='ij')
    d = np.stack([X.ravel() - about[0], Y.ravel() - about[1], TH.ravel() - about[2]], 1)
    return (d * wgt.ravel()[:, None]).T @ d, wgt


def pinning(parent_levels: np.ndarray, child_levels: np.ndarray, A: np.ndarray,
            field: Optional[CostField] = None, child_points: Optional[np.ndarray] = None) -> Optional[Pinning]:
    """Correlative search around ``A`` (3x3, cells of the child -> cells of the parent): the
    best pose within the window and the covariance of the pose (see :class:`Pinning`); None
    when too few of the child's walls land on the parent's known cells to say anything.
    ``field`` (``CostField(parent_levels)``) and ``child_points`` (the child's wall cells,
    (N, 2) col, row) when the caller has them cached."""
    field = field if field is not None else CostField(parent_levels)
    if not field.ok:
        return None
    pts = child_points if child_points is not None else _wall_points(child_levels, MAX_POINTS)
    pts, mapped = _seen(field, pts, A)
    if mapped.shape[0] < MIN_POINTS:
        return None
    centre = mapped.mean(axis=0)
    q = mapped - centre
    half, step, hdeg, sdeg, share = COARSE
    qc = q[::share] if q.shape[0] >= share * MIN_POINTS else q
    costs_c, xs, ys, yaws = _search(field, qc, centre, half, step, hdeg, sdeg, (0.0, 0.0, 0.0))
    mode_c = _mode(costs_c, xs, ys, yaws)
    cov_c, wgt_c = _moments(costs_c, xs, ys, yaws, (0.0, 0.0, 0.0))
    half_f, step_f, hdeg_f, sdeg_f, _ = FINE
    costs_f, xf, yf, yawf = _search(field, q, centre, half_f, step_f, hdeg_f, sdeg_f, mode_c)
    best = _mode(costs_f, xf, yf, yawf)
    # the coarse likelihood's mass within the fine window: the fine moments describe it
    TH, Y, X = np.meshgrid(yaws, ys, xs, indexing='ij')
    within = ((np.abs(X - mode_c[0]) <= half_f) & (np.abs(Y - mode_c[1]) <= half_f)
              & (np.abs(TH - mode_c[2]) <= math.radians(hdeg_f) + 1e-9))
    if float(wgt_c[within].sum()) >= 0.9:
        cov, _ = _moments(costs_f, xf, yf, yawf, (0.0, 0.0, 0.0))
        cov_b, _ = _moments(costs_f, xf, yf, yawf, best)
        q_step, q_deg = step_f, sdeg_f
    else:
        cov = cov_c
        cov_b, _ = _moments(costs_c, xs, ys, yaws, best)
        q_step, q_deg = step, sdeg
    # the window's quantisation (a uniform over a step) and the grids' own
    floor = np.diag([q_step ** 2 / 12.0 + FLOOR_CELLS ** 2] * 2
                    + [math.radians(q_deg) ** 2 / 12.0 + math.radians(FLOOR_DEG) ** 2])
    D = se2(best[0], best[1], 0.0) @ se2(centre[0], centre[1], best[2]) @ se2(-centre[0], -centre[1], 0.0)
    cost0 = _search(field, q, centre, 0, 1, 0.0, 1.0, (0.0, 0.0, 0.0))[0].item()
    return Pinning(D @ A, cov + floor, cov_b + floor, centre, cost0, float(costs_f.min()), pts)


def search(field: CostField, child_points: np.ndarray, A: np.ndarray, half_cells: int,
           half_deg: float, pivot: Optional[np.ndarray] = None) -> Optional[Tuple[np.ndarray, float]]:
    """The least-cost pose of the child's walls within a wide window around ``A`` (3x3, cells of
    the child -> cells of the parent): +-``half_cells`` of translation in the parent's cells,
    +-``half_deg`` of turn about ``pivot`` (the child's cells; default the walls' centre);
    coarse (:data:`SEARCH_STEP`, a third of the walls), then :data:`FINE` around the coarse
    window's best poses. Unlike :func:`pinning`
    every wall cell of the child is scored, wherever it lands under ``A`` (``A`` may be a metre
    off: which walls overlap changes across the window); a wall landing on no wall of the
    parent (unknown, free, outside) costs the truncation. Returns (the best pose, its mean
    cost, cells^2), or None when the parent has no walls or the child too few."""
    if not field.ok or child_points.shape[0] < MIN_POINTS:
        return None
    pts = child_points
    if pts.shape[0] > MAX_POINTS:
        pts = pts[:: int(math.ceil(pts.shape[0] / float(MAX_POINTS)))]
    mapped = pts @ A[:2, :2].T + A[:2, 2]
    centre = mapped.mean(axis=0) if pivot is None else A[:2, :2] @ np.asarray(pivot, np.float64) + A[:2, 2]
    q = mapped - centre
    share = COARSE[4]
    qc = q[::share] if q.shape[0] >= share * MIN_POINTS else q
    step, step_deg = SEARCH_STEP
    half = max(step, step * int(math.ceil(half_cells / float(step))))
    costs, xs, ys, yaws = _search(field, qc, centre, half, step, max(step_deg, half_deg), step_deg,
                                  (0.0, 0.0, 0.0))
    half_f, step_f, hdeg_f, sdeg_f, _ = FINE
    best = None
    # the coarse grid can straddle the right pose's basin (walls far from the pivot sweep
    # cells per step of turn) while another pose falls on a grid point: the fine window goes
    # around each of the coarse grid's SEARCH_CANDIDATES best, mutually distinct, poses
    for mode in _best_poses(costs, xs, ys, yaws, SEARCH_CANDIDATES, (half_f, math.radians(hdeg_f))):
        costs_f, xf, yf, yawf = _search(field, q, centre, half_f, step_f, hdeg_f, sdeg_f, mode)
        cost = float(costs_f.min())
        if best is None or cost < best[1]:
            best = (_mode(costs_f, xf, yf, yawf), cost)
    (bx, by, bth), cost = best
    D = se2(bx, by, 0.0) @ se2(centre[0], centre[1], bth) @ se2(-centre[0], -centre[1], 0.0)
    return D @ A, cost


def _best_poses(costs: np.ndarray, xs, ys, yaws, n: int, apart: Tuple[float, float]):
    """Up to ``n`` least-cost poses (x, y cells, yaw rad) of a window, each farther than
    ``apart`` (cells, radians, in x or y or yaw) from every better one."""
    out = []
    for k in np.argsort(costs, axis=None, kind='stable'):
        i, j, m = np.unravel_index(int(k), costs.shape)
        p = (float(xs[m]), float(ys[j]), float(yaws[i]))
        if all(abs(p[0] - o[0]) > apart[0] or abs(p[1] - o[1]) > apart[0] or abs(p[2] - o[2]) > apart[1]
               for o in out):
            out.append(p)
            if len(out) == n:
                break
    return out


def _seen(field: CostField, pts: np.ndarray, A: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """(the child's wall cells (thinned to MAX_POINTS) that land on the parent's known cells
    under ``A``, where they land): only those say anything about the pose."""
    if pts.shape[0] > MAX_POINTS:
        pts = pts[:: int(math.ceil(pts.shape[0] / float(MAX_POINTS)))]
    mapped = pts @ A[:2, :2].T + A[:2, 2]
    ci = np.rint(mapped).astype(np.int64)
    h, w = field.levels.shape
    inside = (ci[:, 0] >= 0) & (ci[:, 0] < w) & (ci[:, 1] >= 0) & (ci[:, 1] < h)
    seen = np.zeros(len(mapped), bool)
    seen[inside] = field.levels[ci[inside, 1], ci[inside, 0]] != UNKNOWN
    return pts[seen], mapped[seen]


def mean_cost(field: CostField, child_points: np.ndarray, A: np.ndarray) -> Optional[float]:
    """:attr:`Pinning.cost` of a pose ``A`` without the search (None where :func:`pinning`
    would say nothing): the mean truncated squared wall distance (cells^2) of the child's wall
    cells that land on the parent's known cells."""
    _, mapped = _seen(field, child_points, A)
    if mapped.shape[0] < MIN_POINTS:
        return None
    centre = mapped.mean(axis=0)
    return _search(field, mapped - centre, centre, 0, 1, 0.0, 1.0, (0.0, 0.0, 0.0))[0].item()


def metric_covariance(cov_cells: np.ndarray, centre: np.ndarray, T: np.ndarray,
                      parent_resolution: float, parent_origin: Sequence[float]) -> np.ndarray:
    """The covariance of a perturbation in the parent's cells (dx, dy cells, dyaw about
    ``centre``, cells) as the covariance of (x, y, yaw) of the pose ``T`` (3x3: metres of the
    child's map frame -> metres of the parent's; x, y metres in the parent's frame, yaw
    radians). A turn about the walls' centre moves the child frame's origin sideways by its
    distance from there."""
    W = cell_to_metric(parent_resolution, parent_origin)
    c = W[:2, :2] @ centre + W[:2, 2]                 # the pivot in metres
    lever = T[:2, 2] - c
    G = np.zeros((3, 3))
    G[:2, :2] = W[:2, :2]                             # cells -> metres (resolution, origin's yaw)
    G[0, 2], G[1, 2] = -lever[1], lever[0]
    G[2, 2] = 1.0
    return G @ cov_cells @ G.T


def position_sigma(cov: np.ndarray) -> float:
    """Standard deviation (metres) along the worst direction of position: the square root of
    the largest eigenvalue of the covariance's x, y block."""
    return float(math.sqrt(max(0.0, float(np.linalg.eigvalsh(cov[:2, :2])[-1]))))
