"""Maps made by others on real or simulated robots, merged and checked."""
import glob
import itertools
import math
import os

import numpy as np
import pytest

from multi_map_merge import estimate as est
from multi_map_merge.grid import FREE, OCCUPIED
from multi_map_merge.mapio import load_map
from multi_map_merge.merger import MapMerger
from multi_map_merge.transforms import pose_to_image, xyyaw
from conftest import DATA

MAZE = os.path.join(DATA, 'tb3_dans_maze')


def merge(paths, names=None):
    m = MapMerger()
    names = names or [os.path.basename(p)[:-5] for p in paths]
    for n, p in zip(names, paths):
        m.update_map(n, load_map(p))
    m.estimate()
    return m


def cell_agreement(m, a, b):
    """Of the cells known in both a's and b's maps under their placements: the fraction where
    both say free or both say occupied (occupied may be one cell away: wall thickness)."""
    import cv2
    P = m.placements()
    ga, gb = m._maps[a].grid, m._maps[b].grid
    A = pose_to_image(np.linalg.inv(P[a].T) @ P[b].T, ga.resolution, ga.origin, gb.resolution, gb.origin)
    la, lb = ga.levels(), gb.levels()
    wb = cv2.warpAffine(lb, A[:2], (la.shape[1], la.shape[0]), flags=cv2.INTER_NEAREST, borderValue=0)
    both = (la > 0) & (wb > 0)
    k = np.ones((3, 3), np.uint8)
    near_a = cv2.dilate((la == OCCUPIED).astype(np.uint8), k) > 0
    near_b = cv2.dilate((wb == OCCUPIED).astype(np.uint8), k) > 0
    agree = ((la == FREE) & (wb == FREE)) | ((la == OCCUPIED) & near_b) | ((wb == OCCUPIED) & near_a)
    return float((agree & both).sum()) / max(1, both.sum()), int(both.sum())


def test_dans_maze_three_robots_match_the_full_map():
    paths = [os.path.join(MAZE, 'tb3_%d_map.yaml' % n) for n in range(3)]
    m = merge(paths, ['tb3_0', 'tb3_1', 'tb3_2'])
    P = m.placements()
    assert set(P) == {'tb3_0', 'tb3_1', 'tb3_2'}, {n: s.last_attempt for n, s in m.status().items()}
    # The three simulated robots' gmapping frames coincide up to drift (they were spawned
    # together): every relative pose is near identity.
    for n in ('tb3_1', 'tb3_2'):
        x, y, yaw = xyyaw(P[n].T)
        assert math.hypot(x, y) < 0.25 and abs(math.degrees(yaw)) < 2.0, (n, x, y, yaw)
    merged = m.compose()
    full = load_map(os.path.join(MAZE, 'dans_maze_map.yaml'))
    m2 = MapMerger()
    m2.update_map('full', full)
    m2.update_map('merged', merged)
    m2.estimate()
    assert 'merged' in m2.placements()
    A = pose_to_image(m2.placements()['merged'].T, full.resolution, full.origin, merged.resolution, merged.origin)
    agreement, overlap = est.agreement(full.levels(), merged.levels(), A, 2)
    assert agreement > 0.93, agreement
    assert overlap > 0.9 * (full.data >= 0).sum()       # the merge covers the whole maze


def test_isr_small_three_real_robots(shared_data):
    paths = sorted(glob.glob(os.path.join(shared_data, 'mrgs/maps/isr_small__isr_small_gmapping__*.yaml')))
    assert len(paths) == 3
    m = merge(paths)
    P = m.placements()
    assert len(P) == 3, {n: s.last_attempt for n, s in m.status().items()}
    for a, b in itertools.combinations(sorted(P), 2):
        frac, both = cell_agreement(m, a, b)
        assert both > 5000 and frac >= 0.90, (a, b, frac, both)


def test_intel_inner_outer_45_degrees(shared_data):
    d = os.path.join(shared_data, 'mrgs/maps')
    m = merge([os.path.join(d, 'intel__inner.yaml'), os.path.join(d, 'intel__outer.yaml')])
    P = m.placements()
    assert 'intel__outer' in P
    yaw = math.degrees(xyyaw(P['intel__outer'].T)[2])
    assert -55 < yaw < -40, yaw
    frac, _ = cell_agreement(m, 'intel__inner', 'intel__outer')
    assert frac >= 0.9, frac
