#!/usr/bin/env python3
"""Side-by-side benchmark of multi_map_merge and m-explore's map_merge on the same maps.

    python3 bench/run_bench.py [--quick] [--out bench/results]

Every configuration runs in a fresh subprocess (so peak RSS is its own). m-explore runs through
../shared/peers/mexplore/merge_maps_mexplore on the very same map files; when ../shared or its
build is absent, its columns say so and only our side is measured.
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(REPO, 'src'))
SHARED = os.path.abspath(os.path.join(REPO, '..', 'shared'))
DATA = os.path.join(SHARED, 'data')
PEER = os.path.join(SHARED, 'peers', 'mexplore')
PEER_WS = os.environ.get('PEER_WS', '/tmp/peer_ws')

from multi_map_merge.mapio import load_map, save_map  # noqa: E402
from multi_map_merge.synth import cut_piece, random_poses, split_rects  # noqa: E402
from multi_map_merge.grid import known_bbox  # noqa: E402


# ---------------------------------------------------------------- inputs
def world_map(name):
    own = {'intel': os.path.join(REPO, 'test', 'data', 'intel.yaml')}
    path = os.path.join(DATA, 'ground_truth', '%s_gt.yaml' % name)
    if not os.path.exists(path):
        path = own.get(name)
    return load_map(path) if path and os.path.exists(path) else None


def pieces_split(world, n, seed=0):
    """n overlapping pieces tiling the world (split_rects), each at a random pose."""
    return [cut_piece(world, r, p) for r, p in zip(split_rects(world, n, 0.3), random_poses(n, seed))]


def pieces_windows(world, n, frac=0.6, seed=0):
    """n world-sized robots: random windows of ``frac`` of the world each (all overlap)."""
    rng = np.random.default_rng(seed)
    r0, r1, c0, c1 = known_bbox(world.levels())
    h, w = int((r1 - r0) * frac), int((c1 - c0) * frac)
    out = []
    for p in random_poses(n, seed + 1):
        a = int(rng.integers(r0, r1 - h + 1))
        b = int(rng.integers(c0, c1 - w + 1))
        out.append(cut_piece(world, (a, a + h, b, b + w), p))
    return out


def write_inputs(name, grids_truth, root):
    """Write the robots' maps as map_server files; returns (paths, truths or None)."""
    d = os.path.join(root, name)
    os.makedirs(d, exist_ok=True)
    paths, truths = [], []
    for k, (g, T) in enumerate(grids_truth):
        p = os.path.join(d, 'r%02d.yaml' % k)
        save_map(g, p)
        paths.append(p)
        truths.append(T)
    if truths[0] is None:
        return paths, None
    return paths, [np.linalg.inv(truths[0]) @ T for T in truths]


def configurations(quick):
    confs = []
    house = sorted(glob.glob(os.path.join(DATA, 'tb3_house', 'tb3_*_map.yaml')))
    if house:
        confs.append(('house 4', [(load_map(p), None) for p in house]))
    for name in (['intel'] if quick else ['intel', 'aces', 'edmonton']):
        w = world_map(name)
        if w is not None:
            confs.append(('%s 4' % name, pieces_split(w, 4)))
    w = world_map('intel')
    for n in ([2, 4, 8] if quick else [2, 4, 8, 16, 32]):
        confs.append(('intel-sized x%d' % n, pieces_windows(w, n)))
    return confs


# ---------------------------------------------------------------- our side (child process)
OURS = r'''
import io, json, math, os, sys, time, resource, itertools
import numpy as np
sys.path.insert(0, %(src)r)
from multi_map_merge.mapio import load_map
from multi_map_merge.merger import MapMerger, RobotMap
from multi_map_merge.config import MergeConfig
from multi_map_merge.features import FeatureExtractor
from multi_map_merge.transforms import se2, pose_distance
paths = %(paths)r
truth = %(truth)r
reps = %(reps)d
grids = [load_map(p) for p in paths]
cfg = MergeConfig()
fe = FeatureExtractor(cfg.akaze_threshold, cfg.max_features, cfg.feature_cells)
feat = []
for g in grids:
    lv = g.levels(); t = time.perf_counter(); fe(lv); feat.append(time.perf_counter() - t)
m0 = MapMerger(cfg)
rms = [RobotMap('r%%02d' %% k, g, k + 1, 0).at(g.resolution) for k, g in enumerate(grids)]
for r in rms:
    m0._features_of(r)
pairs = list(itertools.combinations(range(len(rms)), 2))[:12]
pair = []
for a, b in pairs:
    t = time.perf_counter(); m0.estimate_grids(rms[a], rms[b]); pair.append(time.perf_counter() - t)
cold, warm, comp_cold, comp_warm, pub = [], [], [], [], []
for _ in range(reps):
    m = MapMerger(cfg)
    for k, g in enumerate(grids):
        m.update_map('r%%02d' %% k, g)
    t = time.perf_counter(); m.estimate(); cold.append(time.perf_counter() - t)
    t = time.perf_counter(); m.estimate(); warm.append(time.perf_counter() - t)
    t = time.perf_counter(); merged = m.compose(); comp_cold.append(time.perf_counter() - t)
    t = time.perf_counter(); merged = m.compose(); comp_warm.append(time.perf_counter() - t)
    import rospy
    from multi_map_merge.ros_adapter import grid_to_msg
    t = time.perf_counter()
    msg = grid_to_msg(merged, rospy.Time(0), 'map'); buf = io.BytesIO(); msg.serialize(buf)
    pub.append(time.perf_counter() - t)
P = m.placements()
errs = []
if truth is not None:
    for k in range(1, len(grids)):
        n = 'r%%02d' %% k
        if n in P:
            d, a = pose_distance(P[n].T, np.array(truth[k]))
            errs.append((d, math.degrees(a)))
import multi_map_merge.merger as mm
kids = 0.0                      # the estimation workers' peaks count too (they are the
if mm._POOL is not None:        # forkserver's children, not ours: read /proc)
    for pid in list(mm._POOL._processes):
        try:
            kids += [int(l.split()[1]) for l in open('/proc/%%d/status' %% pid) if l.startswith('VmHWM')][0] / 1024.0
        except (OSError, IndexError):
            pass
med = lambda v: float(np.median(v)) * 1000.0
print(json.dumps({
    'features_ms': med(feat), 'pair_ms': med(pair), 'cold_ms': med(cold), 'warm_ms': med(warm),
    'compose_cold_ms': med(comp_cold), 'compose_warm_ms': med(comp_warm), 'publish_ms': med(pub),
    'rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 + kids,
    'placed': len(P) - 1, 'robots': len(grids),
    'max_err_m': max([e[0] for e in errs]) if errs else None,
    'max_err_deg': max([e[1] for e in errs]) if errs else None,
    'merged_cells': int(merged.width * merged.height),
    'map_cells': int(np.median([g.width * g.height for g in grids])),
}))
'''


def run_ours(paths, truth, reps):
    code = OURS % {'src': os.path.join(REPO, 'src'), 'paths': paths, 'reps': reps,
                   'truth': None if truth is None else [T.tolist() for T in truth]}
    r = subprocess.run(['/usr/bin/python3', '-c', code], capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-2000:])
    return json.loads(r.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------- m-explore (same files)
def peer_available():
    if not os.path.isdir(PEER):
        return False, '../shared/peers/mexplore is absent: m-explore columns not measured'
    if not os.path.exists(os.path.join(PEER_WS, 'mexplore_merge')):
        r = subprocess.run([os.path.join(PEER, 'build.sh')], capture_output=True, text=True)
        if r.returncode != 0:
            return False, 'm-explore did not build: %s' % r.stdout[-500:]
    return True, ''


def run_peer(paths, truth, reps, root):
    out = tempfile.mkdtemp(prefix='peer_', dir=root)
    cmd = [os.path.join(PEER, 'merge_maps_mexplore')] + paths + [
        '-o', os.path.join(out, 'm.yaml'), '--transforms', os.path.join(out, 'T.yaml'), '--reps', str(reps)]
    t = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True, env=dict(os.environ, PATH='/usr/bin:' + os.environ['PATH']))
    wall = time.time() - t
    if r.returncode != 0:
        return {'error': r.stderr[-300:]}
    timing = json.loads(r.stdout.strip().splitlines()[-1])
    import yaml
    rep = yaml.safe_load(open(os.path.join(out, 'T.yaml')))
    stems = [os.path.splitext(os.path.basename(p))[0] for p in paths]
    placed = sum(1 for v in rep['maps'].values() if v.get('merged'))
    errs = []
    if truth is not None and rep['reference'] in stems:
        from multi_map_merge.transforms import pose_distance, se2
        j = stems.index(rep['reference'])
        for k, s in enumerate(stems):
            v = rep['maps'].get(s)
            if v and v.get('merged'):
                T_true = np.linalg.inv(truth[j]) @ truth[k]
                d, a = pose_distance(se2(v['x'], v['y'], v['yaw']), T_true)
                errs.append((d, math.degrees(a)))
    return {'estimate_ms': timing['estimate_ms'], 'compose_ms': timing['compose_ms'], 'placed': placed,
            'max_err_m': max([e[0] for e in errs]) if errs else None,
            'max_err_deg': max([e[1] for e in errs]) if errs else None, 'wall_s': wall}


# ---------------------------------------------------------------- report
def machine():
    model = ''
    try:
        for line in open('/proc/cpuinfo'):
            if line.startswith('model name'):
                model = line.split(':', 1)[1].strip()
                break
        mem = [l for l in open('/proc/meminfo') if l.startswith('MemTotal')][0].split()[1]
    except OSError:
        mem = '?'
    return {'cpus': os.cpu_count(), 'cpu_model': model, 'mem_kb': mem, 'python': platform.python_version(),
            'date': time.strftime('%Y-%m-%d %H:%M')}


def ratio(a, b):
    return None if a is None or not b else a / b


def fmt(v, f='%.0f'):
    return '-' if v is None else f % v


def plot(rows, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.5))
    sweep = [r for r in rows if r['name'].startswith('intel-sized')]
    sizes = [r for r in rows if not r['name'].startswith('intel-sized')]
    for key, lab, st in (('cold_ms', 'ours: estimation (cold)', 'o-'), ('compose_cold_ms', 'ours: compositing', 's-')):
        ax[0].plot([r['robots'] for r in sweep], [r['ours'][key] for r in sweep], st, label=lab)
    ax[0].plot([r['robots'] for r in sweep if r['peer'].get('estimate_ms')],
               [r['peer']['estimate_ms'] for r in sweep if r['peer'].get('estimate_ms')], 'x--', label='m-explore: estimation')
    ax[0].set_xscale('log', base=2); ax[0].set_yscale('log')
    ax[0].set_xlabel('robots (intel-sized maps)'); ax[0].set_ylabel('ms'); ax[0].legend(); ax[0].grid(True, alpha=.3)
    ax[0].set_title('time against robot count')
    x = [r['ours']['map_cells'] for r in sizes]
    ax[1].plot(x, [r['ours']['cold_ms'] for r in sizes], 'o', label='ours: estimation, 4 robots')
    ax[1].plot([r['ours']['map_cells'] for r in sizes if r['peer'].get('estimate_ms')],
               [r['peer']['estimate_ms'] for r in sizes if r['peer'].get('estimate_ms')], 'x', label='m-explore')
    for r in sizes:
        ax[1].annotate(r['name'].split()[0], (r['ours']['map_cells'], r['ours']['cold_ms']))
    ax[1].set_xscale('log'); ax[1].set_yscale('log'); ax[1].set_xlabel('cells per robot map')
    ax[1].set_ylabel('ms'); ax[1].legend(); ax[1].grid(True, alpha=.3); ax[1].set_title('time against map size')
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--quick', action='store_true', help='fewer, smaller configurations')
    ap.add_argument('--out', default=os.path.join(HERE, 'results'))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    peer_ok, why = peer_available()
    if not peer_ok:
        print('NOTE:', why)
    if not os.path.isdir(DATA):
        print('NOTE: ../shared/data is absent: only the shipped intel map is used')
    root = tempfile.mkdtemp(prefix='mmm_bench_')
    rows = []
    t_all = time.time()
    for name, gt in configurations(a.quick):
        paths, truth = write_inputs(name.replace(' ', '_'), gt, root)
        reps = 3 if len(paths) <= 8 else 1
        ours = run_ours(paths, truth, reps)
        peer = {}
        if peer_ok and len(paths) <= 16:
            peer = run_peer(paths, truth, reps, root)
        elif peer_ok:
            peer = {'skipped': 'over 16 robots: too slow to repeat'}
        rows.append({'name': name, 'robots': len(paths), 'ours': ours, 'peer': peer})
        print('.. %-18s ours %6.0f ms  m-explore %s' % (name, ours['cold_ms'], fmt(peer.get('estimate_ms'))), flush=True)
    total = time.time() - t_all

    hdr = ('%-18s %6s %7s | %8s %8s %6s | %7s %6s | %7s %7s %6s %6s | %7s %5s | %s'
           % ('input', 'cells', 'robots', 'est cold', 'mexplore', 'ratio', 'warm', '%cold', 'compose',
              'mexpl.', 'ratio', 'publ.', 'RSS MB', 'feat', 'placed (ours/mexpl), max error ours | mexpl'))
    print('\n' + hdr + '\n' + '-' * len(hdr))
    for r in rows:
        o, p = r['ours'], r['peer']
        err_o = '%s m %s deg' % (fmt(o['max_err_m'], '%.3f'), fmt(o['max_err_deg'], '%.2f'))
        err_p = '%s m %s deg' % (fmt(p.get('max_err_m'), '%.3f'), fmt(p.get('max_err_deg'), '%.2f'))
        print('%-18s %6s %7d | %8.0f %8s %6s | %7.1f %5.1f%% | %7.1f %7s %6s %6.1f | %7.0f %5.0f | %d/%s, %s | %s' % (
            r['name'], '%dk' % (o['map_cells'] // 1000), r['robots'], o['cold_ms'], fmt(p.get('estimate_ms')),
            fmt(ratio(o['cold_ms'], p.get('estimate_ms')), '%.2fx'), o['warm_ms'], 100 * o['warm_ms'] / o['cold_ms'],
            o['compose_cold_ms'], fmt(p.get('compose_ms'), '%.1f'),
            fmt(ratio(o['compose_cold_ms'] + o['publish_ms'], p.get('compose_ms')), '%.2fx'), o['publish_ms'],
            o['rss_mb'], o['features_ms'], o['placed'], p.get('placed', '-'), err_o, err_p))
    print('\nper pair (match + RANSAC + verification), ours: ' +
          ', '.join('%s %.0f ms' % (r['name'], r['ours']['pair_ms']) for r in rows))
    print('bench took %.0f s; machine: %s' % (total, machine()))
    result = {'machine': machine(), 'total_s': total, 'peer': peer_ok or why, 'rows': rows}
    with open(os.path.join(a.out, 'bench.json'), 'w') as f:
        json.dump(result, f, indent=1)
    try:
        plot(rows, os.path.join(a.out, 'bench.png'))
        print('wrote %s/bench.json and bench.png' % a.out)
    except ImportError:
        print('wrote %s/bench.json (matplotlib missing: no plot)' % a.out)


if __name__ == '__main__':
    main()
