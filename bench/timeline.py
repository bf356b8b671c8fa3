"""Coverage over time, team against lone robot: what a team gains is the building mapped sooner
(issue 51 section 1; the way Explore-Bench measures exploration: explored area over time, the
time to a fraction of the world).

The maps over time are what each robot's SLAM would have published during its run:
``rbpf_slam_replay --snapshot_every S`` writes its map every S seconds of bag time (from the bag's
first message; the team's robots drive at once, so one clock serves the four). At each snapshot
time t the team's four maps at t are merged by our merger, in process, as ``merge_maps`` merges
(``MapMerger``: update_map, estimate, compose; the merger's default configuration, one worker),
and the merged map (in the reference robot's map frame) is aligned with the ground truth by the
scorer (``lab/evaluate.score_map``: ICP from the reference's true start); the lone robot's map at t
likewise from its own start. Each map at t gets:

- **free**: the fraction of the ground truth's free cells known free in the map: a truth free
  cell counts when a free cell of the aligned map lies within ``TOLERANCE_M`` (0.10 m, the
  scorer's correspondence distance) of its centre;
- **walls**: the fraction of the truth's wall surface (its occupied cells with a free cell among
  their 8 neighbours: what a laser can see; a thick wall's inside is never observed) with an
  occupied cell of the aligned map within the same tolerance;
- the Fitness of that alignment.

A merge that places fewer robots at t composites only those: coverage counts what is placed.
Then per run: the time to 90 % and to 99 % of the truth's free area (the first snapshot time
whose ``free`` reaches it, so to within S; None when never reached), and at equal time (the team's
end: its bag's last second) and at each one's end the Fitness, inlier RMSE and coverage of both,
scored as ``make accuracy`` scores its rows (``best_score``: the start pose and eight headings,
the best Fitness kept).

Run by ``bench/accuracy.py`` after a condition's SLAM runs, one process per condition::

    bench/bench.py timeline --truth TEAM.truth.yaml --world WORLD.yaml --every S --out timeline.json \\
        --team tb3_0=PREFIX0 ... --single PREFIX   # PREFIX.yaml the final map, PREFIX.snap/ its snapshots

The pure parts (``time_to``, ``coverage``) are unit-tested in test/unit/bench/test_timeline.py.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import re
import sys
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

TOLERANCE_M = 0.10        # m: a truth cell counts as known when the map has its class within this
LEVELS = (0.90, 0.99)     # the fractions of the truth's free area whose times are reported
SNAPSHOT_RE = re.compile(r'_t(\d{5})\.yaml$')


def snapshot_every(single_duration_s: float, points: int = 100, step_s: float = 5.0) -> float:
    """The snapshot period (s of bag time) for a world whose lone robot drives
    ``single_duration_s``: about ``points`` snapshots of the lone run, a multiple of ``step_s``,
    at least ``step_s`` (the home's 460 s: 5 s; the Intel lab's 2180 s: 20 s)."""
    raw = float(single_duration_s) / points
    return max(step_s, step_s * round(raw / step_s))


def time_to(series: Sequence[Tuple[float, float]], level: float) -> Optional[float]:
    """The first time (s) whose value reaches ``level`` in ``series`` [(t, value)] sorted by t;
    None when it never does."""
    for t, v in series:
        if v is not None and v >= level:
            return float(t)
    return None


def coverage(grid, truth, T, tolerance_m: float = TOLERANCE_M) -> Dict[str, float]:
    """{'free', 'walls'}: the fractions of ``truth``'s free cells and of its wall surface
    (occupied cells with a free 8-neighbour) that ``grid`` knows as free, resp. occupied, within
    ``tolerance_m`` (m), ``T`` (3x3) the pose of ``grid``'s frame in ``truth``'s frame (metres,
    radians). Each truth cell's centre is taken into the grid's frame and looked up in the grid's
    free (occupied) cells dilated by the tolerance (a disc of round(tolerance / resolution)
    cells); cells outside the grid are unknown."""
    import cv2
    import numpy as np

    from multi_map_merge.core.grid import FREE, OCCUPIED
    from multi_map_merge.core.transforms import cell_to_metric, inverse
    lt, lm = truth.levels(), grid.levels()
    k = max(0, int(round(tolerance_m / grid.resolution)))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * k + 1, 2 * k + 1))
    Wt = cell_to_metric(truth.resolution, truth.origin)
    Wm_inv = inverse(cell_to_metric(grid.resolution, grid.origin)) @ inverse(np.asarray(T, np.float64))
    M = Wm_inv @ Wt                              # truth cell (col, row) -> grid cell (col, row)
    near_free = cv2.dilate((lt == FREE).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    targets = {'free': lt == FREE, 'walls': (lt == OCCUPIED) & near_free}
    out = {}
    for name, level in (('free', FREE), ('walls', OCCUPIED)):
        tr, tc = np.nonzero(targets[name])
        if len(tr) == 0:
            out[name] = 0.0
            continue
        known = cv2.dilate((lm == level).astype(np.uint8), disc) if k else (lm == level).astype(np.uint8)
        cc = np.stack([tc, tr], axis=1).astype(np.float64) @ M[:2, :2].T + M[:2, 2]
        c, r = np.rint(cc[:, 0]).astype(np.int64), np.rint(cc[:, 1]).astype(np.int64)
        inside = (c >= 0) & (r >= 0) & (c < grid.width) & (r < grid.height)
        hit = np.zeros(len(tr), bool)
        hit[inside] = known[r[inside], c[inside]] > 0
        out[name] = float(hit.mean())
    return out


def snapshots(prefix: str) -> Dict[int, str]:
    """{t (s of bag time): map yaml} of the snapshots ``rbpf_slam_replay`` wrote under
    ``prefix``.snap/."""
    out = {}
    for p in glob.glob(os.path.join(prefix + '.snap', '*.yaml')):
        m = SNAPSHOT_RE.search(p)
        if m:
            out[int(m.group(1))] = p
    return out


def merge(grids: Dict[str, Any], reference: str, config=None):
    """Our merger on ``grids`` (name -> Grid), as ``merge_maps`` runs it: (merged grid in the
    reference's map frame, names placed besides the reference)."""
    import dataclasses

    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.merger import MapMerger
    from multi_map_merge.core.report import transforms_report
    cfg = config or MergeConfig.from_dict({'workers': 1})
    merger = MapMerger(dataclasses.replace(cfg, reference_robot=reference))
    names = sorted(grids)
    for n in names:
        merger.update_map(n, grids[n])
    merger.estimate()
    merged = merger.compose()
    report = transforms_report(merger, reference, names)
    placed = [n for n, r in report['maps'].items() if r.get('merged')]
    return merged, placed


def point(grid, truth, T0) -> Dict[str, Any]:
    """One time point of a map: ICP from ``T0`` (the scorer's), Fitness and coverage."""
    from multi_map_merge.lab.evaluate import GridError, score_map
    try:
        s = score_map(grid, truth, T0)
    except GridError as e:
        return {'fitness': None, 'free': 0.0, 'walls': 0.0, 'note': str(e)}
    out = {'fitness': round(float(s.fitness), 4)}
    out.update({k: round(v, 4) for k, v in coverage(grid, truth, s.T).items()})
    return out


def full_score(grid, truth, T0) -> Dict[str, Any]:
    """As ``make accuracy`` scores a row (the start pose and eight headings, the best Fitness):
    Fitness, inlier RMSE (m) and coverage."""
    from multi_map_merge.lab.evaluate import GridError, best_fit_score, score_map
    try:
        s = max([score_map(grid, truth, T0), best_fit_score(grid, truth)], key=lambda x: x.fitness)
    except GridError as e:
        return {'invalid': 'cannot be scored: %s' % e}
    out = {'fitness': round(float(s.fitness), 4), 'inlier_rmse': round(float(s.inlier_rmse), 4)}
    out.update({k: round(v, 4) for k, v in coverage(grid, truth, s.T).items()})
    return out


def run(truth_path: str, world_path: str, team: Dict[str, str], single: str, every: float,
        log=print) -> Dict[str, Any]:
    """The timeline of one condition (see the module docstring); ``team`` robot -> SLAM prefix,
    ``single`` the lone robot's prefix."""
    from multi_map_merge.core.mapio import load_map
    from multi_map_merge.lab.evaluate import load_truth
    t0 = time.time()
    td = load_truth(truth_path)
    truth = load_map(world_path)
    starts = td['starts']
    ref = sorted(team)[0]
    team_end = max(float(td['robots'][r].get('duration_s', 0.0)) for r in team)
    single_end = float(td.get('single', {}).get('duration_s', 0.0))
    from multi_map_merge.core.transforms import se2
    single_start = se2(*td['single']['start'])
    snaps = {r: snapshots(p) for r, p in team.items()}
    single_snaps = snapshots(single)

    team_series = []
    times = sorted(set.intersection(*(set(s) for s in snaps.values()))) if snaps else []
    for t in times:
        from multi_map_merge.core.mapio import load_map as lm
        grids = {r: lm(snaps[r][t]) for r in team}
        try:
            merged, placed = merge(grids, ref)
        except Exception as e:                     # noqa: BLE001 (the point says why)
            team_series.append({'t': t, 'placed': 0, 'free': 0.0, 'walls': 0.0, 'fitness': None,
                                'note': 'merge failed: %s: %s' % (type(e).__name__, e)})
            continue
        p = point(merged, truth, starts[ref])
        p.update(t=t, placed=1 + len(placed))
        team_series.append(p)
    finals = {r: load_map(p + '.yaml') for r, p in team.items()}
    merged_end, placed_end = merge(finals, ref)
    end_team = point(merged_end, truth, starts[ref])
    end_team.update(t=round(team_end, 1), placed=1 + len(placed_end))
    team_series.append(end_team)
    log('team: %d points to %.0f s' % (len(team_series), team_end))

    single_series = []
    for t in sorted(single_snaps):
        p = point(load_map(single_snaps[t]), truth, single_start)
        p['t'] = t
        single_series.append(p)
    single_final = load_map(single + '.yaml')
    p = point(single_final, truth, single_start)
    p['t'] = round(single_end, 1)
    single_series.append(p)
    log('single: %d points to %.0f s' % (len(single_series), single_end))

    # at equal time: the lone robot's map as it stood when the team finished (its last snapshot
    # at or before the team's end)
    before = [t for t in single_snaps if t <= team_end]
    single_at_team_end = load_map(single_snaps[max(before)]) if before else None
    out: Dict[str, Any] = {
        'every_s': every, 'tolerance_m': TOLERANCE_M, 'reference': ref,
        'team_end_s': round(team_end, 1), 'single_end_s': round(single_end, 1),
        'team': team_series, 'single': single_series,
        'equal_time': {'t': round(team_end, 1), 'single_snapshot_t': max(before) if before else None,
                       'team': full_score(merged_end, truth, starts[ref]),
                       'single': (full_score(single_at_team_end, truth, single_start)
                                  if single_at_team_end is not None else {'invalid': 'no snapshot by then'})},
        'end': {'team': dict(full_score(merged_end, truth, starts[ref]), t=round(team_end, 1)),
                'single': dict(full_score(single_final, truth, single_start), t=round(single_end, 1))},
    }
    for who, series in (('team', team_series), ('single', single_series)):
        for level in LEVELS:
            out['%s_t%d' % (who, round(level * 100))] = time_to([(p['t'], p['free']) for p in series], level)
    out['wall_s'] = round(time.time() - t0, 1)
    return out


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog='timeline.py', description=__doc__.split('\n\n')[0])
    ap.add_argument('--truth', required=True, help="the team's truth file (make_robot_bags)")
    ap.add_argument('--world', required=True, help='the ground-truth map (map_server yaml)')
    ap.add_argument('--team', nargs='+', required=True, metavar='ROBOT=PREFIX',
                    help="each team robot's SLAM prefix (PREFIX.yaml, PREFIX.snap/)")
    ap.add_argument('--single', required=True, metavar='PREFIX', help="the lone robot's SLAM prefix")
    ap.add_argument('--every', type=float, required=True, help='the snapshot period, s of bag time')
    ap.add_argument('--out', required=True, help='timeline JSON to write')
    a = ap.parse_args(argv)
    team = {}
    for item in a.team:
        name, _, prefix = item.partition('=')
        if not prefix:
            ap.error('--team wants ROBOT=PREFIX, got %r' % item)
        team[name] = prefix
    doc = run(a.truth, a.world, team, a.single, a.every, log=lambda s: print('timeline: ' + s, flush=True))
    tmp = a.out + '.tmp'
    with open(tmp, 'w') as f:
        json.dump(doc, f, indent=1)
    os.replace(tmp, a.out)
    print('timeline: team T90 %s s, T99 %s s; single T90 %s s, T99 %s s; %.0f s'
          % (doc['team_t90'], doc['team_t99'], doc['single_t90'], doc['single_t99'], doc['wall_s']))
    return 0


if __name__ == '__main__':
    sys.exit(main())
