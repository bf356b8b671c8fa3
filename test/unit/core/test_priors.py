"""Priors and their frames (core/priors.py) and the merger's priors given while running
(MapMerger.set_prior, set_prior_in_merged_frame, clear_prior, add_init_pose): plain numbers, no
ROS; the configuration stays as loaded. Also what the merger says of its results that the node
only logs or shows: why a placement is weak (Placement.weak_reason) and which robot is the
reference and why (ReferenceChoice.message)."""
import math

import numpy as np
import pytest

from multi_map_merge.core.config import MergeConfig
from multi_map_merge.core.links import Link
from multi_map_merge.core.merger import MapMerger
from multi_map_merge.core.placement import PRIOR, Placement, add_priors, pin
from multi_map_merge.core.priors import (
    PriorOfReference,
    PriorRefused,
    in_priors_frame,
    pose_of,
    quaternion_yaw,
    relative_pose,
)
from multi_map_merge.core.team import REF_PROPOSED
from multi_map_merge.core.transforms import pose_distance, se2, xyyaw


def same_pose(A, B, tol=1e-9):
    d, a = pose_distance(A, B)
    return d < tol and a < tol


def test_a_pose_from_position_and_quaternion():
    yaw = 0.7
    T = pose_of(1.5, -2.0, 0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    assert same_pose(T, se2(1.5, -2.0, yaw))
    assert abs(quaternion_yaw(0.0, 0.0, math.sin(-1.0), math.cos(-1.0)) + 2.0) < 1e-12


@pytest.mark.parametrize('numbers, why', [
    ((float('nan'), 0.0, 0.0, 0.0, 0.0, 1.0), 'not finite'),
    ((0.0, 0.0, 0.0, 0.0, float('inf'), 1.0), 'not finite'),
    ((0.0, 0.0, 0.0, 0.0, 0.0, 0.0), 'zero quaternion'),
])
def test_a_pose_that_is_not_one_is_refused(numbers, why):
    with pytest.raises(PriorRefused, match=why):
        pose_of(*numbers)


def test_the_pose_two_priors_give_between_map_frames():
    priors = {'a': [1.0, 2.0, 0.5], 'b': [-3.0, 0.0, -1.0]}
    P = relative_pose(priors, 'a', 'b')
    # b's map frame seen from a's: the priors' frame carried into a's
    assert same_pose(se2(*priors['a']) @ P, se2(*priors['b']))
    assert relative_pose(priors, 'a', 'c') is None and relative_pose(priors, 'c', 'b') is None


def test_a_prior_in_the_merged_frame_is_carried_into_the_priors_frame():
    """The merged frame is the reference's map frame, which sits at the reference's prior."""
    T = se2(2.0, 1.0, 0.3)                      # b's map frame in the merged frame (a's)
    priors = {'a': [5.0, -1.0, 1.2], 'c': [0.0, 0.0, 0.0]}
    pose, ref_too = in_priors_frame('b', T, 'a', priors)
    assert not ref_too
    assert same_pose(se2(*pose), se2(*priors['a']) @ T)
    # then the pose between a and b the priors give is T itself
    assert same_pose(relative_pose(dict(priors, b=pose), 'a', 'b'), T)


def test_with_no_other_prior_the_merged_frame_becomes_the_priors_frame():
    T = se2(2.0, 1.0, 0.3)
    pose, ref_too = in_priors_frame('b', T, 'a', {})
    assert ref_too and same_pose(se2(*pose), T)
    # b's own earlier prior is replaced, not related
    pose, ref_too = in_priors_frame('b', T, 'a', {'b': [9.0, 9.0, 0.0]})
    assert ref_too and same_pose(se2(*pose), T)


def test_a_prior_that_cannot_be_related_is_refused():
    with pytest.raises(PriorOfReference, match='a is the reference'):
        in_priors_frame('a', np.eye(3), 'a', {})
    with pytest.raises(PriorRefused, match=r'the other priors \(c\) .* give a a prior'):
        in_priors_frame('b', np.eye(3), 'a', {'c': [1.0, 0.0, 0.0]})


# -- the merger's priors: state, not configuration

def test_set_and_clear_prior_leave_the_config_as_loaded():
    cfg = MergeConfig(reference_robot='a', initial_poses={'a': [0.0, 0.0, 0.0]}, workers=1)
    loaded = cfg.to_dict()
    m = MapMerger(cfg)
    assert m.priors() == {'a': [0.0, 0.0, 0.0]}
    assert m.set_prior('b', [1, 2, 0.5]) == []
    assert m.priors() == {'a': [0.0, 0.0, 0.0], 'b': [1.0, 2.0, 0.5]}
    assert cfg.initial_poses == {'a': [0.0, 0.0, 0.0]} and cfg.to_dict() == loaded
    assert m.clear_prior('b') is True and m.clear_prior('b') is False
    assert m.priors() == {'a': [0.0, 0.0, 0.0]}
    assert m.clear_prior('a') is True and m.priors() == {}
    assert cfg.to_dict() == loaded and m.config is cfg


def test_a_prior_given_in_the_merged_frame_and_cleared():
    """rviz's 2D Pose Estimate with no configured priors: the reference gets [0, 0, 0] while
    another robot has a prior, and loses it with the last one."""
    cfg = MergeConfig(reference_robot='a', workers=1)
    m = MapMerger(cfg)
    T = se2(2.0, 1.0, 0.3)
    assert m.set_prior_in_merged_frame('b', T) == []
    assert set(m.priors()) == {'a', 'b'} and m.priors()['a'] == [0.0, 0.0, 0.0]
    assert same_pose(se2(*m.priors()['b']), T)
    m.set_prior_in_merged_frame('c', se2(-1.0, 0.0, 0.0))
    with pytest.raises(PriorOfReference):
        m.set_prior_in_merged_frame('a', T)
    assert m.clear_prior('b') and set(m.priors()) == {'a', 'c'}
    assert m.clear_prior('c') and m.priors() == {}
    assert cfg.initial_poses == {}


def test_a_prior_in_the_merged_frame_goes_through_the_references_configured_prior():
    m = MapMerger(MergeConfig(reference_robot='a', initial_poses={'a': [5.0, -1.0, 1.2]}, workers=1))
    T = se2(2.0, 1.0, 0.3)
    m.set_prior_in_merged_frame('b', T)
    assert same_pose(relative_pose(m.priors(), 'a', 'b'), T)
    assert m.clear_prior('b') and m.priors() == {'a': [5.0, -1.0, 1.2]}   # the configured one stays
    # configured priors without the reference's: a pose in the merged frame means nothing to them
    m = MapMerger(MergeConfig(reference_robot='a', initial_poses={'c': [1.0, 0.0, 0.0]}, workers=1))
    with pytest.raises(PriorRefused):
        m.set_prior_in_merged_frame('b', T)
    assert m.priors() == {'c': [1.0, 0.0, 0.0]}


def test_init_poses_are_read_only_under_known_init_poses_and_without_a_prior():
    assert not MapMerger(MergeConfig(workers=1)).wants_init_pose('b')
    cfg = MergeConfig(known_init_poses=True, initial_poses={'a': [0.0, 0.0, 0.0]}, workers=1)
    m = MapMerger(cfg)
    assert m.wants_init_pose('b') and not m.wants_init_pose('a')
    assert m.add_init_pose('b', [1, 2, 3]) is False
    assert m.priors()['b'] == [1.0, 2.0, 3.0] and not m.wants_init_pose('b')
    assert cfg.initial_poses == {'a': [0.0, 0.0, 0.0]}
    with pytest.raises(PriorRefused, match='not finite'):
        m.add_init_pose('c', [0.0, float('nan'), 0.0])
    assert 'c' not in m.priors()
    assert m.check_spawn_poses() is None     # no map yet: nothing to check


def test_trusted_priors_place_by_the_priors_given():
    best = {'a': Placement(np.eye(3), 1.0, 1.0, 0, '', ('a',), 0.0)}
    add_priors(MergeConfig(trust_initial_poses=True), best, ['a', 'b', 'c'], 'a',
               {'a': [1.0, 0.0, 0.0], 'b': [1.0, 2.0, 0.0]})
    assert set(best) == {'a', 'b'} and same_pose(best['b'].T, se2(0.0, 2.0, 0.0))
    assert best['b'].via == PRIOR and best['b'].weak and best['b'].weak_reason
    best = {}
    add_priors(MergeConfig(trust_initial_poses=False), best, ['b'], 'a', {'a': [0, 0, 0], 'b': [1, 2, 0]})
    assert best == {}


# -- why a placement is weak: set where weak is

def test_every_weak_placement_says_why_and_only_those():
    cfg = MergeConfig(max_position_sigma=0.1)
    e_ab = Link('a', 'b', se2(2.0, 1.0, 0.3), 0.5, 0.98, 40, 80, 0.0, cov=np.diag([0.08 ** 2, 0.01 ** 2, 1e-6]))
    e_ac = Link('a', 'c', se2(-1.0, 3.0, -1.0), 0.5, 0.98, 40, 80, 0.0, cov=np.diag([0.01 ** 2, 0.005 ** 2, 1e-6]))
    e_ae = Link('a', 'e', se2(0.0, 3.0, 0.0), 0.5, 0.98, 40, 80, 0.0)           # no covariance
    pls = {'a': Placement(np.eye(3), 1.0, 1.0, 0, '', ('a',), 0.0),
           'b': Placement(e_ab.T, 0.5, 0.98, 40, 'a', ('a', 'b'), 0.0),
           'c': Placement(e_ac.T, 0.5, 0.98, 40, 'a', ('a', 'c'), 0.0),
           'd': Placement(se2(1.0, 2.0, 0.0), 0.0, 0.0, 0, PRIOR, ('a', 'd'), 0.0),
           'e': Placement(e_ae.T, 0.5, 0.98, 40, 'a', ('a', 'e'), 0.0)}
    pin(cfg, pls, {('a', 'b'): e_ab, ('a', 'c'): e_ac, ('a', 'e'): e_ae}, 'a', False)
    assert {n: p.weak for n, p in pls.items()} == {'a': False, 'b': True, 'c': False, 'd': True, 'e': True}
    assert all(bool(p.weak_reason) == p.weak for p in pls.values())
    assert pls['b'].weak_reason.startswith('2-sigma 0.160 m > max_position_sigma 0.100 m')
    assert pls['d'].weak_reason == 'placed at its prior, no link pins it'
    assert pls['e'].weak_reason == 'its covariance is unknown (a link on its chain has none)'
    # pinned better later: no longer weak, no reason left
    pin(MergeConfig(max_position_sigma=0.5), pls, {('a', 'b'): e_ab, ('a', 'c'): e_ac}, 'a', False)
    assert not pls['b'].weak and pls['b'].weak_reason == ''


# -- the reference rule and what is said of it

def test_the_first_listed_robot_by_name_is_the_reference():
    m = MapMerger(MergeConfig(robots=['/tb3_2', 'tb3_1'], workers=1))
    choice = m.reference_choice()
    assert (choice.robot, choice.fixed, choice.why) == ('tb3_1', True, REF_PROPOSED)
    assert choice.message().startswith('reference robot tb3_1 (the first of ~robots by name; set '
                                       '~reference_robot to choose another)')
    m = MapMerger(MergeConfig(robots=['tb3_2', 'tb3_1'], reference_robot='tb3_2', workers=1))
    assert m.reference == 'tb3_2'
    assert m.reference_choice().message() == ('reference robot tb3_2 (set by ~reference_robot): the merged '
                                              'frame is its map frame')


def test_the_reference_message_says_whether_it_may_still_change():
    m = MapMerger(MergeConfig(workers=1))
    assert m.reference_choice().message() == ''
    for n in ('b', 'c'):
        m.update_map(n, _small_grid())
    line = m.reference_choice().message()
    assert line.startswith('reference robot b for now (the first by name among the robots with a map: b, c)')
    assert 'set ~reference_robot to fix it' in line


def test_the_reference_line_says_which_robot_why_and_how_to_choose_it():
    """ReferenceChoice.message: the line the node logs of the reference robot: which, why, and
    how to choose it."""
    from multi_map_merge.core.team import REF_FIRST_BY_NAME, REF_PARAMETER, ReferenceChoice
    assert ReferenceChoice('', False, REF_FIRST_BY_NAME).message() == ''
    assert ReferenceChoice('tb3_2', True, REF_PARAMETER).message() == \
        'reference robot tb3_2 (set by ~reference_robot): the merged frame is its map frame'
    line = ReferenceChoice('tb3_0', True, REF_PROPOSED).message()
    assert line.startswith('reference robot tb3_0 (the first of ~robots by name; set ~reference_robot')
    line = ReferenceChoice('tb3_1', False, REF_FIRST_BY_NAME, ('tb3_1', 'tb3_2')).message()
    assert line.startswith('reference robot tb3_1 for now (the first by name among the robots with a map: '
                           'tb3_1, tb3_2)') and 'set ~reference_robot to fix it' in line
    line = ReferenceChoice('tb3_1', True, REF_FIRST_BY_NAME, ('tb3_0', 'tb3_1', 'tb3_2')).message()
    assert line.startswith('reference robot tb3_1, fixed now that another robot is merged with it')
    assert line.endswith('set ~reference_robot: tb3_1 for the same merged frame in every run')


def _small_grid():
    from multi_map_merge.core.grid import Grid
    data = np.full((20, 30), -1, dtype=np.int8)
    data[5:15, 5:25] = 0
    return Grid(data, 0.05, (0.0, 0.0, 0.0), 'x/map')


def test_xyyaw_round_trip_of_a_carried_prior():
    """(the priors' numbers are plain lists of floats: what the state and the logs show)"""
    pose, _ = in_priors_frame('b', se2(1.0, 2.0, 3.0), 'a', {'a': [0.0, 0.0, 0.0]})
    assert isinstance(pose, list) and all(isinstance(v, float) for v in pose)
    assert np.allclose(pose, xyyaw(se2(1.0, 2.0, 3.0)))
