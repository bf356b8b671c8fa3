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

