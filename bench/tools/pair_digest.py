#!/usr/bin/env python3
"""Proof that a change kept the merger's behaviour: a JSON digest of every pair result.

    bench/bench.py pair-digest -o /tmp/digest_before.json     # before the change
    bench/bench.py pair-digest -o /tmp/digest_after.json      # after it
    cmp /tmp/digest_before.json /tmp/digest_after.json

The 13 buildings' maps of ``../shared/data`` (the 11 ground-truth maps and the two AWS maps)
are each cut into overlapping robots' maps at known random rigid poses (``split_rects`` into
4, 4 windows of half of it, 6 windows of 35% of it); every robot's map is given to a fresh
``MapMerger`` and one estimation cycle runs: every pair of robots is aligned. Then one
robot's map grows (a larger cut at the same pose) and a second cycle runs, so the keep / switch
rules and the placement hysteresis act on kept links. The digest holds, per pair and cycle,
its result (the transform between cells, matches, inliers, inlier ratio, agreement, overlap,
accepted, the reason, the runner-up), every placement (pose, chain, inlier ratio, agreement)
and a checksum of the composed map. Floats are written exactly (``repr``): any change of
behaviour changes the file.

The import paths of both layouts (flat, and core/ lab/) are tried, and the attribute names of
before and after renames, so the same script runs before and after a restructuring.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import importlib
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))          # (bench/tools/ -> the checkout)
DATA = os.path.abspath(os.path.join(REPO, '..', 'shared', 'data'))


def _module(*names):
    """The first of ``names`` that imports (the module's path in the current layout)."""
    for n in names:
        try:
            return importlib.import_module(n)
        except ImportError:
            continue
    raise ImportError('none of %s' % (names,))


config_mod = _module('multi_map_merge.core.config', 'multi_map_merge.config')
grid_mod = _module('multi_map_merge.core.grid', 'multi_map_merge.grid')
mapio = _module('multi_map_merge.core.mapio', 'multi_map_merge.mapio')
merger_mod = _module('multi_map_merge.core.merger', 'multi_map_merge.merger')
pieces_mod = _module('multi_map_merge.lab.pieces', 'multi_map_merge.lab.synth', 'multi_map_merge.synth')


def buildings():
    """[(name, yaml path)] of the 13 buildings, sorted by name."""
    out = []
    gt = os.path.join(DATA, 'ground_truth')
    for f in sorted(os.listdir(gt)):
        if f.endswith('_gt.yaml'):
            out.append((f[:-len('_gt.yaml')], os.path.join(gt, f)))
    for n in ('bookstore', 'small_house'):
        out.append(('aws_' + n, os.path.join(DATA, 'aws', n, 'map.yaml')))
    return sorted(out)


def grown(rect, world, by=0.15):
    """``rect`` grown by ``by`` of its size on every side, within the world's known box."""
    r0, r1, c0, c1 = rect
    b = grid_mod.known_bbox(world.levels())
    dr, dc = int((r1 - r0) * by), int((c1 - c0) * by)
    return (max(b[0], r0 - dr), min(b[1], r1 + dr), max(b[2], c0 - dc), min(b[3], c1 + dc))


def windows(world, n, frac, seed):
    """n random windows of ``frac`` of the world's known box (cells, half-open)."""
    rng = np.random.default_rng(seed)
    r0, r1, c0, c1 = grid_mod.known_bbox(world.levels())
    h, w = int((r1 - r0) * frac), int((c1 - c0) * frac)
    out = []
    for _ in range(n):
        a = int(rng.integers(r0, r1 - h + 1))
        b = int(rng.integers(c0, c1 - w + 1))
        out.append((a, a + h, b, b + w))
    return out


def cases(world, seed):
    """[(case, rects, poses)]: the world split into 4 overlapping pieces, 4 windows of half of
    it (every pair overlaps), 6 windows of 35% of it (some pairs barely or do not overlap: the
    rejections and look-alikes)."""
    return [('split4', pieces_mod.split_rects(world, 4, 0.3), pieces_mod.random_poses(4, seed)),
            ('windows4', windows(world, 4, 0.5, seed + 100), pieces_mod.random_poses(4, seed + 1)),
            ('windows6', windows(world, 6, 0.35, seed + 200), pieces_mod.random_poses(6, seed + 2))]


def _f(x):
    return float(x)


def _matrix(A):
    return None if A is None else [[_f(v) for v in row] for row in np.asarray(A)]


def _pair_results(m):
    """{(parent, child): the pair's last result} of a merger (its public accessor, or the
    attribute it read before there was one, under its names before and after the renames)."""
    if hasattr(m, 'pair_results'):
        return m.pair_results()
    for name in ('_results', '_attempts'):
        if hasattr(m, name):
            return getattr(m, name)
    raise AttributeError('no pair results in %r' % m)


def pair_record(key, r):
    ratio = getattr(r, 'inlier_ratio', None)
    if ratio is None:
        ratio = r.reliability
    runner = getattr(r, 'runner_up', None)
    if runner is None:
        runner = getattr(r, 'extra', {}).get('runner_up')
    return {'pair': list(key), 'A': _matrix(r.A), 'matches': int(r.matches), 'inliers': int(r.inliers),
            'inlier_ratio': _f(ratio), 'agreement': _f(r.agreement), 'overlap': int(r.overlap),
            'accepted': bool(r.accepted), 'reason': r.reason,
            'runner_up': None if runner is None else [_f(v) for v in runner]}


def placement_record(name, p):
    ratio = getattr(p, 'inlier_ratio', None)
    if ratio is None:
        ratio = p.reliability
    return {'robot': name, 'T': _matrix(p.T), 'inlier_ratio': _f(ratio), 'agreement': _f(p.agreement),
            'inliers': int(p.inliers), 'via': p.via, 'path': list(p.path)}


def cycle_record(m, events):
    merged = m.compose()
    return {'pairs': [pair_record(k, r) for k, r in sorted(_pair_results(m).items())],
            'placements': [placement_record(n, p) for n, p in sorted(m.placements().items())],
            'events': [e for e in events],
            'composite': None if merged is None else {
                'size': [merged.width, merged.height], 'origin': [_f(v) for v in merged.origin],
                'sha1': hashlib.sha1(np.ascontiguousarray(merged.data).tobytes()).hexdigest()}}


def run_case(world, case, rects, poses, workers):
    # every pair of a cycle aligned, however long it takes (estimation_budget, where it exists, 0)
    fields = {f.name for f in dataclasses.fields(config_mod.MergeConfig)}
    budget = {'estimation_budget': 0.0} if 'estimation_budget' in fields else {}
    m = merger_mod.MapMerger(config_mod.MergeConfig(workers=workers, **budget))
    names = ['r%d' % k for k in range(len(rects))]
    for n, rect, pose in zip(names, rects, poses):
        m.update_map(n, pieces_mod.cut_piece(world, rect, pose, frame_id=n + '/map')[0])
    first = cycle_record(m, m.estimate())
    # robot 1's map grows (the same frame, a larger cut): its pairs are aligned again
    m.update_map(names[1], pieces_mod.cut_piece(world, grown(rects[1], world), poses[1], frame_id=names[1] + '/map')[0])
    second = cycle_record(m, m.estimate())
    truth = [_matrix(pieces_mod.cut_piece(world, r, p)[1]) for r, p in zip(rects[:1], poses[:1])]
    return {'case': case, 'rects': [list(r) for r in rects], 'poses': [[_f(v) for v in p] for p in poses],
            'truth_0': truth[0], 'cycles': [first, second]}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('-o', '--output', required=True, help='JSON digest to write')
    ap.add_argument('--workers', type=int, default=2, help='estimation processes (the result does not depend on it)')
    ap.add_argument('--only', nargs='*', help='building names (default: all 13)')
    a = ap.parse_args(argv)
    if not os.path.isdir(DATA):
        sys.exit('pair_digest: %s is absent' % DATA)
    out = []
    t0 = time.time()
    for seed, (name, path) in enumerate(buildings()):
        if a.only and name not in a.only:
            continue
        world = mapio.load_map(path)
        for case, rects, poses in cases(world, seed):
            rec = run_case(world, case, rects, poses, a.workers)
            rec['building'] = name
            out.append(rec)
            n = sum(len(c['pairs']) for c in rec['cycles'])
            print('%-16s %-9s %2d pair results, %d placed  (%.0f s)'
                  % (name, case, n, len(rec['cycles'][-1]['placements']), time.time() - t0), flush=True)
    with open(a.output, 'w') as f:
        json.dump(out, f, indent=1, sort_keys=True)
        f.write('\n')
    total = sum(len(c['pairs']) for r in out for c in r['cycles'])
    print('%d pair records (2 cycles) over %d buildings -> %s' % (total, len({r['building'] for r in out}), a.output))


if __name__ == '__main__':
    main()
