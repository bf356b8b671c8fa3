"""The benchmark's inputs: robots' maps cut out of real maps, written as map_server files.

Both mergers read the very same files. Where the maps are cut from a ground-truth map
(``pieces.split_rects`` / windows + ``cut_piece`` at ``random_poses``), the true pose of every
robot's map frame is known and returned, so both mergers' answers can be scored.
"""
from __future__ import annotations

import glob
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
SHARED = os.path.abspath(os.path.join(REPO, '..', 'shared'))
DATA = os.path.join(SHARED, 'data')

from multi_map_merge.core.mapio import load_map, save_map  # noqa: E402
from multi_map_merge.lab.pieces import cut_piece, pieces_windows, random_poses, split_rects  # noqa: E402


def world_map(name, required=False):
    """A ground-truth map of ../shared/data (others' data, read in place); None if absent, or,
    ``required``, exit naming the missing file."""
    path = os.path.join(DATA, 'ground_truth', '%s_gt.yaml' % name)
    if os.path.exists(path):
        return load_map(path)
    if required:
        raise SystemExit("%s is absent: the benchmarks read others' maps in place from ../shared/data" % path)
    return None


def pieces_split(world, n, seed=0, overlap=0.3):
    """n overlapping pieces tiling the world (split_rects), each at a random pose: [(grid, T)]."""
    return [cut_piece(world, r, p) for r, p in zip(split_rects(world, n, overlap), random_poses(n, seed))]


def write_inputs(name, grids_truth, root):
    """Write the robots' maps as ``root/name/rNN.yaml``; returns (paths, truths or None), truths
    being the pose of every map frame in map 0's frame (3x3 lists)."""
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
    return paths, [(np.linalg.inv(truths[0]) @ T).tolist() for T in truths]


def configurations(quick=False):
    """[(name, kind, [(grid, T or None)])]: kind 'size' rows sweep the map size at 4 robots,
    kind 'count' rows sweep the robot count on intel-sized maps."""
    confs = []
    house = sorted(glob.glob(os.path.join(DATA, 'tb3_house', 'tb3_*_map.yaml')))
    if house:
        confs.append(('house 4', 'size', [(load_map(p), None) for p in house]))
    for name in (['intel'] if quick else ['intel', 'aces', 'edmonton']):
        w = world_map(name)
        if w is not None:
            confs.append(('%s 4' % name, 'size', pieces_split(w, 4)))
    w = world_map('intel', required=True)
    for n in ([2, 4, 8] if quick else [2, 4, 8, 16, 32]):
        confs.append(('intel-sized x%d' % n, 'count', pieces_windows(w, n)))
    return confs


def row_paths(name, root):
    """The maps of run_bench.py's row ``name`` ('house 4', 'intel-sized x8'...) written as map
    files under ``root``; exits naming the rows when there is none of that name."""
    confs = configurations()
    for n, _, pieces in confs:
        if n == name:
            return write_inputs(name.replace(' ', '_'), pieces, root)[0]
    raise SystemExit('no row %r (rows: %s)' % (name, ', '.join(n for n, _, _ in confs)))


def median_cells(paths):
    """Median cell count (width x height) of the map files ``paths``."""
    return float(np.median([g.width * g.height for g in (load_map(p) for p in paths)]))
