"""Step (5) past rigid (docs/design.md): every placed map bent, a little, onto the walls the other maps
give it, in the merged map only.

A gmapping map bends: its far parts sit shifted and turned against the frame it is drawn in
(:mod:`drift`), so no rigid placement fits it everywhere, and where two robots' maps meet far
from where they were fitted their walls stand side by side. Here each placed map carries a
coarse grid of *nodes* (``spacing`` metres apart in its own map frame) and one rigid motion of
the whole map. Each node has a small correction (x, y in metres of the merged frame, yaw in
radians about the node); a point of the map moves by the bilinear blend of its four nodes'
corrections, a smooth field with no seams. The corrections and the maps' rigid motions minimise,
all maps at once, over a few rounds of ICP with a shrinking gate (:data:`GATES`):

- **pull**: every wall point of a map within the gate of another map's wall, along that
  wall's normal where it is a line (walls may slide along each other), else point to point;
- **stiffness**: two neighbouring nodes of one map move alike, as far as the map's own drift
  allows over the distance ``d`` between them (``drift * d`` per axis, ``drift_yaw *
  sqrt(d)`` in the heading: :mod:`drift`'s model);
- **shape**: a node moves with its map's rigid motion, the more loosely the farther it lies
  from its map's origin (where the robot started and the map is right by construction:
  ``drift * L``, ``drift_yaw * sqrt(L)``);
- **placement**: a map's rigid motion stays within :data:`PLACEMENT_SIGMA` of its placement;
  the reference map's stays at none (the merged frame is its map frame).

A rigid motion of a whole map costs no stiffness; a place one map alone saw follows its
neighbouring nodes. The placements (and so TF) stay rigid: the fields change the merged grid
only. A map that pairs with no other map keeps no field.

Frames: a map's points in its own map frame (metres) give the blend weights; corrections, the
pull and a field's displacement are in the merged frame (metres, radians) at the rigid placement
``T`` (3x3, map frame -> merged frame).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Iterable, List, Optional, Tuple

import cv2
import numpy as np

from .composite import Lattice, Patch
from .grid import OCCUPIED
from .transforms import apply, cell_to_metric, inverse

# ICP rounds' pairing gates (metres): wide first to bring bent walls within reach, then ones
# that keep only walls that nearly coincide
GATES = (0.5, 0.4, 0.3, 0.25, 0.2, 0.15, 0.12, 0.1, 0.1, 0.1)
# a wall point's position is known to about a cell; neighbouring wall cells of one wall share
# their error, so each pair counts as this fraction of an independent measurement
POINT_SIGMA = 0.05                            # m
POINT_SHARE = 0.1
# how far a map's rigid motion may stray from its placement (1 sigma): the placement's own
# uncertainty, loosely
PLACEMENT_SIGMA = (0.3, math.radians(3.0))    # m, rad
# the shape term's floor (1 sigma) at a map's origin
SHAPE_FLOOR = (0.01, math.radians(0.1))       # m, rad
# wall points per map used (evenly thinned)
MAX_POINTS = 6000
# neighbours a wall point's normal is fitted on, and how line-like they must be (smaller
# spread over larger) for a pair to pull along the normal only
NORMAL_K = 8
LINE_RATIO = 0.2
# pairs a map needs with the other maps for it to get a field
MIN_PAIRS = 50
# a solution that moves any node further than this (metres) is not a bend but a failure (walls
# paired with the wrong walls): no field at all then
MAX_CORRECTION = 1.0
# a map bent this far (metres, its largest node move) or more is named in its status message
REPORT_BENT = 0.2
# the inverse warp is computed every this many lattice cells and interpolated between (the field
# is smooth over a node spacing, tens of cells)
WARP_STEP = 4


@dataclass
class NodeGrid:
    """A map's nodes: ``ny`` x ``nx`` points ``spacing`` metres apart in its map frame, the
    first at ``(x0, y0)``; node (j, i) is number ``j * nx + i``."""

    x0: float
    y0: float
    spacing: float
    nx: int
    ny: int

    @property
    def count(self) -> int:
        return self.nx * self.ny

    def positions(self) -> np.ndarray:
        """(count, 2) node positions in the map frame (metres)."""
        ii, jj = np.meshgrid(np.arange(self.nx), np.arange(self.ny))
        return np.stack([self.x0 + ii.ravel() * self.spacing, self.y0 + jj.ravel() * self.spacing], axis=1)

    def weights(self, pts: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """For (N, 2) points of the map frame: (N, 4) node numbers and (N, 4) bilinear
        weights (a point beyond the grid takes the weights of the border, clipped)."""
        u = np.clip((pts[:, 0] - self.x0) / self.spacing, 0.0, max(self.nx - 1, 0))
        v = np.clip((pts[:, 1] - self.y0) / self.spacing, 0.0, max(self.ny - 1, 0))
        i = np.minimum(np.floor(u).astype(np.int64), max(self.nx - 2, 0))
        j = np.minimum(np.floor(v).astype(np.int64), max(self.ny - 2, 0))
        fu, fv = u - i, v - j
        i1 = np.minimum(i + 1, self.nx - 1)
        j1 = np.minimum(j + 1, self.ny - 1)
        idx = np.stack([j * self.nx + i, j * self.nx + i1, j1 * self.nx + i, j1 * self.nx + i1], axis=1)
        w = np.stack([(1 - fu) * (1 - fv), fu * (1 - fv), (1 - fu) * fv, fu * fv], axis=1)
        return idx, w


def node_grid(pts: np.ndarray, spacing: float) -> NodeGrid:
    """Nodes ``spacing`` metres apart covering the (N, 2) points (metres, map frame), centred
    on their box."""
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    nx = int(math.ceil((hi[0] - lo[0]) / spacing)) + 1
    ny = int(math.ceil((hi[1] - lo[1]) / spacing)) + 1
    x0 = 0.5 * (lo[0] + hi[0]) - 0.5 * (nx - 1) * spacing
    y0 = 0.5 * (lo[1] + hi[1]) - 0.5 * (ny - 1) * spacing
    return NodeGrid(float(x0), float(y0), float(spacing), nx, ny)


@dataclass
class Field:
    """One map's correction field: its nodes, the rigid placement ``T`` it is about (3x3, map
    frame -> merged frame), the nodes' positions in the merged frame at ``T`` and, per node,
    its correction (x m, y m, yaw rad; merged frame, about the node)."""

    nodes: NodeGrid
    T: np.ndarray
    centres: np.ndarray         # (count, 2)
    corrections: np.ndarray     # (count, 3)

    def displacement(self, pts_map: np.ndarray) -> np.ndarray:
        """(N, 2) metres (merged frame) by which points of the map frame move, on top of ``T``."""
        idx, w = self.nodes.weights(pts_map)
        rel = apply(self.T, pts_map)[:, None, :] - self.centres[idx]     # (N, 4, 2)
        c = self.corrections[idx]                                         # (N, 4, 3)
        dx = c[..., 0] - c[..., 2] * rel[..., 1]
        dy = c[..., 1] + c[..., 2] * rel[..., 0]
        return np.stack([(w * dx).sum(axis=1), (w * dy).sum(axis=1)], axis=1)

    def largest(self) -> float:
        """The largest node translation (metres)."""
        return float(np.hypot(self.corrections[:, 0], self.corrections[:, 1]).max(initial=0.0))

    def reach(self) -> float:
        """A bound (metres) on how far any point within a node spacing of its nodes moves."""
        turn = float(np.abs(self.corrections[:, 2]).max(initial=0.0))
        return self.largest() + turn * self.nodes.spacing * 1.5


def wall_points(levels: np.ndarray, resolution: float, origin) -> np.ndarray:
    """(N, 2) metres in the map frame of a grid's occupied cells (``levels``: Grid.levels)."""
    rr, cc = np.nonzero(levels == OCCUPIED)
    cells = np.stack([cc, rr], axis=1).astype(np.float64)
    return apply(cell_to_metric(resolution, origin), cells)


def _normals(pts: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Unit normals (N, 2) of the walls through each point (the spread of its NORMAL_K nearest
    points) and whether that neighbourhood is line-like."""
    k = min(NORMAL_K, pts.shape[0])
    from scipy.spatial import cKDTree
    _, nb = cKDTree(pts).query(pts, k=k)
    d = pts[nb] - pts[nb].mean(axis=1, keepdims=True)       # (N, k, 2)
    cxx = (d[..., 0] ** 2).mean(axis=1)
    cyy = (d[..., 1] ** 2).mean(axis=1)
    cxy = (d[..., 0] * d[..., 1]).mean(axis=1)
    half = np.sqrt(((cxx - cyy) * 0.5) ** 2 + cxy ** 2)
    big, small = 0.5 * (cxx + cyy) + half, 0.5 * (cxx + cyy) - half
    along = 0.5 * np.arctan2(2 * cxy, cxx - cyy)             # the wall's direction
    normal = np.stack([-np.sin(along), np.cos(along)], axis=1)
    return normal, small <= LINE_RATIO * np.maximum(big, 1e-12)


class _Rows:
    """Rows of a sparse whitened linear system, one residual each."""

    def __init__(self) -> None:
        self.rows: List[int] = []
        self.cols: List[int] = []
        self.vals: List[float] = []
        self.n = 0

    def add(self, entries: Iterable[Tuple[int, float]], inv_sigma: float) -> None:
        for c, v in entries:
            self.rows.append(self.n)
            self.cols.append(c)
            self.vals.append(v * inv_sigma)
        self.n += 1

    def matrix(self, nvar: int):
        """The rows as a scipy.sparse CSR matrix of ``nvar`` columns."""
        from scipy import sparse
        return sparse.csr_matrix((self.vals, (self.rows, self.cols)), shape=(self.n, nvar))


def fit_fields(walls: Dict[str, np.ndarray], poses: Dict[str, np.ndarray], reference: str,
               spacing: float, drift: float, drift_yaw: float,
               fixed: Iterable[str] = ()) -> Dict[str, Field]:
    """The correction field of every placed map that pairs with another.

    ``walls``: per map, (N, 2) wall points in its map frame (metres); ``poses``: its placement
    (3x3, map frame -> merged frame); ``reference``: the map whose rigid motion is none;
    ``spacing``: metres between nodes; ``drift``: metres off per metre from a map's origin,
    ``drift_yaw``: radians per square root of a metre (1 sigma, :mod:`drift`); ``fixed``: maps
    held exactly where they are (no motion, no bend). Deterministic. Returns {} when fewer than
    two maps have walls, or when the solution fails (MAX_CORRECTION)."""
    names = [n for n in sorted(walls) if n in poses and walls[n].shape[0] >= NORMAL_K]
    if len(names) < 2 or not spacing > 0:
        return {}
    # (scipy is imported only where maps are bent: the node that does not bend never pays its memory)
    from scipy import sparse
    from scipy.sparse.linalg import spsolve
    from scipy.spatial import cKDTree
    fixed = set(fixed)
    pts_map, pts0, normals, lines, grids, widx, wts, base = {}, {}, {}, {}, {}, {}, {}, {}
    total = 0
    for n in names:
        p = walls[n]
        if p.shape[0] > MAX_POINTS:
            p = p[:: int(math.ceil(p.shape[0] / MAX_POINTS))]
        pts_map[n] = p
        pts0[n] = apply(poses[n], p)
        nrm, lines[n] = _normals(p)
        normals[n] = nrm @ poses[n][:2, :2].T
        grids[n] = node_grid(p, spacing)
        widx[n], wts[n] = grids[n].weights(p)
        base[n] = 3 * total
        total += grids[n].count
    centres = {n: apply(poses[n], grids[n].positions()) for n in names}
    motion = {n: 3 * total + 3 * i for i, n in enumerate(names)}    # the maps' rigid motions
    nvar = 3 * total + 3 * len(names)

    # --- the fixed terms: stiffness, shape, placement
    fx = _Rows()
    tight = (1e-4, 1e-6)
    for n in names:
        g, b, C = grids[n], base[n], centres[n]
        origin = poses[n][:2, 2]
        for k, far in enumerate(np.hypot(*g.positions().T)):
            s_xy = tight[0] if n in fixed else max(drift * far, SHAPE_FLOOR[0])
            s_yaw = tight[1] if n in fixed else max(drift_yaw * math.sqrt(far), SHAPE_FLOOR[1])
            m, r = motion[n], C[k] - origin
            a = b + 3 * k
            # node correction - the map's rigid motion (about its origin) at the node
            fx.add([(a, 1.0), (m, -1.0), (m + 2, r[1])], 1.0 / s_xy)
            fx.add([(a + 1, 1.0), (m + 1, -1.0), (m + 2, -r[0])], 1.0 / s_xy)
            fx.add([(a + 2, 1.0), (m + 2, -1.0)], 1.0 / s_yaw)
        s_xy, s_yaw = tight if (n == reference or n in fixed) else PLACEMENT_SIGMA
        fx.add([(motion[n], 1.0)], 1.0 / s_xy)
        fx.add([(motion[n] + 1, 1.0)], 1.0 / s_xy)
        fx.add([(motion[n] + 2, 1.0)], 1.0 / s_yaw)
        d = g.spacing
        s_xy, s_yaw = max(drift * d, 1e-3), max(drift_yaw * math.sqrt(d), 1e-4)
        for k in range(g.count):
            i, j = k % g.nx, k // g.nx
            for k2 in ([k + 1] if i + 1 < g.nx else []) + ([k + g.nx] if j + 1 < g.ny else []):
                a, a2 = b + 3 * k, b + 3 * k2
                mid = 0.5 * (C[k] + C[k2])
                ra, rb = mid - C[k], mid - C[k2]
                # the two nodes' motions of their midpoint agree, and their turns
                fx.add([(a, 1.0), (a + 2, -ra[1]), (a2, -1.0), (a2 + 2, rb[1])], 1.0 / s_xy)
                fx.add([(a + 1, 1.0), (a + 2, ra[0]), (a2 + 1, -1.0), (a2 + 2, -rb[0])], 1.0 / s_xy)
                fx.add([(a + 2, 1.0), (a2 + 2, -1.0)], 1.0 / s_yaw)
    A = fx.matrix(nvar)
    H_fixed = (A.T @ A).tocsc()

    def field_of(n: str, u: np.ndarray) -> Field:
        return Field(grids[n], poses[n], centres[n], u[base[n]:base[n] + 3 * grids[n].count].reshape(-1, 3))

    w_pair = POINT_SHARE / POINT_SIGMA ** 2
    u = np.zeros(nvar)
    pairs = {n: 0 for n in names}
    for gate in GATES:
        cur = {n: pts0[n] + field_of(n, u).displacement(pts_map[n]) for n in names}
        J_rows, J_cols, J_vals, res = [], [], [], []
        npair = 0
        for ai, a in enumerate(names):
            others = names[:ai] + names[ai + 1:]
            dist, nn = cKDTree(np.concatenate([cur[o] for o in others])).query(cur[a], k=1,
                                                                               distance_upper_bound=gate)
            src = np.flatnonzero(np.isfinite(dist))
            pairs[a] = max(pairs[a], int(src.size))
            owner = np.concatenate([np.full(cur[o].shape[0], i) for i, o in enumerate(others)])
            local = np.concatenate([np.arange(cur[o].shape[0]) for o in others])
            for oi, o in enumerate(others):
                sel = owner[nn[src]] == oi
                if not sel.any():
                    continue
                pa, pb = src[sel], local[nn[src[sel]]]
                diff = cur[a][pa] - cur[o][pb]
                line = lines[o][pb]
                # point to line where the other's wall is a line (one row), else x and y
                for dvec, use in ((normals[o][pb], line), (np.array([1.0, 0.0]), ~line),
                                  (np.array([0.0, 1.0]), ~line)):
                    rows = np.flatnonzero(use)
                    if rows.size == 0:
                        continue
                    dv = np.broadcast_to(dvec, diff.shape)[rows]
                    res.append((diff[rows] * dv).sum(axis=1))
                    rr = npair + np.arange(rows.size)
                    for name, idxs, sign in ((a, pa[rows], 1.0), (o, pb[rows], -1.0)):
                        nidx, w = widx[name][idxs], wts[name][idxs]
                        rel = cur[name][idxs][:, None, :] - centres[name][nidx]
                        col = base[name] + 3 * nidx
                        for q in range(4):
                            J_rows += [rr, rr, rr]
                            J_cols += [col[:, q], col[:, q] + 1, col[:, q] + 2]
                            J_vals += [sign * w[:, q] * dv[:, 0], sign * w[:, q] * dv[:, 1],
                                       sign * w[:, q] * (rel[:, q, 0] * dv[:, 1] - rel[:, q, 1] * dv[:, 0])]
                    npair += rows.size
        if npair < MIN_PAIRS:
            break
        J = sparse.csr_matrix((np.concatenate(J_vals), (np.concatenate(J_rows), np.concatenate(J_cols))),
                              shape=(npair, nvar))
        # minimise |A (u + du)|^2 + w_pair |r + J du|^2 over du
        H = H_fixed + w_pair * (J.T @ J)
        g = -(H_fixed @ u) - w_pair * (J.T @ np.concatenate(res))
        du = spsolve(H.tocsc(), g)
        if not np.all(np.isfinite(du)):
            return {}
        u = u + du
    out = {}
    for n in names:
        if n in fixed or pairs[n] < MIN_PAIRS:
            continue
        f = field_of(n, u)
        f = Field(f.nodes, f.T, f.centres, f.corrections.copy())
        if f.largest() > MAX_CORRECTION:
            return {}
        out[n] = f
    return out


def warp_field_patch(known: np.ndarray, box: Tuple[int, int, int, int], resolution: float, origin,
                     field: Field, lattice: Lattice, max_cells: int) -> Optional[Patch]:
    """:func:`composite.warp_patch` through a correction field: each lattice cell takes the map
    cell that the placement plus the field puts there (the field inverted by two fixed-point
    steps, computed every WARP_STEP cells and interpolated between). Returns None when the
    patch would exceed ``max_cells``."""
    r0, r1, c0, c1 = box
    W_k = cell_to_metric(resolution, origin)
    T = field.T
    corners = np.array([[c0 - 0.5, r0 - 0.5], [c1 - 0.5, r0 - 0.5],
                        [c0 - 0.5, r1 - 0.5], [c1 - 0.5, r1 - 0.5]], np.float64)
    m = apply(T @ W_k, corners)
    margin = field.reach() + resolution
    res = lattice.resolution
    i0 = int(math.floor((m[:, 0].min() - margin - lattice.x0) / res))
    i1 = int(math.ceil((m[:, 0].max() + margin - lattice.x0) / res))
    j0 = int(math.floor((m[:, 1].min() - margin - lattice.y0) / res))
    j1 = int(math.ceil((m[:, 1].max() + margin - lattice.y0) / res))
    w, h = i1 - i0, j1 - j0
    if w <= 0 or h <= 0 or w * h > max_cells:
        return None
    # the inverse map on a coarse lattice (every WARP_STEP cells, both ends included)
    ws, hs = (w - 1) // WARP_STEP + 2, (h - 1) // WARP_STEP + 2
    ii, jj = np.meshgrid(np.arange(ws) * float(WARP_STEP), np.arange(hs) * float(WARP_STEP))
    q = np.stack([lattice.x0 + (i0 + ii.ravel() + 0.5) * res, lattice.y0 + (j0 + jj.ravel() + 0.5) * res], axis=1)
    Tinv = inverse(T)
    p = apply(Tinv, q)
    for _ in range(2):
        p = apply(Tinv, q - field.displacement(p))
    cells = apply(inverse(W_k), p)
    # bilinear between the coarse points (exact for the affine part; the rest is smooth)
    fine_x = np.broadcast_to(np.arange(w, dtype=np.float32) / WARP_STEP, (h, w))
    fine_y = np.broadcast_to((np.arange(h, dtype=np.float32) / WARP_STEP)[:, None], (h, w))
    fine_x, fine_y = np.ascontiguousarray(fine_x), np.ascontiguousarray(fine_y)
    mx, my = ((v.reshape(hs, ws).astype(np.float32)) for v in (cells[:, 0] - c0, cells[:, 1] - r0))
    mx = cv2.remap(mx, fine_x, fine_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    my = cv2.remap(my, fine_x, fine_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    out = cv2.remap(known.view(np.uint8), mx, my, interpolation=cv2.INTER_NEAREST,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=255)
    return Patch(i0, j0, out.view(np.int8))

