"""A first cycle with ``defer_refinement`` (what the nodes run): robots placed from their links
alone, provisional, then the spare time (refresh) makes the placements the whole cycle gives."""
import math

import numpy as np
import pytest
from conftest import shared_file
from test_merger_behaviour import strip_pieces

from multi_map_merge.core.config import MergeConfig
from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.merger import MapMerger
from multi_map_merge.core.transforms import xyyaw

# the bound between the spare time's placements and the whole cycle's
SAME = (0.001, math.radians(0.01))


def fed(maps, **config):
    m = MapMerger(MergeConfig(**config))
    for n, g in maps.items():
        m.update_map(n, g)
    return m


def differences(a, b):
    """Per robot of ``a``: (metres, radians) between its placement in ``a`` and in ``b``."""
    out = {}
    for n, p in a.items():
        x, y, yaw = xyyaw(np.linalg.inv(p.T) @ b[n].T)
        out[n] = (math.hypot(x, y), abs(yaw))
    return out


def assert_deferral_ends_where_the_whole_cycle_does(maps, **config):
    whole = fed(maps, **config)
    whole.estimate()
    first = fed(maps, **config)
    first.estimate(defer_refinement=True)
    early = first.placements()
    ref = first.reference
    # placed as soon, from the verified links alone: provisional, the new links' covariances not
    # searched yet (a robot placed only by links that corroborate each other waits too)
    assert len(early) >= 2 and set(early) <= set(whole.placements())
    assert all(p.provisional for n, p in early.items() if n != ref)
    assert any(e.cov is None for e in first.links().values())
    assert not any(p.weak for p in early.values())        # provisional is not weakly pinned
    first.refresh(math.inf)
    late, want = first.placements(), whole.placements()
    assert set(late) == set(want)
    assert not any(p.provisional for p in late.values())
    for n, (d, a) in differences(want, late).items():
        assert d <= SAME[0] and a <= SAME[1], (n, d, math.degrees(a))
    for n, p in want.items():
        assert (p.cov is None) == (late[n].cov is None) and p.weak_reason == late[n].weak_reason, n
        if p.cov is not None:
            assert np.allclose(p.cov, late[n].cov, rtol=1e-6, atol=1e-12), n
    assert {k: e.cov is None for k, e in whole.links().items()} == {k: e.cov is None for k, e in first.links().items()}
    return early, want


def test_the_intel_strips(intel):
    ps = strip_pieces(intel, [(0, 0, 0), (3, -2, 2.0), (-4, 1, -2.5)])
    assert_deferral_ends_where_the_whole_cycle_does({n: g for n, (g, _) in zip('abc', ps)})


@pytest.mark.slow
def test_a_simulated_team_whose_maps_bend(house_team):
    """Four simulated Burgers' bent maps of the AWS house: the joint refinement moves their
    placements, so the first placement and the refined one differ, and the spare time ends
    where the whole cycle does."""
    maps, _ = house_team
    early, want = assert_deferral_ends_where_the_whole_cycle_does(maps)
    moved = differences({n: want[n] for n in early}, early)
    assert max(d for d, _ in moved.values()) > SAME[0] or max(a for _, a in moved.values()) > SAME[1], moved


def test_the_tb3_house_gmapping_maps():
    paths = [shared_file('tb3_house', 'tb3_%d_map.yaml' % k) for k in range(4)]
    assert_deferral_ends_where_the_whole_cycle_does({'tb3_%d' % k: load_map(p) for k, p in enumerate(paths)})


def test_a_cycle_that_aligns_nothing_completes_the_deferred_work(intel):
    """Without spare time (a library caller, a node whose cycles overrun), the next cycle that
    has nothing new to align does what the deferred one left."""
    ps = strip_pieces(intel, [(0, 0, 0), (3, -2, 2.0), (-4, 1, -2.5)])
    maps = {n: g for n, (g, _) in zip('abc', ps)}
    whole = fed(maps)
    whole.estimate()
    m = fed(maps)
    m.estimate(defer_refinement=True)
    assert any(p.provisional for p in m.placements().values())
    m.estimate(defer_refinement=True)
    assert not any(p.provisional for p in m.placements().values())
    for n, (d, a) in differences(whole.placements(), m.placements()).items():
        assert d <= SAME[0] and a <= SAME[1], (n, d, math.degrees(a))


def test_cycles_of_a_placed_team_are_the_same_with_or_without_it(intel):
    """Once every robot is placed, a cycle is what it is without ``defer_refinement``: new map
    versions, one map grown by half, give the same placements, none provisional."""
    from multi_map_merge.core.grid import Grid
    from multi_map_merge.core.schedule import SLOW_EVERY
    ps = strip_pieces(intel, [(0, 0, 0), (3, -2, 2.0), (-4, 1, -2.5)])
    maps = {n: g for n, (g, _) in zip('abc', ps)}
    # b's map at first with a third of its columns not yet seen: it grows by half later, which
    # has its links aligned again from features
    grown = maps['b']
    cols = np.flatnonzero((grown.data >= 0).any(axis=0))
    young = grown.data.copy()
    young[:, cols[0] + 2 * len(cols) // 3:] = -1
    first = dict(maps, b=Grid(young, grown.resolution, grown.origin))
    node, lib = fed(first), fed(first)
    node.estimate(defer_refinement=True)
    node.refresh(math.inf)
    lib.estimate()
    assert len(lib.placements()) == 3
    for k in range(SLOW_EVERY + 1):
        for m in (node, lib):
            for n, g in maps.items():     # every map again, as a new version
                m.update_map(n, Grid(g.data.copy(), g.resolution, g.origin))
        node.estimate(defer_refinement=True)
        lib.estimate()
        assert not any(p.provisional for p in node.placements().values()), k
        for n, (d, a) in differences(lib.placements(), node.placements()).items():
            assert d <= 1e-9 and a <= 1e-9, (k, n, d, a)
