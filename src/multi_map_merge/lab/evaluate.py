"""A map scored against a ground-truth map, as the paper does: ICP of the occupied cells.

**What the paper's figures mean.** Table 1 of the paper gives two numbers of Open3D's
``registration_icp`` between a map and the ground truth, both taken once the map is aligned:

- **Fitness** (0..1): the fraction of the *map's* occupied points that have a ground-truth
  occupied point within the correspondence distance. 1.0 means every wall the map drew is where
  a real wall is; walls drawn twice (drift), misplaced rooms or a wrongly merged robot lower
  it. It does not say how much of the building the map covers (a map of one room can score 1).
- **inlier RMSE** (metres): the root mean square distance of those matched pairs only: how
  sharp the walls that did match are. It is bounded by the correspondence distance, so it
  says little on its own once Fitness is low.

The paper reports 0.9105 / 0.076 m for its four-robot merged map and 0.7024 / 0.085 m for a
single robot that explored alone (its drift drew walls beside walls).

We compute the same with Open3D (Debian's ``python3-open3d``; on Ubuntu 20.04, which does not
package it, ``pip3 install open3d``, rosdep key ``python3-open3d-pip``; the rest of the package
runs without it, and scoring without it raises :class:`Open3DMissing` naming what to install,
``evaluate_map`` exits 2 with that message): point-to-point ICP of the
centres of occupied cells as 3D points with z = 0, the map as the source, the ground truth as
the target, ``max_correspondence_distance`` = **0.10 m** by default. That is two cells at
0.05 m: it tolerates rasterisation (a wall drawn one cell off, 0.05 m, or one cell off
diagonally, 0.07 m) but not a misplaced wall, so a distorted or wrongly merged map loses
Fitness. Larger distances hide misplacement (a wall 0.2 m off still "fits" at 0.3 m); smaller
ones charge rasterisation itself (at 0.05 m a diagonal wall one cell off no longer fits).

ICP only converges from near the answer, so it is started from a **coarse pose** of the map's
frame in the ground truth's frame: given (e.g. the reference robot's start pose from the bag
generator's truth file), or estimated by our own merger with the ground truth as the reference
map, or (when the merger cannot place the map) the identity, which is reported. The alignment
runs coarse to fine: ICP at 8, 4 and 2 times the correspondence distance pulls in a coarse
pose a few decimetres or degrees off (at 0.10 m alone, ICP stays 3 degrees off on the Intel
map), then a final ``registration_icp`` at the correspondence distance itself runs from that
pose and from the coarse pose itself (the paper's plain ICP), and the better of the two
(higher Fitness) is kept: misplaced walls can pull the wide stages aside. The Fitness and
inlier RMSE reported are Open3D's result of that final run, i.e. the paper's figures at 0.10 m.
The pose is kept planar: x, y and yaw are read from ICP's 4x4 (ICP of z = 0 points never leaves
the plane).

Two more figures a user cares about:

- **coverage** (0..1): the fraction of the ground truth's free cells that the aligned map knows
  as free (each free truth cell's centre looked up in the nearest cell of the map);
- **wrongly occupied area** (m2): the map's occupied cells that land on a ground-truth free
  cell farther than the correspondence distance from any ground-truth wall (a distance
  transform of the truth's occupied cells): walls where there is open floor.

Frames: every pose is a 3x3 homogeneous SE(2) matrix (metres, radians). ``T`` of a score is the
pose of the map's frame (its ``frame_id``, e.g. the merged ``map``) in the ground truth's
frame: it maps metres in the map's frame to metres in the truth's frame. Point sets are in
metres in their grid's frame, through the grid's origin (x, y and yaw).

No ROS in here: ``scripts/evaluate_map`` calls :func:`main`.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np
import yaml

from ..core.grid import FREE, OCCUPIED, Grid, GridError
from ..core.transforms import cell_to_metric, inverse, pose_distance, se2, xyyaw

DEFAULT_MAX_DISTANCE = 0.10          # m: two cells at 0.05 m (see the module docstring)
ICP_STAGES = (8.0, 4.0, 2.0, 1.0)    # correspondence distances of the ICP runs, x max_distance
ICP_ITERATIONS = 100                 # at most, per run (Open3D's default is 30)
OPEN3D_MISSING = ('Open3D is not installed; scoring a map (ICP Fitness, inlier RMSE) needs it: '
                  'pip3 install --user open3d (rosdep key python3-open3d-pip; Debian 12: '
                  'apt install python3-open3d)')


class Open3DMissing(ImportError):
    """Open3D cannot be imported: the message says what to install (an optional dependency)."""


def open3d():
    """The ``open3d`` module, or :class:`Open3DMissing` naming what to install."""
    try:
        import open3d as o3d
    except ImportError as e:
        raise Open3DMissing(OPEN3D_MISSING) from e
    return o3d


@dataclass
class MapScore:
    """How well a map fits the ground truth (see the module docstring for each figure)."""

    fitness: float                   # 0..1, Open3D: map points with a truth point within max_distance
    inlier_rmse: float               # m, Open3D: RMS distance of those pairs
    coverage: float                  # 0..1 of the truth's free cells that are free in the aligned map
    wrong_occupied_m2: float         # m2 of the map's walls on truth free space away from truth walls
    T: np.ndarray                    # 3x3 pose of the map's frame in the truth's frame after ICP
    correction: Tuple[float, float, float]  # ICP's change on top of T_init: x m, y m, yaw rad (in the map's frame)
    init_source: str                 # where T_init came from: 'given', 'merger' or 'none' (identity)
    occupied_points: int             # occupied cells of the map (ICP source points)
    truth_points: int = 0            # occupied cells of the truth (ICP target points)
    max_distance: float = DEFAULT_MAX_DISTANCE   # m, the correspondence distance used
    T_init: np.ndarray = field(default_factory=lambda: np.eye(3))  # 3x3, the coarse pose ICP started from
    note: str = ''                   # why the coarse pose is what it is ('none': the merger's reason)

    def as_dict(self) -> Dict[str, Any]:
        """Plain types for JSON: poses as [x m, y m, yaw rad]."""
        return {'fitness': self.fitness, 'inlier_rmse': self.inlier_rmse, 'coverage': self.coverage,
                'wrong_occupied_m2': self.wrong_occupied_m2, 'pose': list(xyyaw(self.T)),
                'init_pose': list(xyyaw(self.T_init)), 'correction': list(self.correction),
                'init_source': self.init_source, 'note': self.note,
                'occupied_points': self.occupied_points, 'truth_points': self.truth_points,
                'max_distance': self.max_distance}


# ------------------------------------------------------------------------------ geometry

def occupied_points(grid: Grid) -> np.ndarray:
    """Centres of the OCCUPIED cells, (N, 2) metres in the grid's frame (origin x, y and yaw)."""
    r, c = np.nonzero(grid.levels() == OCCUPIED)
    W = cell_to_metric(grid.resolution, grid.origin)
    return (W[:2, :2] @ np.stack([c, r]).astype(np.float64)).T + W[:2, 2]


def _cells_of(grid: Grid, pts: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nearest cell (row, col) of each point (N, 2), metres in the grid's frame, and whether it
    lies inside the grid (row and col are only meaningful where it does)."""
    Wi = inverse(cell_to_metric(grid.resolution, grid.origin))
    cc = pts @ Wi[:2, :2].T + Wi[:2, 2]             # continuous (col, row), centres at integers
    c = np.rint(cc[:, 0]).astype(np.int64)
    r = np.rint(cc[:, 1]).astype(np.int64)
    inside = (c >= 0) & (r >= 0) & (c < grid.width) & (r < grid.height)
    return r, c, inside


def coarse_pose(grid: Grid, truth: Grid) -> Tuple[Optional[np.ndarray], str]:
    """Pose (3x3) of ``grid``'s frame in ``truth``'s frame estimated by our own merger, the
    truth being the reference map; (None, reason) when the merger cannot place it.

    The merger runs in this process (``workers: 1``): features, matching, RANSAC, ICP and the
    verification on the grids, exactly as for two robots."""
    from ..core.config import MergeConfig
    from ..core.merger import MapMerger
    try:
        m = MapMerger(MergeConfig.from_dict({'workers': 1, 'reference_robot': 'truth'}))
        m.update_map('truth', truth)
        m.update_map('map', grid)
        m.estimate()
        pl = m.placements().get('map')
        if pl is not None:
            return pl.T, ('inlier ratio %.3f, agreement %.3f, %d inliers'
                          % (pl.inlier_ratio, pl.agreement, pl.inliers))
        st = m.status().get('map')
        why = st.last_attempt.reason if st is not None and st.last_attempt is not None else 'no estimate'
        return None, 'the merger could not place the map on the ground truth (%s)' % why
    except Exception as e:
        return None, 'the merger failed: %s: %s' % (type(e).__name__, e)


def icp(src: np.ndarray, dst: np.ndarray, T0: np.ndarray, max_distance: float,
        stages: Sequence[float] = ICP_STAGES,
        iterations: int = ICP_ITERATIONS) -> Tuple[float, float, np.ndarray]:
    """Open3D point-to-point ICP of 2D points as z = 0 points: (fitness, inlier_rmse m, 3x3 pose).

    Args:
        src: (N, 2) metres in the source's frame (the map).
        dst: (M, 2) metres in the target's frame (the ground truth).
        T0: 3x3 coarse pose of the source's frame in the target's frame.
        max_distance: metres, the correspondence distance of the final run, whose Open3D
            ``fitness`` and ``inlier_rmse`` are returned.
        stages: correspondence distances of successive runs as multiples of ``max_distance``,
            each from the previous pose; the last one is run at ``max_distance`` (multiple 1)
            whatever it says.
        iterations: at most this many iterations per run.

    The final run at ``max_distance`` starts both from the coarse stages' pose and from ``T0``
    itself (the paper's plain ICP) and the better result is kept (higher Fitness, then lower
    RMSE): on a distorted map the wide stages can be pulled by misplaced walls into another
    local optimum than the one next to ``T0``. Returns the final pose of the source's frame in
    the target's frame, planar (x, y, yaw).
    """
    o3d = open3d()
    reg = o3d.pipelines.registration
    P = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.c_[src, np.zeros(len(src))]))
    Q = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.c_[dst, np.zeros(len(dst))]))
    # stop on the pose, not on a fitness that barely changes while ICP slides along a wall
    crit = reg.ICPConvergenceCriteria(relative_fitness=1e-9, relative_rmse=1e-9, max_iteration=iterations)

    def run(T: np.ndarray, dist: float):
        T4 = np.eye(4)
        T4[:2, :2], T4[:2, 3] = T[:2, :2], T[:2, 2]
        res = reg.registration_icp(P, Q, dist, T4, reg.TransformationEstimationPointToPoint(), crit)
        M = np.asarray(res.transformation)
        return res, se2(M[0, 3], M[1, 3], math.atan2(M[1, 0], M[0, 0]))   # keep it planar and rigid

    T0 = np.asarray(T0, np.float64)
    T = T0
    for k in list(stages)[:-1]:
        T = run(T, float(k) * max_distance)[1]
    best = None
    for start in ([T, T0] if len(stages) > 1 else [T0]):
        res, T = run(start, max_distance)
        key = (float(res.fitness), -float(res.inlier_rmse))
        if best is None or key > best[0]:
            best = (key, float(res.fitness), float(res.inlier_rmse), T)
    return best[1], best[2], best[3]


# ------------------------------------------------------------------------------ the score

def score_map(grid: Grid, truth: Grid, T_init: Optional[np.ndarray] = None,
              max_distance: float = DEFAULT_MAX_DISTANCE,
              stages: Sequence[float] = ICP_STAGES) -> MapScore:
    """Score ``grid`` (a map) against ``truth`` (the ground-truth map).

    Args:
        grid: the map, in its own frame (e.g. the merged frame = the reference robot's map frame).
        truth: the ground-truth map, in the world frame.
        T_init: 3x3 coarse pose of ``grid``'s frame in ``truth``'s frame (metres, radians);
            None: estimated by our merger (:func:`coarse_pose`), or the identity if it cannot
            place the map (``init_source`` 'none', the reason in ``note``).
        max_distance: metres, ICP's correspondence distance, also the wall tolerance of
            ``wrong_occupied_m2`` (default 0.10 m, see the module docstring).
        stages: coarse-to-fine correspondence distances, multiples of ``max_distance``.
    Raises:
        GridError (a ValueError) when the map or the truth has no occupied cell;
        ValueError for a non-positive ``max_distance`` or a ``T_init`` that is not a finite 3x3;
        Open3DMissing (an ImportError) when Open3D is not installed.
    """
    if not (isinstance(max_distance, (int, float)) and math.isfinite(max_distance) and max_distance > 0):
        raise ValueError('max_distance must be a positive number of metres, got %r' % (max_distance,))
    src = occupied_points(grid)
    dst = occupied_points(truth)
    if len(src) == 0:
        raise GridError('the map%s has no occupied cell to align with the ground truth'
                        % (' ' + grid.frame_id if grid.frame_id else ''))
    if len(dst) == 0:
        raise GridError('the ground truth%s has no occupied cell' % (' ' + truth.frame_id if truth.frame_id else ''))
    note = ''
    if T_init is not None:
        T_init = np.asarray(T_init, np.float64)
        if T_init.shape != (3, 3) or not np.all(np.isfinite(T_init)):
            raise ValueError('T_init must be a finite 3x3 SE(2) pose, got shape %s' % (T_init.shape,))
        T_init = se2(*xyyaw(T_init))    # rigid, whatever rounding it carried
        source = 'given'
    else:
        open3d()                        # missing: say so before the coarse pose's estimation
        T_init, note = coarse_pose(grid, truth)
        source = 'merger'
        if T_init is None:
            T_init, source = np.eye(3), 'none'
            note += '; ICP started from the identity'
    fit, rmse, T = icp(src, dst, T_init, float(max_distance), stages)

    # coverage: the truth's free cells that the aligned map knows as free (nearest cell)
    lt = truth.levels()
    tr, tc = np.nonzero(lt == FREE)
    if len(tr):
        Wt = cell_to_metric(truth.resolution, truth.origin)
        free_t = np.stack([tc, tr], axis=1).astype(np.float64) @ Wt[:2, :2].T + Wt[:2, 2]
        Ti = inverse(T)                                   # truth frame -> map frame
        r, c, inside = _cells_of(grid, free_t @ Ti[:2, :2].T + Ti[:2, 2])
        covered = np.zeros(len(tr), bool)
        covered[inside] = grid.levels()[r[inside], c[inside]] == FREE
        coverage = float(covered.mean())
    else:
        coverage = 0.0

    # wrongly occupied: the map's walls on truth free cells farther than max_distance from a wall
    dist = cv2.distanceTransform(np.where(lt == OCCUPIED, 0, 1).astype(np.uint8), cv2.DIST_L2,
                                 cv2.DIST_MASK_PRECISE) * truth.resolution   # m to the nearest truth wall
    r, c, inside = _cells_of(truth, src @ T[:2, :2].T + T[:2, 2])
    wrong = np.zeros(len(src), bool)
    wrong[inside] = (lt[r[inside], c[inside]] == FREE) & (dist[r[inside], c[inside]] > max_distance)

    return MapScore(fitness=fit, inlier_rmse=rmse, coverage=coverage,
                    wrong_occupied_m2=float(wrong.sum()) * grid.resolution ** 2, T=T,
                    correction=xyyaw(inverse(T_init) @ T), init_source=source,
                    occupied_points=int(len(src)), truth_points=int(len(dst)),
                    max_distance=float(max_distance), T_init=T_init, note=note)


def best_fit_score(grid: Grid, truth: Grid, max_distance: float = DEFAULT_MAX_DISTANCE,
                   headings: int = 8) -> MapScore:
    """``score_map`` with no coarse pose at all (e.g. a floor plan that no robot's start is
    known in): ICP from ``headings`` evenly spaced rotations, each with the map's occupied
    centroid on the truth's, and the best Fitness kept."""
    src, dst = occupied_points(grid), occupied_points(truth)
    if len(src) == 0 or len(dst) == 0:
        return score_map(grid, truth, np.eye(3), max_distance)    # raises the clear error
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    best = None
    for k in range(headings):
        yaw = 2.0 * math.pi * k / headings
        R = se2(0.0, 0.0, yaw)[:2, :2]
        t = cd - R @ cs
        s = score_map(grid, truth, se2(float(t[0]), float(t[1]), yaw), max_distance)
        if best is None or s.fitness > best.fitness:
            best = s
    return best


def transform_errors(estimated: Dict[str, np.ndarray], starts: Dict[str, np.ndarray],
                     reference: str) -> Dict[str, Optional[Tuple[float, float]]]:
    """Each robot's estimated transform against the truth.

    Args:
        estimated: robot -> 3x3 pose of its map frame in the merged frame (= the reference
            robot's map frame), e.g. the TF ``map -> tb3_k/map`` or merge_maps' transforms.
        starts: robot -> 3x3 true pose of its map frame in the world (ground-truth) frame.
        reference: the robot whose map frame is the merged frame.
    Returns robot -> (translation error m, rotation error deg) against the true relative pose
    ``inv(starts[reference]) @ starts[k]``, for every robot of ``starts``; None for a robot
    with no estimate. Robots only in ``estimated`` are left out (nothing to compare with).
    Raises ValueError when ``reference`` has no start pose.
    """
    if reference not in starts:
        raise ValueError('reference %r has no start pose (robots: %s)' % (reference, ', '.join(sorted(starts))))
    out: Dict[str, Optional[Tuple[float, float]]] = {}
    S0i = inverse(np.asarray(starts[reference], np.float64))
    for k in sorted(starts):
        if k not in estimated or estimated[k] is None:
            out[k] = None
            continue
        d, a = pose_distance(np.asarray(estimated[k], np.float64), S0i @ np.asarray(starts[k], np.float64))
        out[k] = (float(d), math.degrees(a))
    return out


# ------------------------------------------------------------------------------ files

def _pose3(v: Any, where: str) -> Tuple[float, float, float]:
    try:
        p = tuple(float(x) for x in v)
    except (TypeError, ValueError):
        raise ValueError('%s: needs [x, y, yaw] numbers, got %r' % (where, v)) from None
    if len(p) != 3 or not all(math.isfinite(x) for x in p):
        raise ValueError('%s: needs [x, y, yaw] finite numbers, got %r' % (where, v))
    return p  # type: ignore[return-value]


def load_truth(path: str) -> Dict[str, Any]:
    """The truth file ``make_robot_bags`` writes beside its bag (YAML)::

        world: ground_truth.yaml        # map_server file; a relative path is relative to this file's directory
        reference: tb3_0
        robots:
          tb3_0: {start: [x, y, yaw]}   # pose of tb3_0/map in the world frame, metres / radians
          tb3_1: {start: [x, y, yaw]}

    Returns the document with ``world_path`` (the world map's path, resolved), ``reference``
    (default: the first robot by name) and ``starts`` (robot -> 3x3 pose of its map frame in
    the world frame) added; other keys (e.g. ``single``) pass through.
    Raises ValueError naming the file when it cannot be read or lacks a field.
    """
    try:
        with open(path) as f:
            doc = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        raise ValueError('%s: cannot read truth file: %s' % (path, e)) from None
    if not isinstance(doc, dict) or 'world' not in doc or not isinstance(doc.get('robots'), dict) \
            or not doc['robots']:
        raise ValueError('%s: not a truth file (needs world and robots: {name: {start: [x, y, yaw]}})' % path)
    w = str(doc['world'])
    doc['world_path'] = w if os.path.isabs(w) else os.path.normpath(
        os.path.join(os.path.dirname(os.path.abspath(path)), w))
    starts = {}
    for k, v in doc['robots'].items():
        if not isinstance(v, dict) or 'start' not in v:
            raise ValueError('%s: robot %s has no start: [x, y, yaw]' % (path, k))
        starts[str(k)] = se2(*_pose3(v['start'], '%s: robot %s start' % (path, k)))
    doc['robots'] = {str(k): v for k, v in doc['robots'].items()}
    ref = doc.get('reference')
    doc['reference'] = str(ref) if ref is not None else sorted(starts)[0]
    if doc['reference'] not in starts:
        raise ValueError('%s: reference %s is not one of the robots (%s)'
                         % (path, doc['reference'], ', '.join(sorted(starts))))
    doc['starts'] = starts
    return doc


def load_transforms(path: str) -> Dict[str, np.ndarray]:
    """merge_maps' transforms report (``--transforms``; ``{reference: A, maps: {B: {merged:
    true, x, y, yaw, ...}, C: {merged: false, reason: ...}}}``): name -> 3x3 pose of that map's frame in the
    merged frame (metres, radians), the reference first (the identity); maps not merged are
    left out. Raises ValueError naming the file on any problem."""
    try:
        with open(path) as f:
            doc = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        raise ValueError('%s: cannot read transforms report: %s' % (path, e)) from None
    if not isinstance(doc, dict) or 'reference' not in doc or not isinstance(doc.get('maps') or {}, dict):
        raise ValueError('%s: not a merge_maps transforms report (needs reference and maps)' % path)
    out = {str(doc['reference']): np.eye(3)}
    for k, v in (doc.get('maps') or {}).items():
        if not isinstance(v, dict):
            raise ValueError('%s: map %s: not a mapping' % (path, k))
        if v.get('merged'):
            out[str(k)] = se2(*_pose3([v.get('x'), v.get('y'), v.get('yaw')], '%s: map %s' % (path, k)))
    return out


# ------------------------------------------------------------------------------ command line

def main(argv: Optional[List[str]] = None) -> int:
    """``evaluate_map MAP.yaml GROUND_TRUTH.yaml [--max-distance 0.1] [--init X Y YAW]
    [--truth NAME.truth.yaml [--robot NAME]] [--transforms T.yaml] [--json out.json]``.

    Exit status 0 scored, 2 bad arguments, a bad input file (the message names it) or no Open3D
    (the message says what to install)."""
    import argparse
    import json
    import sys

    from ..core.mapio import MapFileError, load_map

    def fail(msg: str) -> int:
        print('evaluate_map: %s' % msg, file=sys.stderr)
        return 2

    ap = argparse.ArgumentParser(
        prog='evaluate_map',
        description='Score a map against a ground-truth map: the paper\'s Fitness and inlier RMSE '
                    '(Open3D point-to-point ICP of occupied cells), coverage of the free space and '
                    'wrongly occupied area.')
    ap.add_argument('map', help='the map to score (map_server .yaml), e.g. merge_maps\' output')
    ap.add_argument('ground_truth', help='the ground-truth map (map_server .yaml)')
    ap.add_argument('--max-distance', type=float, default=DEFAULT_MAX_DISTANCE,
                    help='ICP correspondence distance, m (default 0.10: two cells at 0.05 m)')
    ap.add_argument('--init', type=float, nargs=3, metavar=('X', 'Y', 'YAW'),
                    help='coarse pose of the map\'s frame in the ground truth\'s frame (m, m, rad)')
    ap.add_argument('--truth', help='make_robot_bags\' truth file: without --init the coarse pose is '
                                    '--robot\'s start pose')
    ap.add_argument('--robot', help='robot whose map frame the map is in (default: the --transforms '
                                    'report\'s reference if it is a robot of the truth file, else the '
                                    'truth file\'s reference)')
    ap.add_argument('--transforms', help='merge_maps --transforms report: also print each robot\'s '
                                         'transform error against the truth file (needs --truth)')
    ap.add_argument('--json', help='write the figures here (JSON)')
    a = ap.parse_args(argv)
    if not (math.isfinite(a.max_distance) and a.max_distance > 0):
        return fail('--max-distance must be a positive number of metres, got %r' % a.max_distance)
    if a.transforms and not a.truth:
        return fail('--transforms needs --truth (the true start poses)')
    try:
        grid = load_map(a.map)
        gt = load_map(a.ground_truth)
    except MapFileError as e:
        return fail(str(e))
    truth = placed = None
    try:
        if a.truth:
            truth = load_truth(a.truth)
        if a.transforms:
            placed = load_transforms(a.transforms)
    except ValueError as e:
        return fail(str(e))
    robot = None
    if truth is not None:
        robot = a.robot
        if robot is None and placed is not None:
            ref_t = next(iter(placed))                   # load_transforms puts the reference first
            robot = ref_t if ref_t in truth['starts'] else None
        robot = robot or truth['reference']
        if robot not in truth['starts']:
            return fail('%s: no robot %s (robots: %s)' % (a.truth, robot, ', '.join(sorted(truth['starts']))))
    T0 = None
    if a.init:
        T0 = se2(*a.init)
    elif truth is not None:
        T0 = truth['starts'][robot]
    try:
        s = score_map(grid, gt, T0, a.max_distance)
    except GridError as e:
        return fail('%s vs %s: %s' % (a.map, a.ground_truth, e))
    except Open3DMissing as e:
        return fail(str(e))

    x, y, yaw = xyyaw(s.T)
    cx, cy, cyaw = s.correction
    src = {'given': ('--init' if a.init else 'start pose of %s in %s' % (robot, a.truth)),
           'merger': 'our merger, ground truth as reference', 'none': 'identity'}[s.init_source]
    print('map %s vs ground truth %s (ICP correspondence distance %.2f m)' % (a.map, a.ground_truth, s.max_distance))
    print('Fitness            %.4f   (map walls with a ground-truth wall within %.2f m; %d of %d occupied cells)'
          % (s.fitness, s.max_distance, int(round(s.fitness * s.occupied_points)), s.occupied_points))
    print('inlier RMSE        %.4f m' % s.inlier_rmse)
    print('coverage           %.4f   (of the ground truth\'s free cells, free in the map)' % s.coverage)
    print('wrongly occupied   %.2f m2 (map walls on open floor, > %.2f m from any ground-truth wall)'
          % (s.wrong_occupied_m2, s.max_distance))
    print('alignment          %s: coarse pose from %s%s' % (s.init_source, src, ' (%s)' % s.note if s.note else ''))
    print('ICP correction     %.3f m, %.3f m, %.2f deg; map frame in ground truth: x %.3f m, y %.3f m, yaw %.2f deg'
          % (cx, cy, math.degrees(cyaw), x, y, math.degrees(yaw)))
    out = s.as_dict()
    out.update(map=a.map, ground_truth=a.ground_truth)
    if placed is not None and truth is not None:
        ref_t = next(iter(placed))
        if ref_t not in truth['starts']:
            return fail('%s: reference %s is not a robot of %s (robots: %s)' % (
                a.transforms, ref_t, a.truth, ', '.join(sorted(truth['starts']))))
        errs = transform_errors(placed, truth['starts'], ref_t)
        unknown = sorted(set(placed) - set(truth['starts']))
        out['transform_errors'] = {k: (None if e is None else {'translation_m': e[0], 'rotation_deg': e[1]})
                                   for k, e in errs.items()}
        print('transforms %s against %s (merged frame = %s\'s map frame):' % (a.transforms, a.truth, ref_t))
        for k, e in errs.items():
            if k == ref_t:
                print('  %-12s reference' % k)
            else:
                print('  %-12s %s' % (k, 'NOT merged' if e is None else 'error %.3f m %.2f deg' % e))
        if unknown:
            print('  (not in the truth file, not scored: %s)' % ', '.join(unknown))
    if a.json:
        try:
            with open(a.json, 'w') as f:
                json.dump(out, f, indent=1)
        except OSError as e:
            return fail('%s: cannot write: %s' % (a.json, e))
    return 0
