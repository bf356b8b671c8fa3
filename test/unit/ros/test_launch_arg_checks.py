"""A launch arg outside its fixed set of values stops roslaunch with a message naming the arg,
its value and the values allowed (launch/includes/check_arg.launch), and nothing starts; so does
slam:=gmapping where ROS has no gmapping, with one line naming the package and slam:=rbpf
(launch/includes/check_package.launch, from includes/slam_robot.launch).

Where ROS has no gmapping, the rest of the module runs roslaunch with a stand-in package gmapping
(a package.xml alone, conftest.gmapping_stand_in) first on its ROS_PACKAGE_PATH, so the
slam:=gmapping path parses: the tests of the missing-gmapping line take it out again.

Runs roslaunch itself (its dry parse, ``roslaunch --nodes``, and once a real ``roslaunch``):
what a user types, the exit code and the text they read. No master is needed: the check fires
while roslaunch loads the files, before it contacts or starts one.
Run after sourcing the workspace's devel/setup.bash (``make unit`` does).
"""
import os
import re
import shutil
import signal
import socket
import subprocess

import pytest

pytest.importorskip('roslaunch')
import rospkg  # noqa: E402
from conftest import BURGER_XACRO, REPO, SHARED, gmapping_stand_in, shared_file  # noqa: E402,F401

LAUNCH = os.path.join(REPO, 'launch')
ANSI = re.compile(r'\x1b\[[0-9;]*m')
BURGER = os.path.join(SHARED, BURGER_XACRO)   # ROBOTIS's, in ../shared/data: skipped where absent


@pytest.fixture(scope='module', autouse=True)
def _gmapping_parses(gmapping_stand_in):  # noqa: F811
    STAND_IN[:] = [gmapping_stand_in] if gmapping_stand_in else []
    yield
    STAND_IN[:] = []


STAND_IN = []     # the stand-in gmapping's directory, while the module runs where ROS has none
# what roslaunch says for slam:=gmapping where ROS has no gmapping (includes/slam_robot.launch)
NO_GMAPPING = ('Value error: slam:=gmapping needs the ROS package gmapping (Ubuntu: sudo apt install '
               'ros-noetic-gmapping), which ROS cannot find here: use slam:=rbpf (multi_map_merge\'s own '
               'RBPF SLAM over MRPT)')


def without_stand_in():
    """The environment of roslaunch without the stand-in gmapping: ROS as it is here."""
    path = [d for d in os.environ.get('ROS_PACKAGE_PATH', '').split(os.pathsep)
            if not any(d == os.path.dirname(s) for s in STAND_IN)]
    return {'ROS_PACKAGE_PATH': os.pathsep.join(path)}


@pytest.fixture(scope='module', autouse=True)
def _workspace():
    if shutil.which('roslaunch') is None:
        pytest.skip('roslaunch is not installed')
    try:
        rospkg.RosPack().get_path('multi_map_merge')
    except rospkg.ResourceNotFound:
        pytest.fail('multi_map_merge is not on ROS_PACKAGE_PATH: '
                    'source the workspace devel/setup.bash (make build) first')


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def roslaunch(*args, dry=True, timeout=30, option='--nodes', env=None):
    """(exit code, stdout, stderr) of ``roslaunch [option] launch/<args...>`` (``dry``: with the
    option, by default --nodes), on a master URI nobody serves (nothing here may reach another
    master on the machine); ``env``: variables changed."""
    env = dict(os.environ, ROS_MASTER_URI='http://127.0.0.1:%d' % free_port(), **(env or {}))
    argv = ['roslaunch'] + ([option] if dry else []) + [os.path.join(LAUNCH, args[0])] + list(args[1:])
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                         universal_newlines=True)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        # it launched after all (the check did not fire): Ctrl-C makes roslaunch stop the master
        # and the nodes it started (they run in sessions of their own: a kill would orphan them)
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=60)
        pytest.fail('roslaunch %s ran for %d s instead of stopping:\n%s%s' % (' '.join(args), timeout, out, err))
    return p.returncode, ANSI.sub('', out), ANSI.sub('', err)


BAD = [
    (('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=gmaping'),
     'slam:=gmaping is not one of: recorded, gmapping, rbpf'),
    (('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=gmapping', 'robot_count:=5'),
     'robot_count:=5 is not one of: 1, 2, 3, 4 (slam:=gmapping runs one SLAM for each of tb3_0 .. tb3_3'),
    (('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=rbpf', 'robot_count:=5'),
     'robot_count:=5 is not one of: 1, 2, 3, 4 (slam:=rbpf runs one SLAM for each of tb3_0 .. tb3_3'),
    (('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=gmapping', 'robot_count:=0'),
     'robot_count:=0 is not one of: 1, 2, 3, 4'),
    (('team_bags_gmapping.launch', 'bag_0:=/tmp/a.bag', 'bag_1:=/tmp/b.bag', 'clock_bag:=2'),
     'clock_bag:=2 is not one of: 0, 1 (the indexes of the bags given'),
    (('team_bags_gmapping.launch', 'bag_0:=/tmp/a.bag', 'bag_1:=/tmp/b.bag', 'clock_bag:=5'),
     'clock_bag:=5 is not one of: 0, 1 (the indexes of the bags given'),
    (('team_bags_gmapping.launch', 'rviz:=false'),
     'clock_bag:=0 is not one of: (none) (the indexes of the bags given'),
    (('turtlebot3_multi_slam.launch', 'urdf_file:=' + BURGER, 'robot_count:=5'),
     'robot_count:=5 is not one of: 1, 2, 3, 4 (1 to 4 robots'),
    (('turtlebot3_multi_slam.launch', 'urdf_file:=' + BURGER, 'robot_count:=0'),
     'robot_count:=0 is not one of: 1, 2, 3, 4 (1 to 4 robots'),
    (('turtlebot3_multi_slam.launch', 'urdf_file:=' + BURGER, 'slam_on:=robto'),
     'slam_on:=robto is not one of: base, robot'),
    (('turtlebot3_multi_slam.launch', 'model:=burgr', 'robot_count:=1'),
     'model:=burgr is not one of: burger, waffle, waffle_pi'),
    (('turtlebot3_multi_slam.launch', 'urdf_file:=' + BURGER, 'slam:=rpbf'),
     'slam:=rpbf is not one of: gmapping, rbpf'),
    (('team_bags_gmapping.launch', 'bag_0:=/tmp/a.bag', 'slam:=recorded'),
     'slam:=recorded is not one of: gmapping, rbpf'),
    (('map_merge.launch', 'output:=scren'), 'output:=scren is not one of: screen, log'),
]


@pytest.mark.parametrize('args,message', BAD, ids=[' '.join(a[0:1] + a[-1:]) for a, _ in BAD])
def test_a_wrong_value_stops_roslaunch_naming_it(args, message):
    if 'urdf_file:=' + BURGER in args:
        shared_file(BURGER_XACRO)
    rc, out, err = roslaunch(*args)
    assert rc == 1, (rc, out, err)
    assert 'Value error: ' + message in err, err
    assert 'Traceback' not in err and 'list index out of range' not in err, err
    assert out.strip() == '', out      # no node listed: nothing would start


GOOD = [
    (('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=gmapping', 'robot_count:=1'),
     ['/rosbag_play', '/tf_relay', '/tb3_0/scan_frame_relay', '/tb3_0/slam_gmapping', '/map_merge', '/rviz']),
    (('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=rbpf', 'robot_count:=2', 'rviz:=false'),
     ['/rosbag_play', '/tf_relay', '/tb3_0/scan_frame_relay', '/tb3_0/rbpf_slam',
      '/tb3_1/scan_frame_relay', '/tb3_1/rbpf_slam', '/map_merge']),
    (('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=recorded', 'robot_count:=9', 'rviz:=false'),
     ['/rosbag_play', '/map_merge']),           # robot_count is not used by slam:=recorded
    (('team_bags_gmapping.launch', 'bag_0:=/tmp/a.bag', 'bag_2:=/tmp/c.bag', 'clock_bag:=2', 'rviz:=false'),
     ['/play_tb3_0', '/tb3_0/frame_prefix_relay', '/tb3_0/slam_gmapping',
      '/play_tb3_2', '/tb3_2/frame_prefix_relay', '/tb3_2/slam_gmapping', '/map_merge']),
    (('team_bags_gmapping.launch', 'bag_0:=/tmp/a.bag', 'slam:=rbpf', 'rviz:=false'),
     ['/play_tb3_0', '/tb3_0/frame_prefix_relay', '/tb3_0/rbpf_slam', '/map_merge']),
    (('turtlebot3_multi_slam.launch', 'urdf_file:=' + BURGER, 'robot_count:=1', 'model:=anything', 'rviz:=false'),
     ['/tb3_0/robot_state_publisher', '/tb3_0/scan_frame_relay', '/tb3_0/slam_gmapping', '/map_merge']),
    (('turtlebot3_multi_slam.launch', 'urdf_file:=' + BURGER, 'robot_count:=1', 'slam:=rbpf', 'rviz:=false'),
     ['/tb3_0/robot_state_publisher', '/tb3_0/scan_frame_relay', '/tb3_0/rbpf_slam', '/map_merge']),
]


@pytest.mark.parametrize('args,expected', GOOD, ids=[' '.join(a[0:1] + a[-3:]) for a, _ in GOOD])
def test_right_values_pass_the_checks(args, expected):
    if 'urdf_file:=' + BURGER in args:
        shared_file(BURGER_XACRO)
    rc, out, err = roslaunch(*args)
    assert rc == 0, (rc, out, err)
    assert sorted(out.split()) == sorted(expected), out


def test_real_roslaunch_stops_before_any_master_or_node():
    """Not the dry parse: ``roslaunch bag_replay.launch slam:=gmaping`` exits 1 with the message,
    having started no master (the URI is on a free port) and no process."""
    rc, out, err = roslaunch('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=gmaping', 'rviz:=false',
                             dry=False)
    assert rc == 1, (rc, out, err)
    assert 'Value error: slam:=gmaping is not one of: recorded, gmapping' in err, err
    for started in ('auto-starting new master', 'process[', 'started roslaunch server', 'ROS_MASTER_URI='):
        assert started not in out + err, out + err


@pytest.mark.parametrize('slam,exe', [('gmapping', 'slam_gmapping'), ('rbpf', 'rbpf_slam')])
def test_bag_replay_live_slam_relays_each_robots_scans_into_its_own_frame(slam, exe):
    """Bags of real LDS-02 robots have their scans in "base_scan": each SLAM reads the scans
    scan_frame_relay puts into tb3_N/base_scan; fix_scan_frame:=false reads /tb3_N/scan as it is."""
    from roslaunch.config import ROSLaunchConfig
    from roslaunch.xmlloader import XmlLoader

    def load(*args):
        cfg = ROSLaunchConfig()
        XmlLoader().load(os.path.join(LAUNCH, 'bag_replay.launch'), cfg, verbose=False,
                         argv=['bag:=/tmp/x.bag', 'slam:=' + slam, 'rviz:=false'] + list(args))
        return cfg
    cfg = load('robot_count:=3')
    relays = sorted(n.namespace for n in cfg.nodes if n.type == 'scan_frame_relay')
    assert relays == ['/tb3_0/', '/tb3_1/', '/tb3_2/']
    for i in range(3):
        assert cfg.params['/tb3_%d/scan_frame_relay/frame_id' % i].value == 'tb3_%d/base_scan' % i
        (g,) = [n for n in cfg.nodes if n.type == exe and n.namespace == '/tb3_%d/' % i]
        assert g.remap_args == [['scan', 'scan_framed']]
    cfg = load('robot_count:=2', 'fix_scan_frame:=false')
    assert [n for n in cfg.nodes if n.type == 'scan_frame_relay'] == []
    slams = [n for n in cfg.nodes if n.type == exe]
    assert len(slams) == 2 and all(n.remap_args == [] for n in slams)


@pytest.mark.parametrize('name', ['map_merge.launch', 'bag_replay.launch'])
def test_the_merger_s_earlier_parameters_are_cleared(name):
    """Parameters an earlier launch left under /map_merge (e.g. one of ours beside m-explore's
    name for it, where ours wins) are deleted before this launch sets its own."""
    from roslaunch.config import ROSLaunchConfig
    from roslaunch.xmlloader import XmlLoader
    cfg = ROSLaunchConfig()
    XmlLoader().load(os.path.join(LAUNCH, name), cfg, argv=['bag:=/tmp/x.bag'], verbose=False)
    assert '/map_merge/' in cfg.clear_params, cfg.clear_params


def test_every_node_that_loads_a_yaml_clears_its_parameters_first():
    """Issue 32: clear_params where a YAML is loaded. Every <node> of the package's launch files
    (launch/, launch/includes/, the test launch files) with a <rosparam command="load"> in it
    has clear_params="true", so a parameter an earlier launch left under its name cannot win
    over the YAML's (or its aliases)."""
    import glob
    import xml.etree.ElementTree as ET
    files = sorted(glob.glob(os.path.join(LAUNCH, '*.launch')) + glob.glob(os.path.join(LAUNCH, 'includes', '*.launch'))
                   + glob.glob(os.path.join(REPO, 'test', 'ros', '*.launch')))
    loading = []
    for path in files:
        for node in ET.parse(path).getroot().iter('node'):
            if any(r.get('command', 'load') == 'load' and r.get('file') for r in node.iter('rosparam')):
                loading.append((os.path.relpath(path, REPO), node.get('name')))
                assert node.get('clear_params') == 'true', (path, node.attrib)
    # the merger, each robot's SLAM (gmapping's or ours; and the test's second one, without the
    # relay), move_base
    assert ('launch/map_merge.launch', 'map_merge') in loading
    assert ('launch/includes/slam_robot.launch', 'slam_gmapping') in loading
    assert ('launch/includes/slam_robot.launch', 'rbpf_slam') in loading
    assert len(loading) >= 4, loading


MISSING_GMAPPING = [
    ('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=gmapping', 'robot_count:=1'),
    ('turtlebot3_multi_slam.launch', 'urdf_file:=' + BURGER),          # slam defaults to gmapping
    ('turtlebot3_multi_slam.launch', 'urdf_file:=' + BURGER, 'slam_on:=robot', 'robot_count:=2'),
    ('team_bags_gmapping.launch', 'bag_0:=/tmp/a.bag'),                 # so does it here
]


# every launch's dry parse; roslaunch's other dry parses and the real one on two of them
MISSING_CASES = ([(a, '--nodes') for a in MISSING_GMAPPING]
                 + [(MISSING_GMAPPING[0], o) for o in ('--args=/tb3_0/slam_gmapping', '--dump-params', None)]
                 + [(MISSING_GMAPPING[1], None)])


@pytest.mark.parametrize('args,option', MISSING_CASES,
                         ids=[' '.join(a[:1] + a[2:]) + ' ' + str(o) for a, o in MISSING_CASES])
def test_slam_gmapping_without_gmapping_stops_roslaunch_with_one_line(args, option):
    """Where ROS has no gmapping (Debian), slam:=gmapping stops roslaunch (its dry parses and the
    real one) before anything starts, with one line naming the package and slam:=rbpf; the same
    launch with slam:=rbpf goes on."""
    if not STAND_IN:
        pytest.skip('ROS has gmapping here: nothing is missing')
    rc, out, err = roslaunch(*args, 'rviz:=false', dry=option is not None, option=option, env=without_stand_in())
    if option == '--dump-params':
        # roslaunch's own way here: the loader's message after its own words, and exit code 0
        assert err.strip() == 'Unable to load file %s: %s' % (os.path.join(LAUNCH, args[0]),
                                                              NO_GMAPPING[len('Value error: '):]), err
        assert out.strip() == '', out       # no parameter dumped
    else:
        assert rc == 1, (rc, out, err)
        # the line, then roslaunch's own pointer to its log: no traceback, no ROS path list
        assert err.strip().splitlines() == [NO_GMAPPING,
                                            'The traceback for the exception was written to the log file'], err
        assert option is None or out.strip() == '', out
    for started in ('auto-starting new master', 'process[', 'started roslaunch server', 'ROS_MASTER_URI='):
        assert started not in out + err
    if option == '--nodes':
        rc, out, err = roslaunch(*args, 'rviz:=false', 'slam:=rbpf', env=without_stand_in())
        assert rc == 0 and 'rbpf_slam' in out, (rc, out, err)


def test_check_package_stops_on_a_package_ros_cannot_find():
    """check_package.launch itself, wherever gmapping is or not: a package ROS cannot find stops
    roslaunch with the message; one it finds (rosbag) passes; the name is data, not code."""
    check = os.path.join('includes', 'check_package.launch')
    rc, out, err = roslaunch(check, 'package:=no_such_package_xyz', 'needed_by:=thing x',
                             'install:=apt install it', 'instead:=thing y')
    assert rc == 1 and err.strip().splitlines()[0] == (
        'Value error: thing x needs the ROS package no_such_package_xyz (apt install it), which ROS '
        'cannot find here: use thing y'), err
    rc, out, err = roslaunch(check, "package:=x') or True or ('", 'needed_by:=a test')
    assert rc == 1 and "needs the ROS package x') or True or ('," in err, err
    rc, out, err = roslaunch(check, 'package:=rosbag', 'needed_by:=a test')
    assert (rc, out.strip()) == (0, ''), (rc, out, err)
