"""Shared fixtures and helpers of the unit tests (no ROS master needed): the shared data (others'
maps and launch files, read in place), a merger run on some maps, pose errors."""
import math
import os
import sys

import numpy as np
import pytest

REPO = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..'))
sys.path.insert(0, os.path.join(REPO, 'src'))
SHARED = os.path.abspath(os.path.join(REPO, '..', 'shared', 'data'))
# others' files in ../shared/data (../shared/data/README.md), never shipped with the project
INTEL_MAP = 'ground_truth/intel_gt.yaml'      # the Intel lab (CARMEN log, rasterised)
HOUSE_MAP = 'aws/small_house/map.yaml'        # the AWS RoboMaker small house
MAZE = 'tb3_dans_maze'                        # three Turtlebot3s' gmapping maps of a maze, and the whole
ROBOTIS = 'robotis/turtlebot3'                # ROBOTIS's bringup launch files and the Burger's URDF
BURGER_XACRO = ROBOTIS + '/turtlebot3_description/urdf/turtlebot3_burger.urdf.xacro'

from multi_map_merge.core.config import MergeConfig  # noqa: E402
from multi_map_merge.core.mapio import load_map  # noqa: E402
from multi_map_merge.core.merger import MapMerger  # noqa: E402
from multi_map_merge.core.transforms import pose_distance  # noqa: E402


def shared_file(*parts: str) -> str:
    """The path of ``parts`` under ../shared/data (others' data, beside CI's clone but not part of
    the project: read in place), or skip the test with one line naming the missing path."""
    path = os.path.join(SHARED, *parts)
    if not os.path.exists(path):
        pytest.skip('%s is absent: others\' data is read in place from ../shared/data, not shipped' % path)
    return path


@pytest.fixture
def shared_data():
    """../shared/data, or skip."""
    return shared_file()


@pytest.fixture
def open3d():
    """Open3D, or skip: evaluation's ICP (Fitness, inlier RMSE) needs it, and Ubuntu 20.04 does
    not package it (an optional dependency there: pip3 install open3d, rosdep python3-open3d-pip)."""
    return pytest.importorskip('open3d', reason='Open3D is not installed (optional: evaluation '
                                                'only; pip3 install open3d, Debian python3-open3d)')


def pose_error(T_est, T_true):
    """(metres, degrees) between two 3x3 poses."""
    d, a = pose_distance(T_est, T_true)
    return d, math.degrees(a)


def truth(T_ref, T_k):
    """Pose of piece k's frame in the reference piece's frame."""
    return np.linalg.inv(T_ref) @ T_k


def pytest_configure(config):
    config.addinivalue_line('markers', 'slow: takes tens of seconds (real buildings, simulated robots); '
                                       '-m "not slow" skips it')


@pytest.fixture
def house_yaml():
    """The AWS small house's map_server .yaml (../shared/data), or skip."""
    return shared_file(HOUSE_MAP)


@pytest.fixture(scope='session')
def intel():
    """The Intel lab's map (CARMEN, rasterised; ../shared/data), or skip."""
    return load_map(shared_file(INTEL_MAP))


@pytest.fixture(scope='session')
def house():
    """The AWS small house's map (../shared/data), or skip."""
    return load_map(shared_file(HOUSE_MAP))


# the simulated team of the house tests (test_corroborate, test_drift, test_spawn, test_deform):
# make_robot_bags' seed 2 with its SLAM model's drift scaled by this (its --slam-drift)
HOUSE_TEAM_DRIFT = 6.0


@pytest.fixture(scope='session')
def house_team(house):
    """Four simulated Turtlebot3s' final maps of the AWS house and where each started, as
    ``make_robot_bags --robots 4 --seed 2 --slam-drift 6`` makes them (lab/simulate: the robots
    start within 1 m of each other, headings apart, and explore apart; each map drawn at its
    robot's drifting SLAM poses, so the maps bend): ({robot: Grid in its own map frame},
    {robot: its start (x, y, yaw) in the house}). About 30 s, once a session."""
    from multi_map_merge.lab import simulate as sim
    cfg = sim.SimConfig(robots=4, seed=2)
    k = HOUSE_TEAM_DRIFT
    cfg.slam_trans_var *= k * k
    cfg.slam_rot_var *= k * k
    cfg.slam_turn_var *= k * k
    cfg.slam_bias *= k
    team, _ = sim.simulate_world(house, cfg)
    return {r.name: r.maps[-1][1] for r in team}, {r.name: list(r.start) for r in team}


def merged(maps, **config):
    """A MapMerger after one estimation cycle on ``maps`` (name -> Grid or map_server .yaml
    path, fed in that order); ``config``: MergeConfig fields."""
    m = MapMerger(MergeConfig(**config))
    for n, g in maps.items():
        m.update_map(n, load_map(g) if isinstance(g, str) else g)
    m.estimate()
    return m


@pytest.fixture(scope='module')
def halves_merged(intel):
    """A merger after one cycle on robots a, b (two overlapping parts of the Intel lab, b turned
    and moved; reference a) and c (a corner of it too small to place: not merged)."""
    from multi_map_merge.core.grid import known_bbox
    from multi_map_merge.lab.pieces import cut_piece
    r0, r1, c0, c1 = known_bbox(intel.levels())
    a = cut_piece(intel, (r0, r1, c0, c0 + int(0.6 * (c1 - c0))), (0, 0, 0))[0]
    b = cut_piece(intel, (r0, r1, c0 + int(0.4 * (c1 - c0)), c1), (3, -2, 2.0))[0]
    c = cut_piece(intel, (r0, r0 + 40, c0, c0 + 40), (1, 1, 1.0))[0]
    # (pieces of one ground truth do not drift from their frames' origins)
    return merged({'a': a, 'b': b, 'c': c}, reference_robot='a', map_drift=0.0, map_drift_yaw=0.0)


# ---------------------------------------------------------------- gmapping for a parse of its launch path
GMAPPING_STAND_IN_XML = """<?xml version="1.0"?>
<package format="2">
  <name>gmapping</name>
  <version>0.0.0</version>
  <description>Stand-in of the unit tests: a package.xml named gmapping and nothing else, so that
    roslaunch parses slam:=gmapping where ROS has no gmapping. No node can start from it.</description>
  <maintainer email="nobody@example.com">nobody</maintainer>
  <license>BSD</license>
</package>
"""


def reset_roslaunch_rospack():
    """roslaunch's $(find) and $(eval find()) keep one RosPack (its crawl of ROS_PACKAGE_PATH) for
    the process: forget it, so the next parse sees the ROS_PACKAGE_PATH of now."""
    import roslaunch.substitution_args
    roslaunch.substitution_args._rospack = None


@pytest.fixture(scope='module')
def gmapping_stand_in(tmp_path_factory):
    """Lets the module parse the launch files' slam:=gmapping path (launch/includes/slam_robot.launch
    stops roslaunch where ROS has no package gmapping). Where ROS has gmapping: nothing to do,
    yields None. Elsewhere (Debian): puts a stand-in package gmapping (a package.xml alone) first on
    ROS_PACKAGE_PATH of this process and of the roslaunch it runs, for the module's tests only, and
    yields its directory. Parse-only: a test must treat that directory as no gmapping."""
    import rospkg
    try:
        rospkg.RosPack().get_path('gmapping')
        yield None
        return
    except rospkg.ResourceNotFound:
        pass
    root = tmp_path_factory.mktemp('stand_in')
    (root / 'gmapping').mkdir()
    (root / 'gmapping' / 'package.xml').write_text(GMAPPING_STAND_IN_XML)
    old = os.environ.get('ROS_PACKAGE_PATH')
    os.environ['ROS_PACKAGE_PATH'] = os.pathsep.join([str(root)] + ([old] if old else []))
    reset_roslaunch_rospack()
    try:
        yield str(root / 'gmapping')
    finally:
        if old is None:
            del os.environ['ROS_PACKAGE_PATH']
        else:
            os.environ['ROS_PACKAGE_PATH'] = old
        reset_roslaunch_rospack()
