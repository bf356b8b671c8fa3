#!/usr/bin/env python3
"""MRPT's grid map aligner behind merge_maps' interface: a reference merger for the benchmarks.

    bench/bench.py mrpt-merge A.yaml B.yaml ... -o merged.yaml --transforms T.yaml
                                [--reference A] [--seed N] [--no-icp]
    bench/bench.py mrpt-merge --build        (only build the driver; prints its path)

Every pair of maps is aligned by ``mrpt::slam::CGridMapAligner`` (MRPT 2.5.8, Debian's
``libmrpt-dev``) through bench/mrpt_grid_align.cpp, the project's own driver, compiled with g++
on first use into MRPT_GRID_ALIGN_DIR (default /tmp/mmm_mrpt_grid_align), never into the tree.
Settings: MRPT's grid-matching example (see the driver). Decision, as MRPT gives it: a pair is
kept when the aligner's sum of Gaussians is not empty; its transform is the most likely mode, its
quality the ICP goodness of that mode. Maps are chained to the reference over the maximum spanning
tree of the kept pairs by that quality. T.yaml: ``reference``, ``maps`` ({stem: {merged, x, y,
yaw, parent, quality}}: pose of each map's frame in the reference's frame; the reference itself is
not listed) and ``pairs`` (every pair's result). merged.yaml: the placed maps composited as
merge_maps composites them (occupied, then free, then unknown) in the reference's frame.
Nothing of MRPT is part of multi_map_merge: this runs beside it, for measurement only.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SOURCE = os.path.join(HERE, 'mrpt_grid_align.cpp')
OUT_DIR = os.environ.get('MRPT_GRID_ALIGN_DIR', '/tmp/mmm_mrpt_grid_align')
HEADER = '/usr/include/mrpt/slam/include/mrpt/slam/CGridMapAligner.h'
NOT_INSTALLED = 'MRPT not installed (libmrpt-dev): not measured'
LIBS = ['slam', 'maps', 'vision', 'obs', 'poses', 'math', 'random', 'system', 'rtti', 'containers',
        'serialization', 'core']
ENV = dict(os.environ, PATH='/usr/bin:/bin:' + os.environ.get('PATH', ''))
DRIVER: dict = {}   # the last driver run's wall_s, cpu_s, rss_mb (align_all)


def available():
    """(True, '') or (False, why): MRPT's headers and g++ are here."""
    if not os.path.exists(HEADER):
        return False, NOT_INSTALLED
    if subprocess.run(['which', 'g++'], capture_output=True, env=ENV).returncode != 0:
        return False, 'g++ not installed: MRPT not measured'
    return True, ''


def _compile_cmd(exe):
    inc = ['-I' + os.path.join('/usr/include/mrpt', d, 'include') for d in sorted(os.listdir('/usr/include/mrpt'))
           if os.path.isdir(os.path.join('/usr/include/mrpt', d, 'include'))]
    eigen = subprocess.run(['pkg-config', '--cflags', 'eigen3'], capture_output=True, text=True, env=ENV).stdout.split()
    return (['g++', '-std=c++17', '-O2', '-DNDEBUG'] + inc + (eigen or ['-I/usr/include/eigen3']) +
            [SOURCE, '-o', exe] + ['-lmrpt-' + m for m in LIBS])


def binary():
    """Path of the built driver, compiled first when the source changed (keyed by its hash)."""
    ok, why = available()
    if not ok:
        raise RuntimeError(why)
    with open(SOURCE, 'rb') as f:
        key = hashlib.md5(f.read()).hexdigest()[:10]
    exe = os.path.join(OUT_DIR, key, 'mrpt_grid_align')
    if os.path.exists(exe):
        return exe
    os.makedirs(os.path.dirname(exe), exist_ok=True)
    tmp = '%s.%d.tmp' % (exe, os.getpid())
    r = subprocess.run(_compile_cmd(tmp), capture_output=True, text=True, env=ENV)
    if r.returncode != 0:
        raise RuntimeError('cannot build %s: %s' % (SOURCE, r.stderr[-1500:]))
    os.replace(tmp, exe)      # at once: a concurrent build finds either nothing or the whole file
    return exe


def peak_rss_mb():
    """This process's peak RSS (VmHWM), MB."""
    with open('/proc/self/status') as f:
        for line in f:
            if line.startswith('VmHWM:'):
                return int(line.split()[1]) / 1024.0
    return None


def se2(x, y, yaw):
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def xyyaw(T):
    return float(T[0, 2]), float(T[1, 2]), float(math.atan2(T[1, 0], T[0, 0]))


def trinary_image(grid):
    """A Grid (OccupancyGrid order, row 0 at the bottom) as MRPT reads a bitmap: row 0 at the
    top, 255 free, 0 occupied, 128 unknown."""
    from multi_map_merge.core.grid import FREE, OCCUPIED
    lv = grid.levels()
    img = np.full(lv.shape, 128, np.uint8)
    img[lv == FREE] = 255
    img[lv == OCCUPIED] = 0
    return np.ascontiguousarray(img[::-1])


def align_all(grids, seed=1, icp=True, work=None):
    """MRPT on every pair of ``grids`` (one resolution): [{'i', 'j', 'kept', 'T' (3x3: pose of
    grid j's map frame in grid i's map frame), 'quality', 'seconds', ...}]."""
    import cv2
    res = {round(g.resolution, 9) for g in grids}
    if len(res) != 1:
        raise ValueError('MRPT\'s aligner needs one resolution; these maps have %s' % sorted(res))
    work = work or tempfile.mkdtemp(prefix='mmm_mrpt_')
    imgs = []
    for k, g in enumerate(grids):
        p = os.path.join(work, 'grid_%d.png' % k)
        cv2.imwrite(p, trinary_image(g))
        imgs.append(p)
    cmd = [binary(), '--seed', str(seed)] + ([] if icp else ['--no-icp']) + [repr(grids[0].resolution)] + imgs
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True, env=ENV, cwd=work)
    if r.returncode != 0:
        raise RuntimeError('mrpt_grid_align failed (exit %d): %s' % (r.returncode, r.stderr[-800:]))
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    # the driver's own figures: CPU from this process's children (the driver alone since
    # ``before``); peak RSS as the driver reads its own (a child's ru_maxrss would count this
    # process's pages too: a forked child starts with them until its exec)
    DRIVER.update({'wall_s': time.time() - t0, 'rss_mb': None,
                   'cpu_s': (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)})
    out = []
    for line in r.stdout.splitlines():
        if not line.startswith('{'):
            continue
        p = json.loads(line)
        if 'peak_rss_kb' in p:
            DRIVER['rss_mb'] = p['peak_rss_kb'] / 1024.0
            continue
        if p['kept']:
            gi, gj = grids[p['i']], grids[p['j']]
            # the driver's frames have their origin at each grid's lower-left corner
            L = se2(*p['pose'])
            p['T'] = se2(*gi.origin) @ L @ np.linalg.inv(se2(*gj.origin))
            p['quality'] = p.get('icp_goodness', 1.0)
        out.append(p)
    return out


def spanning_tree(n, pairs, ref):
    """{k: (parent, T_parent_k)} of the maximum spanning tree (by quality) of the kept ``pairs``
    grown from ``ref`` (Prim); maps it does not reach are absent."""
    edges = {}
    for p in pairs:
        if p['kept']:
            i, j, T = p['i'], p['j'], p['T']
            edges.setdefault(i, []).append((p['quality'], j, T))
            edges.setdefault(j, []).append((p['quality'], i, np.linalg.inv(T)))
    tree = {ref: (None, np.eye(3))}
    while True:
        best = None
        for a in tree:
            for q, b, T in edges.get(a, []):
                if b not in tree and (best is None or q > best[0]):
                    best = (q, a, b, T)
        if best is None:
            return tree
        tree[best[2]] = (best[1], best[3])


def merge(paths, reference=None, seed=1, icp=True):
    """(report for T.yaml, {index: 3x3 pose in the reference's frame}, grids)."""
    from multi_map_merge.core.mapio import load_map
    grids = [load_map(p) for p in paths]
    stems = [os.path.splitext(os.path.basename(p))[0] for p in paths]
    ref = stems.index(reference) if reference is not None else 0
    t0 = time.time()
    pairs = align_all(grids, seed=seed, icp=icp)
    tree = spanning_tree(len(grids), pairs, ref)
    poses = {}

    def pose_of(k):
        if k not in poses:
            parent, T = tree[k]
            poses[k] = T if parent is None else pose_of(parent) @ T
        return poses[k]

    maps = {}
    for k, s in enumerate(stems):
        if k == ref:
            continue
        if k in tree:
            x, y, yaw = xyyaw(pose_of(k))
            q = next(p['quality'] for p in pairs if {p['i'], p['j']} == {k, tree[k][0]} and p['kept'])
            maps[s] = {'merged': True, 'x': x, 'y': y, 'yaw': yaw, 'scale': 1.0, 'parent': stems[tree[k][0]],
                       'quality': float(q)}
        else:
            maps[s] = {'merged': False}
    for k in tree:
        pose_of(k)
    rep = {'reference': stems[ref], 'merger': 'MRPT CGridMapAligner (bench/mrpt_merge.py)', 'seed': seed,
           'seconds': round(time.time() - t0, 3), 'driver': dict(DRIVER), 'maps': maps,
           'pairs': [{'a': stems[p['i']], 'b': stems[p['j']], 'kept': p['kept'], 'modes': p['modes'],
                      'quality': p.get('quality'), 'seconds': p['seconds'],
                      'pose': list(xyyaw(p['T'])) if p['kept'] else None} for p in pairs]}
    return rep, poses, grids


def composite_grids(grids, poses, ref):
    """The placed grids composited as merge_maps composites (occupied > free > unknown) on the
    reference's lattice."""
    from multi_map_merge.core.composite import composite, lattice_for, warp_patch
    from multi_map_merge.core.config import MergeConfig
    c = MergeConfig()
    lattice = lattice_for(grids[ref])
    patches = []
    for k in sorted(poses):
        g = grids[k]
        kv = g.known_values(c.free_thresh, c.occupied_thresh)
        if kv is not None:
            patches.append(warp_patch(kv[1], kv[0], g.resolution, g.origin, poses[k], lattice, c.max_cells))
    return composite(patches, lattice, 'map', c.max_cells)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('maps', nargs='*', help='map_server yaml files')
    ap.add_argument('-o', '--output', help='merged map yaml')
    ap.add_argument('--transforms', help='T.yaml: placements and every pair\'s result')
    ap.add_argument('--reference', help='stem of the reference map (default: the first)')
    ap.add_argument('--seed', type=int, default=1, help='MRPT\'s random seed (default 1)')
    ap.add_argument('--no-icp', action='store_true', help='without the aligner\'s ICP stage')
    ap.add_argument('--build', action='store_true', help='only build the driver and print its path')
    a = ap.parse_args(argv)
    ok, why = available()
    if not ok:
        print(why, file=sys.stderr)
        return 3
    if a.build:
        print(binary())
        return 0
    if len(a.maps) < 2 or not a.output:
        ap.error('needs two maps or more and -o')
    import yaml

    from multi_map_merge.core.mapio import save_map
    rep, poses, grids = merge(a.maps, a.reference, a.seed, not a.no_icp)
    ref = [os.path.splitext(os.path.basename(p))[0] for p in a.maps].index(rep['reference'])
    grid = composite_grids(grids, poses, ref)
    if grid is not None:
        save_map(grid, a.output)
    rep['frontend_rss_mb'] = peak_rss_mb()
    if a.transforms:
        with open(a.transforms, 'w') as f:
            yaml.safe_dump(rep, f, default_flow_style=None, sort_keys=False)
    placed = 1 + sum(1 for v in rep['maps'].values() if v['merged'])
    print('MRPT: %d/%d maps placed, %.2f s' % (placed, len(a.maps), rep['seconds']))
    return 0


if __name__ == '__main__':
    sys.exit(main())
