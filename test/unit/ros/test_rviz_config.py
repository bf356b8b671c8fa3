"""The rviz config robots_rviz writes (ros/rviz_config.py): the merger's topics follow the
node's name and namespace, and each robot has its own 2D Nav Goal topic. No master, no rviz."""
import os

import pytest
import yaml
from conftest import REPO

from multi_map_merge.ros.rviz_config import node_topics, robots_rviz_config

RVIZ = os.path.join(REPO, 'rviz', 'multi_map_merge.rviz')


def config(*args, **kw):
    with open(RVIZ) as f:
        return yaml.safe_load(robots_rviz_config(f.read(), *args, **kw))['Visualization Manager']


def topics(vm):
    markers = [d['Marker Topic'] for d in vm['Displays'] if d['Class'] == 'rviz/MarkerArray']
    maps = [(d['Name'], d['Topic']) for d in vm['Displays'] if d['Class'] == 'rviz/Map']
    goals = [t['Topic'] for t in vm['Tools'] if t['Class'] == 'rviz/SetGoal']
    return markers, maps, goals


def test_map_merge_launch_names_the_node_map_merge():
    markers, maps, goals = topics(config(['tb3_0', 'tb3_1']))
    assert markers == ['/map_merge/markers']
    assert maps == [('Merged map', '/map'), ('tb3_0 map', '/tb3_0/map'), ('tb3_1 map', '/tb3_1/map')]
    assert goals == ['/tb3_0/move_base_simple/goal', '/tb3_1/move_base_simple/goal']


def test_mexplore_launch_puts_the_node_in_the_namespace_map_merge():
    markers, maps, goals = topics(config(['tb3_0', 'robots/r1'], node='/map_merge/map_merge'))
    assert markers == ['/map_merge/map_merge/markers']
    assert maps == [('Merged map', '/map_merge/map'), ('tb3_0 map', '/tb3_0/map'),
                    ('robots/r1 map', '/robots/r1/map')]
    assert goals == ['/tb3_0/move_base_simple/goal', '/robots/r1/move_base_simple/goal']


def test_a_global_merged_map_topic_stays():
    assert node_topics('/team/merger', '/merged') == {'markers': '/team/merger/markers', 'map': '/merged'}
    assert node_topics('map_merge') == {'markers': '/map_merge/markers', 'map': '/map'}


@pytest.mark.parametrize('node', ['/', 'a b', '/1x'])
def test_a_bad_node_name_is_an_error(node):
    with pytest.raises(ValueError):
        node_topics(node)


def test_the_shipped_config_has_no_global_goal():
    with open(RVIZ) as f:
        vm = yaml.safe_load(f)['Visualization Manager']
    assert [t['Topic'] for t in vm['Tools'] if t['Class'] == 'rviz/SetGoal'] == [
        '/tb3_%d/move_base_simple/goal' % i for i in range(4)]
