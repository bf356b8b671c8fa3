"""The node's /diagnostics as pure functions of the merger's status (ros/diagnostics.py; needs
the message classes, no master): each robot's status and the node's own."""
import numpy as np
import pytest

pytest.importorskip('diagnostic_msgs')   # the ROS shell: not on a stack without ROS (make test-focal)

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402

from multi_map_merge.core.merger import RobotStatus  # noqa: E402
from multi_map_merge.core.placement import Placement  # noqa: E402
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
    """A placement there reads as core.state.placement_dict says, as in the state and
    transforms files."""
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
