"""Every launch file parses with roslaunch's own loader and starts what it should. gmapping and
rviz are not in Debian: those two packages are tolerated when missing, nothing else is."""
import os

import pytest
import yaml

roslaunch = pytest.importorskip('roslaunch')
import rospkg  # noqa: E402
from roslaunch.config import ROSLaunchConfig  # noqa: E402
from roslaunch.xmlloader import XmlLoader  # noqa: E402

from conftest import REPO  # noqa: E402

LAUNCH = os.path.join(REPO, 'launch')
MAY_BE_MISSING = {'gmapping', 'rviz'}


def load(name, *args):
    if os.environ.get('ROS_PACKAGE_PATH', '').find('multi_map_merge') < 0:
        try:
            rospkg.RosPack().get_path('multi_map_merge')
        except rospkg.ResourceNotFound:
            pytest.skip('the package is not on ROS_PACKAGE_PATH: run through make test')
    cfg = ROSLaunchConfig()
    XmlLoader().load(os.path.join(LAUNCH, name), cfg, argv=list(args), verbose=False)
    return cfg


def nodes(cfg, type_):
    return [n for n in cfg.nodes if n.type == type_]


def check_executables(cfg):
    rp = rospkg.RosPack()
    for n in cfg.nodes:
        try:
            path = rp.get_path(n.package)
        except rospkg.ResourceNotFound:
            assert n.package in MAY_BE_MISSING, 'package %s of node %s not found' % (n.package, n.name)
            continue
        if n.package == 'multi_map_merge':
            assert os.access(os.path.join(REPO, 'scripts', n.type), os.X_OK), n.type
        else:
            assert os.path.isdir(path)


def test_map_merge_launch_loads_config():
    cfg = load('map_merge.launch', 'reference_robot:=tb3_2')
    (node,) = nodes(cfg, 'map_merge_node')
    assert node.package == 'multi_map_merge' and node.name == 'map_merge'
    assert cfg.params['/map_merge/estimation_rate'].value == 0.5
    assert cfg.params['/map_merge/robot_namespace_pattern'].value == 'tb3_*'
    assert cfg.params['/map_merge/reference_robot'].value == 'tb3_2'
    check_executables(cfg)


@pytest.mark.parametrize('count', [2, 4])
def test_multi_slam(count):
    cfg = load('turtlebot3_multi_slam.launch', 'robot_count:=%d' % count, 'rviz:=true')
    g = nodes(cfg, 'slam_gmapping')
    assert sorted(n.namespace for n in g) == ['/tb3_%d/' % i for i in range(count)]
    for i in range(count):
        p = '/tb3_%d/slam_gmapping/' % i
        assert cfg.params[p + 'map_frame'].value == 'tb3_%d/map' % i
        assert cfg.params[p + 'odom_frame'].value == 'tb3_%d/odom' % i
        assert cfg.params[p + 'base_frame'].value == 'tb3_%d/base_footprint' % i
        assert cfg.params[p + 'maxRange'].value == 8.0      # LDS-02
    assert len(nodes(cfg, 'map_merge_node')) == 1 and len(nodes(cfg, 'rviz')) == 1
    assert '$(find' not in nodes(cfg, 'rviz')[0].args and 'multi_map_merge.rviz' in nodes(cfg, 'rviz')[0].args
    check_executables(cfg)


def test_bag_replay_recorded_and_gmapping():
    cfg = load('bag_replay.launch', 'bag:=/tmp/robots.bag', 'slam:=recorded', 'rviz:=false')
    (play,) = nodes(cfg, 'play')
    assert '--clock' in play.args and '/tmp/robots.bag' in play.args
    assert cfg.params['/use_sim_time'].value is True
    assert nodes(cfg, 'slam_gmapping') == [] and nodes(cfg, 'rviz') == []
    assert len(nodes(cfg, 'map_merge_node')) == 1
    check_executables(cfg)
    cfg = load('bag_replay.launch', 'bag:=/tmp/robots.bag', 'slam:=gmapping', 'robot_count:=3')
    assert len(nodes(cfg, 'slam_gmapping')) == 3 and len(nodes(cfg, 'rviz')) == 1
    check_executables(cfg)


def test_rviz_config():
    with open(os.path.join(REPO, 'rviz', 'multi_map_merge.rviz')) as f:
        cfg = yaml.safe_load(f)
    vm = cfg['Visualization Manager']
    assert vm['Global Options']['Fixed Frame'] == 'map'
    topics = {d.get('Topic') for d in vm['Displays'] if d['Class'] == 'rviz/Map'}
    assert {'/map', '/tb3_0/map', '/tb3_3/map'} <= topics
    assert any(d['Class'] == 'rviz/TF' for d in vm['Displays'])
