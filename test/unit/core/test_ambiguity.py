"""A map that fits two different places of another equally well is left unmerged, with the
reason in its status (and so on /diagnostics), instead of being put in one of them at random.
True merges, which never have such a second placement, are kept."""
import math
import os

import numpy as np
import pytest
from conftest import HOUSE_MAP, merged, pose_error, shared_file

from multi_map_merge.core.grid import Grid, known_bbox
from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import xyyaw
from multi_map_merge.lab.pieces import cut_piece


def look_alike_building():
    """A building of two identical halves (the second turned by 180 degrees), the same half
    alone, and a robot's map of part of that half in its own frame (pose T in the half's)."""
    w = load_map(shared_file(HOUSE_MAP))
    r0, r1, c0, c1 = known_bbox(w.levels())
    half = w.data[r0:r1, c0:(c0 + c1) // 2]
    gap = np.full((half.shape[0], 10), -1, np.int8)
    double = Grid(np.hstack([half, gap, np.rot90(half, 2)]).astype(np.int8), w.resolution)
    single = Grid(np.hstack([half, gap, np.full_like(half, -1)]).astype(np.int8), w.resolution)
    h, wd = half.shape
    child, T = cut_piece(single, (int(0.1 * h), int(0.9 * h), int(0.1 * wd), int(0.9 * wd)), (2.0, -1.0, 0.7))
    return double, single, child, T


@pytest.mark.slow
def test_map_that_fits_both_halves_stays_unmerged_and_says_why():
    double, single, child, T = look_alike_building()
    m = merged({'a': double, 'b': child})
    assert 'b' not in m.placements()
    st = m.status()['b']
    assert not st.merged and st.last_attempt_with == 'a'
    assert st.last_attempt.reason.startswith('ambiguous: a second placement'), st.last_attempt.reason
    ag, apart, turn = st.last_attempt.runner_up
    assert ag > 0.95 and apart > 5.0 and abs(turn - 180) < 2
    # without the rule the grids pick one of the two halves, here the wrong one
    m = merged({'a': double, 'b': child}, ambiguity_margin=0.0)
    d, a = pose_error(m.placements()['b'].T, T)
    assert d > 5.0 and a > 170, (d, a)
    # the same map with only one such half is merged, where it belongs
    m = merged({'a': single, 'b': child})
    d, a = pose_error(m.placements()['b'].T, T)
    assert d <= 0.1 and a <= 1.0, (d, a)


def test_tb3_house_robot_maps_in_the_whole_house(shared_data):
    """The Turtlebot3 double house seen whole (whole_map), and each robot's map of one half:
    the true pose is about identity (all maps share one frame), the 180-degree turn stacks the
    bottom half onto the top one and verifies as well (agreement 0.98-0.99 against 0.96-0.99
    at the truth). Each robot map is either placed near identity or left unmerged as ambiguous.
    (feature_cells=0: the whole map would otherwise be described at half resolution and match
    no robot map at all.)"""
    d = os.path.join(shared_data, 'tb3_house')
    whole = load_map(os.path.join(d, 'whole_map.yaml'))
    placed, wrong_without_rule = [], []
    for i in range(4):
        g = load_map(os.path.join(d, 'tb3_%d_map.yaml' % i))
        m = merged({'house': whole, 'robot': g}, feature_cells=0)
        if 'robot' in m.placements():
            x, y, yaw = xyyaw(m.placements()['robot'].T)
            assert math.hypot(x, y) < 0.3 and abs(math.degrees(yaw)) < 3.0, (i, x, y, math.degrees(yaw))
            placed.append(i)
        else:
            reason = m.status()['robot'].last_attempt.reason
            assert reason.startswith('ambiguous'), (i, reason)
        m = merged({'house': whole, 'robot': g}, feature_cells=0, ambiguity_margin=0.0)
        if 'robot' in m.placements() and abs(xyyaw(m.placements()['robot'].T)[2]) > math.radians(90):
            wrong_without_rule.append(i)
    assert placed, 'no robot map placed in the whole house'
    assert wrong_without_rule, 'the trap is gone: the rule is no longer exercised here'


def test_tb3_house_without_priors_keeps_the_true_links(shared_data):
    """The two robots of each half link to each other near identity; no link gets a second
    verified placement, so the rule leaves every one of them alone. (Without priors the two
    halves still stack: across the halves the true pose overlaps by at most a few hundred
    cells, is never among the hypotheses, and the stacked links agree at 0.98-0.999, as well
    as the true ones. The maps alone cannot tell the halves apart: initial_poses can.)"""
    d = os.path.join(shared_data, 'tb3_house')
    m = merged({'tb3_%d' % i: load_map(os.path.join(d, 'tb3_%d_map.yaml' % i)) for i in range(4)})
    links, results = m.links(), m.pair_results()
    for a, b in (('tb3_0', 'tb3_2'), ('tb3_1', 'tb3_3')):
        assert (a, b) in links, results.get((a, b))
        x, y, yaw = xyyaw(links[(a, b)].T)
        assert math.hypot(x, y) < 0.3 and abs(math.degrees(yaw)) < 3.0, (a, b, x, y, math.degrees(yaw))
    assert all(r.accepted for r in results.values()), {k: r.reason for k, r in results.items()}
