"""Placement by what all the overlaps say (core/joint.py): every placement refined against every
placed map it overlaps, bounded, deterministic, and still in the node's placements."""
import dataclasses
import math

import numpy as np
import pytest
from conftest import INTEL_MAP, MAZE, merged, shared_file

from multi_map_merge.core import joint
from multi_map_merge.core.composite import lattice_for
from multi_map_merge.core.grid import known_bbox
from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import apply, inverse, pose_distance, se2, within


def robots_of(grids):
    return {n: joint.Robot.of(g, g.levels(), g.known_values()) for n, g in grids.items()}


def at_walls(robot, T, D):
    """``D`` (a perturbation in the merged frame) applied about the centre of the robot's walls."""
    c = apply(T @ robot.W, robot.walls.mean(axis=0)[None])[0]
    return se2(c[0], c[1], 0.0) @ D @ se2(-c[0], -c[1], 0.0) @ T


def displaced(house_pair):
    """(robots, tb3_1's placement by its link, that placement moved 0.2 m and 4 degrees off at
    its walls, the lattice) of the house pair."""
    grids, m = house_pair
    robots = robots_of(grids)
    T_link = m.placements()['tb3_1'].T
    T_off = at_walls(robots['tb3_1'], T_link, se2(0.15, -0.13, math.radians(4.0)))
    return robots, T_link, T_off, lattice_for(grids['tb3_0'])


@pytest.fixture(scope='module')
def house_pair():
    """Two real gmapping maps of one half of the Turtlebot3 double house (ROBOTIS's tb3_house in
    ../shared/data: its robots tb3_0 and tb3_2, here tb3_0 and tb3_1), a pair that links on its
    own, and their merger. Both maps are in one frame: the link is about identity."""
    last = {'tb3_0': load_map(shared_file('tb3_house', 'tb3_0_map.yaml')),
            'tb3_1': load_map(shared_file('tb3_house', 'tb3_2_map.yaml'))}
    m = merged(last, reference_robot='tb3_0')
    assert set(m.placements()) == {'tb3_0', 'tb3_1'}
    d, a = pose_distance(m.placements()['tb3_1'].T, np.eye(3))
    assert d < 0.3 and math.degrees(a) < 3.0, (d, math.degrees(a))
    return last, m


def test_a_displaced_placement_comes_back_and_agrees_better(house_pair):
    """tb3_1 moved 0.2 m and 4 degrees off its link: refined against tb3_0, it comes back to
    within a few centimetres and a degree of where its link put it, and the two maps agree
    better than at the displaced pose."""
    robots, T_link, T_off, lattice = displaced(house_pair)
    anchors = {'tb3_0': np.eye(3), 'tb3_1': T_off}
    out = joint.refine_placements(robots, anchors, 'tb3_0', lattice, 2)
    assert np.array_equal(out['tb3_0'], np.eye(3))                  # the reference stays
    d_off, a_off = pose_distance(T_off, T_link)
    d, a = pose_distance(out['tb3_1'], T_link)
    assert d < 0.3 * d_off and math.degrees(a) < 1.0, (d, math.degrees(a))
    assert joint.joint_agreement(robots, out, 2) > joint.joint_agreement(robots, anchors, 2) + 0.05


def test_refining_its_own_result_moves_nothing(house_pair):
    """No jitter from cycle to cycle: a robot's refined pose is a function of the maps, its anchor
    and the other robots' poses, not of where it stands now. Refined again as the merger's next
    cycle does (its anchor unchanged, its own result as its current pose) it stays bit for bit;
    and so it does from any other current pose (its link's, a far one)."""
    robots, T_link, T_off, lattice = displaced(house_pair)
    anchors = {'tb3_0': np.eye(3), 'tb3_1': T_off}
    once = joint.refine_placements(robots, anchors, 'tb3_0', lattice, 2)
    assert pose_distance(once['tb3_1'], T_off)[0] > 0.1          # it moved: there is a result to keep
    far = at_walls(robots['tb3_1'], T_link, se2(0.8, 0.6, math.radians(15.0)))
    for name, T_now in (('its own result', once['tb3_1']), ('its link', T_link), ('far', far)):
        again = joint.refine_placements(robots, anchors, 'tb3_0', lattice, 2,
                                        current={'tb3_0': np.eye(3), 'tb3_1': T_now}, moving={'tb3_1'})
        assert np.array_equal(again['tb3_1'], once['tb3_1']), (name, pose_distance(again['tb3_1'], once['tb3_1']))
    # nor of anything kept between calls: robots made anew from copies of the maps give it too
    fresh = robots_of({n: dataclasses.replace(g, data=g.data.copy()) for n, g in house_pair[0].items()})
    assert np.array_equal(joint.refine_placements(fresh, anchors, 'tb3_0', lattice, 2)['tb3_1'], once['tb3_1'])


def test_never_moves_beyond_its_window(house_pair):
    """A placement the links put 1 m and 15 degrees off is moved at most SEARCH_WINDOW (at its
    walls' centre) from there, or not at all: never pulled to a far pose."""
    grids, m = house_pair
    robots = robots_of(grids)
    T_link = m.placements()['tb3_1'].T
    T_far = at_walls(robots['tb3_1'], T_link, se2(0.8, 0.6, math.radians(15.0)))
    out = joint.refine_placements(robots, {'tb3_0': np.eye(3), 'tb3_1': T_far}, 'tb3_0',
                                  lattice_for(grids['tb3_0']), 2)
    c = robots['tb3_1'].walls.mean(axis=0)[None]
    moved = apply(out['tb3_1'] @ robots['tb3_1'].W, c) - apply(T_far @ robots['tb3_1'].W, c)
    assert float(np.hypot(*moved[0])) <= joint.SEARCH_WINDOW[0] + 1e-6
    assert pose_distance(out['tb3_1'], T_far)[1] <= joint.SEARCH_WINDOW[1] + 1e-6


def test_three_maze_robots_agree_at_least_as_well_and_no_worse_than_the_truth():
    """The three real gmapping maze maps (one of them bent): jointly refined, the maps agree at
    least as well as their links' placements, and no robot ends farther from the truth (the
    robots and the full map share one frame) than 0.15 m and 1.5 degrees."""
    grids = {'tb3_%d' % n: load_map(shared_file(MAZE, 'tb3_%d_map.yaml' % n)) for n in range(3)}
    m = merged(grids, joint_placement=False)
    anchors = {n: p.T for n, p in m.placements().items()}
    assert set(anchors) == set(grids)
    robots = robots_of(grids)
    out = joint.refine_placements(robots, anchors, 'tb3_0', lattice_for(grids['tb3_0']), 2)
    assert joint.joint_agreement(robots, out, 2) >= joint.joint_agreement(robots, anchors, 2)
    for n in ('tb3_1', 'tb3_2'):
        d, a = pose_distance(out[n], np.eye(3))
        assert d < 0.15 and math.degrees(a) < 1.5, (n, d, math.degrees(a))


def grown(g):
    """``g`` with a strip of free cells 3 wide along its known box's right side (unknown there
    before): a map that really changed, and little."""
    data = g.data.copy()
    r0, r1, c0, c1 = known_bbox(g.levels())
    strip = data[r0:r1, c1:c1 + 3]
    strip[strip == -1] = 0
    assert not np.array_equal(data, g.data)
    return dataclasses.replace(g, data=data)


def test_the_merger_refines_once_and_keeps_its_placements(house_pair, monkeypatch):
    """In MapMerger: a refined placement keeps the links' pose in ``graph_T`` and its
    covariance (pin); a second cycle with nothing changed keeps the very same placements
    without refining; a map that changed is refined again (``refresh_links`` off: at once, not
    once it grew by REFINE_GROWTH), moves less than SAME_POSE and so keeps its placement; the
    map as it was gives the pose of the first refinement again, bit for bit (the same function
    of the same inputs). Off, the placements are the links' own."""
    grids, _ = house_pair
    calls = []       # per joint refinement: (the robots it refined, None: all; its poses)
    refine = joint.refine_placements

    def recorded(*args, **kwargs):
        out = refine(*args, **kwargs)
        moving = kwargs.get('moving', args[6] if len(args) > 6 else None)
        calls.append((None if moving is None else sorted(moving), out))
        return out

    monkeypatch.setattr(joint, 'refine_placements', recorded)
    m = merged(grids, reference_robot='tb3_0', refresh_links=False)
    monkeypatch.setattr(joint, 'refine_placements', refine)
    off = merged(grids, reference_robot='tb3_0', joint_placement=False, refresh_links=False)
    monkeypatch.setattr(joint, 'refine_placements', recorded)
    assert [c[0] for c in calls] == [None]                # the first cycle refined every robot
    first = calls[0][1]['tb3_1']
    p, q = m.placements()['tb3_1'], off.placements()['tb3_1']
    assert q.graph_T is None
    if p.graph_T is not None:                  # moved: from the links' pose
        assert np.allclose(p.graph_T, q.T) and np.array_equal(p.T, first)
    else:                                      # not beyond SAME_POSE: the links' pose stands
        assert np.array_equal(p.T, q.T) and within(first, q.T, joint.SAME_POSE)
    assert p.cov is not None and q.cov is not None
    before = m.placements()
    version = m.state_version
    del calls[:]
    m.estimate()
    after = m.placements()
    assert all(after[n] is before[n] for n in before) and m.state_version == version
    assert calls == []                          # nothing changed: nothing refined
    m.update_map('tb3_1', grown(grids['tb3_1']))
    m.estimate()
    assert [c[0] for c in calls] == [['tb3_1']], [c[0] for c in calls]    # refined again, alone
    assert within(calls[0][1]['tb3_1'], before['tb3_1'].T, joint.SAME_POSE)
    assert m.placements()['tb3_1'] is before['tb3_1']      # a move within SAME_POSE: kept
    del calls[:]
    m.update_map('tb3_1', grids['tb3_1'])       # the map as it was
    m.estimate()
    assert [c[0] for c in calls] == [['tb3_1']], [c[0] for c in calls]
    assert np.array_equal(calls[0][1]['tb3_1'], first)


def test_robots_without_overlap_keep_their_pose():
    """A robot whose walls land on nothing another robot knows is left where it is."""
    g = load_map(shared_file(MAZE, 'tb3_0_map.yaml'))
    robots = robots_of({'a': g, 'b': g})
    far = se2(500.0, 0.0, 0.0)
    out = joint.refine_placements(robots, {'a': np.eye(3), 'b': far}, 'a', lattice_for(g), 2)
    assert np.array_equal(out['b'], far)
    assert np.array_equal(out['a'], np.eye(3))       # the reference
    # the same map near 'a' overlaps it: refined, it moves (so 'b' stayed for want of overlap)
    near = at_walls(robots['b'], np.eye(3), se2(0.1, -0.08, math.radians(2.0)))
    moved = joint.refine_placements(robots, {'a': np.eye(3), 'b': near}, 'a', lattice_for(g), 2)
    assert pose_distance(moved['b'], near)[0] > 0.03, pose_distance(moved['b'], near)


def test_only_the_robots_that_moved_are_refined_the_others_held(house_pair):
    """``moving``: tb3_1 displaced but not among the robots refined stays where ``current``
    holds it; among them, it comes back as when every robot is refined."""
    robots, T_link, T_off, lattice = displaced(house_pair)
    anchors = {'tb3_0': np.eye(3), 'tb3_1': T_off}
    held = joint.refine_placements(robots, anchors, 'tb3_0', lattice, 2, current={'tb3_1': T_link}, moving=set())
    assert np.array_equal(held['tb3_1'], T_link)
    refined = joint.refine_placements(robots, anchors, 'tb3_0', lattice, 2, current={'tb3_1': T_link},
                                      moving={'tb3_1'})
    everyone = joint.refine_placements(robots, anchors, 'tb3_0', lattice, 2)
    assert np.array_equal(refined['tb3_1'], everyone['tb3_1'])


def test_a_robot_is_refined_against_the_maps_it_can_meet_most():
    """neighbours: the robots whose placed known boxes meet its own (grown by NEAR), at most
    ``most``, those it meets most; a map far away is none of them."""
    g = load_map(shared_file(MAZE, 'tb3_0_map.yaml'))
    names = ['a', 'b', 'c', 'd']
    robots = robots_of({n: g for n in names})
    r0, r1, c0, c1 = robots['a'].box
    width = (c1 - c0) * g.resolution
    poses = {'a': np.eye(3), 'b': se2(0.2 * width, 0, 0), 'c': se2(0.6 * width, 0, 0), 'd': se2(500.0, 0, 0)}
    assert joint.neighbours(robots, poses, 'a') == ['b', 'c']
    assert joint.neighbours(robots, poses, 'a', most=1) == ['b']
    assert joint.neighbours(robots, poses, 'd') == []


def test_worker_processes_give_the_poses_refined_here(monkeypatch):
    """With a runner (:class:`runtime.pool.PoolRunner`, two worker processes) a round's refinements
    (AHEAD_FROM or more) run ahead in the workers, and a robot whose neighbour moved earlier in the round is refined
    again here: the poses are those of the refinement in this process, bit for bit. Six
    windows of the Intel lab, their anchors off the truth by a few centimetres and a degree so
    that robots move (the workers' results used and discarded both)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from multi_map_merge.lab.pieces import pieces_windows
    from multi_map_merge.runtime.pool import PoolRunner
    world = load_map(shared_file(INTEL_MAP))
    team = pieces_windows(world, 6, seed=3)
    grids = {'r%d' % k: g for k, (g, _) in enumerate(team)}
    truth = {'r%d' % k: inverse(team[0][1]) @ T for k, (_, T) in enumerate(team)}
    rng = np.random.default_rng(5)
    anchors = {n: T if n == 'r0' else at_walls(joint.Robot.of(grids[n], grids[n].levels(), grids[n].known_values()),
                                              T, se2(*rng.uniform(-0.06, 0.06, 2), math.radians(rng.uniform(-1, 1))))
               for n, T in truth.items()}
    robots = robots_of(grids)
    lattice = lattice_for(grids['r0'])
    here = []
    refine_one = joint._refine_one
    monkeypatch.setattr(joint, '_refine_one', lambda *a: here.append(a[1]) or refine_one(*a))
    monkeypatch.setattr(joint, 'AHEAD_FROM', 2)      # (a team of six: in the workers all the same)
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context('spawn')) as pool:
        for moving in (None, sorted(truth)[1:]):
            inline = joint.refine_placements(robots, anchors, 'r0', lattice, 2, dict(anchors), moving)
            del here[:]
            pooled = joint.refine_placements(robots, anchors, 'r0', lattice, 2, dict(anchors), moving,
                                             PoolRunner(pool))
            assert all(np.array_equal(inline[n], pooled[n]) for n in anchors), moving
            assert sum(not np.array_equal(inline[n], anchors[n]) for n in anchors) >= 2
            # some refined in the workers, some again here (a neighbour moved before them)
            assert 0 < len(here) < 5 * (3 if moving is None else 1), here


def test_the_walls_near_a_robots_start_weigh_most():
    """joint.near_start_first: nearly every wall within 0.3 m of the map frame's origin stays, a share 1 / (1 + (d /
    START_SCALE)^2) of those d metres away (a fifth at 4 m, a 26th at 10 m with the 2 m scale);
    the shares are relative to the nearest wall (a map whose walls all lie 10 m off keeps them
    all), the same walls give the same points, and too few left gives the walls as they are."""
    res = 0.05
    W = np.array([[res, 0.0, -20.0], [0.0, res, -20.0], [0.0, 0.0, 1.0]])   # cell (400, 400) at the origin
    ring = lambda d, n: np.column_stack([np.full(n, 400.0 + d / res), 400.0 + np.arange(n) % 7])  # noqa: E731
    walls = np.vstack([ring(0.0, 1000), ring(4.0, 5000), ring(10.0, 26000)])
    kept = joint.near_start_first(walls, W, least=10)
    at = np.rint((kept[:, 0] - 400.0) * res)
    assert (at == 0).sum() >= 970
    assert abs((at == 4).sum() - 1000) < 30 and abs((at == 10).sum() - 1000) < 30, np.unique(at, return_counts=True)
    assert np.array_equal(kept, joint.near_start_first(walls, W, least=10))
    far = ring(10.0, 3000)
    assert np.array_equal(joint.near_start_first(far, W, least=10), far)
    few = np.vstack([ring(0.0, 5), ring(10.0, 200)])
    assert np.array_equal(joint.near_start_first(few, W, least=100), few)
