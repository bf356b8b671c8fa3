#!/usr/bin/env python3
"""The paper's experiment as a benchmark: four Turtlebot3s merged vs one robot alone (Table 1's
Fitness), over several seeds and worlds, every map made by a real SLAM: rbpf_slam (ours, over
MRPT's Rao-Blackwellized particle filter, the algorithm gmapping implements) or gmapping.

    bench/bench.py accuracy [--seeds 5] [--first-seed 1] [--worlds home,intel] [--quick]
                              [--slam rbpf|gmapping] [--work /tmp/mmm_accuracy] [--jobs 2] [--port 12500]

For every world and seed:

1. ``make_robot_bags --world W --seed S --robots 4 --sensors-only``: four Burgers (LDS-02) that
   start together and explore different regions (``team.bag``: scans, odometry and their TF
   only) and one robot exploring it all alone (``team_single.bag``), with the truth file;
2. one SLAM run per robot, team robots and the lone robot: ``--slam rbpf`` (the default):
   ``rbpf_slam_replay --bag_filename BAG --scan_topic /tb3_k/scan --seed S`` (built by ``make
   build`` into the workspace) with config/rbpf_lds02.yaml (the Turtlebot3 LDS-02 settings under
   gmapping's names) as ``/rbpf_slam/...``; ``--slam gmapping``: ``slam_gmapping_replay``, the same
   flags, with config/gmapping_lds02.yaml as ``/slam_gmapping/...``, where ROS has gmapping
   (elsewhere every row says INVALID and why). Either with the robot's frames
   (``tb3_k/base_footprint``, ``tb3_k/odom``, ``tb3_k/map``). The replayer reads the bag itself and
   drops no scan; each run has its own roscore on a free port (from ``--port``) and, when the bag
   is read, saves its latched last ``/map`` (``scripts/save_map``) through ``--on_done``. Printed
   per robot: the scans in its bag, the scans the SLAM processed (its ``update frame`` lines) and
   its CPU seconds;
3. scored against the world's ground truth (``lab/evaluate.py``: the paper's Fitness, Open3D ICP
   at 0.10 m): the single robot's map, our ``merge_maps`` on the four final maps, each robot's map
   alone (mean), the **rigid bound** (every robot's map placed at its own map's best fit to the
   truth and composited as ``merge_maps`` composites: what a merge that places every robot
   perfectly, rigidly, could reach), and m-explore's and MRPT's merges of the same four maps.
   MRPT: ``bench/mrpt_merge.py`` (its CGridMapAligner through the project's own driver, built
   on first use); its transforms composited the same way, so that only the placements differ
   between the merge rows; robots it did not merge are left out, and how many it merged is
   printed. m-explore: where its node is installed (ros-noetic-multirobot-map-merge;
   ``bench/peer.py``), its own merged /map (known_init_poses false, the last one 10 s after its
   first) scored as it is (it publishes no placements); elsewhere its row is INVALID: not installed.

Every map is scored from its frame's known start pose (the reference robot's, for a merge) and
from ``best_fit_score``'s eight headings; the best Fitness is kept (a distorted map's ICP from
one coarse pose can stop in a worse local optimum).

Then, per world, the mean and the worst over the seeds; the last line printed is::

    accuracy: N seeds x W worlds; merged mean M, single mean S, own maps mean O, rigid bound mean B; \
worst loss to the rigid bound L

(one line; ``L`` = the largest rigid bound - merged over all seeds and worlds).

A row whose condition was not created (the SLAM missing, a robot's SLAM processed nothing or
saved no map, a peer absent or failed, a merge that failed) says INVALID and why, not a number;
a mean over it is INVALID too.

Bags and SLAM maps are cached under ``--work``: the bags (``bags/WORLD-sSEED-BAGKEY``) keyed
by world, seed, the arguments and the simulator's files; each robot's map
(``rbpf_slam/WORLD-sSEED-content-SHA1``, gmapping's in ``gmapping/...``) by what its bag holds
(``content.json`` beside the bags: a digest of their messages, not of their files;
``bag_content_digest``), the robot, the SLAM, its config and its binary: one SLAM's map is never
taken for the other's. Bags remade alike by changed sources find the maps already made, and so do
gmapping results of the earlier scheme, keyed by the bag key (``resolve_gmapping``: copied, never
deleted). The JSON keeps gmapping's key names for the SLAM's runs (``gmapping``,
``gmapping_cpu_s_sum``, ...); ``args.slam`` says which SLAM made them.
A rerun only merges and scores again (about a minute). It runs at nice 10 (it renices itself; whatever it starts
inherits that), at most ``--jobs`` (2) heavy steps at a time. Everything it starts is stopped on exit, also on Ctrl-C.

The worlds: ``home``, the project's own home (lab/home.py, written into ``--work``), ``house``,
the AWS small house read in place from ../shared/data, ``intel``, the Intel lab of ../shared/data.

Writes bench/results/accuracy.{json,md,txt} (``--quick``: 1 seed, the home only, into
accuracy_quick.*; ``--slam gmapping``: accuracy_gmapping.*, accuracy_quick_gmapping.*). Run it
with Debian's /usr/bin/python3 and the workspace sourced (``make accuracy`` does both).
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
from typing import Any, Dict, List, Optional

import accuracy_common as C
import results
from accuracy_common import DEFAULT_SLAM, HERE, NICENESS, REPO, SLAMS, WORLDS, Scheduler, say, stop_all
from accuracy_condition import Condition, plan
from accuracy_slam import peers_available, replay_binary, slam_missing
from accuracy_summary import (
    BEND_TOLERANCE,
    ROW_NAMES,
    ROWS,
    STARTS_TOLERANCE,
    Invalid,
    aggregate,
    bend_decision,
    fmt,
    is_valid,
    markdown,
    secs,
    summary_line,
    to_json,
)
from bend_summary import OFF

from multi_map_merge.lab.home import write_home_map

# ------------------------------------------------------------------------------ results

CONDITIONS: List[Condition] = []
_write_lock = threading.Lock()



def write_results(final: bool = False) -> Dict[str, Any]:
    """accuracy.json and accuracy.md of what is done so far (rewritten after every condition)."""
    with _write_lock:
        done = [c for c in CONDITIONS if c.result is not None]
        conds = [{'world': c.world, 'seed': c.seed, 'rows': c.result['rows'],
                  'merged_counts': c.result.get('merged_counts', {}), 'timeline': c.result.get('timeline')}
                 for c in done]
        worlds = (C.ARGS.world_list if final
                  else [w for w in C.ARGS.world_list if any(c['world'] == w for c in conds)])
        agg = aggregate(conds, worlds, merged_row=default_merged_row())
        line = summary_line(agg['overall'])
        doc = {'complete': final and len(done) == len(CONDITIONS), 'line': line,
               'args': {'seeds': C.ARGS.seed_list, 'worlds': C.ARGS.world_list, 'work': C.ARGS.work,
                        'jobs': C.ARGS.jobs, 'bag_args': C.BAG_ARGS,
                        'slam': C.ARGS.slam, 'slam_binary': replay_binary(C.ARGS.slam),
                        'slam_config': os.path.relpath(SLAMS[C.ARGS.slam]['config'], REPO)},
               'worlds': {w: {'title': WORLDS[w][1], 'truth': WORLDS[w][0],
                              'rows': {r: {'mean': to_json(d[r]['mean']), 'worst': to_json(d[r]['worst'])}
                                       for r in ROWS},
                              'loss_to_rigid_bound': {'mean': to_json(d['loss']['mean']),
                                                      'worst': to_json(d['loss']['worst'])},
                              'merged_minus_true_starts': d['vs_starts'], 'bent_minus_unbent': d['bend_gain'],
                              'time': d['time'],
                              'seeds': d['seeds']}
                          for w, d in agg['worlds'].items()},
               'merged_row': agg['merged_row'],
               'overall': {k: (to_json(v) if k in ROWS or k in ('worst_loss', 'merged_default', 'worst_vs_starts')
                               else v) for k, v in agg['overall'].items()},
               'peers': C.PEERS, 'runtime_s': round(time.time() - C.T_START, 1),
               'conditions': [c.as_json() for c in done]}
        os.makedirs(C.ARGS.results, exist_ok=True)
        results.write_json(os.path.join(C.ARGS.results, C.ARGS.stem + '.json'), doc, doc['args'],
                           default=C._json_default)
        titles = {w: WORLDS[w][1] for w in WORLDS}
        md = ['# Accuracy: 4 Turtlebot3s merged vs 1 alone, every map by %s (bench/accuracy.py --slam %s)'
              % (SLAMS[C.ARGS.slam]['label'], C.ARGS.slam), '',
              'Fitness (Open3D ICP at 0.10 m against the ground truth, the paper\'s Table 1); '
              '(k/4): robots the merge placed. %s%s' % (
                  'Complete run' if doc['complete']
                  else 'PARTIAL: %d of %d conditions done' % (len(done), len(CONDITIONS)),
                  ', %.0f s.' % doc['runtime_s']), '']
        md.append(markdown(conds, agg, worlds, titles))
        results.write_text(os.path.join(C.ARGS.results, C.ARGS.stem + '.md'), md, doc['args'], comment='>')
        results.write_text(os.path.join(C.ARGS.results, C.ARGS.stem + '.txt'), C._out_lines, doc['args'])
        return {'agg': agg, 'line': line, 'done': done}


def default_merged_row() -> str:
    """The row that is the merger as it ships: ``merged`` (bent) when ``bend_maps`` is on by
    default (core/config.MergeConfig), else ``merged_rigid`` (the same placements composited
    rigidly: what the default merge publishes)."""
    from multi_map_merge.core.config import MergeConfig
    return 'merged' if MergeConfig().bend_maps else 'merged_rigid'


def target_lines(agg: Dict[str, Any]) -> List[str]:
    """Issue 51's targets per world and seed, and the times: printed after the Fitness tables."""
    mrow = agg['merged_row']
    lines = ['', 'targets (issue 51): the merge (%s, the default) at least the team at its true starts - %.2f '
             'in every seed; ~bend_maps on only where bent >= unbent - %.3f in every seed and above on the mean'
             % (ROW_NAMES[mrow], STARTS_TOLERANCE, BEND_TOLERANCE)]
    for w, d in agg['worlds'].items():
        vs = d['vs_starts']['per_seed']
        ok = all(is_valid(v) and v >= -STARTS_TOLERANCE for v in vs)
        lines.append('  %-6s merged minus true starts per seed %s: %s; bent minus unbent %s (mean %s): bend_maps %s'
                     % (w, ' '.join(fmt(v) for v in vs), 'MET' if ok else 'NOT MET',
                        ' '.join(fmt(v) for v in d['bend_gain']['per_seed']), fmt(d['bend_gain']['mean']),
                        bend_decision(d['bend_gain']['per_seed'])))
        t = d['time']
        lines.append('  %-6s time to 90%%: team %s (worst %s), single %s (worst %s); to 99%%: team %s, single %s'
                     % ((w,) + tuple(secs(t[k][m]) for k, m in (('team_t90', 'mean'), ('team_t90', 'worst'),
                                                                 ('single_t90', 'mean'), ('single_t90', 'worst'),
                                                                 ('team_t99', 'mean'), ('single_t99', 'mean')))))
        lines.append('  %-6s final Fitness: team %s (worst %s), single %s (worst %s); at the team\'s end the single '
                     'robot: Fitness %s, free area %s (team %s)'
                     % (w, fmt(t['end_team_fitness']['mean']), fmt(t['end_team_fitness']['worst']),
                        fmt(t['end_single_fitness']['mean']), fmt(t['end_single_fitness']['worst']),
                        fmt(t['equal_time_single_fitness']['mean']), fmt(t['equal_time_single_free']['mean']),
                        fmt(t['equal_time_team_free']['mean'])))
    return lines


def print_summary(res: Dict[str, Any]) -> None:
    agg = res['agg']
    lines = ['']
    for w, d in agg['worlds'].items():
        lines.append('== %s: over seeds %s' % (WORLDS[w][1], ', '.join(str(s) for s in d['seeds'])))
        lines.append('  %-26s %8s %8s' % ('Fitness', 'mean', 'worst'))
        for r in ROWS:
            lines.append('  %-26s %8s %8s' % (ROW_NAMES[r], fmt(d[r]['mean']), fmt(d[r]['worst'])))
        lines.append('  %-26s %8s %8s (largest)' % ('loss to the rigid bound', fmt(d['loss']['mean']),
                                                    fmt(d['loss']['worst'])))
        for r in ROWS + ('loss',):
            v = d[r]['mean']
            if isinstance(v, Invalid):
                lines.append('  INVALID %s: %s' % (ROW_NAMES.get(r, 'loss to the rigid bound'), v.reason))
    lines += target_lines(agg)
    recs = [p for c in res['done'] for p in ((c.result or {}).get('details') or {}).get('placements', [])]
    if recs:
        with_cov = [p for p in recs if p['in95'] is not None]
        off = [p for p in recs if p['off']]
        lines.append('')
        lines.append('placements: %d robots placed; %d of the %d with a covariance within their 95%% ellipse '
                     '(against the maps\' best rigid fits); off (> %.2f m or %.1f deg) %d, flagged weak %d of them'
                     % (len(recs), sum(1 for p in with_cov if p['in95']), len(with_cov), OFF[0], OFF[1],
                        len(off), sum(1 for p in off if p['weak'])))
    times = [c.timing()['span_s'] for c in res['done']]
    if times:
        lines.append('')
        lines.append('time: %.0f s in all; per condition (world, seed) %s' % (
            time.time() - C.T_START, ', '.join('%s s%d %.0f s' % (c.world, c.seed, c.timing()['span_s'])
                                             for c in res['done'])))
    say(*lines)


# ------------------------------------------------------------------------------ main



def parse_args(argv: Optional[List[str]] = None):
    ap = argparse.ArgumentParser(prog='accuracy.py', description=__doc__.split('\n\n')[0])
    ap.add_argument('--seeds', type=int, default=5, help='how many seeds (default 5)')
    ap.add_argument('--first-seed', type=int, default=1, help='the first seed (default 1)')
    ap.add_argument('--worlds', default='home,intel',
                    help='comma-separated: %s (default home,intel)' % ', '.join(WORLDS))
    ap.add_argument('--quick', action='store_true', help='1 seed, the home only (results in accuracy_quick.*)')
    ap.add_argument('--work', default='/tmp/mmm_accuracy',
                    help='cache of bags and SLAM maps (default /tmp/mmm_accuracy)')
    ap.add_argument('--slam', choices=sorted(SLAMS), default=DEFAULT_SLAM,
                    help='the SLAM making every map: rbpf (rbpf_slam_replay, config/rbpf_lds02.yaml; the '
                         'default) or gmapping (slam_gmapping_replay, config/gmapping_lds02.yaml, where ROS has '
                         'gmapping: elsewhere every row is INVALID)')
    ap.add_argument('--results', default=os.path.join(HERE, 'results'), help='where accuracy.{json,md,txt} go')
    ap.add_argument('--jobs', type=int, default=2, help='heavy steps at once (1 or 2; default 2)')
    ap.add_argument('--port', type=int, default=12500, help='first port tried for the roscores (default 12500)')
    ap.add_argument('--no-build', action='store_true', help='do not build MRPT\'s driver (bench/mrpt_merge.py)')
    ap.add_argument('--unbent', action='store_true',
                    help='our merge with bend_maps false (default: true; the row "ours, unbent" composites '
                         'the same placements rigidly either way)')
    a = ap.parse_args(argv)
    if a.quick:
        a.seeds, a.worlds = 1, 'home'
    a.world_list = [w.strip() for w in a.worlds.split(',') if w.strip()]
    for w in a.world_list:
        if w not in WORLDS:
            ap.error('unknown world %r (known: %s)' % (w, ', '.join(WORLDS)))
    if a.seeds < 1:
        ap.error('--seeds must be at least 1')
    a.jobs = max(1, min(2, a.jobs))
    a.seed_list = list(range(a.first_seed, a.first_seed + a.seeds))
    a.stem = ('accuracy_quick' if a.quick else 'accuracy') + ('' if a.slam == DEFAULT_SLAM else '_' + a.slam)
    a.work = os.path.abspath(a.work)
    return a


def main(argv: Optional[List[str]] = None) -> int:
    C.ARGS = parse_args(argv)
    C.WRITE_RESULTS = write_results
    os.makedirs(C.ARGS.work, exist_ok=True)
    if 'home' in C.ARGS.world_list:
        _, home_yaml = write_home_map(os.path.join(C.ARGS.work, 'worlds', 'home.yaml'))
        WORLDS['home'] = (home_yaml, WORLDS['home'][1])
    if os.nice(0) < NICENESS:
        os.nice(NICENESS - os.nice(0))   # the merges and scores in here too, not only the children

    def on_signal(sig, _frame):
        raise SystemExit(128 + sig)
    for s in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, on_signal)
    try:
        for w in C.ARGS.world_list:
            if not os.path.exists(WORLDS[w][0]):
                say('accuracy: world %s: %s is absent: its rows are INVALID' % (w, WORLDS[w][0]))
        exe = replay_binary(C.ARGS.slam)
        say('accuracy: %d seeds (%s) x %d worlds (%s); work dir %s; %d jobs at once, nice 10'
            % (len(C.ARGS.seed_list), ', '.join(map(str, C.ARGS.seed_list)), len(C.ARGS.world_list),
               ', '.join(C.ARGS.world_list), C.ARGS.work, C.ARGS.jobs),
            'accuracy: SLAM %s: %s, %s' % (
                C.ARGS.slam, exe or 'NONE: every row is INVALID: %s' % slam_missing(C.ARGS.slam),
                os.path.relpath(SLAMS[C.ARGS.slam]['config'], REPO)))
        C.PEERS = peers_available(build=not C.ARGS.no_build)
        for p, why in C.PEERS.items():
            say('accuracy: peer %s: %s' % (p, 'ready' if why is None else 'INVALID: ' + why))
        sched = Scheduler()
        k = 0
        for seed in C.ARGS.seed_list:
            for w in C.ARGS.world_list:
                c = Condition(k, w, seed)
                CONDITIONS.append(c)
                k += 1
                if not os.path.exists(c.world_yaml):
                    why = 'world %s is absent' % c.world_yaml
                    c.result = {'rows': {r: Invalid(why) for r in ROWS}, 'details': {}, 'merged_counts': {}}
                    continue
                plan(c, sched)
        sched.run(C.ARGS.jobs)
        for c in CONDITIONS:
            if c.result is None:
                c.result = {'rows': {r: Invalid('not completed') for r in ROWS}, 'details': {}, 'merged_counts': {}}
        res = write_results(final=True)
        print_summary(res)
        say(res['line'])
        write_results(final=True)
        return 0
    except KeyboardInterrupt:
        say('accuracy: interrupted')
        return 130
    finally:
        stop_all()


if __name__ == '__main__':
    sys.exit(main())
