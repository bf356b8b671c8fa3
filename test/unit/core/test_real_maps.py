"""Maps made by others on real or simulated robots, merged and checked."""
import glob
import itertools
import math
import os

import numpy as np
import pytest
from conftest import MAZE, merged, pose_error, shared_file, truth

from multi_map_merge.core import verify
from multi_map_merge.core.grid import FREE, OCCUPIED
from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.merger import MapMerger
from multi_map_merge.core.transforms import pose_to_image, xyyaw


def merge(paths, names=None):
    """(a merger after one cycle on map files, {robot: its grid}), each robot named ``names``
    or by its file's stem."""
    grids = {n: load_map(p) for n, p in zip(names or [os.path.basename(p)[:-5] for p in paths], paths)}
    return merged(grids), grids


def cell_agreement(m, grids, a, b):
    """Of the cells known in both a's and b's maps (``grids``: robot -> the grid it was given)
    under their placements: the fraction where both say free or both say occupied (occupied
    may be one cell away: wall thickness)."""
    import cv2
    P = m.placements()
    ga, gb = grids[a], grids[b]
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
    paths = [shared_file(MAZE, 'tb3_%d_map.yaml' % n) for n in range(3)]
    m, _ = merge(paths, ['tb3_0', 'tb3_1', 'tb3_2'])
    P = m.placements()
    assert set(P) == {'tb3_0', 'tb3_1', 'tb3_2'}, {n: s.last_attempt for n, s in m.status().items()}
    # The three simulated robots' gmapping frames coincide up to drift (they were spawned
    # together): every relative pose is near identity.
    for n in ('tb3_1', 'tb3_2'):
        x, y, yaw = xyyaw(P[n].T)
        assert math.hypot(x, y) < 0.25 and abs(math.degrees(yaw)) < 2.0, (n, x, y, yaw)
    merged = m.compose()
    full = load_map(shared_file(MAZE, 'dans_maze_map.yaml'))
    m2 = MapMerger()
    m2.update_map('full', full)
    m2.update_map('merged', merged)
    m2.estimate()
    assert 'merged' in m2.placements()
    A = pose_to_image(m2.placements()['merged'].T, full.resolution, full.origin, merged.resolution, merged.origin)
    agreement, overlap = verify.agreement(full.levels(), merged.levels(), A, 2)
    assert agreement > 0.93, agreement
    assert overlap > 0.9 * (full.data >= 0).sum()       # the merge covers the whole maze


def test_isr_small_three_real_robots(shared_data):
    paths = sorted(glob.glob(os.path.join(shared_data, 'mrgs/maps/isr_small__isr_small_gmapping__*.yaml')))
    assert len(paths) == 3
    m, grids = merge(paths)
    P = m.placements()
    assert len(P) == 3, {n: s.last_attempt for n, s in m.status().items()}
    for a, b in itertools.combinations(sorted(P), 2):
        frac, both = cell_agreement(m, grids, a, b)
        assert both > 5000 and frac >= 0.90, (a, b, frac, both)


def test_intel_inner_outer_45_degrees(shared_data):
    d = os.path.join(shared_data, 'mrgs/maps')
    m, grids = merge([os.path.join(d, 'intel__inner.yaml'), os.path.join(d, 'intel__outer.yaml')])
    P = m.placements()
    assert 'intel__outer' in P
    yaw = math.degrees(xyyaw(P['intel__outer'].T)[2])
    assert -55 < yaw < -40, yaw
    frac, _ = cell_agreement(m, grids, 'intel__inner', 'intel__outer')
    assert frac >= 0.9, frac


def house(shared_data, **kw):
    from multi_map_merge.core.config import MergeConfig
    m = MapMerger(MergeConfig(**kw))
    for i in range(4):
        m.update_map('tb3_%d' % i, load_map(os.path.join(shared_data, 'tb3_house', 'tb3_%d_map.yaml' % i)))
    m.estimate()
    return m


def test_tb3_house_trap_with_initial_poses(shared_data):
    """The Turtlebot3 double house is two near-identical halves: tb3_0 and tb3_2 mapped one,
    tb3_1 and tb3_3 the other, all four started together with the same heading. Matching alone
    stacks the halves (a known limit, also m-explore's). With the robots' initial poses the
    stacked placements (180 degrees off) are rejected and said why; never merged wrongly."""
    pri = {'tb3_%d' % i: [0.0, 0.0, 0.0] for i in range(4)}
    m = house(shared_data, initial_poses=pri)
    P = m.placements()
    assert set(P) == {'tb3_0', 'tb3_2'}
    x, y, yaw = xyyaw(P['tb3_2'].T)
    assert math.hypot(x, y) < 0.5 and abs(yaw) < math.radians(3)
    st = m.status()
    assert st['tb3_1'].linked_to == ('tb3_3',) and not st['tb3_1'].merged
    reasons = [r.reason for pair, r in m.pair_results().items() if set(pair) == {'tb3_0', 'tb3_3'}]
    assert reasons and 'contradicts initial poses' in reasons[0]
    # trusting the priors places the other half at its start pose: the whole house is covered
    m = house(shared_data, initial_poses=pri, trust_initial_poses=True)
    assert set(m.placements()) == {'tb3_0', 'tb3_1', 'tb3_2', 'tb3_3'}
    assert m.placements()['tb3_1'].via == 'initial_pose'
    known = (m.compose().data >= 0).sum()
    stacked = (house(shared_data).compose().data >= 0).sum()
    whole = load_map(os.path.join(shared_data, 'tb3_house', 'whole_map.yaml'))
    # stacked: about 45% of the whole map's known cells; both halves: about 75% (the robots
    # did not see everything the whole-map run saw)
    assert known > 0.7 * (whole.data >= 0).sum() and known > 1.5 * stacked, (known, stacked)


@pytest.mark.slow
def test_different_buildings_never_merge(shared_data):
    """False-merge rate on pairs with no true overlap, all from ../shared/data: zero."""
    d = shared_data
    maps = {
        'isr': os.path.join(d, 'mrgs/maps/isr_small__isr_small_gmapping__1.yaml'),
        'arena': os.path.join(d, 'mrgs/maps/arena__arena_gmapping__1.yaml'),
        'intel': os.path.join(d, 'mrgs/maps/intel__outer.yaml'),
        'house': os.path.join(d, 'tb3_house/tb3_0_map.yaml'),
        'maze': os.path.join(d, 'tb3_dans_maze/tb3_1_map.yaml'),
        'aws': os.path.join(d, 'aws/small_house/map.yaml'),
        'bookstore': os.path.join(d, 'aws/bookstore/map.yaml'),
        'fhw': os.path.join(d, 'ground_truth/fhw_gt.yaml'),
        'fr079': os.path.join(d, 'ground_truth/freiburg-079_gt.yaml'),
    }
    false = []
    for a, b in itertools.combinations(sorted(maps), 2):
        m, _ = merge([maps[a], maps[b]], [a, b])
        if b in m.placements():
            false.append((a, b, m.placements()[b].agreement))
    assert false == [], false


def test_dans_maze_each_robot_map_belongs_where_the_full_map_says():
    """The three robots and the full-map run share one world frame (spawned at the same
    place), so each robot map belongs at about identity in the full map. tb3_0 (short run)
    fits it there almost perfectly; tb3_1 drifted (visibly bent: at identity only ~75% of its
    walls agree) but is still found near identity by the merger; no robot is ever misplaced.
    Its placement in the merge, carried into the full map's frame, lands near identity too."""
    full = load_map(shared_file(MAZE, 'dans_maze_map.yaml'))
    lf = full.levels()
    robots = {n: load_map(shared_file(MAZE, 'tb3_%d_map.yaml' % n)) for n in range(3)}
    at_identity = {}
    for n, g in robots.items():
        A = pose_to_image(np.eye(3), full.resolution, full.origin, g.resolution, g.origin)
        at_identity[n], overlap = verify.agreement(lf, g.levels(), A, 2)
        assert overlap > 0.9 * (g.data >= 0).sum()          # all of it lies inside the maze
    assert at_identity[0] > 0.98 and at_identity[2] > 0.94, at_identity
    assert at_identity[1] < 0.85, at_identity                 # the drifted one
    found = {}
    for n, g in robots.items():
        m = merged({'full': full, 'r': g})
        if 'r' in m.placements():
            T = m.placements()['r'].T
            x, y, yaw = xyyaw(T)
            assert math.hypot(x, y) < 0.3 and abs(math.degrees(yaw)) < 3.0, (n, x, y, math.degrees(yaw))
            A = pose_to_image(T, full.resolution, full.origin, g.resolution, g.origin)
            found[n] = verify.agreement(lf, g.levels(), A, 2)[0]
            assert found[n] >= max(0.95, at_identity[n]), (n, found[n], at_identity[n])
    assert {1, 2} <= set(found), found
    # the merge of the three, placed in the full map: every robot frame near identity
    m = merged({'tb3_%d' % n: g for n, g in robots.items()})
    mf = merged({'full': full, 'merged': m.compose()})
    assert 'merged' in mf.placements()
    T_full_merged = mf.placements()['merged'].T
    for n, pl in m.placements().items():
        x, y, yaw = xyyaw(T_full_merged @ pl.T)
        assert math.hypot(x, y) < 0.3 and abs(math.degrees(yaw)) < 3.0, (n, x, y, math.degrees(yaw))


@pytest.mark.slow
def test_isr_small_live_orders_never_end_on_a_look_alike(shared_data):
    """The three real robots' gmapping bags, their maps fed in live-like orders (half of the
    maps dropped, estimation at random moments, seeded): an early link can be a corridor
    look-alike with a higher inlier ratio than the right one found later. In these orders
    the merger once ended 1.6-2.3 m off; it must end on a placement the last grids agree
    with."""
    import random

    pytest.importorskip('rosbag')        # the bags are read with ROS's rosbag API
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.ros.replay import read_bag_maps
    bags = [os.path.join(shared_data, 'mrgs/bags_gmapping/isr_small_gmapping_%d.bag' % k) for k in (1, 2, 3)]
    seq = []
    for k, b in enumerate(bags):
        for g in read_bag_maps(b)['/map']:
            g.frame_id = ''
            seq.append((g.stamp, 'tb3_%d' % k, g))
    seq.sort(key=lambda s: s[0])
    last = {n: g for _, n, g in seq}
    for seed in (19, 22):
        rnd = random.Random(seed)
        m = MapMerger(MergeConfig(reference_robot='tb3_0', workers=1))
        for _, n, g in seq:
            if rnd.random() < 0.5 and g is not last[n]:   # every robot's last map arrives
                continue
            m.update_map(n, g)
            if rnd.random() < 0.3:
                m.estimate()
        for _ in range(2):
            m.estimate()
        P = m.placements()
        assert len(P) == 3
        for a, b in itertools.combinations(sorted(P), 2):
            frac, both = cell_agreement(m, last, a, b)
            assert frac >= 0.95, (seed, a, b, frac, both)


# Windows of look-alike rooms: without the evidence gate a link of few inliers whose walls
# agree only in the main puts robots metres off, on Debian 12's stack and on Ubuntu 20.04's
# (`make test-focal`) alike: each window yields such a look-alike link on both stacks. The gate
# loosened (more inliers, or a lower agreement, than its thresholds) lets one of them through:
# a test for its thresholds as well as for its being on.
LOOK_ALIKE_WINDOWS = [('aces', 8, 0.4, 7), ('aces', 6, 0.35, 14), ('seattle', 6, 0.35, 13),
                      ('freiburg-101', 8, 0.4, 16)]


@pytest.mark.parametrize('world, robots, frac, seed', LOOK_ALIKE_WINDOWS)
def test_look_alike_windows_with_little_evidence_are_not_placed(shared_data, world, robots, frac, seed):
    """Windows of a building's true map, each robot at a random pose (bench's look-alike sweep):
    without the evidence gate (few_inliers 0) a look-alike link puts robots metres off (the
    premise, checked first: a window where it does not hold tests nothing); with the gate every
    placed robot is right, and no robot placed right without it is lost with it."""
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.lab.pieces import pieces_windows
    world_map = load_map(os.path.join(shared_data, 'ground_truth', '%s_gt.yaml' % world))
    pieces = pieces_windows(world_map, robots, frac, seed)
    errors = {}
    gated = MergeConfig().few_inliers
    for gate in (0, gated):
        m = MapMerger(MergeConfig(workers=1, few_inliers=gate))
        for k, (g, _) in enumerate(pieces):
            m.update_map('r%02d' % k, g)
        m.estimate()
        errors[gate] = [pose_error(p.T, truth(pieces[0][1], pieces[int(n[1:])][1]))[0]
                        for n, p in m.placements().items() if n != 'r00']
    assert max(errors[0], default=0.0) > 5.0, (
        'premise: without the gate a look-alike link places a robot metres off here', errors)
    assert all(e < 0.2 for e in errors[gated]), errors
    # and no robot placed right without the gate is lost with it
    assert len(errors[gated]) >= sum(e < 0.2 for e in errors[0]), errors
