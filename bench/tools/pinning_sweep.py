#!/usr/bin/env python3
"""Issue 22's sweeps: how far off each placed robot is, and whether each link's covariance
(:mod:`core.covariance`) covers its true error.

    bench/bench.py pinning-sweep -o /tmp/sweep.json            # merge every case (minutes)
    bench/bench.py pinning-sweep --cases /tmp/sweep.pkl ...     # reuse the merges
    bench/bench.py pinning-sweep --robots-csv results/pinning_chain_flood.csv   # per robot

Cases, per ground-truth building (``lab/drives.py``: the 11 with a CARMEN log, along their
real drive, and the two AWS maps, along a drive planned through their free space): ``chain``
(the drive cut into 4, 6 and 8 consecutive stretches, each grown into its neighbours; a drive
that comes back to a place makes its stretches overlap more than neighbours; seeds 0 and 1)
and ``flood`` (4 and 6 robots spreading out from a common start, seed 0), every robot's map at
a random pose. Each case is merged by a fresh ``MapMerger`` (one cycle). Then:

- per placed robot: position error (m), yaw error (deg), placed right (within 0.10 m and 1
  degree), and the reported 2-sigma position (when placements carry a covariance);
- per kept link: its true error (x, y, yaw of the link's pose against the truth, in the
  parent's frame) and the Mahalanobis distance under the link's covariance: covered at 95%
  when under 7.81 (chi-square, 3 dof) and, position only, 5.99 (2 dof).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import pickle
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))          # (bench/tools/ -> the checkout)
DATA = os.path.abspath(os.path.join(REPO, '..', 'shared', 'data'))

from multi_map_merge.core import covariance  # noqa: E402
from multi_map_merge.core.config import MergeConfig  # noqa: E402
from multi_map_merge.core.merger import MapMerger  # noqa: E402
from multi_map_merge.core.transforms import inverse, pose_to_image, wrap_angle, xyyaw  # noqa: E402
from multi_map_merge.lab import drives  # noqa: E402

CHI2_3, CHI2_2 = 7.81, 5.99
RIGHT = (0.10, 1.0)      # metres, degrees


def case_list(quick=False):
    out = [('chain', n, s) for n in (4, 6, 8) for s in (0, 1)] + [('flood', n, 0) for n in (4, 6)]
    return out[:2] + out[-1:] if quick else out


def merge_case(pieces, config):
    m = MapMerger(MergeConfig(reference_robot='r0', **config))
    for k, (g, _) in enumerate(pieces):
        m.update_map('r%d' % k, g)
    t = time.time()
    m.estimate()
    return m, time.time() - t


def link_cov(m, e):
    """The link's covariance: its own when it carries one, else computed here on the grids."""
    cov = getattr(e, 'cov', None)
    if cov is not None:
        return np.asarray(cov)
    pa, ch = m._team.maps[e.parent].grid, m._team.maps[e.child].grid
    A = pose_to_image(e.T, pa.resolution, pa.origin, ch.resolution, ch.origin)
    p = covariance.pinning(pa.levels(), ch.levels(), A)
    if p is None:
        return None
    return covariance.metric_covariance(p.cov, p.centre, e.T, pa.resolution, pa.origin)


def err_vec(T, T_true):
    x, y, a = xyyaw(T)
    xt, yt, at = xyyaw(T_true)
    return np.array([x - xt, y - yt, float(wrap_angle(a - at))])


def evaluate(m, truths):
    """(links, robots) records of one merged case; truths: name -> T_world_k."""
    links, robots = [], []
    for (a, b), e in sorted(m._linker.ledger.links.items()):
        T_true = inverse(truths[a]) @ truths[b]
        ev = err_vec(e.T, T_true)
        cov = link_cov(m, e)
        rec = {'parent': a, 'child': b, 'err': ev.tolist(), 'inliers': int(e.inliers),
               'agreement': float(e.agreement)}
        if cov is not None:
            rec['cov'] = cov.tolist()
            rec['d2'] = float(ev @ np.linalg.solve(cov, ev))
            rec['d2_pos'] = float(ev[:2] @ np.linalg.solve(cov[:2, :2], ev[:2]))
            rec['sigma_pos'] = covariance.position_sigma(cov)
        links.append(rec)
    ref = truths['r0']
    for n, pl in sorted(m.placements().items()):
        if n == 'r0':
            continue
        ev = err_vec(pl.T, inverse(ref) @ truths[n])
        d, yaw = float(math.hypot(ev[0], ev[1])), float(abs(math.degrees(ev[2])))
        rec = {'robot': n, 'err_m': d, 'err_deg': yaw, 'right': d <= RIGHT[0] and yaw <= RIGHT[1],
               'via': pl.via}
        cov = getattr(pl, 'cov', None)
        if cov is not None:
            rec['sigma_pos'] = covariance.position_sigma(np.asarray(cov))
            rec['d2_pos'] = float(ev[:2] @ np.linalg.solve(np.asarray(cov)[:2, :2], ev[:2]))
            rec['weak'] = bool(getattr(pl, 'weak', False))
        robots.append(rec)
    return links, robots


def link_inputs(m, truths):
    """[(parent levels, child levels, A, T, parent resolution, origin, true error)] of the kept
    links of a merged case: what calibration recomputes the covariance of."""
    out = []
    for (a, b), e in sorted(m._linker.ledger.links.items()):
        pa, ch = m._team.maps[a].grid, m._team.maps[b].grid
        A = pose_to_image(e.T, pa.resolution, pa.origin, ch.resolution, ch.origin)
        out.append((pa.levels(), ch.levels(), A, e.T, pa.resolution, pa.origin,
                    err_vec(e.T, inverse(truths[a]) @ truths[b])))
    return out


def calibrate(inputs, temperatures, floors_cells, floors_deg):
    """Coverage of the links' true errors by their 95% ellipses (3 dof; 2 dof position) for
    each temperature and floor, and the median reported 2-sigma position."""
    saved = covariance.FLOOR_CELLS, covariance.FLOOR_DEG, covariance.TEMPERATURE
    covariance.FLOOR_CELLS = covariance.FLOOR_DEG = 0.0
    try:
        for t in temperatures:
            covariance.TEMPERATURE = t
            raw = []
            for lv_a, lv_b, A, T, res, origin, ev in inputs:
                p = covariance.pinning(lv_a, lv_b, A)
                if p is not None:
                    raw.append((p, T, res, origin, ev))
            for fc in floors_cells:
                for fd in floors_deg:
                    d2, d2p, sig = [], [], []
                    for p, T, res, origin, ev in raw:
                        cells = p.cov + np.diag([fc ** 2, fc ** 2, math.radians(fd) ** 2])
                        C = covariance.metric_covariance(cells, p.centre, T, res, origin)
                        d2.append(ev @ np.linalg.solve(C, ev))
                        d2p.append(ev[:2] @ np.linalg.solve(C[:2, :2], ev[:2]))
                        sig.append(covariance.position_sigma(C))
                    d2, d2p = np.array(d2), np.array(d2p)
                    print('temperature %.3f floor %.2f cells %.3f deg: %d links, inside 95%%: %.3f (3 dof), '
                          '%.3f (position); d2 95th percentile %.2f; median 2-sigma position %.3f m'
                          % (t, fc, fd, len(d2), np.mean(d2 <= CHI2_3), np.mean(d2p <= CHI2_2),
                             np.percentile(d2, 95), 2 * np.median(sig)), flush=True)
    finally:
        covariance.FLOOR_CELLS, covariance.FLOOR_DEG, covariance.TEMPERATURE = saved


def summary(results):
    lines = []
    for kind in ('chain', 'flood'):
        rs = [r for r in results if r['kind'] == kind]
        n_rob = sum(r.get('robots_cut', r['n']) - 1 for r in rs)
        placed = [x for r in rs for x in r['robots']]
        right = sum(x['right'] for x in placed)
        off = sorted(x['err_m'] for x in placed if not x['right'])
        lk = [x for r in rs for x in r['links'] if 'd2' in x]
        lines.append('%s: %d cases, %d robots: %d placed, %d right, %d not merged; placed wrong: %s'
                     % (kind, len(rs), n_rob, len(placed), right, n_rob - len(placed),
                        ' '.join('%.2f' % v for v in off) or '-'))
        if lk:
            c3 = np.mean([x['d2'] <= CHI2_3 for x in lk])
            c2 = np.mean([x['d2_pos'] <= CHI2_2 for x in lk])
            big = [x for x in lk if math.hypot(*x['err'][:2]) > 0.05]
            cb = np.mean([x['d2_pos'] <= CHI2_2 for x in big]) if big else float('nan')
            lines.append('  links: %d; true error inside the 95%% ellipse: %.3f (3 dof, %.2f), %.3f '
                         '(position, 2 dof, %.2f); of the %d links over 0.05 m off: %.3f (position); '
                         'median 2-sigma position %.3f m'
                         % (len(lk), c3, CHI2_3, c2, CHI2_2, len(big), cb,
                            2 * np.median([x['sigma_pos'] for x in lk])))
        pr = [x for x in placed if 'sigma_pos' in x]
        if pr:
            c = np.mean([x['d2_pos'] <= CHI2_2 for x in pr])
            weak = [x for x in pr if x['weak']]
            lines.append('  placements: inside the 95%% position ellipse %.3f; weak %d (of them right %d); '
                         'not weak and wrong %d' % (c, len(weak), sum(x['right'] for x in weak),
                                                     sum(1 for x in pr if not x['weak'] and not x['right'])))
    return '\n'.join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('-o', '--output', help='JSON of every record')
    ap.add_argument('--robots-csv', help='CSV of every placed robot: its error, its reported sigma, weak or not')
    ap.add_argument('--cases', default='/tmp/pinning_cases', help='cache of cut maps and logs (directory)')
    ap.add_argument('--quick', action='store_true', help='3 cases per building')
    ap.add_argument('--only', nargs='*', help='buildings')
    ap.add_argument('--temperature', type=float, help='covariance.TEMPERATURE for this run')
    ap.add_argument('--better-cost', type=float, help='covariance.BETTER_COST for this run')
    ap.add_argument('--baseline', action='store_true',
                    help='the merger before issue 22 steps 3-4: pose graph by inlier counts, ICP\'s pose kept '
                         '(links still get a covariance, which changes no estimate: pair digest identical)')
    ap.add_argument('--max-range', type=float, default=drives.MAX_RANGE, help='metres a robot\'s map reaches')
    ap.add_argument('--overlap', type=float, default=0.15, help='chain: share of a stretch added at both ends')
    ap.add_argument('--strict', action='store_true',
                    help='chain: each robot keeps only cells no stretch but its neighbours saw (lab/drives.chain)')
    ap.add_argument('--config', default='{}', help='MergeConfig fields as JSON')
    ap.add_argument('--calibrate', action='store_true',
                    help='recompute every link\'s covariance over a range of temperatures and floors')
    ap.add_argument('--temperatures', type=float, nargs='*', default=[0.005, 0.01, 0.02, 0.05])
    ap.add_argument('--floors-cells', type=float, nargs='*', default=[0.0, 0.1, 0.2, 0.3])
    ap.add_argument('--floors-deg', type=float, nargs='*', default=[0.0, 0.02, 0.05])
    a = ap.parse_args()
    if a.temperature:
        covariance.TEMPERATURE = a.temperature
    if a.better_cost is not None:
        covariance.BETTER_COST = a.better_cost
    if a.baseline:
        from multi_map_merge.core import placement
        covariance.BETTER_COST = float('inf')
        graph_poses = placement.graph_poses
        placement.graph_poses = lambda best, links, ref, covs=None: graph_poses(best, links, ref)
    drives.MAX_RANGE = a.max_range
    tag = '' if (a.max_range, a.overlap) == (8.0, 0.15) else '_r%g_o%g' % (a.max_range, a.overlap)
    tag += '_strict' if a.strict else ''
    config = json.loads(a.config)
    config.setdefault('workers', 1)
    results, inputs = [], []
    t_merge = 0.0
    for name in drives.buildings(DATA):
        if a.only and name not in a.only:
            continue
        world = poses = None
        for kind, n, seed in case_list(a.quick):
            if a.strict and kind != 'chain':
                continue
            f = os.path.join(a.cases, '%s_%s%d_%d%s.pkl' % (name, kind, n, seed, tag))
            if os.path.exists(f):
                with open(f, 'rb') as fh:
                    pieces = pickle.load(fh)
            else:
                if world is None:
                    world, poses, ranges, angles = drives.load(DATA, name, a.cases)
                if kind == 'chain':
                    pieces = drives.chain(world, poses, ranges, angles, n, seed, a.overlap, a.strict)
                else:
                    pieces = drives.flood(world, poses, ranges, angles, n, seed)
                with open(f, 'wb') as fh:
                    pickle.dump(pieces, fh)
            m, dt = merge_case(pieces, config)
            t_merge += dt
            truths = {'r%d' % k: T for k, (_, T) in enumerate(pieces)}
            links, robots = evaluate(m, truths)
            if a.calibrate:
                inputs += link_inputs(m, truths)
            results.append({'building': name, 'kind': kind, 'n': n, 'robots_cut': len(pieces),
                            'seed': seed, 'links': links,
                            'robots': robots, 'seconds': dt})
            print('%-16s %s%d/%d: placed %d/%d right %d  worst %.3f m  links %d  (%.1f s)'
                  % (name, kind, n, seed, len(robots), len(pieces) - 1, sum(r['right'] for r in robots),
                     max([r['err_m'] for r in robots] or [0.0]), len(links), dt), flush=True)
    print(summary(results))
    print('estimation cycles: %.1f s in all' % t_merge)
    if a.calibrate:
        calibrate(inputs, a.temperatures, a.floors_cells, a.floors_deg)
    if a.output:
        with open(a.output, 'w') as fh:
            json.dump(results, fh)
    if a.robots_csv:
        write_robots_csv(results, a.robots_csv)


def write_robots_csv(results, path):
    """One line per placed robot of every case: where it is off (m, deg), the 1-sigma of its
    position in its worst direction (m), its squared Mahalanobis distance (position, 2 dof),
    and whether it was placed right and reported weak."""
    with open(path, 'w') as fh:
        fh.write('building,kind,robots,seed,robot,via,err_m,err_deg,sigma_pos_m,d2_pos,right,weak\n')
        for c in results:
            for r in c['robots']:
                sig, d2 = r.get('sigma_pos'), r.get('d2_pos')
                fh.write('%s,%s,%d,%d,%s,%s,%.4f,%.3f,%s,%s,%d,%d\n' % (
                    c['building'], c['kind'], c['n'], c['seed'], r['robot'], r['via'], r['err_m'],
                    r['err_deg'], '' if sig is None else '%.4f' % sig, '' if d2 is None else '%.2f' % d2,
                    r['right'], r.get('weak', False)))


if __name__ == '__main__':
    main()
