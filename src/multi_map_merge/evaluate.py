"""A map scored against a ground-truth map, as the paper does: ICP of the occupied cells.

The paper's Table 1 gives Open3D's ``registration_icp`` figures: **Fitness**, the fraction of
the map's occupied points that have a ground-truth occupied point within the correspondence
distance once aligned, and **inlier RMSE**, the root mean square distance (metres) of those
pairs. We use the same (Open3D from Debian's ``python3-open3d``, point-to-point ICP on the
centres of occupied cells, z = 0) with a correspondence distance of **0.10 m**: two cells at
0.05 m. It tolerates rasterisation (a wall drawn one cell off, 0.05 m, or diagonally 0.07 m)
but not a misplaced wall: a distorted or wrongly merged map loses Fitness. Larger distances
hide misplacement (a map 0.2 m off still "fits" at 0.3 m); at 0.05 m rasterisation alone costs
Fitness.

Two more figures a user cares about:

- **coverage**: the fraction of the ground truth's free cells that the map knows as free;
- **wrongly occupied area** (m2): occupied cells of the map that land on ground-truth free
  space farther than the correspondence distance from any ground-truth wall.

ICP needs a coarse alignment: the pose of the map's frame in the ground truth's frame, given
(e.g. the reference robot's start pose from the bag generator's truth file) or estimated by our
own merger (the ground truth as the reference map). All poses are 3x3 SE(2) matrices, metres.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Dict, Optional, Tuple

import cv2
import numpy as np
import yaml

from .grid import FREE, OCCUPIED, Grid, GridError
from .transforms import cell_to_metric, pose_distance, se2, xyyaw

DEFAULT_MAX_DISTANCE = 0.10   # m


@dataclass
class MapScore:
    """How well a map fits the ground truth (see the module docstring)."""
    fitness: float               # 0..1
    inlier_rmse: float           # m
    coverage: float              # 0..1 of the truth's free cells
    wrong_occupied_m2: float     # m2
    T: np.ndarray                # 3x3 pose of the map's frame in the truth's frame after ICP
    correction: Tuple[float, float, float]   # ICP's change to the coarse pose: m, m, rad
    init_source: str             # 'given', 'merger' or 'none'
    occupied_points: int


def occupied_points(grid: Grid) -> np.ndarray:
    """Centres (N, 2) of the occupied cells, metres in the grid's frame."""
    r, c = np.nonzero(grid.levels() == OCCUPIED)
    W = cell_to_metric(grid.resolution, grid.origin)
    return (W[:2, :2] @ np.stack([c, r]).astype(np.float64)).T + W[:2, 2]


def coarse_pose(grid: Grid, truth: Grid) -> Optional[np.ndarray]:
    """Pose of ``grid``'s frame in ``truth``'s frame by our own merger (truth = reference)."""
    from .config import MergeConfig
    from .merger import MapMerger
    m = MapMerger(MergeConfig.from_dict({'reference_robot': 'truth', 'workers': 1}))
    m.update_map('truth', truth)
    m.update_map('map', grid)
    m.estimate()
    pl = m.placements().get('map')
    return None if pl is None else pl.T


def icp(src: np.ndarray, dst: np.ndarray, T0: np.ndarray, max_distance: float, iterations: int = 60):
    """Open3D point-to-point ICP of 2D points (z = 0): (fitness, inlier_rmse, 3x3 pose)."""
    import open3d as o3d
    P = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.c_[src, np.zeros(len(src))]))
    Q = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.c_[dst, np.zeros(len(dst))]))
    T4 = np.eye(4)
    T4[:2, :2], T4[:2, 3] = T0[:2, :2], T0[:2, 2]
    reg = o3d.pipelines.registration
    res = reg.registration_icp(P, Q, max_distance, T4, reg.TransformationEstimationPointToPoint(),
                               reg.ICPConvergenceCriteria(max_iteration=iterations))
    M = np.asarray(res.transformation)
    yaw = math.atan2(M[1, 0], M[0, 0])          # keep it planar and rigid
    return float(res.fitness), float(res.inlier_rmse), se2(M[0, 3], M[1, 3], yaw)


def score_map(grid: Grid, truth: Grid, T_init: Optional[np.ndarray] = None,
              max_distance: float = DEFAULT_MAX_DISTANCE) -> MapScore:
    """Score ``grid`` against ``truth``. ``T_init``: pose of the grid's frame in the truth's
    frame (coarse); None asks our merger for it. Raises GridError for a map without walls."""
    src = occupied_points(grid)
    dst = occupied_points(truth)
    if len(src) == 0:
        raise GridError('the map has no occupied cell to align')
    if len(dst) == 0:
        raise GridError('the ground truth has no occupied cell')
    source = 'given'
    if T_init is None:
        T_init = coarse_pose(grid, truth)
        source = 'merger'
        if T_init is None:
            T_init, source = np.eye(3), 'none'
    fit, rmse, T = icp(src, dst, T_init, max_distance)
    # the truth's free cells that the aligned map knows as free: look each one up in the map
    tr, tc = np.nonzero(truth.levels() == FREE)
    pts = (cell_to_metric(truth.resolution, truth.origin) @ np.stack([tc, tr, np.ones_like(tr)]).astype(float))
    cells = np.linalg.inv(cell_to_metric(grid.resolution, grid.origin)) @ np.linalg.inv(T) @ pts
    c, r = np.rint(cells[0]).astype(np.int64), np.rint(cells[1]).astype(np.int64)
    inside = (c >= 0) & (r >= 0) & (c < grid.width) & (r < grid.height)
    lv = grid.levels()
    covered = np.zeros(len(tr), bool)
    covered[inside] = lv[r[inside], c[inside]] == FREE
    coverage = float(covered.mean()) if len(tr) else 0.0
    # the map's walls on the truth's free space, far from any truth wall
    occ = truth.levels() == OCCUPIED
    dist = cv2.distanceTransform((~occ).astype(np.uint8), cv2.DIST_L2, 5) * truth.resolution
    sp = np.linalg.inv(cell_to_metric(truth.resolution, truth.origin)) @ T @ np.c_[src, np.ones(len(src))].T
    c, r = np.rint(sp[0]).astype(np.int64), np.rint(sp[1]).astype(np.int64)
    inside = (c >= 0) & (r >= 0) & (c < truth.width) & (r < truth.height)
    wrong = np.zeros(len(src), bool)
    wrong[inside] = (truth.levels()[r[inside], c[inside]] == FREE) & (dist[r[inside], c[inside]] > max_distance)
    corr = xyyaw(np.linalg.inv(T_init) @ T)
    return MapScore(fit, rmse, coverage, float(wrong.sum()) * grid.resolution ** 2, T, corr, source, len(src))


def transform_errors(estimated: Dict[str, np.ndarray], starts: Dict[str, np.ndarray],
                     reference: str) -> Dict[str, Optional[Tuple[float, float]]]:
    """(translation m, rotation deg) of each robot's estimated map-frame pose in the merged
    (= reference's map) frame against the truth ``inv(starts[reference]) @ starts[k]``; None
    for a robot with no estimate."""
    out: Dict[str, Optional[Tuple[float, float]]] = {}
    S0 = np.linalg.inv(starts[reference])
    for k, S in starts.items():
        if k not in estimated:
            out[k] = None
            continue
        d, a = pose_distance(estimated[k], S0 @ S)
        out[k] = (d, math.degrees(a))
    return out


def load_truth(path: str) -> Dict:
    """The truth file make_robot_bags writes beside its bag, with ``world_path`` resolved
    (a relative ``world`` is relative to the file's directory)."""
    try:
        with open(path) as f:
            doc = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        raise ValueError('%s: cannot read truth file: %s' % (path, e)) from None
    if not isinstance(doc, dict) or 'world' not in doc or 'robots' not in doc:
        raise ValueError('%s: not a truth file (needs world, robots)' % path)
    w = str(doc['world'])
    doc['world_path'] = w if os.path.isabs(w) else os.path.join(os.path.dirname(os.path.abspath(path)), w)
    doc.setdefault('reference', sorted(doc['robots'])[0])
    return doc


def load_transforms(path: str) -> Dict[str, np.ndarray]:
    """merge_maps' ``--transforms`` file: pose of every merged map frame in the merged frame."""
    with open(path) as f:
        doc = yaml.safe_load(f) or {}
    out = {doc.get('reference', ''): np.eye(3)}
    for k, v in (doc.get('maps') or {}).items():
        if v.get('merged'):
            out[k] = se2(v['x'], v['y'], v['yaw'])
    return out


def main(argv=None) -> int:
    """``evaluate_map MAP.yaml GROUND_TRUTH.yaml [--max-distance 0.1] [--init X Y YAW]
    [--truth NAME.truth.yaml [--robot NAME]] [--transforms T.yaml]``: exit 2 on a bad file."""
    import argparse
    import json
    import sys
    from .mapio import MapFileError, load_map
    ap = argparse.ArgumentParser(prog='evaluate_map', description='Score a map against a ground-truth map '
                                 '(Open3D ICP Fitness and inlier RMSE, coverage, wrongly occupied area).')
    ap.add_argument('map')
    ap.add_argument('ground_truth')
    ap.add_argument('--max-distance', type=float, default=DEFAULT_MAX_DISTANCE,
                    help='ICP correspondence distance, m (default 0.10: two cells at 0.05 m)')
    ap.add_argument('--init', type=float, nargs=3, metavar=('X', 'Y', 'YAW'),
                    help='coarse pose of the map\'s frame in the ground truth\'s frame (m, m, rad)')
    ap.add_argument('--truth', help='make_robot_bags\' truth file: the coarse pose is --robot\'s start')
    ap.add_argument('--robot', help='robot whose map frame the map is in (default: the truth file\'s reference)')
    ap.add_argument('--transforms', help='merge_maps --transforms file: also score each robot\'s transform (needs --truth)')
    ap.add_argument('--json', help='write the figures here')
    a = ap.parse_args(argv)
    try:
        grid = load_map(a.map)
        gt = load_map(a.ground_truth)
    except MapFileError as e:
        print('evaluate_map: %s' % e, file=sys.stderr)
        return 2
    truth = None
    if a.truth:
        try:
            truth = load_truth(a.truth)
        except ValueError as e:
            print('evaluate_map: %s' % e, file=sys.stderr)
            return 2
    T0 = None
    if a.init:
        T0 = se2(*a.init)
    elif truth is not None:
        robot = a.robot or truth['reference']
        if robot not in truth['robots']:
            print('evaluate_map: %s: no robot %s' % (a.truth, robot), file=sys.stderr)
            return 2
        T0 = se2(*truth['robots'][robot]['start'])
    try:
        s = score_map(grid, gt, T0, a.max_distance)
    except GridError as e:
        print('evaluate_map: %s' % e, file=sys.stderr)
        return 2
    cx, cy, cyaw = s.correction
    print('Fitness       %.4f   (occupied cells of the map with a ground-truth wall within %.2f m)' % (s.fitness, a.max_distance))
    print('inlier RMSE   %.4f m' % s.inlier_rmse)
    print('coverage      %.4f   (of the ground truth\'s free cells)' % s.coverage)
    print('wrongly occupied %.2f m2' % s.wrong_occupied_m2)
    print('alignment     %s coarse pose, ICP corrected it by %.3f m, %.3f m, %.2f deg' % (
        s.init_source, cx, cy, math.degrees(cyaw)))
    out = {'fitness': s.fitness, 'inlier_rmse': s.inlier_rmse, 'coverage': s.coverage,
           'wrong_occupied_m2': s.wrong_occupied_m2, 'pose': list(xyyaw(s.T)), 'init_source': s.init_source}
    if a.transforms:
        if truth is None:
            print('evaluate_map: --transforms needs --truth', file=sys.stderr)
            return 2
        try:
            est = load_transforms(a.transforms)
        except (OSError, yaml.YAMLError, KeyError, TypeError) as e:
            print('evaluate_map: %s: %s' % (a.transforms, e), file=sys.stderr)
            return 2
        starts = {k: se2(*v['start']) for k, v in truth['robots'].items()}
        errs = transform_errors(est, starts, a.robot or truth['reference'])
        out['transform_errors'] = errs
        for k, e in sorted(errs.items()):
            print('  %-10s %s' % (k, 'not merged' if e is None else 'error %.3f m %.2f deg' % e))
    if a.json:
        with open(a.json, 'w') as f:
            json.dump(out, f, indent=1)
    return 0
