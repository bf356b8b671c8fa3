"""One condition of ``make accuracy`` (a world and a seed): its bags, its five SLAM runs, its
merges and scores, its coverage over time (bench/timeline.py), its report; and the chain of its
jobs (``plan``)."""
from __future__ import annotations

import os
import threading
import time
import traceback
from typing import Any, Dict, Optional

import accuracy_common as C
import accuracy_scoring as scoring
from accuracy_cache import (
    BAG_FILES,
    bag_contents,
    cached_bags,
    file_digest,
    key_of,
    make_bags_dir,
    read_json,
    resolve_gmapping,
    world_digest,
)
from accuracy_common import (
    BAG_ARGS,
    HERE,
    PY,
    REPO,
    SIM_SOURCES,
    SINGLE,
    SLAMS,
    TEAM,
    WORLDS,
    Scheduler,
    child_env,
    run_timed,
    say,
    stamp,
)
from accuracy_scoring import best_score, compose_maps, placement_checks
from accuracy_slam import replay_binary, run_gmapping, slam_missing
from accuracy_summary import ROW_NAMES, ROWS, Invalid, fmt, group_reasons, is_valid, loss, mean, timeline_lines, to_json

# ------------------------------------------------------------------------------ a condition

class Condition:
    """One world and seed: its bags, its five SLAM runs (``self.gm``), its scores."""

    def __init__(self, index: int, world: str, seed: int):
        self.index, self.world, self.seed = index, world, seed
        self.world_yaml, self.title = WORLDS[world]
        self.lock = threading.Lock()
        self.gm: Dict[str, Dict[str, Any]] = {}
        self.bag: Dict[str, Any] = {}
        self.t_first: Optional[float] = None
        self.t_done: Optional[float] = None
        self.result: Optional[Dict[str, Any]] = None
        self.run_dir = os.path.join(C.ARGS.work, 'runs', '%s-s%d' % (world, seed))

    @property
    def name(self) -> str:
        return '%s seed %d' % (self.world, self.seed)

    def started(self) -> None:
        with self.lock:
            if self.t_first is None:
                self.t_first = time.time()

    # --- 1. bags
    def make_bags(self) -> None:
        self.started()
        doc = {'world': os.path.abspath(self.world_yaml), 'world_digest': world_digest(self.world_yaml),
               'seed': self.seed, 'args': BAG_ARGS,
               'sources': {os.path.relpath(p, REPO): file_digest(p) for p in SIM_SOURCES if os.path.exists(p)}}
        key = key_of(doc)
        d = os.path.join(C.ARGS.work, 'bags', '%s-s%d-%s' % (self.world, self.seed, key))
        self.bag = {'dir': d, 'key': key, 'team': os.path.join(d, 'team.bag'),
                    'single': os.path.join(d, 'team_single.bag'), 'truth': os.path.join(d, 'team.truth.yaml')}
        cached = cached_bags(d)
        if cached is not None:
            self.bag.update(cached, cached=True)
            say('%s %s: bags cached (%s)' % (stamp(), self.name, d))
        else:
            say('%s %s: making the bags (make_robot_bags --world %s --seed %d %s) ...'
                % (stamp(), self.name, os.path.relpath(self.world_yaml, REPO), self.seed, ' '.join(BAG_ARGS)))
            r = make_bags_dir(d, doc, lambda tmp: [
                PY, os.path.join(REPO, 'scripts', 'make_robot_bags'), '-o', os.path.join(tmp, 'team.bag'),
                '--world', os.path.abspath(self.world_yaml), '--seed', str(self.seed)] + BAG_ARGS)
            self.bag.update(wall_s=r['wall_s'], cpu_s=r['cpu_s'], cached=False)
            say('%s %s: bags made in %.0f s' % (stamp(), self.name, r['wall_s']))
        # what the bags hold: the SLAM runs are keyed by it (digested once, kept in content.json)
        contents = bag_contents(d, log=self.log)
        if contents is None or any(n not in contents for n in BAG_FILES):
            raise RuntimeError('bags incomplete in %s (%s)' % (d, ', '.join(n for n in BAG_FILES
                                                                             if n not in (contents or {}))))
        self.bag['content'] = {n: contents[n]['sha1'] for n in BAG_FILES}

    def truth_doc(self) -> Dict[str, Any]:
        from multi_map_merge.lab.evaluate import load_truth
        return load_truth(self.bag['truth'])

    def log(self, line: str) -> None:
        say('%s %s: %s' % (stamp(), self.name, line))

    # --- 2. one robot's SLAM (--slam: rbpf_slam or gmapping)
    def gmapping(self, robot: str) -> None:
        self.started()
        res = self._gmapping(robot)
        with self.lock:
            self.gm[robot] = res
        label = SLAMS[C.ARGS.slam]['label']
        if res.get('invalid'):
            say('%s %s: %s %s INVALID: %s' % (stamp(), self.name, label, robot, res['invalid']))
        else:
            say('%s %s: %s %-6s %4d scans in its bag, %4d processed%s, %s' % (
                stamp(), self.name, label, robot, res['scans'], res['processed'],
                ', %d dropped' % res['dropped'] if res.get('dropped') else '',
                'cached' if res.get('cached') else '%.0f s wall, %s CPU s' % (res['wall_s'], res['cpu_s'])))
        if res.get('migrated_now'):
            say('  (an old-scheme result of the same bag content, %s: copied into %s)'
                % (res['migrated_from']['meta'], os.path.dirname(res['map'])))

    def _gmapping(self, robot: str) -> Dict[str, Any]:
        slam = C.ARGS.slam
        exe = replay_binary(slam)
        if exe is None:
            return {'invalid': slam_missing(slam)}
        if robot == SINGLE:
            bag_file, name = 'team_single.bag', self.truth_doc().get('single', {}).get('name', 'tb3_0')
        else:
            bag_file, name = 'team.bag', robot
        bag = os.path.join(self.bag['dir'], bag_file)
        content = self.bag['content'][bag_file]
        topic = '/%s/scan' % name
        st = os.stat(exe)
        # keyed by what the bag holds, not by the sources that made it (a bag remade alike finds it)
        # and by the SLAM, its config and its binary ('gmapping_seed': the SLAM's seed, the old name)
        doc = {'bag': content, 'robot': robot, 'topic': topic, 'gmapping_seed': self.seed, 'slam': slam,
               'config': file_digest(SLAMS[slam]['config']), 'binary': [exe, st.st_size, int(st.st_mtime)]}
        every = self.snapshot_every() if slam == 'rbpf' else None
        if every:      # the maps along the way too (bench/timeline.py): another run than one without
            doc['snapshot_every'] = every
        key = key_of(doc)
        prefix, meta = resolve_gmapping(C.ARGS.work, self.world, self.seed, robot, bag_file, content, doc,
                                        log=self.log)
        if meta is not None:
            return meta
        td = self.truth_doc()
        info = td.get('single', {}) if robot == SINGLE else td['robots'].get(name, {})
        timeout = 600.0 + 4.0 * float(info.get('duration_s', 1800.0))
        return run_gmapping(exe, bag, topic, name, self.seed, SLAMS[slam]['config'], prefix,
                            {'key': key, 'args': doc, 'robot': robot}, timeout, C.ARGS.port,
                            os.path.join(C.ARGS.work, 'ros_home'), slam=slam, snapshot_every=every)

    def snapshot_every(self) -> float:
        """The SLAM's snapshot period here (s of bag time; timeline.snapshot_every of the lone
        robot's drive)."""
        import timeline
        return timeline.snapshot_every(float(self.truth_doc().get('single', {}).get('duration_s', 500.0)))

    # --- 4. coverage over time (bench/timeline.py, a process of its own)
    def timeline(self) -> Dict[str, Any]:
        if C.ARGS.slam != 'rbpf':
            return {'invalid': 'coverage over time needs rbpf_slam\'s snapshots (--slam rbpf)'}
        bad = [r for r in TEAM + [SINGLE] if (self.gm.get(r) or {}).get('invalid') or r not in self.gm]
        if bad:
            return {'invalid': 'SLAM runs missing: %s' % ', '.join(bad)}
        prefix = {r: os.path.splitext(self.gm[r]['map'])[0] for r in TEAM + [SINGLE]}
        out = os.path.join(self.run_dir, 'timeline.json')
        if os.path.exists(out):
            os.remove(out)
        cmd = [PY, os.path.join(HERE, 'timeline.py'), '--truth', self.bag['truth'], '--world', self.world_yaml,
               '--every', str(self.snapshot_every()), '--out', out, '--single', prefix[SINGLE],
               '--team'] + ['%s=%s' % (r, prefix[r]) for r in TEAM]
        log = os.path.join(self.run_dir, 'timeline.log')
        r = run_timed(cmd, log, child_env(), 3600)
        doc = read_json(out)
        if r['rc'] != 0 or not isinstance(doc, dict):
            return {'invalid': 'timeline.py failed (exit %s, %s)' % (r['rc'], log)}
        doc['cpu_s'] = r['cpu_s']
        return doc

    # --- 3. merges and scores
    def score(self) -> None:
        """Merges and scores, then the coverage over time; ``self.result`` is set once both are
        done (the results written meanwhile by other conditions list this one as not done)."""
        t0 = time.time()
        try:
            result = self._score()
        except Exception as e:                    # noqa: BLE001 (named in the row and printed)
            traceback.print_exc()
            why = 'scoring failed: %s: %s' % (type(e).__name__, e)
            result = {'rows': {r: Invalid(why) for r in ROWS}, 'details': {}, 'merged_counts': {}}
        try:
            result['timeline'] = self.timeline()
        except Exception as e:                    # noqa: BLE001 (named in the report and printed)
            traceback.print_exc()
            result['timeline'] = {'invalid': 'timeline failed: %s: %s' % (type(e).__name__, e)}
        self.t_done = time.time()
        result['score_wall_s'] = round(self.t_done - t0, 1)
        self.result = result
        self.report()
        C.WRITE_RESULTS()

    def _score(self) -> Dict[str, Any]:
        import numpy as np

        from multi_map_merge.core.mapio import MapFileError, load_map
        from multi_map_merge.core.transforms import se2
        truth_doc = self.truth_doc()
        truth = load_map(self.world_yaml)
        starts = truth_doc['starts']
        os.makedirs(self.run_dir, exist_ok=True)
        rows: Dict[str, Any] = {}
        details: Dict[str, Any] = {}
        counts: Dict[str, str] = {}

        def gm_map(robot):
            g = self.gm.get(robot) or {'invalid': 'not run'}
            if g.get('invalid'):
                return None, g['invalid']
            try:
                return load_map(g['map']), None
            except MapFileError as e:
                return None, str(e)

        # the single robot
        g, why = gm_map(SINGLE)
        if g is None:
            rows['single'] = Invalid('lone robot: %s' % why)
        else:
            s = best_score(g, truth, [se2(*truth_doc['single']['start'])])
            rows['single'] = s['fitness'] if 'fitness' in s else Invalid(s['invalid'])
            details['single'] = s
        # the robots' own maps, each alone, and their best fits
        maps, bad = {}, []
        for r in TEAM:
            g, why = gm_map(r)
            if g is None:
                bad.append((r, why))
            else:
                maps[r] = g
        own = {}
        for r, g in maps.items():
            own[r] = best_score(g, truth, [starts[r]])
        details['own'] = own
        if bad:
            for k in ('own', 'rigid', 'merged', 'merged_rigid', 'mexplore', 'mrpt'):
                rows[k] = Invalid(group_reasons(bad))
        else:
            vals = [own[r]['fitness'] if 'fitness' in own[r] else Invalid(own[r]['invalid']) for r in TEAM]
            rows['own'] = mean(vals)
            # the rigid bound: every map at its own best fit, composited in the truth's frame
            if all(is_valid(v) for v in vals):
                poses = {r: np.array(own[r]['T']) for r in TEAM}
                grid = compose_maps(maps, poses, truth, 'world')
                s = best_score(grid, truth, [np.eye(3)])
                rows['rigid'] = s['fitness'] if 'fitness' in s else Invalid(s['invalid'])
                details['rigid'] = s
            else:
                rows['rigid'] = Invalid('an own map could not be scored')
            # every robot's map frame where its robot really started (the reference's start in
            # the truth's frame): what knowing the start poses exactly would give
            grid = compose_maps(maps, {r: starts[r] for r in TEAM}, truth, 'world')
            s = best_score(grid, truth, [np.eye(3)])
            rows['starts'] = s['fitness'] if 'fitness' in s else Invalid(s['invalid'])
            details['starts'] = s
            paths = [self.gm[r]['map'] for r in TEAM]
            # ours
            rows['merged'], counts['merged'], details['merged'] = self.merge_ours(paths, truth, starts)
            # the same placements composited rigidly: what bending the maps (core/deform.py) gained
            rows['merged_rigid'], details['merged_rigid'] = self.unbent(maps, details['merged'], truth, starts)
            if all(is_valid(v) for v in vals) and details['merged'].get('transforms'):
                details['placements'] = placement_checks(details['merged']['transforms'], own, starts)
            # the peers
            for peer in ('mexplore', 'mrpt'):
                if C.PEERS.get(peer):
                    rows[peer] = Invalid(C.PEERS[peer])
                    continue
                rows[peer], counts[peer], details[peer] = self.merge_peer(peer, paths, maps, truth, starts)
        return {'rows': rows, 'details': details, 'merged_counts': counts}

    merge_ours = scoring.merge_ours
    unbent = scoring.unbent
    merge_peer = scoring.merge_peer

    # --- the report of one condition
    def timing(self) -> Dict[str, Any]:
        gm_wall = sum(g.get('wall_s') or 0 for g in self.gm.values() if not g.get('cached'))
        gm_cpu = sum(g.get('cpu_s') or 0 for g in self.gm.values() if not g.get('cached'))
        return {'span_s': round((self.t_done or time.time()) - (self.t_first or time.time()), 1),
                'bags_wall_s': None if self.bag.get('cached') else self.bag.get('wall_s'),
                'gmapping_wall_s_sum': round(gm_wall, 1), 'gmapping_cpu_s_sum': round(gm_cpu, 1),
                'score_wall_s': (self.result or {}).get('score_wall_s'),
                'cached': {'bags': bool(self.bag.get('cached')),
                           'gmapping': sorted(k for k, g in self.gm.items() if g.get('cached'))}}

    def report(self) -> None:
        res = self.result
        t = self.timing()
        rows = res['rows']
        lines = ['', '== %s: %s' % (self.name, self.title)]
        try:
            td = self.truth_doc()
            lines.append('  driven: %s; alone %.1f m' % (', '.join(
                '%s %.1f m' % (k, v.get('distance_m', float('nan'))) for k, v in sorted(td['robots'].items())),
                td.get('single', {}).get('distance_m', float('nan'))))
        except Exception:                         # noqa: BLE001 (the truth file's trouble is in the rows)
            pass
        label = SLAMS[C.ARGS.slam]['label']
        lines.append('  time: %.0f s span; bags %s; %s %.0f s wall, %.0f CPU s (summed over runs%s); '
                     'scoring %.0f s'
                     % (t['span_s'], 'cached' if t['cached']['bags'] else '%s s' % t['bags_wall_s'], label,
                        t['gmapping_wall_s_sum'], t['gmapping_cpu_s_sum'],
                        ', cached: ' + ' '.join(t['cached']['gmapping']) if t['cached']['gmapping'] else '',
                        res.get('score_wall_s') or 0))
        for r in [SINGLE] + TEAM:
            g = self.gm.get(r, {})
            who = 'lone robot' if r == SINGLE else r
            if 'scans' in g:
                lines.append('  %s %-10s %4d scans in its bag, %4d processed (update frame)%s%s%s%s' % (
                    label, who, g['scans'], g['processed'],
                    ', %d dropped' % g['dropped'] if g.get('dropped') else '',
                    ', %d without TF' % g['without_tf'] if g.get('without_tf') else '',
                    ', %s CPU s' % g['cpu_s'] if g.get('cpu_s') is not None else '',
                    ': INVALID: %s' % g['invalid'] if g.get('invalid') else ''))
            else:
                lines.append('  %s %-10s INVALID: %s' % (label, who, g.get('invalid', 'not run')))
        det = res.get('details', {})
        for r in ROWS:
            v = rows.get(r, Invalid('not run'))
            extra = ''
            d = det.get(r) if r != 'own' else None
            if is_valid(v) and isinstance(d, dict) and 'coverage' in d:
                extra = '  coverage %.3f  inlier RMSE %.3f m' % (d['coverage'], d['inlier_rmse'])
            if r in res.get('merged_counts', {}) and res['merged_counts'][r]:
                extra += '  (%s merged)' % res['merged_counts'][r]
            if r == 'own' and det.get('own'):
                extra = '  (' + ' '.join('%s %s' % (k, fmt(s.get('fitness')))
                                         for k, s in sorted(det['own'].items())) + ')'
            lines.append('  %-26s %s%s' % (ROW_NAMES[r], fmt(v) if is_valid(v) else 'INVALID: %s' % v.reason, extra))
        lines.append('  %-26s %s' % ('loss to the rigid bound', fmt(loss(rows.get('rigid'), rows.get('merged')))))
        for p in det.get('placements', []):
            lines.append('  placed %s: %.3f m %.2f deg off its best fit (%.3f m %.2f deg off its start); '
                         '2-sigma %s m; %s the 95%% ellipse%s%s'
                         % (p['robot'], p['err_m'], p['err_deg'], p['start']['err_m'], p['start']['err_deg'],
                            '%.3f' % p['sigma2_m'] if p['sigma2_m'] is not None else '-',
                            'within' if p['in95'] else 'outside', '; weak' if p['weak'] else '',
                            '; OFF' if p['off'] else ''))
        lines += timeline_lines(res.get('timeline') or {'invalid': 'not run'})
        say(*lines)

    def as_json(self) -> Dict[str, Any]:
        res = self.result or {'rows': {}, 'details': {}, 'merged_counts': {}}
        return {'world': self.world, 'seed': self.seed, 'bags': self.bag,
                'gmapping': self.gm, 'rows': {r: to_json(res['rows'].get(r, Invalid('not run'))) for r in ROWS},
                'loss_to_rigid_bound': to_json(loss(res['rows'].get('rigid'), res['rows'].get('merged'))),
                'merged_counts': res.get('merged_counts', {}), 'details': res.get('details', {}),
                'timeline': res.get('timeline', {'invalid': 'not run'}), 'timing': self.timing()}




def plan(cond: Condition, sched: Scheduler) -> None:
    """The chain of one condition: bags -> five SLAM runs (the lone robot first, the longest)
    -> merges and scores."""
    i = cond.index
    left = {'n': 1 + len(TEAM)}

    def gm(robot):
        return C.slam_job(cond, robot, C.ARGS.slam, left, lambda: sched.submit((i, 0), cond.score))

    def bags():
        try:
            cond.make_bags()
        except Exception as e:                    # noqa: BLE001
            traceback.print_exc()
            why = 'bags not made: %s' % e
            cond.result = {'rows': {r: Invalid(why) for r in ROWS}, 'details': {}, 'merged_counts': {}}
            cond.t_done = time.time()
            cond.report()
            C.WRITE_RESULTS()
            return
        sched.submit((i, 1), gm(SINGLE))
        for k, r in enumerate(TEAM):
            sched.submit((i, 2 + k), gm(r))

    sched.submit((i, 0), bags)


