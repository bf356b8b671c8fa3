"""Message conversions of the ROS adapter (needs rospy importable, no master)."""
import math

import numpy as np
import pytest

rospy = pytest.importorskip('rospy')   # the ROS shell: not on a stack without ROS (make test-focal)

from multi_map_merge.core.grid import Grid, GridError  # noqa: E402
from multi_map_merge.core.transforms import se2  # noqa: E402
from multi_map_merge.ros.convert import grid_from_msg, grid_to_msg, transform_msg  # noqa: E402


def test_round_trip_keeps_cells_and_origin():
    d = np.random.default_rng(0).choice(np.array([-1, 0, 100], np.int8), (30, 40))
    g = Grid(d, 0.05, (1.5, -2.0, 0.3), 'tb3_1/map')
    msg = grid_to_msg(g, rospy.Time(5), 'tb3_1/map')
    assert isinstance(msg.data, np.ndarray) and msg.data.dtype == np.int8   # numpy_msg, no lists
    back = grid_from_msg(msg, 10 ** 6)
    assert np.array_equal(back.data, d) and back.frame_id == 'tb3_1/map'
    assert back.origin == pytest.approx((1.5, -2.0, 0.3))


@pytest.mark.parametrize('q', [(0, 0, math.inf, 1), (0, 0, 0, math.nan), (-math.inf, 0, 0, 1)])
def test_non_finite_orientation_refused(q):
    msg = grid_to_msg(Grid(np.zeros((3, 3), np.int8), 0.05), rospy.Time(0), 'm')
    o = msg.info.origin.orientation
    o.x, o.y, o.z, o.w = q
    with pytest.raises(GridError, match='orientation'):
        grid_from_msg(msg, 10 ** 6)


def test_unset_orientation_is_yaw_zero():
    msg = grid_to_msg(Grid(np.zeros((3, 3), np.int8), 0.05), rospy.Time(0), 'm')
    o = msg.info.origin.orientation
    o.x = o.y = o.z = o.w = 0.0
    assert grid_from_msg(msg, 10 ** 6).origin[2] == 0.0


def test_transform_msg():
    t = transform_msg(se2(1.0, 2.0, math.pi / 2), 'map', 'tb3_1/map', rospy.Time(1))
    assert (t.header.frame_id, t.child_frame_id) == ('map', 'tb3_1/map')
    assert (t.transform.translation.x, t.transform.translation.y) == pytest.approx((1.0, 2.0))
    assert (t.transform.rotation.z, t.transform.rotation.w) == pytest.approx((math.sqrt(.5), math.sqrt(.5)))



COV = np.array([[4e-4, 1e-4, 2e-5],
                [1e-4, 9e-4, -3e-5],
                [2e-5, -3e-5, 1e-5]])


def test_pose_with_covariance_in_ros_order():
    """x, y, yaw of the 3x3 at rows/columns 0, 1, 5 of the 6x6 (x, y, z, roll, pitch, yaw),
    z, roll, pitch 0; the pose is the 3x3 pose's."""
    from multi_map_merge.ros.convert import covariance_of, pose_with_covariance_msg, quaternion_yaw
    m = pose_with_covariance_msg(se2(1.0, -2.0, 2.5), COV, 'map', rospy.Time(3))
    assert (m.header.frame_id, m.header.stamp) == ('map', rospy.Time(3))
    p = m.pose.pose
    assert (p.position.x, p.position.y, p.position.z) == pytest.approx((1.0, -2.0, 0.0))
    assert quaternion_yaw(p.orientation) == pytest.approx(2.5) and (p.orientation.x, p.orientation.y) == (0, 0)
    c = np.array(m.pose.covariance).reshape(6, 6)
    assert len(m.pose.covariance) == 36 and np.array_equal(c, c.T)
    names = 'x y z roll pitch yaw'.split()
    for i, a in enumerate('x y yaw'.split()):
        for j, b in enumerate('x y yaw'.split()):
            assert c[names.index(a), names.index(b)] == COV[i, j], (a, b)
    assert not c[2:5].any() and not c[:, 2:5].any()            # z, roll, pitch: 0
    assert np.array_equal(covariance_of(m), COV)
    skew = COV + np.array([[0, 1e-12, 0], [0, 0, 0], [0, 0, 0]])   # a numerical inverse's last bits
    c = np.array(pose_with_covariance_msg(np.eye(3), skew, 'map', rospy.Time(0)).pose.covariance).reshape(6, 6)
    assert np.array_equal(c, c.T) and c[0, 1] == pytest.approx(COV[0, 1] + 0.5e-12, abs=1e-18)


def test_pose_covariance_unknown_or_exact():
    """No covariance: -1 first and 0 elsewhere (unknown), or all 0 for an exact pose (the
    reference)."""
    from multi_map_merge.ros.convert import covariance_of, pose_with_covariance_msg
    m = pose_with_covariance_msg(se2(1.0, 2.0, 0.0), None, 'map', rospy.Time(0))
    assert m.pose.covariance[0] == -1.0 and not any(m.pose.covariance[1:])
    assert covariance_of(m) is None
    m = pose_with_covariance_msg(np.eye(3), None, 'map', rospy.Time(0), exact=True)
    assert not any(m.pose.covariance) and covariance_of(m).shape == (3, 3)
    assert m.pose.pose.orientation.w == 1.0
