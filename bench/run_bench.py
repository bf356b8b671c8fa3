#!/usr/bin/env python3
"""Side-by-side benchmark of multi_map_merge and m-explore's map_merge on the same maps.

    python3 bench/run_bench.py [--quick] [--no-peer] [--out bench/results]

(after `make build` with its devel/setup.bash sourced; `make bench` does both and then runs
bench/live_gap.py). Every configuration runs in fresh processes: ours in bench/ours.py, m-explore
through ../shared/peers/mexplore/merge_maps_mexplore on the very same map files (bench/peer.py).
Without ../shared, only our side is measured and the table says the m-explore columns are missing.
Prints the tables, writes results/bench.json (with the machine) and results/bench.png.
"""
from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import duel  # noqa: E402
import inputs  # noqa: E402
import memtree  # noqa: E402
import peer  # noqa: E402
import report  # noqa: E402


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


def _serve(paths, root, flag):
    """bench/ours.py serving ``flag`` (--serve: compositing, --serve-estimate: cold cycles) on
    the maps ``paths``, as a duel.Server."""
    spec = os.path.join(root, 'serve_%d.json' % len(os.listdir(root)))
    with open(spec, 'w') as f:
        json.dump({'paths': paths}, f)
    return duel.Server([sys.executable, os.path.join(HERE, 'ours.py'), flag, spec])


def _close(servers):
    for s in servers:
        s.close()


def compose_duel(paths, pr, reps, own, root):
    """Compositing in pairs (bench/duel.py): our compose + publish against m-explore's
    composeGrids() on the maps at our poses ('same_output') and, when ``own``, on its own
    estimate ('own')."""
    ours = _serve(paths, root, '--serve')
    peers = {}
    try:
        peers['same_output'] = duel.Server(pr.compose_cmd(paths, reps, poses=ours.ready['poses']), peer.ENV)
        if own:
            peers['own'] = duel.Server(pr.compose_cmd(paths, reps), peer.ENV)
        return duel.duel(ours, peers)
    finally:
        _close([ours] + list(peers.values()))


def estimate_duel(paths, pr, root):
    """Cold estimation in pairs (bench/duel.py): one cold cycle of ours (a new merger, workers
    started) against one estimateTransforms() of m-explore, round after round."""
    ours = _serve(paths, root, '--serve-estimate')
    peers = {}
    try:
        peers['mexplore'] = duel.Server(pr.estimate_cmd(paths, 1), peer.ENV)
        return duel.duel(ours, peers, key='estimate_ms')
    finally:
        _close([ours] + list(peers.values()))


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


def memory_only(a):
    """Each row's peak memory: ours (memory_ours) against m-explore's full run (its peak RSS),
    measured one after the other on the same maps (memory does not depend on the load)."""
    peer_ok, note = (False, 'm-explore not measured (--no-peer)') if a.no_peer else peer.available()
    root = tempfile.mkdtemp(prefix='mmm_bench_')
    pr = peer.Peer(root) if peer_ok else None
    h = '%-16s %3s | %-9s %-9s %-9s %-9s | %-12s | %s' % ('input', 'N', 'ours MB', '(node)', 'RSS sum', 'PSS',
                                                         'm-explore MB', 'ratio (target <= 2)')
    print('PEAK MEMORY  (ours: the node\'s process tree, pages counted once; RSS sum: each process\'s '
          'peak RSS summed, the old figure; m-explore: peak RSS of its full run)%s\n%s\n%s' % (
              '' if peer_ok else '  NOTE: ' + note, h, '-' * len(h)), flush=True)
    for name, _kind, gt in inputs.configurations(a.quick):
        paths, _ = inputs.write_inputs(name.replace(' ', '_'), gt, root)
        n = len(paths)
        cycles = 1 if n > 8 or inputs.median_cells(paths) > 1_500_000 else 3
        m = memory_ours(paths, root, cycles)
        ours = m['unique_mb'] if m['unique_mb'] is not None else m['pss_mb']
        theirs = pr.run(paths, cycles)[2] if pr is not None and n <= a.peer_max_robots else None
        print('%-16s %3d | %-9.0f %-9.0f %-9.0f %-9.0f | %-12s | %s' % (
            name, n, ours, m['self_hwm_mb'], m['hwm_sum_mb'], m['pss_mb'], report._f(theirs, '%.0f'),
            report._f(report._r(ours, theirs), '%.2fx')), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer, smaller configurations (about a minute)')
    ap.add_argument('--no-peer', action='store_true', help='measure our side only')
    ap.add_argument('--peer-max-robots', type=int, default=16,
                    help='m-explore\'s full run only up to this many robots (it grows fast)')
    ap.add_argument('--no-soak', action='store_true',
                    help='skip the soak (bench/soak.py: the live node over 30 robot minutes at 10x, '
                         'about 3 min, 6 with m-explore); --quick skips it too')
    ap.add_argument('--memory-only', action='store_true',
                    help='only the memory: the node\'s tree against m-explore\'s full run (about 3 min); '
                         'prints the table, writes nothing')
    ap.add_argument('--out', default=os.path.join(HERE, 'results'))
    a = ap.parse_args()
    if a.memory_only:
        return memory_only(a)
    os.makedirs(a.out, exist_ok=True)
    t_all = time.time()
    peer_ok, note = (False, 'm-explore not measured (--no-peer)') if a.no_peer else peer.available()
    if note:
        print('NOTE:', note, flush=True)
    root = tempfile.mkdtemp(prefix='mmm_bench_')
    pr = peer.Peer(root) if peer_ok else None
    rows = []
    for name, kind, gt in inputs.configurations(a.quick):
        paths, truth = inputs.write_inputs(name.replace(' ', '_'), gt, root)
        n = len(paths)
        reps = 3 if n <= 16 else 1    # fresh processes for ours
        # cycles per process, both sides (m-explore's --reps): x16 takes m-explore ~50 s per
        # estimation, edmonton x4 ~20 s; one repetition there keeps the run short
        big = n > 8 or inputs.median_cells(paths) > 1_500_000
        cycles = 1 if big else reps
        pairs = [list(p) for p in itertools.combinations(range(min(n, 3)), 2)]
        t0 = time.time()
        ours = run_ours(paths, truth, reps, pairs, root, cycles)
        mem = memory_ours(paths, root, cycles)
        ours.update({'memory': mem, 'rss_self_mb': mem['self_hwm_mb'],
                     'rss_mb': mem['unique_mb'] if mem['unique_mb'] is not None else mem['pss_mb']})
        t_ours = time.time() - t0
        p = {}
        if pr is not None:
            t0 = time.time()
            full = n <= a.peer_max_robots
            p = pr.measure(paths, truth, cycles, [tuple(x) for x in pairs], full=full)
            p['reps'] = cycles
            comp = compose_duel(paths, pr, ours['compose_reps'], full, root)
            short = p.get('estimate_ms') is not None and p['estimate_ms'] < report.PAIR_ESTIMATE_S * 1000.0
            est = estimate_duel(paths, pr, root) if short else None
            if not full:
                p['skipped'] = 'full run skipped above %d robots (m-explore x16 takes ~50 s)' % a.peer_max_robots
            p['bench_s'] = time.time() - t0
        else:
            p = {'skipped': note}
            comp = est = None
        ours['bench_s'] = t_ours
        rows.append({'name': name, 'kind': kind, 'robots': n, 'reps': reps, 'cycles': cycles, 'pairs': pairs,
                     'ours': ours, 'peer': p, 'compose': comp, 'estimate': est})
        print('.. %-16s ours: cold %7.0f ms (%.0f s)   m-explore: %s ms (%s s)' % (
            name, ours['cold_ms'], t_ours, report._f(p.get('estimate_ms')), report._f(p.get('bench_s'))),
            flush=True)
    text = report.rows_table(rows, note)
    print(text)
    soak = None
    if not (a.quick or a.no_soak):
        soak = run_soak(a.out, a.no_peer)
        print('\n' + soak['text'])
    total = time.time() - t_all
    mach = report.machine()
    print('\nrun_bench took %.0f s on %d cores (%s, %s MB RAM)' % (total, mach['nproc'], mach['cpu_model'],
                                                                  mach['mem_total_mb']))
    result = {'machine': mach, 'total_s': total, 'peer_measured': peer_ok, 'peer_note': note,
              'tolerance': {'m': report.TOL_M, 'deg': report.TOL_DEG}, 'rows': rows, 'table': text,
              'soak': soak}
    with open(os.path.join(a.out, 'bench.json'), 'w') as f:
        json.dump(result, f, indent=1)
    try:
        report.plot(rows, os.path.join(a.out, 'bench.png'))
        print('wrote %s and bench.png' % os.path.join(a.out, 'bench.json'))
    except ImportError:
        print('wrote %s (matplotlib missing: no plot; apt-get install python3-matplotlib)'
              % os.path.join(a.out, 'bench.json'))


if __name__ == '__main__':
    main()
