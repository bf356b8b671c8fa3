#!/usr/bin/env python3
"""Side-by-side benchmark of multi_map_merge, MRPT's grid map aligner and m-explore's map_merge.

    bench/bench.py speed [--quick] [--no-peer] [--out bench/results]

(after `make build` with its devel/setup.bash sourced; `make bench` does both and then runs
bench/live_gap.py). Every configuration runs in fresh processes: ours in bench/ours.py; MRPT's
CGridMapAligner through bench/mrpt_merge.py (the project's own driver, bench/mrpt_grid_align.cpp,
built on first use) on the very same map files; m-explore's map_merge node where it is installed
(ros-noetic-multirobot-map-merge, bench/peer.py: its time from start to its first merged /map, its
CPU and peak RSS). Where a peer is not installed its columns say so, never a number.
Prints the tables, writes results/bench.json (with the machine) and results/bench.png.
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))

import duel  # noqa: E402
import first_tf  # noqa: E402
import inputs  # noqa: E402
import memtree  # noqa: E402
import mrpt_merge  # noqa: E402
import peer  # noqa: E402
import peer_estimate  # noqa: E402
import report  # noqa: E402
import results  # noqa: E402


def run_ours_once(paths, truth, pairs, root, reps):
    """One fresh process of bench/ours.py: its own peak RSS; ``reps`` cycles in it, each of a
    new merger (no cache of its own: cold), as m-explore's ``--reps`` runs in one process."""
    spec = os.path.join(root, 'spec_%d.json' % len(os.listdir(root)))
    with open(spec, 'w') as f:
        json.dump({'paths': paths, 'truth': truth, 'reps': reps, 'pairs': pairs}, f)
    r = subprocess.run([sys.executable, os.path.join(HERE, 'ours.py'), spec], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError('bench/ours.py failed:\n' + r.stderr[-3000:])
    return json.loads(r.stdout.strip().splitlines()[-1])


HOUSE = 'house 4'     # the row of a Turtlebot3 team in a house: its first TF is measured live too
MEMORY_SECONDS = 3.0   # cold cycles repeated for at least this long while the tree is sampled


def memory_ours(paths, root, reps):
    """The node's memory on these maps (bench/ours.py --memory, watched by bench/memtree.py):
    the peak of its process tree (the node-like process and its workers), each physical page
    counted once; PSS where pages cannot be counted (not root). At least ``reps`` cold cycles,
    repeated for MEMORY_SECONDS: m-explore's figure is its exact peak (ru_maxrss), ours a
    sampled one, which three short cycles left up to 10 MB under the peak of many."""
    spec = os.path.join(root, 'memory_%d.json' % len(os.listdir(root)))
    with open(spec, 'w') as f:
        json.dump({'paths': paths, 'reps': reps, 'min_seconds': MEMORY_SECONDS}, f)
    return memtree.watch([sys.executable, os.path.join(HERE, 'ours.py'), '--memory', spec])


def run_ours(paths, truth, runs, pairs, root, reps):
    """Median over ``runs`` fresh processes (each the median of its ``reps`` cycles) of every
    figure; placements and errors of the first run (estimation is deterministic: RANSAC is
    seeded per pair); each run's figures kept."""
    import numpy as np
    got = [run_ours_once(paths, truth, pairs, root, reps) for _ in range(runs)]
    out = dict(got[0])
    for k, v in got[0].items():
        if isinstance(v, float) and all(isinstance(g.get(k), (int, float)) for g in got):
            out[k] = float(np.median([g[k] for g in got]))
    out['runs'] = [{k: v for k, v in g.items() if isinstance(v, (int, float))} for g in got]
    out['placed_each_run'] = [g['placed'] for g in got]
    return out


def run_mrpt_once(paths, truth, root):
    """One fresh process of bench/mrpt_merge.py on ``paths`` (reference: the first map, seed 1):
    its wall time and its tree's CPU (wait4: the front end and the aligner it runs), the
    aligner's own figures (T.yaml ``driver``: wall, CPU, peak RSS as it reads its own VmHWM), the
    front end's peak RSS, placements and their errors against ``truth``."""
    import numpy as np
    import yaml

    from multi_map_merge.core.transforms import pose_distance, se2
    out = tempfile.mkdtemp(prefix='mrpt_', dir=root)
    stems = [os.path.splitext(os.path.basename(p))[0] for p in paths]
    cmd = [sys.executable, os.path.join(HERE, 'mrpt_merge.py')] + list(paths) + [
        '-o', os.path.join(out, 'merged.yaml'), '--transforms', os.path.join(out, 'T.yaml'),
        '--reference', stems[0], '--seed', '1']
    t0 = time.time()
    with open(os.path.join(out, 'log.txt'), 'w') as log:
        p = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        _, status, ru = os.wait4(p.pid, 0)
    wall = time.time() - t0
    if status != 0 or not os.path.exists(os.path.join(out, 'T.yaml')):
        raise RuntimeError('bench/mrpt_merge.py failed: %s' % open(os.path.join(out, 'log.txt')).read()[-1500:])
    rep = yaml.safe_load(open(os.path.join(out, 'T.yaml')))
    errs = {}
    for k, st in enumerate(stems[1:], 1):
        v = rep['maps'].get(st) or {}
        if v.get('merged') and truth is not None:
            d, ang = pose_distance(se2(v['x'], v['y'], v['yaw']), np.array(truth[k]))
            errs[st] = (float(d), math.degrees(float(ang)))
    drv = rep.get('driver') or {}
    return {'wall_s': wall, 'cpu_s': ru.ru_utime + ru.ru_stime, 'rss_frontend_mb': rep.get('frontend_rss_mb'),
            'align_s': drv.get('wall_s'), 'align_cpu_s': drv.get('cpu_s'), 'rss_mb': drv.get('rss_mb'),
            'placed': sum(1 for v in rep['maps'].values() if v.get('merged')),
            'errors': errs if truth is not None else {},
            'max_err_m': max([e[0] for e in errs.values()]) if errs else None,
            'max_err_deg': max([e[1] for e in errs.values()]) if errs else None,
            'pairs_kept': sum(1 for q in rep['pairs'] if q['kept']), 'pairs': len(rep['pairs'])}


def run_mrpt(paths, truth, runs, root):
    """Median over ``runs`` fresh processes of each time figure; placements of the first (MRPT
    is seeded: every run places alike)."""
    import numpy as np
    got = [run_mrpt_once(paths, truth, root) for _ in range(runs)]
    out = dict(got[0])
    for k in ('wall_s', 'cpu_s', 'align_s', 'align_cpu_s'):
        if all(g.get(k) is not None for g in got):
            out[k] = float(np.median([g[k] for g in got]))
    out['rss_mb'] = max((g['rss_mb'] for g in got if g.get('rss_mb') is not None), default=None)
    out['runs'] = [{k: g[k] for k in ('wall_s', 'cpu_s', 'align_s', 'placed')} for g in got]
    return out


def run_mexplore(paths, root):
    """m-explore's node once on ``paths`` (bench/peer.py run_node, known_init_poses false):
    {'first_map_s', 'cpu_s', 'rss_mb', ...} or {'invalid': why}."""
    return peer.run_node(paths, out_dir=tempfile.mkdtemp(prefix='mexplore_', dir=root))


def run_mexplore_estimate(paths, root):
    """m-explore's cold estimation on ``paths`` (bench/peer_estimate.py run_estimation: its node's
    own cycles, timed by its DEBUG lines): {'estimate_ms', 'estimate_first_ms', ...} or {'invalid': why}."""
    return peer_estimate.run_estimation(paths, out_dir=tempfile.mkdtemp(prefix='mexplore_est_', dir=root))


def pair_mexplore(paths, root, rounds):
    """Ours' cold estimation and m-explore's, alternated round after round in the same minutes
    (bench/duel.py: this shared machine's speed drifts by up to 2x over minutes): ours from
    bench/ours.py --serve-estimate (a new merger each cycle, its pool warm), m-explore's node held
    stopped between its cycles (peer_estimate.EstimateServer); one uncounted cycle of ours first
    (m-explore's node has run cycles before it is ready). {'ours_ms', 'mexplore_ms' (medians over
    the rounds), 'ratio' (median of the rounds' ours / m-explore), 'rounds', each round's figures}
    or {'invalid': why}."""
    spec = os.path.join(root, 'serve_%d.json' % len(os.listdir(root)))
    with open(spec, 'w') as f:
        json.dump({'paths': paths}, f)
    ours = mx = None
    try:
        mx = peer_estimate.EstimateServer(paths, tempfile.mkdtemp(prefix='mexplore_pair_', dir=root))
        if not mx.ready:
            return {'invalid': mx.why}
        ours = duel.Server([sys.executable, os.path.join(HERE, 'ours.py'), '--serve-estimate', spec])
        ours.burst()
        got = duel.duel(ours, {'mexplore': mx}, rounds, key='ms')
    except RuntimeError as e:
        return {'invalid': 'INVALID: %s' % e}
    finally:
        for side in (ours, mx):
            if side is not None:
                side.close()
    m = got['mexplore']
    return {'ours_ms': got['ours_ms'], 'mexplore_ms': m['ms'], 'ratio': m['ratio'], 'rounds': rounds,
            'ours_rounds_ms': got['ours_rounds'], 'mexplore_rounds_ms': m['rounds'], 'ratios': m['ratios']}


def run_soak(out, no_peer):
    """bench/soak.py (the live node's memory, CPU and threads over 30 robot minutes at 10x; its
    own roscore), in its own process: {'text': its summary, 'json': results/soak.json} or why not."""
    cmd = [sys.executable, os.path.join(HERE, 'soak.py'), '--no-build', '--out', out]
    path = os.path.join(out, 'soak.txt')
    if os.path.exists(path):
        os.remove(path)     # (a failed run must not show the last run's summary)
    r = subprocess.run(cmd + (['--no-peer'] if no_peer else []), capture_output=True, text=True)
    if r.returncode != 0 or not os.path.exists(path):
        return {'text': 'SOAK: NOT measured: bench/soak.py failed:\n' + r.stderr[-1500:], 'json': None}
    return {'text': open(path).read().rstrip(), 'json': os.path.join(out, 'soak.json')}


def peers_state(a):
    """({'mrpt': why or None, 'mexplore': why or None}, note): which peers are measured."""
    if a.no_peer:
        return {'mrpt': 'MRPT not measured (--no-peer)', 'mexplore': 'm-explore not measured (--no-peer)'}, ''
    why = {}
    ok, w = mrpt_merge.available()
    if ok:
        try:
            print('MRPT: its driver: %s' % mrpt_merge.binary(), flush=True)   # built here, not in a timed run
        except RuntimeError as e:
            ok, w = False, 'MRPT\'s driver did not build: %s' % e
    why['mrpt'] = None if ok else w
    ok, w = peer.available()
    why['mexplore'] = None if ok else w
    note = '; '.join(v for v in why.values() if v)
    return why, note


def configurations(a):
    """inputs.configurations, only the rows named by ``--rows`` when given (exits naming the rows
    when one is unknown)."""
    confs = inputs.configurations(a.quick)
    if not a.rows:
        return confs
    names = [c[0] for c in confs]
    unknown = [r for r in a.rows if r not in names]
    if unknown:
        raise SystemExit('no row %s (rows: %s)' % (', '.join(map(repr, unknown)), ', '.join(names)))
    return [c for c in confs if c[0] in a.rows]


def memory_only(a):
    """Each row's peak memory: ours (memory_ours) against MRPT's aligner and m-explore's node,
    measured one after the other on the same maps (memory does not depend on the load)."""
    why, note = peers_state(a)
    root = tempfile.mkdtemp(prefix='mmm_bench_')
    h = '%-16s %3s | %-9s %-9s %-9s %-9s | %-14s | %s' % ('input', 'N', 'ours MB', '(node)', 'RSS sum', 'PSS',
                                                         'MRPT MB', 'm-explore MB')
    print('PEAK MEMORY  (ours: the node\'s process tree, pages counted once; RSS sum: each process\'s '
          'peak RSS summed, the old figure; MRPT: its aligner process\'s peak RSS; m-explore: its node\'s '
          'peak RSS)%s\n%s\n%s' % ('' if not note else '  NOTE: ' + note, h, '-' * len(h)), flush=True)
    for name, _kind, gt in configurations(a):
        paths, truth = inputs.write_inputs(name.replace(' ', '_'), gt, root)
        n = len(paths)
        cycles = 1 if n > 8 or inputs.median_cells(paths) > 1_500_000 else 3
        m = memory_ours(paths, root, cycles)
        ours = m['unique_mb'] if m['unique_mb'] is not None else m['pss_mb']
        mr = run_mrpt_once(paths, truth, root) if why['mrpt'] is None and n <= a.peer_max_robots else {}
        mx = run_mexplore(paths, root) if why['mexplore'] is None and n <= a.peer_max_robots else \
            {'invalid': why['mexplore'] or 'skipped above %d robots' % a.peer_max_robots}
        print('%-16s %3d | %-9.0f %-9.0f %-9.0f %-9.0f | %-14s | %s' % (
            name, n, ours, m['self_hwm_mb'], m['hwm_sum_mb'], m['pss_mb'],
            report._f(mr.get('rss_mb')) if mr else (why['mrpt'] or 'skipped')[:14],
            peer.column(mx, 'rss_mb', '%.0f')), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer, smaller configurations (about a minute)')
    ap.add_argument('--no-peer', action='store_true', help='measure our side only (neither MRPT nor m-explore)')
    ap.add_argument('--peer-max-robots', type=int, default=16,
                    help='MRPT and m-explore only up to this many robots (both match every pair: they grow fast)')
    ap.add_argument('--no-soak', action='store_true',
                    help='skip the soak (bench/soak.py: the live node over 30 robot minutes at 10x, '
                         'about 3 min, 6 with m-explore); --quick skips it too')
    ap.add_argument('--memory-only', action='store_true',
                    help='only the memory: the node\'s tree against the peers (about 3 min); '
                         'prints the table, writes nothing')
    ap.add_argument('--rows', action='append', metavar='NAME',
                    help="only these rows ('house 4', 'intel-sized x8'...; repeat for more); nothing of the "
                         'run is written but its table (a partial run must not stand for the whole)')
    ap.add_argument('--out', default=os.path.join(HERE, 'results'))
    a = ap.parse_args()
    if a.memory_only:
        return memory_only(a)
    os.makedirs(a.out, exist_ok=True)
    t_all = time.time()
    why, note = peers_state(a)
    if note:
        print('NOTE:', note, flush=True)
    root = tempfile.mkdtemp(prefix='mmm_bench_')
    rows = []
    for name, kind, gt in configurations(a):
        paths, truth = inputs.write_inputs(name.replace(' ', '_'), gt, root)
        n = len(paths)
        reps = 3 if n <= 16 else 1    # fresh processes for ours
        # cycles per process: one repetition on the big rows keeps the run short
        big = n > 8 or inputs.median_cells(paths) > 1_500_000
        cycles = 1 if big else reps
        pairs = [list(p) for p in itertools.combinations(range(min(n, 3)), 2)]
        t0 = time.time()
        ours = run_ours(paths, truth, reps, pairs, root, cycles)
        if name == HOUSE:
            ours['first_tf'] = first_tf.first_tf(paths)
        mem = memory_ours(paths, root, cycles)
        ours.update({'memory': mem, 'rss_self_mb': mem['self_hwm_mb'],
                     'rss_mb': mem['unique_mb'] if mem['unique_mb'] is not None else mem['pss_mb']})
        ours['bench_s'] = time.time() - t0
        above = 'skipped above %d robots (every pair matched: %d pairs)' % (a.peer_max_robots, n * (n - 1) // 2)
        t0 = time.time()
        if why['mrpt']:
            mrpt = {'skipped': why['mrpt']}
        elif n > a.peer_max_robots:
            mrpt = {'skipped': above}
        else:
            try:
                mrpt = run_mrpt(paths, truth, 1 if big else 3, root)
            except RuntimeError as e:
                mrpt = {'skipped': 'INVALID: %s' % e}
        mrpt['bench_s'] = time.time() - t0
        if why['mexplore']:
            mx = mx_est = {'invalid': why['mexplore']}
        elif n > a.peer_max_robots:
            mx = mx_est = {'invalid': above}
        else:
            mx = run_mexplore(paths, root)
            mx_est = run_mexplore_estimate(paths, root)
        paired = {'invalid': mx_est['invalid']} if 'invalid' in mx_est else \
            pair_mexplore(paths, root, 3 if big else duel.ROUNDS)
        rows.append({'name': name, 'kind': kind, 'robots': n, 'reps': reps, 'cycles': cycles, 'pairs': pairs,
                     'ours': ours, 'mrpt': mrpt, 'mexplore': mx, 'mexplore_est': mx_est, 'mexplore_paired': paired})
        print('.. %-16s ours: cold %7.0f ms (%.0f s)   MRPT: aligner %s s, whole run %s s (%.0f s)   m-explore: %s; '
              'its estimation %s'
              % (name, ours['cold_ms'], ours['bench_s'], report._f(mrpt.get('align_s'), '%.2f'),
                 report._f(mrpt.get('wall_s'), '%.2f'), mrpt['bench_s'],
                 peer.column(mx, 'first_map_s', '%.1f s to its first merged /map'),
                 peer.column(mx_est, 'estimate_ms', '%.0f ms (median of its cycles)')), flush=True)
        if 'ratio' in paired:
            print('   %-16s paired rounds: ours cold %.0f ms, m-explore estimation %.0f ms, ours/m-explore %.2fx'
                  % ('', paired['ours_ms'], paired['mexplore_ms'], paired['ratio']), flush=True)
    text = report.rows_table(rows, note) + first_tf_lines(rows)
    print(text)
    if a.rows:
        print('\n(--rows: a partial run, nothing written; run_bench took %.0f s)' % (time.time() - t_all))
        return
    soak = None
    if not (a.quick or a.no_soak):
        soak = run_soak(a.out, a.no_peer)
        print('\n' + soak['text'])
    total = time.time() - t_all
    mach = report.machine()
    print('\nrun_bench took %.0f s on %d cores (%s, %s MB RAM)' % (total, mach['nproc'], mach['cpu_model'],
                                                                  mach['mem_total_mb']))
    result = {'machine': mach, 'total_s': total, 'peers': why, 'peer_note': note,
              'tolerance': {'m': report.TOL_M, 'deg': report.TOL_DEG}, 'rows': rows, 'table': text,
              'soak': soak}
    results.write_json(os.path.join(a.out, 'bench.json'), result, vars(a))
    try:
        report.plot(rows, os.path.join(a.out, 'bench.png'))
        print('wrote %s and bench.png' % os.path.join(a.out, 'bench.json'))
    except ImportError:
        print('wrote %s (matplotlib missing: no plot; apt-get install python3-matplotlib)'
              % os.path.join(a.out, 'bench.json'))


def first_tf_lines(rows) -> str:
    """The house's first TF beside its cold cycle (bench/first_tf.py), as lines of the table."""
    for r in rows:
        o = r['ours']
        if r['name'] != HOUSE or 'first_tf' not in o:
            continue
        f = o['first_tf']
        head = ('\n\nFIRST TF  (%s, the live node: from the maps\' publication to the first map -> tb3_N/map a tf2 '
                'listener resolves, the reference tb3_0 aside; discovery and estimation at 1 Hz as m-explore\'s node '
                'is run; median of %d runs)\n' % (HOUSE, len(f.get('runs', []))))
        if 'invalid' in f:
            return head + 'INVALID: %s' % f['invalid']
        return head + ('first robot %.2f s, every robot %.2f s; est cold %.0f ms (what the first TF waits for), '
                       'the spare time\'s refinement after it %.0f ms'
                       % (f['first_tf_s'], f['all_tf_s'], o['cold_ms'], o.get('refine_ms', float('nan'))))
    return ''


if __name__ == '__main__':
    main()
