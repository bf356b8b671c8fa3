#!/usr/bin/env python3
"""Do the placements' covariances cover the real error, on REAL SLAM maps of REAL laser logs?
And how well does each robot's SLAM map fit the log's ground truth?

    bench/bench.py bend-sweep [--logs aces,fhw,...] [--robots 3,4] [--seeds 1,2] [--cases 'aces-*']
                                [--slam rbpf|gmapping] [--config KEY=VALUE ...] [--slam-param KEY=VALUE ...]
                                [--merge-only] [--no-fit] [--stem bend_sweep]
                                [--work /tmp/mmm_bend] [--jobs 1] [--port 13500]

A case is one CARMEN log (``../shared/data/carmen/LOG-corrected.log.gz``) cut into N robots with
one seed, named ``LOG-Nr-sS`` (``--cases`` takes comma-separated fnmatch patterns of those names):

1. ``make_robot_bags --carmen LOG --world LOG_gt.yaml --robots N --seed S --sensors-only``
   (lab/simulate.py ``simulate_carmen``): the log cut into N consecutive stretches grown by 25%
   at both ends, real scans, odometry with the simulator's Burger-like errors on top of the
   corrected poses; its truth file holds each robot's true start pose in the log's frame;
2. one real SLAM run per robot (bench/accuracy.py ``run_gmapping``, every scan, its own roscore):
   ``--slam rbpf`` (the default) ``rbpf_slam_replay``, ``--slam gmapping`` ``slam_gmapping_replay``
   where ROS has gmapping (elsewhere every case is INVALID and says why); either with
   config/gmapping_default.yaml (gmapping's defaults, 30 particles) and ``SLAM_PARAMS`` over it
   (see there: the CARMEN logs' SICK laser, not a Turtlebot3's LDS-02);
3. one ``MapMerger.estimate()`` on the final maps (``MergeConfig(reference_robot='tb3_0',
   workers=1)`` + ``--config``), and per placed robot (``MapMerger.status()``): its error
   against the truth (its true start pose relative to the reference's), the reported 2-sigma
   position (``covariance.position_sigma``), the squared Mahalanobis distance of (dx, dy, dyaw)
   under the placement's covariance, covered at 95% (chi-square 3 dof < 7.81; position only, 2
   dof < 5.99), weak or not, off or not (bench/bend_summary.py ``OFF``: > 0.10 m or > 1 degree;
   also counted at ``OFF_WIDE``, 0.2 m or 2 degrees). Unless ``--no-fit``, also the error against
   the truth by the maps' best rigid fits to the ground-truth map (lab/evaluate.py through
   accuracy.py ``best_score``; the fit of the reference's map against the fit of the robot's):
   what is left of the error when a map's own bend is not counted as the merger's. Each robot's
   final map's Fitness against the ground truth (lab/evaluate.py through accuracy.py
   ``best_score``: from its robot's known start and from the eight headings of
   ``best_fit_score``, the best kept; ``own_fit`` per case in the JSON, per log mean and worst in
   ``own_maps`` with the SLAM's CPU seconds and its scans processed of those in the bags).

The last line printed::

    bend sweep: N placements in C cases; within 95% ellipse P%; off K, flagged weak W of them; worst E m (2-sigma S m)

(P over the placements with a covariance, 3 dof). A case whose bags or SLAM failed is
INVALID with why, never a number, and counted in no figure.

Bags, SLAM maps and best fits are cached under ``--work`` (default /tmp/mmm_bend), keyed by
their inputs (log, seed, robots, the simulator's sources; the SLAM, its settings and binary;
rbpf_slam's maps in ``rbpf_slam/``, gmapping's in ``gmapping/``): a rerun only merges (seconds per
case), e.g. after a change of core/covariance.py; ``--merge-only`` never runs a SLAM (a case
without cached maps is INVALID). Runs at nice 15, ``--jobs`` (1) heavy steps at a time;
everything it starts is stopped on exit. Writes bench/results/STEM.{json,txt} (``--stem``,
default bend_sweep; bend_sweep_gmapping with ``--slam gmapping``). The JSON keeps gmapping's key
names for the SLAM's runs (``gmapping``, ``gmapping_params``, ...); ``args.slam`` says which
SLAM made them. Run it with Debian's
/usr/bin/python3 and the workspace sourced (``make bend-sweep ARGS=...`` does both).
"""
from __future__ import annotations

import argparse
import fnmatch
import json
import os
import signal
import sys
import threading
import time
import traceback
from typing import Any, Dict, List, Optional

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)

import accuracy_cache  # noqa: E402  (cache keys, bags)
import accuracy_common as acc  # noqa: E402  (processes, roscores, printed lines, scheduler)
import accuracy_scoring  # noqa: E402  (best_score)
import accuracy_slam  # noqa: E402  (SLAM runs)
import results  # noqa: E402
from accuracy_summary import group_reasons  # noqa: E402
from bend_summary import (  # noqa: E402
    own_maps,
    own_maps_lines,
    placement_record,
    relative,
    summarize,
    summary_lines,
)

DATA = os.path.join(acc.SHARED, 'data')
# the logs of the default sweep, cheapest first (FLASER records, i.e. scans, and seconds of log:
# seattle 241 / 1165 s, freiburg-101 293 / 1077, edmonton 341 / 726, aces 441 / 1339, fhw 489 /
# 2187, acapulco 861 / 1364; a case maps about 1.5x its log's scans, at about 0.13 CPU s a scan);
# also usable: intel 911 / 2684, freiburg-079 4792 / 1062 (costly). Not usable: orebro and
# freiburg-campus (every timestamp 0), belgioioso, csail and infinite-corridor (timestamps
# written with 6 digits: 1000 s steps): their robots' scans all fall at one instant, and gmapping
# drops them (a case says INVALID). (Those figures are gmapping's, 2026-12-02.)
LOGS = ['seattle', 'freiburg-101', 'edmonton', 'aces', 'fhw', 'acapulco']
# a robot's SLAM that dropped more than this share of its bag's scans (gmapping's "Dropping old
# scan", rbpf_slam_replay's scans without TF) made no map of its stretch: INVALID
MAX_DROPPED = 0.1
# gmapping's defaults, for either SLAM (rbpf_slam reads gmapping's names)
SLAM_CONFIG = os.path.join(REPO, 'config', 'gmapping_default.yaml')
# over gmapping_default.yaml (gmapping's own settings, made for a SICK laser like the logs': 30
# particles, 0.05 m cells, linearUpdate 1 m, angularUpdate 0.5 rad; a map every 2 s): the logs'
# SICK LMS reads to 80 m, make_robot_bags keeps returns under 40 m (its scans' range_max), and
# gmapping's maxUrange would default to that. 20 m keeps for the map the beams whose endpoints a
# heading error of half a degree moves by at most 0.17 m. Measured on intel's first of 3 robots
# (379 scans): 52 CPU s at 20 m, 48 at 40 m (no saving), maps alike. maxRange stays gmapping's
# default (range_max - 0.01).
SLAM_PARAMS: Dict[str, Any] = {'maxUrange': 20.0}
NICENESS = 15
REFERENCE = 'tb3_0'

# printed lines, also kept for bend_sweep.txt: accuracy.py's (its runs print through it too)
say = acc.say
_out_lines = acc._out_lines


def log_path(log: str) -> str:
    return os.path.join(DATA, 'carmen', '%s-corrected.log.gz' % log)


def truth_map_path(log: str) -> str:
    return os.path.join(DATA, 'ground_truth', '%s_gt.yaml' % log)


class Case:
    """One log cut into ``n`` robots with one seed: bags, n SLAM runs (``self.gm``), one merge."""

    def __init__(self, index: int, log: str, n: int, seed: int):
        self.index, self.log, self.n, self.seed = index, log, n, seed
        self.name = '%s-%dr-s%d' % (log, n, seed)
        self.robots = ['tb3_%d' % k for k in range(n)]
        self.lock = threading.Lock()
        self.bag: Dict[str, Any] = {}
        self.gm: Dict[str, Dict[str, Any]] = {}
        self.fits: Dict[str, Any] = {}
        self.result: Optional[Dict[str, Any]] = None

    # --- 1. bags
    def make_bags(self) -> None:
        carmen, world = log_path(self.log), truth_map_path(self.log)
        args = ['--robots', str(self.n), '--seed', str(self.seed), '--sensors-only']
        doc = {'carmen': os.path.basename(carmen), 'carmen_digest': accuracy_cache.file_digest(carmen),
               'world_digest': accuracy_cache.world_digest(world) if os.path.exists(world) else None, 'args': args,
               'sources': {os.path.relpath(p, REPO): accuracy_cache.file_digest(p) for p in acc.SIM_SOURCES
                           if os.path.exists(p)}}
        key = accuracy_cache.key_of(doc)
        d = os.path.join(ARGS.work, 'bags', '%s-%s' % (self.name, key))
        self.bag = {'dir': d, 'key': key, 'team': os.path.join(d, 'team.bag'),
                    'truth': os.path.join(d, 'team.truth.yaml')}
        cached = accuracy_cache.cached_bags(d)
        if cached is not None:
            self.bag.update(cached, cached=True)
            return
        if ARGS.merge_only:
            raise RuntimeError('bags not cached (--merge-only)')
        say('%s %s: making the bags (make_robot_bags --carmen %s %s) ...' % (acc.stamp(), self.name,
                                                                             os.path.basename(carmen), ' '.join(args)))

        def cmd(tmp):
            c = [acc.PY, os.path.join(REPO, 'scripts', 'make_robot_bags'), '-o', os.path.join(tmp, 'team.bag'),
                 '--carmen', carmen] + args
            return c + (['--world', world] if os.path.exists(world) else [])
        r = accuracy_cache.make_bags_dir(d, doc, cmd)
        self.bag.update(wall_s=r['wall_s'], cpu_s=r['cpu_s'], cached=False)
        say('%s %s: bags made in %.0f s' % (acc.stamp(), self.name, r['wall_s']))

    def truth_doc(self) -> Dict[str, Any]:
        from multi_map_merge.lab.evaluate import load_truth
        return load_truth(self.bag['truth'])

    # --- 2. one robot's SLAM
    def gmapping(self, robot: str) -> None:
        res = self._gmapping(robot)
        with self.lock:
            self.gm[robot] = res
        label = acc.SLAMS[ARGS.slam]['label']
        if res.get('invalid'):
            say('%s %s: %s %s INVALID: %s' % (acc.stamp(), self.name, label, robot, res['invalid']))
        elif not res.get('cached'):
            say('%s %s: %s %s %4d scans in its bag, %4d processed, %.0f s wall, %s CPU s' % (
                acc.stamp(), self.name, label, robot, res['scans'], res['processed'], res['wall_s'], res['cpu_s']))

    def _gmapping(self, robot: str) -> Dict[str, Any]:
        meta = self._gmapping_run(robot)
        lost = (meta.get('dropped') or 0) + (meta.get('without_tf') or 0)
        if not meta.get('invalid') and lost > MAX_DROPPED * max(1, meta.get('scans', 0)):
            meta = dict(meta, invalid='%s dropped %d of %d scans (%d processed; %s)' % (
                acc.SLAMS[ARGS.slam]['label'], lost, meta['scans'], meta['processed'], meta.get('log')))
        return meta

    def _gmapping_run(self, robot: str) -> Dict[str, Any]:
        slam = ARGS.slam
        exe = accuracy_slam.replay_binary(slam)
        topic = '/%s/scan' % robot
        # each SLAM's maps in a directory of its own, keyed by the SLAM and its binary too
        d = os.path.join(ARGS.work, acc.SLAMS[slam]['cache'], '%s-%s' % (self.name, self.bag['key']))
        prefix = os.path.join(d, robot)
        doc = {'bag': self.bag['key'], 'robot': robot, 'topic': topic, 'gmapping_seed': self.seed, 'slam': slam,
               'config': accuracy_cache.file_digest(SLAM_CONFIG), 'params': ARGS.gmapping_params}
        if exe is not None:
            st = os.stat(exe)
            doc['binary'] = [exe, st.st_size, int(st.st_mtime)]
        key = accuracy_cache.key_of(doc)
        if os.path.exists(prefix + '.json'):
            with open(prefix + '.json') as f:
                meta = json.load(f)
            if meta.get('key') == key or (ARGS.merge_only and exe is None):
                meta['cached'] = True
                return meta
        if ARGS.merge_only:
            return {'invalid': '%s map not cached (--merge-only)' % acc.SLAMS[slam]['label']}
        if exe is None:
            return {'invalid': accuracy_slam.slam_missing(slam)}
        os.makedirs(d, exist_ok=True)
        info = self.truth_doc()['robots'].get(robot, {})
        timeout = 600.0 + 4.0 * float(info.get('duration_s', 1800.0))
        return accuracy_slam.run_gmapping(exe, self.bag['team'], topic, robot, self.seed, SLAM_CONFIG, prefix,
                                {'key': key, 'args': doc, 'robot': robot}, timeout, ARGS.port,
                                os.path.join(ARGS.work, 'ros_home'), ARGS.gmapping_params, slam=slam)

    # --- best rigid fit of a map to the ground truth (cached beside the map)
    def best_fit(self, robot: str, grid, truth, start) -> Dict[str, Any]:
        """``robot``'s map's best fit to the log's ground truth (accuracy.py ``best_score`` from its
        known ``start`` and the eight headings): {'pose' (None when it cannot be scored),
        'fitness', 'from_start_pose' (the Fitness from the start pose alone), 'coverage', 'from',
        'invalid', 'seconds'}, kept in MAP.fit.json."""
        from multi_map_merge.core.transforms import se2, xyyaw
        g = self.gm[robot]
        path = os.path.splitext(g['map'])[0] + '.fit.json'
        key = accuracy_cache.key_of({'map': accuracy_cache.file_digest(os.path.splitext(g['map'])[0] + '.pgm'),
                          'truth': accuracy_cache.world_digest(truth_map_path(self.log)), 'start': list(start)})
        if os.path.exists(path):
            with open(path) as f:
                fit = json.load(f)
            if fit.get('key') == key:
                return fit
        t = time.time()
        s = accuracy_scoring.best_score(grid, truth, [se2(*start)])
        import numpy as np
        fit = {'key': key, 'pose': list(xyyaw(np.array(s['T']))) if 'T' in s else None,
               'fitness': s.get('fitness'), 'from_start_pose': s.get('from_start_pose'),
               'coverage': s.get('coverage'), 'inlier_rmse': s.get('inlier_rmse'), 'from': s.get('from'),
               'invalid': s.get('invalid'), 'seconds': round(time.time() - t, 1)}
        with open(path, 'w') as f:
            json.dump(fit, f, indent=1)
        return fit

    def own_fits(self) -> Dict[str, Dict[str, Any]]:
        """Each robot's final map with a map (its SLAM run valid) scored against the log's ground
        truth from its known start (``best_fit``): {robot: fit}; {} without ``--fit`` or truth."""
        from multi_map_merge.core.mapio import load_map
        if not ARGS.fit or not os.path.exists(truth_map_path(self.log)):
            return {}
        truth = load_map(truth_map_path(self.log))
        starts = {r: list(v['start']) for r, v in self.truth_doc()['robots'].items()}
        out = {}
        for r in self.robots:
            g = self.gm.get(r) or {}
            if g.get('invalid') or not g.get('map') or r not in starts:
                continue
            out[r] = self.best_fit(r, load_map(g['map']), truth, starts[r])
        return out

    # --- 3. the merge
    def merge(self) -> None:
        t0 = time.time()
        try:
            self.result = self._merge()
        except Exception as e:                    # noqa: BLE001 (the case says INVALID and why)
            traceback.print_exc()
            self.result = {'invalid': 'merge failed: %s: %s' % (type(e).__name__, e)}
        self.result['merge_wall_s'] = round(time.time() - t0, 1)
        self.report()
        write_results()

    def _merge(self) -> Dict[str, Any]:
        import numpy as np

        from multi_map_merge.core import covariance
        from multi_map_merge.core.config import MergeConfig
        from multi_map_merge.core.mapio import load_map
        from multi_map_merge.core.merger import MapMerger
        from multi_map_merge.core.transforms import xyyaw
        bad = [(r, self.gm.get(r, {}).get('invalid', 'not run')) for r in self.robots
               if not self.gm.get(r) or self.gm[r].get('invalid')]
        t = time.time()
        own = self.own_fits()         # every robot's own map against the truth, also in a case that fails
        fit_s = time.time() - t
        own_fit = {r: {k: f.get(k) for k in ('fitness', 'from_start_pose', 'coverage', 'inlier_rmse', 'from',
                                             'invalid')} for r, f in own.items()}
        if bad:
            return {'invalid': group_reasons(bad), 'own_fit': own_fit}
        td = self.truth_doc()
        starts = {r: list(td['robots'][r]['start']) for r in self.robots}
        maps = {r: load_map(self.gm[r]['map']) for r in self.robots}
        cfg = dict(ARGS.merge_config)
        cfg.setdefault('workers', 1)
        cfg.setdefault('reference_robot', REFERENCE)
        m = MapMerger(MergeConfig(**cfg))
        for r in self.robots:
            m.update_map(r, maps[r])
        t = time.time()
        m.estimate()
        est_s = time.time() - t
        fits: Dict[str, Optional[List[float]]] = {r: f.get('pose') for r, f in own.items()}
        ref = m.reference
        recs, unplaced = [], []
        pairs = m.pair_results()
        for r, st in sorted(m.status().items()):
            if st.reference:
                continue
            pl = st.placement
            if not st.merged or pl is None:
                unplaced.append({'robot': r, 'pairs': {'%s-%s' % ab: (pr.reason or 'linked')
                                                       for ab, pr in sorted(pairs.items()) if r in ab}})
                continue
            cov = None if pl.cov is None else np.asarray(pl.cov, float)
            fit_true = relative(fits[ref], fits[r]) if fits.get(ref) and fits.get(r) else None
            rec = placement_record(r, list(xyyaw(pl.T)), relative(starts[ref], starts[r]), cov,
                                   None if cov is None else covariance.position_sigma(cov), pl.weak,
                                   pl.via, fit_true)
            rec['case'] = self.name
            recs.append(rec)
        # every kept link against the robots' starts, its covariance as placements count it
        # (with each map's drift from its origin: placement.drift_covs)
        from multi_map_merge.core.placement import drift_covs
        kept = m.links()
        keys = sorted(kept)
        link_recs = []
        for (a, b), C in zip(keys, drift_covs(m.config, kept, [(a, b, kept[(a, b)].T, 1.0) for a, b in keys])):
            e = kept[(a, b)]
            cov = None if C is None else np.asarray(C, float)
            rec = placement_record('%s-%s' % (a, b), list(xyyaw(e.T)), relative(starts[a], starts[b]), cov,
                                   None if cov is None else covariance.position_sigma(cov), False, a,
                                   relative(fits[a], fits[b]) if fits.get(a) and fits.get(b) else None)
            rec['case'] = self.name
            link_recs.append(rec)
        return {'reference': ref, 'placements': recs, 'links': link_recs, 'unplaced': unplaced, 'own_fit': own_fit,
                'estimate_s': round(est_s, 2),
                'fit_s': round(fit_s, 1),
                'map_cells': {r: [int(g.width), int(g.height)] for r, g in maps.items()}}

    # --- reporting
    def timing(self) -> Dict[str, Any]:
        runs = [g for g in self.gm.values() if 'wall_s' in g]
        return {'bags_wall_s': self.bag.get('wall_s'), 'bags_cached': bool(self.bag.get('cached')),
                'gmapping_wall_s_sum': round(sum(g['wall_s'] or 0 for g in runs), 1),
                'gmapping_cpu_s_sum': round(sum(g.get('cpu_s') or 0 for g in runs), 1),
                'gmapping_cached': sorted(r for r, g in self.gm.items() if g.get('cached')),
                'merge_wall_s': (self.result or {}).get('merge_wall_s'),
                'estimate_s': (self.result or {}).get('estimate_s'), 'fit_s': (self.result or {}).get('fit_s')}

    def as_json(self) -> Dict[str, Any]:
        res = self.result or {'invalid': 'not completed'}
        return dict({'name': self.name, 'log': self.log, 'robots': self.n, 'seed': self.seed, 'bags': self.bag,
                     'gmapping': self.gm, 'timing': self.timing()}, **res)

    def report(self) -> None:
        res = self.result
        t = self.timing()
        lines = ['', '== %s (%s cut into %d, seed %d)' % (self.name, os.path.basename(log_path(self.log)),
                                                           self.n, self.seed)]
        gl = []
        for r in self.robots:
            g = self.gm.get(r, {})
            gl.append('%s %s/%s' % (r, g.get('processed', '-'), g.get('scans', '-')))
        label = acc.SLAMS[ARGS.slam]['label']
        lines.append('  %s processed/scans: %s; %s %s %.0f s wall, %.0f CPU s%s; merge %.1f s '
                     '(estimate %s s, fits %s s)'
                     % (label, ', '.join(gl), 'bags cached,' if t['bags_cached'] else 'bags %s s,' % (t['bags_wall_s']
                                                                                                  or '-'), label,
                        t['gmapping_wall_s_sum'], t['gmapping_cpu_s_sum'],
                        ' (cached: %s)' % ' '.join(t['gmapping_cached']) if t['gmapping_cached'] else '',
                        res.get('merge_wall_s') or 0, res.get('estimate_s', '-'), res.get('fit_s', '-')))
        fits = res.get('own_fit') or {}
        if fits:
            lines.append('  own maps against the truth (Fitness; from the start pose alone): %s' % ', '.join(
                '%s %s (%s)' % (r, '-' if f.get('fitness') is None else '%.4f' % f['fitness'],
                                '-' if f.get('from_start_pose') is None else '%.4f' % f['from_start_pose'])
                for r, f in sorted(fits.items())))
        if res.get('invalid'):
            lines.append('  INVALID: %s' % res['invalid'])
            say(*lines)
            return
        lines.append('  %-6s %-6s %7s %7s %8s %7s %7s %-5s %-4s %-4s %s' % (
            'robot', 'via', 'err m', 'err deg', '2sig m', 'd2', 'd2 pos', 'in95', 'weak', 'off', 'fit: err m / deg'))
        for x in res['placements']:
            f = x.get('fit')
            lines.append('  %-6s %-6s %7.3f %7.2f %8s %7s %7s %-5s %-4s %-4s %s' % (
                x['robot'], x['via'], x['err_m'], x['err_deg'],
                '-' if x['sigma2_m'] is None else '%.3f' % x['sigma2_m'],
                '-' if x['d2'] is None else '%.1f' % x['d2'], '-' if x['d2_pos'] is None else '%.1f' % x['d2_pos'],
                '-' if x['in95'] is None else ('yes' if x['in95'] else 'NO'), 'yes' if x['weak'] else 'no',
                'OFF' if x['off'] else '-', '%.3f / %.2f' % (f['err_m'], f['err_deg']) if f else '-'))
        if res['unplaced']:
            for u in res['unplaced']:
                lines.append('  not placed: %s (%s)' % (u['robot'], '; '.join(
                    '%s %s' % kv for kv in sorted(u['pairs'].items())) or 'no pair tried'))
        say(*lines)


# ------------------------------------------------------------------------------ plan, results

CASES: List[Case] = []
_write_lock = threading.Lock()


def plan(case: Case, sched: 'acc.Scheduler') -> None:
    """bags -> one SLAM run per robot -> the merge, the earliest case first."""
    i = case.index
    left = {'n': case.n}

    def gm(robot):
        return acc.slam_job(case, robot, ARGS.slam, left, lambda: sched.submit((i, 0), case.merge))

    def bags():
        try:
            case.make_bags()
        except Exception as e:                    # noqa: BLE001
            if not ARGS.merge_only:
                traceback.print_exc()
            case.result = {'invalid': 'bags not made: %s' % e}
            case.report()
            write_results()
            return
        for k, r in enumerate(case.robots):
            sched.submit((i, 1 + k), gm(r))

    sched.submit((i, 0), bags)


def write_results(final: bool = False) -> Dict[str, Any]:
    with _write_lock:
        done = [c for c in CASES if c.result is not None]
        cases = [c.as_json() for c in done]
        s = summarize(cases)
        own = own_maps(cases)
        lines = own_maps_lines(own, acc.SLAMS[ARGS.slam]['label']) + summary_lines(s)
        doc = {'complete': final and len(done) == len(CASES), 'line': lines[-1], 'summary': s, 'own_maps': own,
               'args': {'cases': [c.name for c in CASES], 'work': ARGS.work, 'jobs': ARGS.jobs,
                        'merge_config': ARGS.merge_config, 'fit': ARGS.fit,
                        'slam': ARGS.slam, 'slam_binary': accuracy_slam.replay_binary(ARGS.slam),
                        'gmapping_config': os.path.relpath(SLAM_CONFIG, REPO),
                        'gmapping_params': ARGS.gmapping_params},
               'thresholds': {'chi2_3dof': 7.81, 'chi2_2dof': 5.99, 'off': [0.10, 1.0], 'off_wide': [0.20, 2.0]},
               'runtime_s': round(time.time() - T_START, 1), 'cases': cases}
        os.makedirs(ARGS.results, exist_ok=True)
        config = {k: v for k, v in vars(ARGS).items()}
        results.write_json(os.path.join(ARGS.results, ARGS.stem + '.json'), doc, config, default=acc._json_default)
        results.write_text(os.path.join(ARGS.results, ARGS.stem + '.txt'),
                           _out_lines + ([''] + lines if not final else []), config)
        return {'summary': s, 'lines': lines, 'done': done}


# ------------------------------------------------------------------------------ main

ARGS: Any = None
T_START = time.time()


def _csv(s: str) -> List[str]:
    return [x.strip() for x in s.split(',') if x.strip()]


def _kv(items: List[str], what: str) -> Dict[str, Any]:
    import yaml
    out = {}
    for it in items:
        if '=' not in it:
            raise SystemExit('bend_sweep.py: %s %r: expected KEY=VALUE' % (what, it))
        k, v = it.split('=', 1)
        out[k.strip()] = yaml.safe_load(v)
    return out


def parse_args(argv: Optional[List[str]] = None):
    ap = argparse.ArgumentParser(prog='bend_sweep.py', description=__doc__.split('\n\n')[0])
    ap.add_argument('--logs', default=','.join(LOGS), help='CARMEN logs, comma-separated (default %(default)s)')
    ap.add_argument('--robots', default='3,4', help='robot counts (default 3,4)')
    ap.add_argument('--seeds', default='1,2', help='seeds (default 1,2)')
    ap.add_argument('--cases', default='', help="comma-separated fnmatch patterns of case names, e.g. 'aces-*,*-3r-s1'")
    ap.add_argument('--config', action='append', default=[], metavar='KEY=VALUE',
                    help='a MergeConfig field for the merges (repeatable; VALUE as YAML)')
    ap.add_argument('--slam', choices=sorted(acc.SLAMS), default=acc.DEFAULT_SLAM,
                    help='the SLAM making every map: rbpf (rbpf_slam_replay; the default) or gmapping '
                         '(slam_gmapping_replay, where ROS has gmapping: elsewhere every case is INVALID)')
    ap.add_argument('--slam-param', '--gmapping-param', dest='gmapping_param', action='append', default=[],
                    metavar='KEY=VALUE',
                    help='a SLAM parameter (gmapping\'s names) over SLAM_PARAMS (repeatable; makes new maps)')
    ap.add_argument('--merge-only', action='store_true', help='never run make_robot_bags or a SLAM: cached maps only')
    ap.add_argument('--no-fit', dest='fit', action='store_false',
                    help="skip the error against the maps' best rigid fits (lab/evaluate.py, Open3D)")
    ap.add_argument('--work', default='/tmp/mmm_bend', help='cache of bags, maps, fits (default /tmp/mmm_bend)')
    ap.add_argument('--results', default=os.path.join(HERE, 'results'), help='where STEM.{json,txt} go')
    ap.add_argument('--stem', default=None,
                    help='result file names (default bend_sweep; bend_sweep_gmapping with --slam gmapping)')
    ap.add_argument('--jobs', type=int, default=1, help='heavy steps at once (1 or 2; default 1)')
    ap.add_argument('--port', type=int, default=13500, help='first port tried for the roscores (default 13500)')
    a = ap.parse_args(argv)
    a.log_list = _csv(a.logs)
    for lg in a.log_list:
        if not os.path.exists(log_path(lg)):
            ap.error('no CARMEN log %s' % log_path(lg))
    a.robot_list = [int(x) for x in _csv(a.robots)]
    a.seed_list = [int(x) for x in _csv(a.seeds)]
    a.patterns = _csv(a.cases)
    a.merge_config = _kv(a.config, '--config')
    a.gmapping_params = dict(SLAM_PARAMS, **_kv(a.gmapping_param, '--slam-param'))
    if a.stem is None:
        a.stem = 'bend_sweep' + ('' if a.slam == acc.DEFAULT_SLAM else '_' + a.slam)
    a.jobs = max(1, min(2, a.jobs))
    a.work = os.path.abspath(a.work)
    return a


def main(argv: Optional[List[str]] = None) -> int:
    global ARGS
    ARGS = parse_args(argv)
    acc.ARGS = ARGS            # accuracy's helpers that read its ARGS (none of those used here need more)
    os.makedirs(ARGS.work, exist_ok=True)
    if os.nice(0) < NICENESS:
        os.nice(NICENESS - os.nice(0))

    def on_signal(sig, _frame):
        raise SystemExit(128 + sig)
    for s in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, on_signal)
    try:
        k = 0
        for seed in ARGS.seed_list:          # every log's first seed first: early results span the logs
            for lg in ARGS.log_list:
                for n in ARGS.robot_list:
                    c = Case(k, lg, n, seed)
                    if ARGS.patterns and not any(fnmatch.fnmatch(c.name, p) for p in ARGS.patterns):
                        continue
                    CASES.append(c)
                    k += 1
        exe = accuracy_slam.replay_binary(ARGS.slam)
        say('bend sweep: %d cases (%s); work dir %s; %d job(s) at once, nice %d; merge config %s'
            % (len(CASES), ', '.join(c.name for c in CASES), ARGS.work, ARGS.jobs, NICENESS,
               json.dumps(ARGS.merge_config) if ARGS.merge_config else 'defaults'),
            'bend sweep: SLAM %s: %s, %s + %s%s' % (
                ARGS.slam, exe or 'NONE: every case is INVALID: %s' % accuracy_slam.slam_missing(ARGS.slam),
                os.path.relpath(SLAM_CONFIG, REPO), json.dumps(ARGS.gmapping_params),
                '; --merge-only' if ARGS.merge_only else ''))
        sched = acc.Scheduler()
        for c in CASES:
            plan(c, sched)
        sched.run(ARGS.jobs)
        for c in CASES:
            if c.result is None:
                c.result = {'invalid': 'not completed'}
        res = write_results(final=True)
        say('', '== summary')
        say(*res['lines'])
        write_results(final=True)
        return 0
    except KeyboardInterrupt:
        say('bend sweep: interrupted')
        return 130
    finally:
        acc.stop_all()


if __name__ == '__main__':
    sys.exit(main())
