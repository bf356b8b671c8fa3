"""A SLAM map's drift from its frame's origin in a placement's covariance (core/drift.py)."""
import math
import os

import numpy as np
import yaml
from conftest import DATA, merged

from multi_map_merge.core import drift
from multi_map_merge.core.transforms import se2, xyyaw

RATE, YAW_RATE = 0.02, math.radians(0.4)


def test_the_drift_grows_with_the_overlaps_distance_from_both_origins():
    T = se2(10.0, 0.0, 0.5)                 # the child's origin 10 m from the parent's
    near_parent = drift.link_covariance((1.0, 0.0), T, RATE, YAW_RATE)      # 1 m and 9 m away
    midway = drift.link_covariance((5.0, 0.0), T, RATE, YAW_RATE)           # 5 m and 5 m
    assert np.allclose(near_parent, near_parent.T) and np.all(np.linalg.eigvalsh(near_parent) > 0)
    assert near_parent[2, 2] == midway[2, 2] == YAW_RATE ** 2 * 10.0       # heading: a random walk
    # position: each map's stretch, and the turn about the overlap moves the child's origin sideways
    assert near_parent[0, 0] == RATE ** 2 * (1.0 + 81.0)
    assert near_parent[1, 1] == RATE ** 2 * 82.0 + YAW_RATE ** 2 * 10.0 * 81.0
    assert midway[1, 1] < near_parent[1, 1]
    assert np.allclose(drift.link_covariance((0.0, 0.0), se2(0.0, 0.0, 0.0), RATE, YAW_RATE), 0.0)
    assert np.allclose(drift.link_covariance((3.0, 4.0), T, 0.0, 0.0), 0.0)


REAL = os.path.join(DATA, 'house_gmapping_s2')


def test_real_gmapping_maps_placements_are_within_their_ellipse_of_the_true_starts():
    """The house, seed 2, four real gmapping maps: every placement's error against where the
    robots really started lies within its 95% ellipse (x, y, yaw) with the maps' drift, and
    the ellipse of the walls alone misses at least one of them."""
    with open(os.path.join(REAL, 'house.truth.yaml')) as f:
        starts = {r: v['start'] for r, v in yaml.safe_load(f)['robots'].items()}
    maps = {r: os.path.join(REAL, r + '.yaml') for r in ('tb3_0', 'tb3_1', 'tb3_2', 'tb3_3')}

    def d2s(**cfg):
        m = merged(maps, reference_robot='tb3_0', workers=1, **cfg)
        out = {}
        for r, pl in m.placements().items():
            if r == 'tb3_0':
                continue
            true = np.linalg.inv(se2(*starts['tb3_0'])) @ se2(*starts[r])
            e = np.array(xyyaw(pl.T)) - np.array(xyyaw(true))
            e[2] = (e[2] + math.pi) % (2 * math.pi) - math.pi
            out[r] = (float(e @ np.linalg.solve(pl.cov, e)), pl.T)
        return out
    with_drift, walls_only = d2s(), d2s(map_drift=0.0, map_drift_yaw=0.0)
    assert set(with_drift) == set(walls_only) == {'tb3_1', 'tb3_2', 'tb3_3'}
    assert all(d2 < 7.81 for d2, _ in with_drift.values()), with_drift
    assert max(d2 for d2, _ in walls_only.values()) > 7.81, walls_only
    # the drift widens what the placement is known to; it does not move it
    for r in with_drift:
        assert np.allclose(with_drift[r][1], walls_only[r][1])
