"""The set-up checks the node makes at start (ros/setup_check.py), without a master."""
import pytest

from multi_map_merge.ros.setup_check import (
    foreign_robot_map_tf,
    foreign_tf_warning,
    rsp_version_warning,
    version_tuple,
)


@pytest.mark.parametrize('version,warned', [
    ('1.15.0', True), ('1.15.1', True), ('1.14.1', True), ('1.13.4', True),
    ('1.15.2', False), ('1.15.3', False), ('1.16.0', False), ('2.0.0', False),
    (None, False), ('', False), ('unknown', False),
])
def test_robot_state_publisher_without_tf_prefix_is_one_line(version, warned):
    line = rsp_version_warning(version)
    assert bool(line) == warned
    if warned:
        assert '\n' not in line and version in line and '1.15.2' in line and 'tf_prefix' in line


def test_version_tuple():
    assert version_tuple('1.15.2') == (1, 15, 2) and version_tuple('1.15.2-1+b1') == (1, 15, 2)
    assert version_tuple('x') is None


def robot_map(frame):
    return frame in ('tb3_1/map', 'robots/r1/map')


@pytest.mark.parametrize('parent,child,authority,foreign', [
    ('map', 'tb3_1/map', '/world_to_tb3_1_tf_broadcaster', True),
    ('/map', '/tb3_1/map', '/world_to_tb3_1_tf_broadcaster', True),   # tf1's leading slashes
    ('map', 'robots/r1/map', '/other', True),
    ('map', 'tb3_1/map', '/map_merge', False),       # our own
    ('map', 'tb3_1/map', '', False),                 # no sender known
    ('world', 'tb3_1/map', '/other', False),          # not from the merged frame
    ('map', 'tb3_1/odom', '/other', False),           # not a robot's map frame
])
def test_another_sender_of_a_robots_map_frame_is_foreign(parent, child, authority, foreign):
    assert foreign_robot_map_tf(parent, child, authority, 'map', '/map_merge', robot_map) == foreign


def test_the_warning_names_the_node_and_the_frames():
    line = foreign_tf_warning('/map', '/tb3_1/map', '/rival', True)
    assert '\n' not in line and '/rival' in line and 'map -> tb3_1/map' in line and '/tf_static' in line
