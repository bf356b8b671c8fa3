"""rviz markers as a pure function of placements and links (ros/markers.py; message classes
only, no master)."""
import math

import numpy as np
import pytest

pytest.importorskip('visualization_msgs')   # the ROS shell: not on a stack without ROS (make test-focal)

from visualization_msgs.msg import Marker  # noqa: E402

from multi_map_merge.core.links import Link  # noqa: E402
from multi_map_merge.core.placement import Placement  # noqa: E402
from multi_map_merge.core.transforms import se2  # noqa: E402
from multi_map_merge.ros.markers import link_colour, markers_key, markers_msg  # noqa: E402


def pl(x, y, yaw, via, path):
    return Placement(se2(x, y, yaw), 0.4, 0.95, 30, via, path, 0.0)


PLACED = {'tb3_0': pl(0.0, 0.0, 0.0, '', ('tb3_0',)),
          'tb3_1': pl(2.0, -1.0, math.pi / 2, 'tb3_0', ('tb3_0', 'tb3_1')),
          'tb3_2': pl(-3.0, 4.0, -2.0, 'tb3_1', ('tb3_0', 'tb3_1', 'tb3_2'))}
LINKS = [Link('tb3_0', 'tb3_1', np.eye(3), 0.48, 0.99, 40, 80, 0.0),
         Link('tb3_1', 'tb3_2', np.eye(3), 0.27, 0.85, 15, 55, 0.0),
         Link('tb3_2', 'tb3_3', np.eye(3), 0.30, 0.90, 20, 60, 0.0)]   # tb3_3 is not placed


def by_ns(arr):
    out = {}
    for m in arr.markers:
        out.setdefault(m.ns, []).append(m)
    return out


def test_one_arrow_and_name_per_placed_robot_at_its_origin():
    arr = markers_msg(PLACED, LINKS, 'map', 0, 0.8)
    assert arr.markers[0].action == Marker.DELETEALL           # gone robots and links disappear
    ns = by_ns(arr)
    arrows = {m.id: m for m in ns['robots']}
    assert len(arrows) == 3 and all(m.type == Marker.ARROW and m.header.frame_id == 'map' for m in arrows.values())
    for i, (_robot, p) in enumerate(sorted(PLACED.items())):
        a = arrows[i]
        x, y = p.T[0, 2], p.T[1, 2]
        yaw = 2 * math.atan2(a.pose.orientation.z, a.pose.orientation.w)
        assert (a.pose.position.x, a.pose.position.y) == pytest.approx((x, y))
        assert math.remainder(yaw - math.atan2(p.T[1, 0], p.T[0, 0]), 2 * math.pi) == pytest.approx(0, abs=1e-9)
    names = sorted(m.text for m in ns['robot_names'])
    assert names == ['tb3_0 (reference)', 'tb3_1', 'tb3_2']


def test_a_line_per_link_between_placed_robots_coloured_by_agreement():
    ns = by_ns(markers_msg(PLACED, LINKS, 'map', 0, 0.8))
    lines = ns['links']
    assert len(lines) == 2                                     # tb3_3 is not placed
    first = [(p.x, p.y) for p in lines[0].points]
    assert first == [(0.0, 0.0), pytest.approx((2.0, -1.0))]
    assert lines[0].color.g == pytest.approx(0.95) and lines[1].color.r == pytest.approx(0.75)
    assert [m.text for m in ns['link_labels']] == ['tb3_0-tb3_1: inlier ratio 0.48, agreement 0.99',
                                                   'tb3_1-tb3_2: inlier ratio 0.27, agreement 0.85']
    assert link_colour(0.5, 0.8).r == 1.0 and link_colour(1.0, 0.8).g == 1.0


def test_the_key_changes_with_a_placement_or_a_link_only():
    k = markers_key(PLACED, LINKS)
    assert markers_key(dict(PLACED), list(LINKS)) == k
    moved = dict(PLACED, tb3_1=pl(2.0, -1.1, math.pi / 2, 'tb3_0', ('tb3_0', 'tb3_1')))
    assert markers_key(moved, LINKS) != k
    assert markers_key(PLACED, LINKS[:2]) != k
    only_ref = markers_msg({'tb3_0': PLACED['tb3_0']}, [], 'map', 0, 0.8)
    assert [m.ns for m in only_ref.markers] == ['', 'robots', 'robot_names']


def test_a_2_sigma_ellipse_per_robot_with_a_covariance():
    """ns robot_ellipses: a flat cylinder at the robot's origin whose half-axes are 2 sqrt of the
    eigenvalues of its placement's x, y covariance (scale is the diameter), its x axis along the
    major eigenvector; red when weakly pinned; none without a covariance (the reference)."""
    rot = np.array([[math.cos(0.6), -math.sin(0.6)], [math.sin(0.6), math.cos(0.6)]])
    cov_xy = rot @ np.diag([0.09 ** 2, 0.02 ** 2]) @ rot.T      # major axis at 0.6 rad
    cov1 = np.zeros((3, 3))
    cov1[:2, :2], cov1[2, 2] = cov_xy, 1e-5
    cov2 = np.diag([0.004 ** 2, 0.01 ** 2, 1e-6])                # major axis along y
    placed = dict(PLACED)
    placed['tb3_1'] = Placement(PLACED['tb3_1'].T, 0.4, 0.95, 30, 'tb3_0', ('tb3_0', 'tb3_1'), 0.0, cov=cov1,
                                weak_reason='2-sigma 0.9 m > max_position_sigma 0.5 m')
    placed['tb3_2'] = Placement(PLACED['tb3_2'].T, 0.4, 0.95, 30, 'tb3_1', ('tb3_0', 'tb3_1', 'tb3_2'), 0.0,
                                cov=cov2)
    ns = by_ns(markers_msg(placed, LINKS, 'map', 0, 0.8))
    ellipses = {m.id: m for m in ns['robot_ellipses']}
    assert sorted(ellipses) == [1, 2]                           # ids: the robots' ranks; tb3_0 has none
    for i, robot in ((1, 'tb3_1'), (2, 'tb3_2')):
        e, p = ellipses[i], placed[robot]
        assert e.type == Marker.CYLINDER and e.header.frame_id == 'map'
        assert (e.pose.position.x, e.pose.position.y) == pytest.approx((p.T[0, 2], p.T[1, 2]))
        w, v = np.linalg.eigh(p.cov[:2, :2])
        assert (e.scale.x / 2, e.scale.y / 2) == pytest.approx((2 * math.sqrt(w[1]), 2 * math.sqrt(w[0])))
        yaw = 2 * math.atan2(e.pose.orientation.z, e.pose.orientation.w)
        along = np.array([math.cos(yaw), math.sin(yaw)])
        assert abs(along @ v[:, 1]) == pytest.approx(1.0, abs=1e-9)   # x axis on the major eigenvector
    assert ellipses[1].scale.x / 2 == pytest.approx(0.18) and ellipses[1].scale.y / 2 == pytest.approx(0.04)
    assert math.remainder(2 * math.atan2(ellipses[1].pose.orientation.z, ellipses[1].pose.orientation.w) - 0.6,
                          math.pi) == pytest.approx(0, abs=1e-9)
    assert (ellipses[1].color.r, ellipses[1].color.g) == (1.0, pytest.approx(0.1))    # weak: red
    assert ellipses[2].color.r < 0.5                                                   # well pinned
    assert markers_key(placed, LINKS) != markers_key(PLACED, LINKS)                   # drawn again
