"""The node's /diagnostics as pure functions of the merger's status (ros/diagnostics.py; needs
the message classes, no master): each robot's status and the node's own."""
import math

import numpy as np
import pytest

pytest.importorskip('diagnostic_msgs')   # the ROS shell: not on a stack without ROS (make test-focal)

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402

from multi_map_merge.core.placement import Placement  # noqa: E402
from multi_map_merge.core.status import RobotStatus  # noqa: E402
from multi_map_merge.core.transforms import se2  # noqa: E402
from multi_map_merge.ros.diagnostics import (  # noqa: E402
    diagnostics_by_robot,
    error_text,
    node_diagnostic,
    robot_diagnostic,
)

NOW = 1000.0


def placed(via, path):
    return Placement(se2(1.0, -2.0, 0.5), 0.4, 0.97, 33, via, path, NOW - 12.0)


def ref():
    return RobotStatus(True, True, Placement(np.eye(3), 1.0, 1.0, 0, '', ('tb3_0',), NOW - 30.0))


def merged():
    return RobotStatus(True, False, placed('tb3_0', ('tb3_0', 'tb3_1')), linked_to=('tb3_0',))


def unmerged():
    return RobotStatus(False, False, None)


def values(s):
    return {kv.key: kv.value for kv in s.values}


def test_robot_statuses_say_merged_or_why_not():
    s = robot_diagnostic('tb3_0', ref(), False, NOW)
    assert (s.level, s.message, s.hardware_id) == (DiagnosticStatus.OK, 'reference map', 'tb3_0')
    s = robot_diagnostic('tb3_1', merged(), False, NOW)
    kv = values(s)
    assert (s.level, s.message) == (DiagnosticStatus.OK, 'merged via tb3_0')
    assert kv['merged'] == 'true' and kv['chain'] == 'tb3_0 -> tb3_1' and kv['publisher'] == 'ok'
    assert (kv['x'], kv['y'], kv['yaw'], kv['age_s']) == ('1.000', '-2.000', '0.5000', '12.0')
    s = robot_diagnostic('tb3_2', unmerged(), False, NOW)
    assert (s.level, s.message, values(s)['merged']) == (DiagnosticStatus.WARN, 'not merged', 'false')
    s = robot_diagnostic('tb3_3', RobotStatus(False, False, None, error='data length 7 != 12'), False, NOW)
    assert (s.level, s.message) == (DiagnosticStatus.ERROR, 'input ignored: data length 7 != 12')


def test_a_vanished_robot_warns_and_keeps_its_placement():
    s = robot_diagnostic('tb3_1', merged(), True, NOW)
    kv = values(s)
    assert s.level == DiagnosticStatus.WARN and 'vanished' in s.message
    assert kv['publisher'] == 'gone' and kv['merged'] == 'true'


def test_node_is_ok_when_every_robot_is_merged():
    st = {'tb3_0': ref(), 'tb3_1': merged()}
    s = node_diagnostic(st, {'tb3_0': False, 'tb3_1': False}, 0.42, None, 2, 2)
    kv = values(s)
    assert s.level == DiagnosticStatus.OK and s.message == '2 robots merged; estimation cycle 0.42 s'
    assert (kv['last_estimation_s'], kv['robots'], kv['merged'], kv['last_error']) == ('0.420', '2', '2', '-')


def test_node_warns_naming_robots_vanished_or_not_merged():
    st = {'tb3_0': ref(), 'tb3_1': merged(), 'tb3_2': unmerged()}
    s = node_diagnostic(st, {'tb3_1': True, 'tb3_2': False}, 0.1, None, 3, 2)
    assert s.level == DiagnosticStatus.WARN
    assert s.message == 'not merged: tb3_2; vanished: tb3_1'
    assert (values(s)['not_merged'], values(s)['vanished']) == ('tb3_2', 'tb3_1')
    s = node_diagnostic({}, {}, 0.0, None, 0, 0)
    assert (s.level, s.message) == (DiagnosticStatus.WARN, 'no robot map yet')


def test_node_is_error_with_the_exception_of_the_last_cycle():
    try:
        np.zeros(3) @ np.zeros(4)      # a real exception, raised by real code
    except ValueError as e:
        err = e
    st = {'tb3_0': ref(), 'tb3_1': unmerged()}
    s = node_diagnostic(st, {}, 0.2, err, 2, 1)
    assert s.level == DiagnosticStatus.ERROR            # over the WARN of tb3_1
    assert s.message == 'estimation failed: ValueError: %s' % err and str(err)
    assert values(s)['last_error'] == 'ValueError: %s' % err
    assert error_text(KeyboardInterrupt()) == 'KeyboardInterrupt'


def test_fills_diagnostic_updaters_status_and_reads_back_by_robot():
    du = pytest.importorskip('diagnostic_updater')
    w = du.DiagnosticStatusWrapper()
    w.hardware_id = 'map_merge'
    assert node_diagnostic({'tb3_0': ref()}, {}, 0.1, None, 1, 1, w) is w
    assert w.level == DiagnosticStatus.OK and w.hardware_id == 'map_merge'   # the node's, kept
    arr = DiagnosticArray(status=[w, robot_diagnostic('tb3_1', merged(), False, NOW, du.DiagnosticStatusWrapper())])
    out = {}
    diagnostics_by_robot(arr, out)
    assert out['tb3_1']['message'] == 'merged via tb3_0' and out['tb3_1']['via'] == 'tb3_0'
    assert out['map_merge']['robots'] == '1'


def test_a_placement_on_diagnostics_reads_as_placement_dict(halves_merged):
    """A placement there reads as core.state.placement_dict says, as in the state file and
    the transforms report."""
    from multi_map_merge.core.state import placement_dict
    m = halves_merged
    pl = m.placements()['b']
    d = placement_dict(pl)
    st = m.status()
    arr = DiagnosticArray(status=[robot_diagnostic(r, st[r], False, pl.stamp + 2.0) for r in st])
    diag = {}
    diagnostics_by_robot(arr, diag)
    b = diag['b']
    assert b['via'] == 'a' and b['chain'] == 'a -> b' and b['age_s'] == '2.0' and b['message'] == 'merged via a'
    assert int(b['inliers']) == d['inliers']
    for k in ('x', 'y', 'yaw', 'inlier_ratio', 'agreement'):
        assert abs(float(b[k]) - d[k]) <= 1e-3, k
    assert diag['a']['message'] == 'reference map' and diag['a']['via'] == '-'
    assert diag['c']['message'].startswith('not merged') and 'via' not in diag['c']


def pinned_team():
    """Placements of a (reference), b and c pinned by the core (placement.pin) from links a-b,
    a-c with covariances: b's link slides 8 cm (1 sigma) along x, c's is pinned to 1 cm."""
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.links import Link
    from multi_map_merge.core.placement import pin
    cfg = MergeConfig(max_position_sigma=0.1)
    e_ab = Link('a', 'b', se2(2.0, 1.0, 0.3), 0.5, 0.98, 40, 80, NOW, cov=np.diag([0.08 ** 2, 0.01 ** 2, 1e-6]))
    e_ac = Link('a', 'c', se2(-1.0, 3.0, -1.0), 0.5, 0.98, 40, 80, NOW, cov=np.diag([0.01 ** 2, 0.005 ** 2, 1e-6]))
    pls = {'a': Placement(np.eye(3), 1.0, 1.0, 0, '', ('a',), NOW - 5.0),
           'b': Placement(e_ab.T, 0.5, 0.98, 40, 'a', ('a', 'b'), NOW - 5.0),
           'c': Placement(e_ac.T, 0.5, 0.98, 40, 'a', ('a', 'c'), NOW - 5.0)}
    pin(cfg, pls, {('a', 'b'): e_ab, ('a', 'c'): e_ac}, 'a', False)
    return {'a': RobotStatus(True, True, pls['a']),
            'b': RobotStatus(True, False, pls['b'], linked_to=('a',)),
            'c': RobotStatus(True, False, pls['c'], linked_to=('a',))}


def test_a_weakly_pinned_robot_warns_with_its_2_sigma():
    """sigma_position and weak on every placed robot's status, as the core computed them; a
    robot whose 2-sigma position exceeds max_position_sigma is merged but WARN, saying by how
    much; one well pinned stays OK; the reference is exact."""
    from multi_map_merge.core.covariance import position_sigma
    st = pinned_team()
    b, c = st['b'].placement, st['c'].placement
    assert b.weak and not c.weak and b.cov is not None and c.cov is not None
    sb, sc = position_sigma(b.cov), position_sigma(c.cov)
    assert abs(sb - 0.08) < 1e-3 and abs(sc - 0.01) < 1e-3     # a single link: its own covariance
    s = robot_diagnostic('b', st['b'], False, NOW)
    kv = values(s)
    assert s.level == DiagnosticStatus.WARN
    assert s.message == 'merged via a, weakly pinned: 2-sigma %.3f m > max_position_sigma 0.100 m' % (2 * sb)
    assert (kv['merged'], kv['weak'], kv['sigma_position']) == ('true', 'true', '%.4f' % sb)
    s = robot_diagnostic('c', st['c'], False, NOW)
    assert (s.level, s.message) == (DiagnosticStatus.OK, 'merged via a')
    assert (values(s)['weak'], values(s)['sigma_position']) == ('false', '%.4f' % sc)
    s = robot_diagnostic('a', st['a'], False, NOW)
    assert (s.level, values(s)['weak'], values(s)['sigma_position']) == (DiagnosticStatus.OK, 'false', '0.0000')


def test_a_robot_at_its_prior_or_of_unknown_covariance_is_weak():
    """Why a placement is weak is the core's (placement.pin sets it); diagnostics says it."""
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.placement import PRIOR, pin
    at_prior = Placement(se2(1.0, 2.0, 0.0), 0.0, 0.0, 0, PRIOR, ('a', 'd'), NOW)
    unknown = Placement(se2(1.0, 2.0, 0.0), 0.5, 0.9, 30, 'a', ('a', 'e'), NOW)
    pin(MergeConfig(), {'d': at_prior, 'e': unknown}, {}, 'a', False)
    s = robot_diagnostic('d', RobotStatus(True, False, at_prior), False, NOW)
    assert s.level == DiagnosticStatus.WARN
    assert s.message == 'merged via initial_pose, weakly pinned: placed at its prior, no link pins it'
    assert (values(s)['weak'], values(s)['sigma_position']) == ('true', '-')
    s = robot_diagnostic('e', RobotStatus(True, False, unknown), False, NOW)
    assert s.level == DiagnosticStatus.WARN
    assert s.message.endswith('its covariance is unknown (a link on its chain has none)')


def test_node_warns_naming_the_weakly_pinned_robots():
    st = pinned_team()
    s = node_diagnostic(st, {}, 0.3, None, 3, 3)
    assert (s.level, s.message) == (DiagnosticStatus.WARN, 'weakly pinned: b')
    assert (values(s)['weakly_pinned'], values(s)['not_merged']) == ('b', '-')
    st['b'].placement.weak_reason = ''
    s = node_diagnostic(st, {}, 0.3, None, 3, 3)
    assert s.level == DiagnosticStatus.OK and values(s)['weakly_pinned'] == '-'


def test_sigma_on_diagnostics_is_the_grids_covariance(halves_merged):
    """On a real merge (the covariance from the grids): sigma_position and weak read as
    core.state.placement_dict says."""
    from multi_map_merge.core.state import placement_dict
    m = halves_merged
    pl = m.placements()['b']
    d = placement_dict(pl)
    assert 'sigma_position' in d
    kv = values(robot_diagnostic('b', m.status()['b'], False, NOW))
    assert abs(float(kv['sigma_position']) - d['sigma_position']) <= 5e-5
    assert kv['weak'] == str(d['weak']).lower()


def with_map_at(st, received):
    st.map_received = received
    return st


def test_a_robot_whose_maps_stopped_is_warn_naming_the_age_and_stays_merged():
    """The publisher is still there (not vanished) but no map came for longer than
    stale_map_timeout: WARN 'no map for 42 s', map_age_s the map's age (age_s stays the
    placement's), still merged."""
    st = with_map_at(merged(), NOW - 42.0)
    s = robot_diagnostic('tb3_1', st, False, NOW, stale_map_timeout=30.0)
    kv = values(s)
    assert s.level == DiagnosticStatus.WARN
    assert s.message == 'merged via tb3_0; no map for 42 s (over ~stale_map_timeout, 30 s; its last map is kept)'
    assert (kv['map_age_s'], kv['age_s'], kv['merged'], kv['publisher']) == ('42.0', '12.0', 'true', 'ok')
    # a fresh map: OK again, its age shown
    s = robot_diagnostic('tb3_1', with_map_at(merged(), NOW - 2.5), False, NOW, stale_map_timeout=30.0)
    assert (s.level, s.message, values(s)['map_age_s']) == (DiagnosticStatus.OK, 'merged via tb3_0', '2.5')
    # 0 = off; the reference too
    assert robot_diagnostic('tb3_1', with_map_at(merged(), NOW - 420.0), False, NOW).level == DiagnosticStatus.OK
    s = robot_diagnostic('tb3_0', with_map_at(ref(), NOW - 31.0), False, NOW, stale_map_timeout=30.0)
    assert s.level == DiagnosticStatus.WARN and s.message.startswith('reference map; no map for 31 s')
    # a robot whose publisher went away is said to have vanished, not stale as well
    s = robot_diagnostic('tb3_1', with_map_at(merged(), NOW - 42.0), True, NOW, stale_map_timeout=30.0)
    assert 'vanished' in s.message and 'no map for' not in s.message


def test_node_warns_naming_robots_whose_maps_stopped_and_clears_when_they_come_again():
    st = {'tb3_0': with_map_at(ref(), NOW - 1.0), 'tb3_1': with_map_at(merged(), NOW - 42.0)}
    gone = {'tb3_0': False, 'tb3_1': False}
    s = node_diagnostic(st, gone, 0.1, None, 2, 2, now=NOW, stale_map_timeout=30.0)
    assert (s.level, s.message) == (DiagnosticStatus.WARN, 'stale: tb3_1 (no map for 42 s)')
    assert values(s)['stale'] == 'tb3_1' and values(s)['merged'] == '2'
    st['tb3_1'] = with_map_at(merged(), NOW - 0.5)
    s = node_diagnostic(st, gone, 0.1, None, 2, 2, now=NOW, stale_map_timeout=30.0)
    assert s.level == DiagnosticStatus.OK and values(s)['stale'] == '-'
    # the vanished are not stale too; no clock given (or 0): no stale check
    st['tb3_1'] = with_map_at(merged(), NOW - 42.0)
    s = node_diagnostic(st, {'tb3_1': True}, 0.1, None, 2, 2, now=NOW, stale_map_timeout=30.0)
    assert s.message == 'vanished: tb3_1' and values(s)['stale'] == '-'
    assert node_diagnostic(st, gone, 0.1, None, 2, 2).level == DiagnosticStatus.OK
    assert node_diagnostic(st, gone, 0.1, None, 2, 2, now=NOW, stale_map_timeout=0.0).level == DiagnosticStatus.OK


def test_the_status_carries_when_the_last_map_arrived():
    """MapMerger.status(): map_received is the arrival of the robot's last map, republished
    unchanged included (a robot standing still under gmapping sends the same grid)."""
    import time

    from multi_map_merge.core.grid import Grid
    from multi_map_merge.core.merger import MapMerger
    m = MapMerger()
    g = Grid(np.zeros((40, 40), np.int8), 0.05, (0.0, 0.0, 0.0), 'a/map')
    t0 = time.time()
    m.update_map('a', g)
    first = m.status()['a'].map_received
    assert t0 <= first <= time.time()
    time.sleep(0.02)
    m.update_map('a', Grid(g.data.copy(), 0.05, (0.0, 0.0, 0.0), 'a/map'))
    assert m.status()['a'].map_received > first


def test_node_warns_naming_listed_robots_that_never_sent_a_map():
    """A robot of ~robots whose map never came (its SLAM not running, a wrong namespace) is
    named on the node's status once the node has waited ~stale_map_timeout; one whose map came
    is not."""
    st = {'tb3_0': with_map_at(ref(), NOW - 1.0), 'tb3_1': with_map_at(merged(), NOW - 1.0)}
    gone = {'tb3_0': False, 'tb3_1': False}
    s = node_diagnostic(st, gone, 0.1, None, 2, 2, now=NOW, stale_map_timeout=30.0,
                        no_map_yet={'tb3_1': 45.0, 'tb3_2': 45.0})
    assert (s.level, s.message) == (DiagnosticStatus.WARN, 'no map yet: tb3_2 (waited 45 s)')
    assert values(s)['no_map_yet'] == 'tb3_2'
    s = node_diagnostic(st, gone, 0.1, None, 2, 2, now=NOW, stale_map_timeout=30.0, no_map_yet={})
    assert s.level == DiagnosticStatus.OK and values(s)['no_map_yet'] == '-'


def test_a_bent_overlap_is_named_in_the_robots_message():
    st = merged()
    st.bends = (('tb3_0', 0.43),)
    s = robot_diagnostic('tb3_2', st, False, NOW)
    assert s.message == "merged via tb3_0; tb3_2's map bends 0.43 m across its overlap with tb3_0"
    assert s.level == DiagnosticStatus.OK          # the bend is in the covariance, which sets weak
    assert values(s)['bends'] == 'tb3_0:0.43'
    assert 'bends' not in values(robot_diagnostic('tb3_1', merged(), False, NOW))


def test_a_map_that_turned_on_the_way_to_an_overlap_is_named_in_the_robots_message():
    st = merged()
    st.turns = (('tb3_1', math.radians(22.0)),)
    s = robot_diagnostic('tb3_0', st, False, NOW)
    assert s.message == ("merged via tb3_0; tb3_0's map and tb3_1's turn 22 deg apart between their starts and "
                         "their overlap (a map turned, or the building does)")
    assert s.level == DiagnosticStatus.OK          # the turn is in the covariance, which sets weak
    assert values(s)['turns (deg)'] == 'tb3_1:22.0'
    assert 'turns (deg)' not in values(robot_diagnostic('tb3_1', merged(), False, NOW))


def test_a_map_bent_in_the_merged_map_says_how_far():
    """~bend_maps: the largest move of a map's walls in the merged map is a key; from
    REPORT_BENT on it is named in the message (a note: TF, the placement, is not bent)."""
    st = merged()
    st.bent = 0.37
    s = robot_diagnostic('tb3_2', st, False, NOW)
    assert s.message == "merged via tb3_0; tb3_2's map bent up to 0.37 m in the merged map to meet the others"
    assert s.level == DiagnosticStatus.OK
    assert values(s)['bent in the merged map (m)'] == '0.37'
    st.bent = 0.05
    s = robot_diagnostic('tb3_2', st, False, NOW)
    assert s.message == 'merged via tb3_0' and values(s)['bent in the merged map (m)'] == '0.05'
    assert 'bent in the merged map (m)' not in values(robot_diagnostic('tb3_1', merged(), False, NOW))


def test_a_first_placement_says_it_is_provisional_until_refined(intel):
    """The node's first cycle (``defer_refinement``) places robots before their links'
    covariances and their joint refinement: OK, not weakly pinned, and said provisional; after
    the spare time's refresh it is no longer (and weakly pinned or not by its covariance)."""
    from multi_map_merge.core.grid import known_bbox
    from multi_map_merge.core.merger import MapMerger
    from multi_map_merge.lab.pieces import cut_piece
    r0, r1, c0, c1 = known_bbox(intel.levels())
    w = c1 - c0
    m = MapMerger()
    for n, (a, b), pose in zip('ab', [(0.0, 0.6), (0.4, 1.0)], [(0, 0, 0), (3, -2, 2.0)]):
        m.update_map(n, cut_piece(intel, (r0, r1, c0 + int(a * w), c0 + int(b * w)), pose)[0])
    m.estimate(defer_refinement=True)
    st = m.status()
    s = robot_diagnostic('b', st['b'], False, NOW)
    assert s.level == DiagnosticStatus.OK
    assert s.message == 'merged via a (first placement: refined before the next cycle)'
    assert (values(s)['provisional'], values(s)['weak']) == ('true', 'false')
    m.refresh(math.inf)
    s = robot_diagnostic('b', m.status()['b'], False, NOW)
    assert values(s)['provisional'] == 'false' and s.message.startswith('merged via a')
    assert 'first placement' not in s.message
