"""The node's parameter resolution (ros/params.py) as a pure function: no master, no rospy.
What a user's YAML or launch file gives -> the NodeConfig the node runs with, and the errors
and warnings it logs."""
import glob
import os
from dataclasses import fields

import pytest
import yaml
from conftest import BURGER_XACRO, REPO, shared_file

from multi_map_merge import node_config
from multi_map_merge.core import parameters as P
from multi_map_merge.node_config import NodeConfig
from multi_map_merge.ros.params import check_library_param, resolve_params, robot_of_map_topic

# the tables (core/parameters.py, node_config.py), by name
RULES = {p.name: p.rule for p in node_config.config_parameters()}                      # NodeConfig's
LIBRARY_RULES = {p.name: (p.rule, p.default) for p in node_config.parameters() if p.library}
MEXPLORE_ALIASES = {old: p.name for p in node_config.parameters() for old, _ in p.mexplore}


def shipped_yaml():
    with open(os.path.join(REPO, 'config', 'map_merge.yaml')) as f:
        return yaml.safe_load(f)


def test_every_parameter_has_a_rule():
    assert set(RULES) == {f.name for f in fields(NodeConfig)}


def test_shipped_yaml_resolves_clean_to_the_defaults():
    res = resolve_params(shipped_yaml())
    assert (res.errors, res.warnings, res.notes) == ([], [], [])
    assert res.config == NodeConfig()


def test_nothing_given_is_the_defaults():
    res = resolve_params({})
    assert res.config == NodeConfig() and not res.errors and not res.warnings


@pytest.mark.parametrize('name', ['estimation_rate', 'merge_rate', 'discovery_rate', 'tf_rate'])
@pytest.mark.parametrize('value', [0, 0.0, -1.0, float('nan'), float('inf'), 'fast', True, [2.0]])
def test_a_bad_rate_is_an_error_naming_it_and_its_range_and_the_default_is_used(name, value):
    res = resolve_params({name: value})
    assert getattr(res.config, name) == getattr(NodeConfig(), name)
    assert len(res.errors) == 1, res.errors
    assert '~%s' % name in res.errors[0] and '> 0' in res.errors[0], res.errors[0]
    assert 'using the default %r' % getattr(NodeConfig(), name) in res.errors[0]


def test_good_values_of_every_kind_are_taken_and_converted():
    given = {'merge_rate': 1, 'estimation_rate': '0.25', 'max_cells': 1e6, 'min_inliers': '12',
             'refine': 'false', 'pose_graph': 0, 'robots': 'tb3_0 tb3_1', 'reference_robot': 'tb3_1',
             'initial_poses': {'/tb3_0': [0, 0, 0], 'tb3_1': ['1.5', -2, 0.1]},
             'initial_pose_tolerance': [0.5, 0.2], 'min_inlier_ratio': 0.3}
    res = resolve_params(given)
    assert not res.errors and not res.warnings
    c = res.config
    assert c.merge_rate == 1.0 and isinstance(c.merge_rate, float) and c.estimation_rate == 0.25
    assert c.max_cells == 1000000 and isinstance(c.max_cells, int) and c.min_inliers == 12
    assert c.refine is False and c.pose_graph is False
    assert c.robots == ['tb3_0', 'tb3_1'] and c.reference_robot == 'tb3_1'
    assert c.initial_poses == {'tb3_0': [0.0, 0.0, 0.0], 'tb3_1': [1.5, -2.0, 0.1]}
    assert c.initial_pose_tolerance == [0.5, 0.2] and c.min_inlier_ratio == 0.3


@pytest.mark.parametrize('name,value,accepts', [
    ('max_cells', 0, 'integer >= 1'),
    ('max_cells', 2.5, 'integer >= 1'),
    ('workers', -1, 'integer >= 0'),
    ('min_agreement', 1.5, '[0, 1]'),
    ('match_ratio', 0, '(0, 1]'),
    ('free_thresh', 101, '[0, 100]'),
    ('akaze_threshold', 0, '> 0'),
    ('refine', 'yes', 'true or false'),
    ('refine', 2, 'true or false'),
    ('map_topic', '', 'one topic name'),
    ('merged_map_frame', {'a': 1}, 'a frame id'),
    ('robots', [1, 2], 'list of robot namespaces'),
    ('initial_poses', {'tb3_0': [0, 0]}, 'robot: [x, y, yaw]'),
    ('initial_poses', {'tb3_0': [0, 'x', 0]}, 'robot: [x, y, yaw]'),
    ('initial_poses', [0, 0, 0], 'robot: [x, y, yaw]'),
    ('initial_pose_tolerance', [1.0], '[metres, radians]'),
    ('initial_pose_tolerance', [1.0, -0.1], '[metres, radians]'),
])
def test_invalid_values_are_errors_and_defaults_are_used(name, value, accepts):
    res = resolve_params({name: value, 'merge_rate': 3.0})
    assert len(res.errors) == 1 and '~%s' % name in res.errors[0] and accepts in res.errors[0], res.errors
    assert getattr(res.config, name) == getattr(NodeConfig(), name)
    assert res.config.merge_rate == 3.0   # the others are still taken


def test_free_thresh_must_be_below_occupied_thresh():
    res = resolve_params({'free_thresh': 70, 'occupied_thresh': 60})
    assert len(res.errors) == 1 and '~free_thresh' in res.errors[0] and '~occupied_thresh' in res.errors[0]
    assert (res.config.free_thresh, res.config.occupied_thresh) == (19.6, 65.0)


@pytest.mark.parametrize('typo,closest', [('merge_rat', 'merge_rate'), ('estimaton_rate', 'estimation_rate'),
                                          ('robot_namespace_patern', 'robot_namespace_pattern'),
                                          ('refne', 'refine'), ('merging_rte', 'merging_rate')])
def test_an_unknown_parameter_is_one_warning_naming_the_closest_known(typo, closest):
    res = resolve_params({typo: 1.0})
    assert res.warnings == ['unknown parameter ~%s ignored: did you mean ~%s?' % (typo, closest)]
    assert res.config == NodeConfig() and not res.errors


def test_diagnostic_updaters_period_is_known_and_documented():
    """~diagnostic_period is read by diagnostic_updater, not by us: no unknown-parameter warning,
    and a row in the README's Parameters table."""
    res = resolve_params({'diagnostic_period': 2.0})
    assert not res.warnings and not res.errors and res.config == NodeConfig()
    with open(os.path.join(REPO, 'README.md')) as f:
        text = f.read()
    for name in LIBRARY_RULES:
        assert '| `~%s` |' % name in text, name


def test_an_unknown_parameter_like_no_known_one_is_still_warned():
    res = resolve_params({'zzzz': 1, 'qqqq_xxxx': 2})
    assert len(res.warnings) == 2 and all('unknown parameter' in w for w in res.warnings)


def test_mexplore_names_are_aliases():
    """m-explore's map_merge parameters, as its README and launch files set them."""
    given = {'robot_map_topic': 'gmap', 'robot_map_updates_topic': 'gmap_updates',
             'robot_namespace': 'robot', 'merged_map_topic': 'merged_map', 'world_frame': 'world',
             'merging_rate': 4.0, 'discovery_rate': 0.05, 'estimation_rate': 0.5,
             'known_init_poses': True}
    res = resolve_params(given)
    assert not res.errors and not res.warnings, (res.errors, res.warnings)
    c = res.config
    assert (c.map_topic, c.map_updates_topic, c.merged_map_topic) == ('gmap', 'gmap_updates', 'merged_map')
    assert c.robot_namespace_pattern == 'robot*' and c.merged_map_frame == 'world'
    assert (c.merge_rate, c.discovery_rate, c.estimation_rate) == (4.0, 0.05, 0.5)
    assert c.known_init_poses is True
    assert len(res.notes) == 5   # one info line per alias read


@pytest.mark.parametrize('ns,pattern', [('', '*'), ('/tb3', 'tb3*'), ('robot_', 'robot_*')])
def test_robot_namespace_becomes_a_prefix_pattern(ns, pattern):
    assert resolve_params({'robot_namespace': ns}).config.robot_namespace_pattern == pattern


def test_ours_wins_over_an_alias_with_a_warning():
    res = resolve_params({'merge_rate': 2.0, 'merging_rate': 8.0, 'map_topic': 'map', 'robot_map_topic': 'x'})
    assert res.config.merge_rate == 2.0 and res.config.map_topic == 'map'
    assert len(res.warnings) == 2
    assert any('~merging_rate' in w and '~merge_rate' in w and 'wins' in w for w in res.warnings)


def test_an_invalid_alias_value_is_an_error_naming_the_alias():
    res = resolve_params({'merging_rate': 0})
    assert res.config.merge_rate == NodeConfig().merge_rate
    assert len(res.errors) == 1 and '~merging_rate' in res.errors[0] and '> 0' in res.errors[0]


def test_estimation_confidence_is_accepted_but_said_to_have_no_equivalent():
    res = resolve_params({'estimation_confidence': 1.0})
    assert res.config == NodeConfig() and not res.errors
    assert len(res.warnings) == 1 and 'no equivalent' in res.warnings[0]


def test_the_former_name_of_min_inlier_ratio_is_still_read():
    assert resolve_params({'min_reliability': 0.3}).config.min_inlier_ratio == 0.3
    res = resolve_params({'min_reliability': 0.3, 'min_inlier_ratio': 0.2})
    assert res.config.min_inlier_ratio == 0.2 and len(res.warnings) == 1


def test_the_readme_documents_every_alias():
    with open(os.path.join(REPO, 'README.md')) as f:
        text = f.read()
    assert 'Switching from m-explore' in text
    for name in list(MEXPLORE_ALIASES) + list(P.MEXPLORE_IGNORED) + ['merged_map_topic']:
        assert '`%s`' % name in text, name


def test_no_launch_file_sets_a_parameter_the_merger_warns_about():
    """Every private parameter our launch files give the merger resolves without a word."""
    roslaunch = pytest.importorskip('roslaunch')
    from roslaunch.config import ROSLaunchConfig
    from roslaunch.xmlloader import XmlLoader
    checked = 0
    # xacro is not in Debian: the real-robot launch reads ROBOTIS's URDF as a file instead
    burger = shared_file(BURGER_XACRO)
    # slam:=rbpf: the merger's parameters are the same with either SLAM, and slam:=gmapping (their
    # default) stops the parse where ROS has no gmapping
    argv = {'turtlebot3_multi_slam.launch': ['urdf_file:=' + burger, 'slam:=rbpf'],
            'team_bags_gmapping.launch': ['bag_0:=/tmp/x.bag', 'slam:=rbpf']}   # clock_bag 0 needs a bag_0
    for path in sorted(glob.glob(os.path.join(REPO, 'launch', '*.launch'))):
        cfg = ROSLaunchConfig()
        try:
            XmlLoader().load(path, cfg, argv=argv.get(os.path.basename(path), []), verbose=False)
        except roslaunch.core.RLException:
            continue   # a launch file with a required arg: test_launch_files covers it
        for n in cfg.nodes:
            if n.type != 'map_merge_node':
                continue
            prefix = (n.namespace + n.name + '/')
            given = {k[len(prefix):]: p.value for k, p in cfg.params.items() if k.startswith(prefix)}
            assert '/' not in ''.join(given), given   # no nested names but the dicts
            res = resolve_params(given)
            assert not res.errors and not res.warnings, (path, res.errors, res.warnings)
            checked += 1
    assert checked >= 1



def test_known_init_poses_is_off_by_default_as_in_mexplore():
    assert NodeConfig().known_init_poses is False
    assert resolve_params(shipped_yaml()).config.known_init_poses is False


def test_init_pose_params_is_a_deprecated_alias_of_known_init_poses():
    res = resolve_params({'init_pose_params': True})
    assert res.config.known_init_poses is True and not res.errors
    assert len(res.warnings) == 1 and 'deprecated' in res.warnings[0] and '~known_init_poses' in res.warnings[0]
    res = resolve_params({'init_pose_params': True, 'known_init_poses': False})
    assert res.config.known_init_poses is False and len(res.warnings) == 1 and 'wins' in res.warnings[0]


def test_the_readme_has_the_robotis_gazebo_troubleshooting_entry():
    with open(os.path.join(REPO, 'README.md')) as f:
        text = f.read()
    assert "ROBOTIS's Gazebo" in text and '`~known_init_poses`' in text


def test_robotis_mexplore_block_resolves_with_only_the_confidence_warning():
    """The parameters turtlebot3_gazebo's multi_map_merge.launch (ROBOTIS, noetic; read in
    ../shared/data/robotis/turtlebot3_simulations) gives m-explore's node, given to ours unchanged (only pkg
    and type changed)."""
    robotis = {'robot_map_topic': 'map', 'robot_namespace': 'tb3', 'merged_map_topic': 'map',
               'world_frame': 'map', 'known_init_poses': True, 'merging_rate': 0.5,
               'discovery_rate': 0.05, 'estimation_rate': 0.1, 'estimation_confidence': 1.0}
    import xml.etree.ElementTree as ET
    root = ET.parse(shared_file('robotis', 'turtlebot3_simulations', 'multi_map_merge.launch'))
    (node,) = [n for n in root.iter('node') if n.get('name') == 'map_merge']
    assert {p.get('name'): yaml.safe_load(p.get('value')) for p in node.iter('param')} == robotis
    res = resolve_params(robotis)
    assert not res.errors
    assert len(res.warnings) == 1 and '~estimation_confidence' in res.warnings[0]
    c = res.config
    assert (c.map_topic, c.robot_namespace_pattern) == ('map', 'tb3*')
    assert (c.merged_map_topic, c.merged_map_frame) == ('map', 'map')
    assert (c.merge_rate, c.discovery_rate, c.estimation_rate, c.known_init_poses) == (0.5, 0.05, 0.1, True)
    assert c.min_inlier_ratio == NodeConfig().min_inlier_ratio   # estimation_confidence maps to nothing


def test_the_former_name_of_state_file_is_still_read():
    res = resolve_params({'transforms_file': '/tmp/links.yaml'})
    assert res.config.state_file == '/tmp/links.yaml' and not res.warnings and not res.errors
    assert res.notes == ["~transforms_file read as ~state_file (its former name): '/tmp/links.yaml'"]


def test_a_former_name_wins_over_our_name_at_its_default_as_config_map_merge_yaml_sets_it():
    """A launch file that loads config/map_merge.yaml (every parameter at its default) and sets a
    former name (test/ros/lifecycle.test: ~transforms_file) means the former name."""
    with open(os.path.join(REPO, 'config', 'map_merge.yaml')) as f:
        defaults = yaml.safe_load(f)
    res = resolve_params(dict(defaults, transforms_file='/tmp/links.yaml', min_reliability=0.3))
    assert res.config.state_file == '/tmp/links.yaml' and res.config.min_inlier_ratio == 0.3
    assert not res.warnings and len(res.notes) == 2
    # our name set to anything else wins, with a warning
    res = resolve_params({'transforms_file': '/tmp/old.yaml', 'state_file': '/tmp/new.yaml'})
    assert res.config.state_file == '/tmp/new.yaml' and len(res.warnings) == 1


# -- every parameter checked: no value the parameter server can hold crashes the node or is taken
#    silently when the node cannot work with it

@pytest.mark.parametrize('name', sorted(set(RULES) | set(LIBRARY_RULES)))
@pytest.mark.parametrize('value', [None, {'x': {}}, [[1]], '', '  '])
def test_every_parameter_refuses_values_of_no_use_with_one_error_naming_it(name, value):
    """Each parameter resolve_params reads, given a value of the wrong type (None, as an empty
    YAML entry gives it; a mapping; a nested list) or an empty string where it needs one: one
    error naming it, and the default. Strings that may be empty (''= none/default) are taken."""
    may_be_empty = {'map_updates_topic', 'reference_robot', 'state_file', 'robots', 'dask_scheduler'}
    res = resolve_params({name: value})
    if isinstance(value, str) and name in may_be_empty:
        assert not res.errors, res.errors
        return
    assert len(res.errors) == 1 and '~%s ' % name in res.errors[0], (name, value, res.errors)
    assert 'using the default' in res.errors[0]
    if name in LIBRARY_RULES:
        assert res.library[name] == LIBRARY_RULES[name][1]
    else:
        assert getattr(res.config, name) == getattr(NodeConfig(), name)


@pytest.mark.parametrize('value', ['abc', 0, -1.0, float('nan'), [1.0], True])
def test_a_bad_diagnostic_period_is_an_error_and_the_updater_gets_the_default(value):
    """diagnostic_updater reads ~diagnostic_period itself: 'abc' made it raise at every update
    (rospy.Duration('abc')), and /diagnostics went silent. Now it is checked like ours."""
    res = resolve_params({'diagnostic_period': value})
    assert res.library['diagnostic_period'] == 1.0
    assert len(res.errors) == 1 and '~diagnostic_period' in res.errors[0] and '> 0' in res.errors[0]
    assert check_library_param('diagnostic_period', value) == (1.0, res.errors[0])
    assert res.library_given == {'diagnostic_period': value}


def test_a_good_diagnostic_period_is_taken():
    res = resolve_params({'diagnostic_period': '2.5'})
    assert res.library == {'diagnostic_period': 2.5} and not res.errors
    assert resolve_params({}).library == {'diagnostic_period': 1.0}


@pytest.mark.parametrize('name,value', [
    ('map_topic', 'a/b'), ('map_topic', '/map'), ('map_topic', 'my map'), ('map_topic', '1map'),
    ('map_updates_topic', '/tb3_0/map_updates'), ('map_updates_topic', 'map updates'),
    ('merged_map_topic', 'merged map'), ('merged_map_topic', '~map'), ('merged_map_topic', 'a//b'),
    ('merged_map_frame', '/map'), ('merged_map_frame', 'my map'),
    ('robot_namespace_pattern', 'robots//tb3_*'), ('robot_namespace_pattern', 'tb3 *'),
    ('robots', ['tb3_0', 'tb3 1']), ('robots', ['0tb3']), ('robots', {'tb3_0': 1}),
    ('reference_robot', 'tb3 0'), ('reference_robot', 5),
    ('stale_map_timeout', -1), ('stale_map_timeout', 'long'),
])
def test_names_the_node_cannot_use_are_errors(name, value):
    """~map_topic a/b passed before, but discovery needs exactly /<robot>/<map_topic>: no robot
    was ever found. Each name is checked for what the node does with it."""
    res = resolve_params({name: value})
    assert len(res.errors) == 1 and '~%s ' % name in res.errors[0], res.errors
    assert getattr(res.config, name) == getattr(NodeConfig(), name)


def test_names_the_node_can_use_are_taken():
    res = resolve_params({'map_topic': ' gmap ', 'map_updates_topic': 'slam/map_updates',
                          'merged_map_topic': '/team/map', 'merged_map_frame': 'world',
                          'robot_namespace_pattern': '/robot_?/', 'robots': '/tb3_0 tb3_1 tb3_0',
                          'reference_robot': '/tb3_1', 'stale_map_timeout': 0})
    assert not res.errors and not res.warnings, (res.errors, res.warnings)
    c = res.config
    assert (c.map_topic, c.map_updates_topic, c.merged_map_topic) == ('gmap', 'slam/map_updates', '/team/map')
    assert (c.merged_map_frame, c.robot_namespace_pattern) == ('world', 'robot_?')
    assert c.robots == ['tb3_0', 'tb3_1'] and c.reference_robot == 'tb3_1'   # (as the maps are keyed)
    assert c.stale_map_timeout == 0.0   # 0 = off


def test_a_reference_robot_not_in_robots_is_an_error_and_the_first_of_robots_is_used():
    res = resolve_params({'robots': ['tb3_0', 'tb3_1'], 'reference_robot': 'tb3_2'})
    assert res.config.reference_robot == '' and res.config.robots == ['tb3_0', 'tb3_1']
    assert len(res.errors) == 1
    assert "~reference_robot 'tb3_2' is not one of ~robots (tb3_0 tb3_1)" in res.errors[0]
    assert 'first of ~robots by name, tb3_0' in res.errors[0]


def test_a_reference_robot_discovery_would_never_find_is_an_error():
    res = resolve_params({'robot_namespace_pattern': 'tb3_*', 'reference_robot': 'robot1'})
    assert res.config.reference_robot == '' and len(res.errors) == 1
    assert "~reference_robot 'robot1' does not match ~robot_namespace_pattern 'tb3_*'" in res.errors[0]
    assert resolve_params({'robot_namespace_pattern': 'robot*', 'reference_robot': 'robot1'}).errors == []


@pytest.mark.parametrize('topic,ttype,map_topic,pattern,robot', [
    ('/tb3_1/map', 'nav_msgs/OccupancyGrid', 'map', 'tb3_*', 'tb3_1'),
    # nested namespaces, as m-explore's map_merge finds them: the robot is the whole namespace
    ('/robots/r1/map', 'nav_msgs/OccupancyGrid', 'map', '*', 'robots/r1'),
    ('/robots/r1/map', 'nav_msgs/OccupancyGrid', 'map', 'robots/*', 'robots/r1'),
    ('/robots/r1/map', 'nav_msgs/OccupancyGrid', 'map', 'robots*', 'robots/r1'),   # robot_namespace: robots
    ('/a/b/c/gmap', 'nav_msgs/OccupancyGrid', 'gmap', '*', 'a/b/c'),
    ('/robots/r1/map', 'nav_msgs/OccupancyGrid', 'map', 'tb3_*', None),          # not matching the pattern
    ('/tb3_1/map', 'nav_msgs/OccupancyGrid', 'gmap', 'tb3_*', None),               # another map topic
    ('/tb3_1/map_updates', 'nav_msgs/OccupancyGrid', 'map', 'tb3_*', None),
    ('/tb3_1/map', 'map_msgs/OccupancyGridUpdate', 'map', 'tb3_*', None),         # not a grid
    ('/map', 'nav_msgs/OccupancyGrid', 'map', '*', None),                         # no namespace
    ('/tb3_1/mapx', 'nav_msgs/OccupancyGrid', 'map', '*', None),
])
def test_robot_of_map_topic_as_mexplore_matches_topics(topic, ttype, map_topic, pattern, robot):
    assert robot_of_map_topic(topic, ttype, map_topic, pattern) == robot


def test_a_nested_pattern_is_taken():
    res = resolve_params({'robot_namespace_pattern': '/robots/*'})
    assert not res.errors and res.config.robot_namespace_pattern == 'robots/*'
