"""The ROS-free half of `make demo` (``scripts/run_demo`` drives ROS; this module never imports rospy).

    python3 -m multi_map_merge.lab.demo config BASE.yaml OUT.yaml key=value ...
    python3 -m multi_map_merge.lab.demo report --truth NAME.truth.yaml --record DIR
            [--single single.yaml] [--png OUT.png] [--title TEXT] [--max-distance 0.1]
            [--world MAP.yaml]

``config`` writes a copy of the merger's parameter file with a few values changed. ``report``
scores what a replay produced (``record_replay``'s ``merged.yaml`` and ``record.yaml``) against
the ground truth of the bag (``make_robot_bags``' truth file): the paper's Table 1 (Fitness and
inlier RMSE of Open3D's ICP, plus coverage and wrongly occupied area) for the merged map and,
when given, the single robot's map; every robot's transform error through the merged TF; and a
picture: ground truth, single-robot map and merged map side by side, then the merged map with
every robot's trajectory drawn through the merged TF. Exit status 1 when a robot was not merged,
or was placed farther from its start truth than :data:`MAX_PLACEMENT_ERROR`.
"""
from __future__ import annotations

import argparse
import os
import sys
from typing import Dict, List, Optional, Sequence, Tuple

import cv2
import numpy as np
import yaml

from ..core.grid import Grid
from ..core.mapio import grid_to_pgm, load_map
from ..core.transforms import apply, cell_to_metric, inverse, pose_to_image, se2

# the paper's Table 1 (four Turtlebot3s vs one, 117 m2 house)
PAPER = {'multi': (0.9105, 0.076), 'single': (0.7024, 0.085)}
#: (metres, degrees): a robot placed farther than either from its start truth (its map frame's
#: true pose relative to the reference's) fails the demo, as an unmerged robot does
MAX_PLACEMENT_ERROR = (0.25, 3.0)
COLOURS = [(230, 25, 75), (60, 180, 75), (0, 130, 200), (245, 130, 48), (145, 30, 180),
           (70, 240, 240), (240, 50, 230), (128, 128, 0)]   # RGB


def write_config(base_yaml: str, out_yaml: str, overrides: Dict[str, object]) -> None:
    with open(base_yaml) as f:
        cfg = yaml.safe_load(f) or {}
    cfg.update(overrides)
    with open(out_yaml, 'w') as f:
        yaml.safe_dump(cfg, f, sort_keys=False)


# ------------------------------------------------------------------------------ pictures

def _image(grid: Grid) -> np.ndarray:
    """RGB picture of a grid, row 0 at the top (north up)."""
    g = grid_to_pgm(grid)
    return cv2.cvtColor(g, cv2.COLOR_GRAY2RGB)


def warp_to(grid: Grid, T_dst_src: np.ndarray, dst: Grid) -> Grid:
    """``grid`` (frame src) resampled on ``dst``'s lattice, given the pose of src in dst's frame."""
    from ..core.grid import levels_to_values
    M = pose_to_image(inverse(T_dst_src), grid.resolution, grid.origin, dst.resolution, dst.origin)
    lv = cv2.warpAffine(grid.levels(), M[:2], (dst.width, dst.height),
                        flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderValue=0)
    return Grid(levels_to_values(lv), dst.resolution, dst.origin, dst.frame_id)


def _to_pixels(pts_xy: np.ndarray, dst: Grid) -> np.ndarray:
    c = apply(inverse(cell_to_metric(dst.resolution, dst.origin)), pts_xy)
    return np.stack([c[:, 0], dst.height - 1 - c[:, 1]], axis=1)


def figure(truth: Grid, panels: Sequence[Tuple[str, Optional[Grid]]],
           trajectories: Dict[str, np.ndarray], path: str, title: str = '',
           truth_label: str = 'ground truth') -> None:
    """Ground truth and the maps (already on the truth's lattice) side by side, then the last
    map with each trajectory (N x 2 metres in the truth's frame) drawn on it."""
    def label(img, text):
        out = np.full((28 + img.shape[0], img.shape[1], 3), 255, np.uint8)
        out[28:] = img
        cv2.putText(out, text, (4, 19), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        return out

    imgs = [label(_image(truth), truth_label)]
    for name, g in panels:
        imgs.append(label(_image(g) if g is not None else np.full(imgs[0].shape[:2] + (3,), 200, np.uint8)[28:],
                          name))
    last = _image(panels[-1][1]) if panels and panels[-1][1] is not None else _image(truth)
    for k, (robot, xy) in enumerate(sorted(trajectories.items())):
        if len(xy) < 2:
            continue
        px = np.round(_to_pixels(xy, truth)).astype(np.int32)
        cv2.polylines(last, [px.reshape(-1, 1, 2)], False, COLOURS[k % len(COLOURS)], 2, cv2.LINE_AA)
        cv2.circle(last, tuple(int(v) for v in px[0]), 4, COLOURS[k % len(COLOURS)], -1)
        cv2.putText(last, robot, (4, 18 + 16 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.45, COLOURS[k % len(COLOURS)], 1,
                    cv2.LINE_AA)
    imgs.append(label(last, 'merged + trajectories (merged TF)'))
    gap = np.full((imgs[0].shape[0], 8, 3), 255, np.uint8)
    row = np.hstack([x for im in imgs for x in (im, gap)][:-1])
    scale = max(1.0, 1400.0 / row.shape[1])
    if scale > 1.0:
        row = cv2.resize(row, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    if title:
        head = np.full((30, row.shape[1], 3), 255, np.uint8)
        cv2.putText(head, title, (6, 21), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        row = np.vstack([head, row])
    cv2.imwrite(path, cv2.cvtColor(row, cv2.COLOR_RGB2BGR))


# ------------------------------------------------------------------------------ the report

def placement_failures(errs: Dict[str, Optional[Tuple[float, float]]], ref: str,
                       limits: Tuple[float, float] = MAX_PLACEMENT_ERROR,
                       fit_errs: Optional[Dict[str, Optional[Tuple[float, float]]]] = None) -> List[str]:
    """One line per placed robot farther than ``limits`` (metres, degrees) from its start truth.
    ``errs``: robot -> (metres, degrees) from :func:`evaluate.transform_errors` (None: not placed,
    reported apart); ``fit_errs``: the same against each robot's own map's best fit to the ground
    truth, added to the line (a placement near its map's fit but far from its start: that map
    itself sits turned or shifted against its start)."""
    out = []
    for r in sorted(errs):
        e = errs[r]
        if r == ref or e is None or (e[0] <= limits[0] and e[1] <= limits[1]):
            continue
        fe = (fit_errs or {}).get(r)
        out.append('FAILED: %s placed %.3f m and %.2f degrees from its start truth (limits %.2f m, %.1f degrees)%s'
                   % (r, e[0], e[1], limits[0], limits[1],
                      '' if fe is None else '; %.3f m and %.2f degrees from its own map\'s best fit' % fe))
    return out


def report(truth_path: str, record_dir: str, single_path: Optional[str], png: Optional[str],
           title: str = '', max_distance: float = 0.1, world_path: Optional[str] = None,
           limits: Tuple[float, float] = MAX_PLACEMENT_ERROR) -> int:
    """Print Table 1 and the transform errors; draw the picture. 0 when every robot merged
    within ``limits`` (metres, degrees) of its start truth. ``world_path``: the ground-truth map
    when not where the truth file says (a copy elsewhere)."""
    from .evaluate import load_truth, score_map, transform_errors
    truth = load_truth(truth_path)
    gt = load_map(world_path or truth['world_path'])
    starts = {r: se2(*v['start']) for r, v in truth['robots'].items()}
    ref = truth['reference']
    with open(os.path.join(record_dir, 'record.yaml')) as f:
        rec = yaml.safe_load(f)
    robots = sorted(truth['robots'])
    merged_path = os.path.join(record_dir, 'merged.yaml')
    merged = load_map(merged_path) if os.path.exists(merged_path) else None
    rows = []
    panels: List[Tuple[str, Optional[Grid]]] = []
    T_gt_merged = None
    if single_path:
        single = load_map(single_path)
        s = score_map(single, gt, se2(*truth['single']['start']), max_distance)
        rows.append(('single robot (%.0f m driven)' % truth['single']['distance_m'], s))
        panels.append(('single robot', warp_to(single, s.T, gt)))
    if merged is not None:
        # the merged map's frame is the reference robot's map frame: its start in the world
        m = score_map(merged, gt, starts[ref], max_distance)
        T_gt_merged = m.T
        rows.append(('multi-robot (%d robots)' % len(robots), m))
        panels.append(('merged (%d robots)' % len(robots), warp_to(merged, m.T, gt)))
    print()
    print(title or 'Map quality against the ground truth')
    print('ICP of occupied cells (Open3D point-to-point, max correspondence %.2f m), as the paper\'s '
          'Table 1' % max_distance)
    h = '%-30s %8s %12s %10s %12s' % ('', 'Fitness', 'inlier RMSE', 'coverage', 'wrong occ.')
    print(h)
    print('-' * len(h))
    for name, s in rows:
        print('%-30s %8.4f %10.3f m %10.3f %9.2f m2'
              % (name, s.fitness, s.inlier_rmse, s.coverage, s.wrong_occupied_m2))
    # each robot's own last map, aligned alone to the truth: what the merge had to work with,
    # and where that map's frame really sits (a SLAM map bends: its best fit to the world can
    # differ from the start pose by a few degrees, and merging can only find the best fit)
    fitted = {}
    own = []
    for r in robots:
        p = os.path.join(record_dir, '%s_map.yaml' % r)
        if os.path.exists(p):
            s = score_map(load_map(p), gt, starts[r], max_distance)
            fitted[r] = s.T
            own.append(s)
    if own:
        print('%-30s %8.4f %10.3f m %10s %9.2f m2' % (
            'robots\' own maps (mean of %d)' % len(own), float(np.mean([s.fitness for s in own])),
            float(np.mean([s.inlier_rmse for s in own])), '-', float(np.mean([s.wrong_occupied_m2 for s in own]))))
    print('%-30s %8.4f %10.3f m' % ('paper: multi-robot (4)', *PAPER['multi']))
    print('%-30s %8.4f %10.3f m' % ('paper: single robot', *PAPER['single']))
    placed = {}
    for r in robots:
        tf = (rec.get('robots', {}).get(r) or {}).get('tf')
        if tf is not None:
            placed[r] = se2(*tf)
    placed.setdefault(ref, np.eye(3))
    errs = transform_errors(placed, starts, ref)
    fit_errs = transform_errors(placed, fitted, ref) if ref in fitted else {}
    print()
    print('every robot\'s map frame in the merged map (TF map -> <robot>/map at the end) against the truth'
          '%s:' % (' (its start pose; "fit": its own map\'s best fit to the ground truth)' if fit_errs else ''))
    ok = True
    for r in robots:
        d = (rec.get('robots', {}).get(r) or {}).get('diagnostics', {})
        e = errs.get(r)
        if r == ref:
            print('  %-6s reference' % r)
        elif e is None:
            ok = False
            print('  %-6s NOT merged: %s' % (r, d.get('message', 'no TF')))
        else:
            fe = fit_errs.get(r)
            via = d.get('chain', d.get('linked_to', '-'))
            print('  %-6s error %.3f m %.2f deg%s   inlier ratio %s  agreement %s  via %s' % (
                r, e[0], e[1], '' if fe is None else ' (fit: %.3f m %.2f deg)' % fe,
                d.get('inlier_ratio', '-'), d.get('agreement', '-'), via))
    for line in placement_failures(errs, ref, limits, fit_errs):
        ok = False
        print(line)
    if png:
        traj = {}
        if T_gt_merged is not None:
            for r in robots:
                pts = np.array([p[1:3] for p in (rec.get('robots', {}).get(r) or {}).get('trajectory', [])], float)
                if len(pts) and r in placed:
                    T = T_gt_merged @ placed[r]   # robot's map frame -> merged frame -> truth
                    traj[r] = (T[:2, :2] @ pts.T).T + T[:2, 2]
        figure(gt, panels, traj, png, title)
        print('\nwrote %s' % png)
    return 0 if ok else 1


def team_report(record_dir: str, floor_plan_path: Optional[str], png: Optional[str], title: str = '',
                max_distance: float = 0.1) -> int:
    """A team of real robots with no ground-truth poses (e.g. the mrgs raw bags through live
    gmapping): whether each robot merged, how well each overlapping pair of their last maps
    agrees under the live TF, and, with a floor plan, the merged map's and each robot's own
    map's best fit to it (:func:`evaluate.best_fit_score`). 0 when every robot merged."""
    from ..core.verify import agreement
    from .evaluate import best_fit_score
    with open(os.path.join(record_dir, 'record.yaml')) as f:
        rec = yaml.safe_load(f)
    robots = sorted(rec.get('robots', {}))
    maps = {r: load_map(os.path.join(record_dir, '%s_map.yaml' % r)) for r in robots
            if os.path.exists(os.path.join(record_dir, '%s_map.yaml' % r))}
    merged_path = os.path.join(record_dir, 'merged.yaml')
    merged = load_map(merged_path) if os.path.exists(merged_path) else None
    print()
    print(title or 'A team of real robots through live gmapping')
    ok = True
    tf = {}
    for r in robots:
        got = rec['robots'][r] or {}
        d = got.get('diagnostics', {})
        if got.get('tf') is not None:
            tf[r] = se2(*got['tf'])
        merged_r = d.get('merged') == 'true' or d.get('reference') == 'true' or (got.get('tf') == [0.0, 0.0, 0.0])
        ok &= merged_r and r in tf
        print('  %-6s %s' % (r, d.get('message', 'no diagnostics') if r in tf else 'NOT merged: %s'
                             % d.get('message', 'no TF')))
    for i, a in enumerate(robots):
        for b in robots[i + 1:]:
            if a in tf and b in tf and a in maps and b in maps:
                ga, gb = maps[a], maps[b]
                A = pose_to_image(inverse(tf[a]) @ tf[b], ga.resolution, ga.origin, gb.resolution, gb.origin)
                ag, overlap = agreement(ga.levels(), gb.levels(), A, 2)
                print('  %s-%s: their last maps agree %.3f under the live TF (%d cells known in both)'
                      % (a, b, ag, overlap))
    panels: List[Tuple[str, Optional[Grid]]] = []
    if floor_plan_path and merged is not None:
        plan = load_map(floor_plan_path)
        print('against the floor plan %s (best ICP fit of the occupied cells, max correspondence %.2f m):'
              % (os.path.basename(floor_plan_path), max_distance))
        h = '  %-28s %8s %12s %10s %12s' % ('', 'Fitness', 'inlier RMSE', 'coverage', 'wrong occ.')
        print(h)
        for name, g in [('merged (%d robots)' % len(robots), merged)] + [('%s alone' % r, maps[r]) for r in robots
                                                                         if r in maps]:
            sc = best_fit_score(g, plan, max_distance, headings=6)
            print('  %-28s %8.4f %10.3f m %10.3f %9.2f m2' % (name, sc.fitness, sc.inlier_rmse, sc.coverage,
                                                             sc.wrong_occupied_m2))
            panels.append((name, warp_to(g, sc.T, plan)))
        if png:
            figure(plan, panels[:1], {}, png, title, truth_label='floor plan')
            print('wrote %s' % png)
    return 0 if ok else 1


def _main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog='python3 -m multi_map_merge.lab.demo')
    sub = ap.add_subparsers(dest='cmd', required=True)
    c = sub.add_parser('config')
    c.add_argument('base')
    c.add_argument('out')
    c.add_argument('overrides', nargs='*', help='key=value (value parsed as YAML)')
    r = sub.add_parser('report')
    r.add_argument('--truth', required=True)
    r.add_argument('--record', required=True)
    r.add_argument('--single')
    r.add_argument('--png')
    r.add_argument('--title', default='')
    r.add_argument('--max-distance', type=float, default=0.1)
    r.add_argument('--world', help="the ground-truth map, when not at the truth file's world")
    r.add_argument('--max-error', type=float, nargs=2, metavar=('M', 'DEG'), default=MAX_PLACEMENT_ERROR,
                   help='a robot placed farther from its start truth fails (default: %g m %g deg)'
                        % MAX_PLACEMENT_ERROR)
    t = sub.add_parser('team-report')
    t.add_argument('--record', required=True)
    t.add_argument('--floor-plan')
    t.add_argument('--png')
    t.add_argument('--title', default='')
    t.add_argument('--max-distance', type=float, default=0.1)
    a = ap.parse_args(argv)
    if a.cmd == 'team-report':
        return team_report(a.record, a.floor_plan, a.png, a.title, a.max_distance)
    if a.cmd == 'config':
        write_config(a.base, a.out, {k: yaml.safe_load(v) for k, v in (o.split('=', 1) for o in a.overrides)})
        return 0
    return report(a.truth, a.record, a.single, a.png, a.title, a.max_distance, a.world, tuple(a.max_error))


if __name__ == '__main__':
    sys.exit(_main())
