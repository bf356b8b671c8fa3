"""Which pairs a cycle works on (core/schedule.py), and the merger following it: kept links
tracked on new maps, alignment from features where it is needed, within the cycle's budget."""
import dataclasses

import numpy as np
import pytest
from conftest import pose_error, truth
from test_merger_behaviour import another_version, strip_pieces

from multi_map_merge.core import schedule
from multi_map_merge.core.config import MergeConfig
from multi_map_merge.core.grid import Grid
from multi_map_merge.core.merger import MapMerger
from multi_map_merge.core.transforms import se2


@dataclasses.dataclass
class FakeLink:
    T: np.ndarray
    overlap: int


def facts(version=1, known=1000, box=(0.0, 0.0, 10.0, 10.0)):
    x0, y0, x1, y1 = box
    return schedule.MapFacts(version, known, np.array([[x0, y0], [x1, y0], [x0, y1], [x1, y1]]))


def plan(f, links=(), tried=None, aligned=None, failed=(), placed=None, via=None, due=(), ref='a'):
    links = {k: FakeLink(np.eye(3), 500) for k in links} if not isinstance(links, dict) else links
    return schedule.plan(f, ref, links, tried or {}, aligned or {}, set(failed), placed or {}, via or {},
                         set(due), 0.05)


def test_pairs_of_puts_the_reference_as_parent():
    assert schedule.pairs_of('cab', 'b') == [('b', 'a'), ('a', 'c'), ('b', 'c')]


def test_a_pair_whose_maps_did_not_change_is_left_alone():
    f = {'a': facts(3), 'b': facts(5)}
    assert plan(f, tried={('a', 'b'): (3, 5)}).todo == []
    assert plan(f, tried={('a', 'b'): (3, 4)}).todo == [('a', 'b')]


def test_a_linked_pair_is_tracked_and_a_failed_track_aligned_first():
    f = {'a': facts(), 'b': facts(), 'c': facts()}
    eye = np.eye(3)
    p = plan(f, links=[('a', 'b')], placed={'a': eye, 'b': eye})
    assert p.track.keys() == {('a', 'b')} and p.todo[0] == ('a', 'b')
    p = plan(f, links=[('a', 'b')], failed=[('a', 'b')], placed={'a': eye, 'b': eye})
    assert not p.track and p.todo[0] == ('a', 'b') and p.why[('a', 'b')] == schedule.FAILED_TRACK


def test_placed_maps_that_cannot_overlap_are_not_aligned_until_they_grow_towards_each_other():
    # b and c are placed (linked to the reference a) but not linked to each other
    eye = np.eye(3)
    links = [('a', 'b'), ('a', 'c')]
    placed = {'a': eye, 'b': eye, 'c': se2(30.0, 0.0, 0.0)}
    far = {'a': facts(), 'b': facts(box=(0, 0, 10, 10)), 'c': facts(box=(0, 0, 10, 10))}
    assert ('b', 'c') not in plan(far, links=links, placed=placed, due={'b', 'c'}).todo
    near = {'a': facts(), 'b': facts(box=(0, 0, 10, 10)), 'c': facts(box=(-25, 0, 10, 10))}   # c grew towards b
    # aligned in a slot of the slow schedule: when b's or c's turn comes
    assert ('b', 'c') not in plan(near, links=links, placed=placed).todo
    p = plan(near, links=links, placed=placed, due={'c'})
    assert ('b', 'c') in p.todo and p.why[('b', 'c')] == schedule.PLACED_PAIR
    # aligned (refused) at that overlap: again only once it can overlap GROWTH times more
    expected = schedule.expected_overlap(near, placed, ('b', 'c'), 0.05)
    assert expected == pytest.approx(5 * 10 / 0.05 ** 2)
    aligned = {('b', 'c'): schedule.Aligned(1, expected)}
    assert ('b', 'c') not in plan(near, links=links, placed=placed, aligned=aligned, due={'c'}).todo
    nearer = {'a': facts(), 'b': facts(box=(0, 0, 10, 10)), 'c': facts(box=(-28, 0, 10, 10))}
    assert ('b', 'c') in plan(nearer, links=links, placed=placed, aligned=aligned, due={'c'}).todo


def test_a_robot_placed_at_its_prior_only_still_needs_a_link():
    eye = np.eye(3)
    p = plan({'a': facts(), 'b': facts()}, placed={'a': eye, 'b': eye})
    assert p.todo == [('a', 'b')] and p.why[('a', 'b')] == schedule.PLACES_ROBOT


def test_pairs_that_can_place_a_robot_go_first_with_a_placed_partner_by_size():
    eye = np.eye(3)
    f = {'a': facts(known=900), 'b': facts(known=5000), 'c': facts(known=2000), 'd': facts(known=100)}
    p = plan(f, placed={'a': eye})
    # a (placed) with b, c, d first, the larger overlap they can have first; then unplaced pairs
    assert p.todo[:3] == [('a', 'b'), ('a', 'c'), ('a', 'd')]
    assert all(p.why[k] == schedule.PLACES_ROBOT_UNPLACED for k in p.todo[3:])
    assert p.todo[3:] == [('b', 'c'), ('b', 'd'), ('c', 'd')]


def test_only_a_robots_largest_overlaps_and_its_placement_link_are_tracked():
    # six robots, every pair linked (overlap: the product of their numbers): per robot two
    names = 'abcdef'
    links = {(a, b): FakeLink(np.eye(3), (i + 1) * (j + 1)) for i, a in enumerate(names)
             for j, b in enumerate(names) if i < j}
    t = schedule.tracked_links(links, {}, {}, per_robot=2)
    assert len(t) <= 2 * len(names) < len(links)
    for n in names:
        mine = sorted((k for k in links if n in k), key=lambda k: -links[k].overlap)
        assert set(mine[:2]) <= t
    assert ('a', 'b') not in t
    # a placement through a link of small overlap: that link too
    assert ('a', 'b') in schedule.tracked_links(links, {'b': 'a'}, {}, per_robot=2)
    # only the robots whose map changed choose: a cost per new map that the team's size does not grow
    t = schedule.tracked_links(links, {'b': 'a', 'c': 'f'}, {}, per_robot=2, robots={'a'})
    assert t == {('a', 'e'), ('a', 'f')}
    # the links whose maps grew most since they were last refreshed, in turn
    t = schedule.tracked_links(links, {}, {('a', 'b'): 3.0, ('a', 'c'): 2.0}, per_robot=2, robots={'a'})
    assert t == {('a', 'b'), ('a', 'c')}


def test_the_slow_schedule_aligns_a_changed_robots_oldest_link():
    eye = np.eye(3)
    f = {'a': facts(), 'b': facts(), 'c': facts()}
    aligned = {('a', 'b'): schedule.Aligned(7, 1.0), ('a', 'c'): schedule.Aligned(3, 1.0)}
    p = plan(f, links=[('a', 'b'), ('a', 'c')], aligned=aligned, placed={n: eye for n in 'abc'}, due={'a'})
    assert p.why[('a', 'c')] == schedule.SLOW_SCHEDULE and set(p.track) == {('a', 'b')}
    assert p.todo.index(('a', 'c')) == len(p.todo) - 1      # last: after the pair (b, c) without a link


# ---------------------------------------------------------------- the merger following it

@pytest.fixture
def ps(intel):
    return strip_pieces(intel, [(0, 0, 0), (3, -2, 2.0), (-4, 1, -2.5)])


def test_a_kept_link_is_tracked_on_new_maps_and_refined(ps):
    m = MapMerger(MergeConfig(reference_robot='a', workers=1))
    for n, (g, _) in zip('abc', ps):
        m.update_map(n, g)
    m.estimate()
    assert set(m.links()) == {('a', 'b'), ('b', 'c')}
    # the kept link nudged off by 10 cm and a degree: a new version of b's map is tracked back
    key = ('a', 'b')
    with m._lock:
        links = m._linker.ledger.links
        links[key] = dataclasses.replace(links[key], T=links[key].T @ se2(0.1, 0.0, np.radians(1.0)))
    m.update_map('b', another_version(ps[1][0]))
    m.estimate()
    r = m.pair_results()[key]
    assert r.tracked and r.accepted and r.inliers == m.links()[key].inliers > 0
    d, a = pose_error(m.links()[key].T, truth(ps[0][1], ps[1][1]))
    assert d < 0.05 and a < 0.5, (d, a)


def test_a_link_that_fails_its_tracking_is_aligned_again_from_features(ps):
    m = MapMerger(MergeConfig(reference_robot='a', workers=1))
    for n, (g, _) in zip('ab', ps):
        m.update_map(n, g)
    m.estimate()
    key = ('a', 'b')
    with m._lock:    # a kept link 2 m off: its tracking cannot verify it
        links = m._linker.ledger.links
        links[key] = dataclasses.replace(links[key], T=links[key].T @ se2(2.0, 0.0, 0.0))
    m.update_map('b', another_version(ps[1][0]))
    m.estimate()
    r = m.pair_results()[key]
    assert r.tracked and not r.accepted and 'aligned again from features' in r.reason
    m.estimate()                     # the same maps: aligned from features on them
    r = m.pair_results()[key]
    assert not r.tracked and r.accepted
    d, a = pose_error(m.links()[key].T, truth(ps[0][1], ps[1][1]))
    assert d < 0.1 and a < 1.0, (d, a)


def test_a_cycle_over_its_budget_leaves_pairs_for_the_next(ps):
    # a budget no alignment fits in: one pair a cycle (at least one, so that cycles progress)
    m = MapMerger(MergeConfig(reference_robot='a', workers=1, estimation_budget=1e-6))
    for n, (g, _) in zip('abc', ps):
        m.update_map(n, g)
    m.estimate()
    assert len(m.pair_results()) == 1 and set(m.placements()) == {'a', 'b'}
    m.estimate()
    assert len(m.pair_results()) == 2 and set(m.placements()) == {'a', 'b', 'c'}
    errors = [pose_error(m.placements()[n].T, truth(ps[0][1], ps[k][1])) for k, n in ((1, 'b'), (2, 'c'))]
    assert all(d < 0.1 and a < 1.0 for d, a in errors), errors


def earlier(g):
    """The map as it was earlier: the same grid with the last fifth of its known rows unknown."""
    data = g.data.copy()
    rows = np.flatnonzero((data >= 0).any(axis=1))
    data[rows[0] + int(0.8 * (rows[-1] - rows[0])):] = -1
    return Grid(data, g.resolution, g.origin)


def test_spare_time_refreshes_a_link_found_on_smaller_maps(ps):
    m = MapMerger(MergeConfig(reference_robot='a', workers=1))
    for n, (g, _) in zip('ab', ps):
        m.update_map(n, earlier(g))
    m.estimate()
    key = ('a', 'b')
    found = m.links()[key]
    assert found.cov is not None
    # the maps grew; no cycle yet: spare time tracks the link on them, with its covariance
    for n, (g, _) in zip('ab', ps):
        m.update_map(n, g)
    m.refresh(30.0)
    now = m.links()[key]
    assert now.overlap > 1.5 * found.overlap
    assert np.trace(now.cov[:2, :2]) < np.trace(found.cov[:2, :2])
    d, a = pose_error(now.T, truth(ps[0][1], ps[1][1]))
    assert d < 0.05 and a < 0.5, (d, a)
    assert m.placements()['b'].T is not None
    d, a = pose_error(m.placements()['b'].T, truth(ps[0][1], ps[1][1]))
    assert d < 0.05 and a < 0.5, (d, a)
    # the maps as they were when it was refreshed: nothing to do
    m.refresh(30.0)
    assert m.links()[key] is now


def test_refresh_links_false_leaves_spare_time_idle(ps):
    m = MapMerger(MergeConfig(reference_robot='a', workers=1, refresh_links=False))
    for n, (g, _) in zip('ab', ps):
        m.update_map(n, earlier(g))
    m.estimate()
    found = m.links()[('a', 'b')]
    for n, (g, _) in zip('ab', ps):
        m.update_map(n, g)
    assert m.refresh(30.0) == [] and m.links()[('a', 'b')] is found


@pytest.mark.parametrize('refresh_links', [True, False])
def test_a_map_that_changed_little_is_refined_in_spare_time(ps, monkeypatch, refresh_links):
    """A robot whose map changed but grew by less than REFINE_GROWTH since its joint refinement
    is not refined again by a cycle: the spare time refines it, once. Without ``refresh_links``
    (no spare-time work) the cycle refines it."""
    from multi_map_merge.core import joint
    refined = []
    real = joint.refine_placements

    def spy(robots, anchors, ref, lattice, tolerance, current=None, moving=None, run=None):
        refined.append(set(anchors) - {ref} if moving is None else set(moving))
        return real(robots, anchors, ref, lattice, tolerance, current, moving, run)
    monkeypatch.setattr(joint, 'refine_placements', spy)
    m = MapMerger(MergeConfig(reference_robot='a', workers=1, refresh_links=refresh_links))
    for n, (g, _) in zip('abc', ps):
        m.update_map(n, g)
    m.estimate()
    assert set(m.placements()) == {'a', 'b', 'c'} and refined[-1] == {'b', 'c'}
    del refined[:]
    m.update_map('b', another_version(ps[1][0]))      # the same known cells
    m.estimate()
    if not refresh_links:
        assert refined == [{'b'}]
        return
    assert refined == []
    m.refresh(30.0)
    assert refined == [{'b'}]
    m.refresh(30.0)                                      # done: nothing pending
    assert refined == [{'b'}]
