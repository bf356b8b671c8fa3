"""The frames and topics our real-robot launch gives each robot's gmapping are exactly those
ROBOTIS's own Noetic nodes publish for that robot (slam:=rbpf's rbpf_slam gets the same:
test_launch_files.py; where ROS has no gmapping this parses with a stand-in package gmapping,
conftest.gmapping_stand_in).

ROBOTIS's launch files and the burger's URDF (noetic branch of ROBOTIS-GIT/turtlebot3, Apache-2.0,
read in place from ../shared/data/robotis/turtlebot3; skipped where absent) are resolved with roslaunch's own XML loader
the way the README tells users to run them (``ROS_NAMESPACE=tb3_0 roslaunch turtlebot3_bringup
turtlebot3_robot.launch multi_robot_name:=tb3_0 set_lidar_frame_id:=tb3_0/base_scan``, and
``turtlebot3_remote.launch multi_robot_name:=tb3_0``). What each of their nodes then publishes
follows from its parameters by the node's code, which is not in this repository; the rules are
written out below with where they come from:

* turtlebot3_core (OpenCR firmware, turtlebot3_core.ino ``updateTFPrefix``): reads
  ``~tf_prefix``; empty: odometry ``odom -> base_footprint``, joint states in ``base_link``;
  else ``<tf_prefix>/odom -> <tf_prefix>/base_footprint``, ``<tf_prefix>/base_link``. Topics
  ``odom`` and ``joint_states``, relative.
* robot_state_publisher (Noetic 1.15): every URDF link ``L`` as ``<tf_prefix>/L`` (``tf_prefix``
  searched from its private namespace up), from ``joint_states`` (relative).
* hls_lfcd_lds_driver (LDS-01, noetic): scans on ``scan`` (relative) in frame ``~frame_id``.
* ld08_driver (LDS-02, ROBOTIS-GIT/ld08_driver branch noetic, src/ld08_driver.cpp): scans on
  ``scan`` (relative) in frame ``base_scan``, always: it reads no ``frame_id`` parameter. This
  is why our launch republishes them in ``<robot>/base_scan`` (scan_frame_relay).
"""
import os
import tempfile
import xml.etree.ElementTree as ET

import pytest

roslaunch = pytest.importorskip('roslaunch')
import rospkg  # noqa: E402
from conftest import REPO, SHARED, gmapping_stand_in, shared_file  # noqa: E402,F401
from conftest import ROBOTIS as ROBOTIS_IN_SHARED  # noqa: E402
from roslaunch import substitution_args  # noqa: E402
from roslaunch.config import ROSLaunchConfig  # noqa: E402
from roslaunch.xmlloader import XmlLoader  # noqa: E402

ROBOTIS = os.path.join(SHARED, ROBOTIS_IN_SHARED)
BRINGUP = os.path.join(ROBOTIS, 'turtlebot3_bringup', 'launch')
BURGER = os.path.join(ROBOTIS, 'turtlebot3_description', 'urdf', 'turtlebot3_burger.urdf.xacro')
OURS = os.path.join(REPO, 'launch', 'turtlebot3_multi_slam.launch')


@pytest.fixture(scope='module', autouse=True)
def _gmapping_parses(gmapping_stand_in):  # noqa: F811
    """turtlebot3_multi_slam.launch's slam:=gmapping (its default) parses without gmapping."""
    yield


@pytest.fixture
def robotis_env(monkeypatch):
    """ROBOTIS's packages found (their copies in ../shared/data first: skipped where absent), the
    README's environment."""
    shared_file(ROBOTIS_IN_SHARED)
    monkeypatch.setenv('ROS_PACKAGE_PATH', ROBOTIS + os.pathsep + os.environ.get('ROS_PACKAGE_PATH', ''))
    monkeypatch.setenv('TURTLEBOT3_MODEL', 'burger')
    monkeypatch.setenv('LDS_MODEL', 'LDS-02')
    monkeypatch.delenv('ROS_NAMESPACE', raising=False)
    # roslaunch keeps one RosPack for $(find) per process: let it see the path above
    monkeypatch.setattr(substitution_args, '_rospack', None)
    try:
        rospkg.RosPack().get_path('multi_map_merge')
    except rospkg.ResourceNotFound:
        pytest.fail('multi_map_merge is not on ROS_PACKAGE_PATH: source the workspace first')
    assert rospkg.RosPack().get_path('turtlebot3_bringup') == os.path.join(ROBOTIS, 'turtlebot3_bringup')
    return monkeypatch


def resolve(path, argv, ns=None, text=None):
    """roslaunch's loader on a file (or its text), with ROS_NAMESPACE as the README sets it."""
    old = os.environ.pop('ROS_NAMESPACE', None)
    if ns:
        os.environ['ROS_NAMESPACE'] = ns
    try:
        cfg = ROSLaunchConfig()
        if text is None:
            XmlLoader().load(path, cfg, argv=list(argv), verbose=False)
        else:
            with tempfile.NamedTemporaryFile('w', suffix='.launch') as f:
                f.write(text)
                f.flush()
                XmlLoader().load(f.name, cfg, argv=list(argv), verbose=False)
        return cfg
    finally:
        os.environ.pop('ROS_NAMESPACE', None)
        if old is not None:
            os.environ['ROS_NAMESPACE'] = old


def node(cfg, type_):
    (n,) = [n for n in cfg.nodes if n.type == type_]
    return n


def private(cfg, n, name):
    key = n.namespace + n.name + '/' + name
    return cfg.params[key].value if key in cfg.params else None


def search_param(cfg, n, name):
    """ros::NodeHandle("~").searchParam: the private name, then up the node's namespaces."""
    ns = n.namespace + n.name + '/'
    while True:
        if ns + name in cfg.params:
            return cfg.params[ns + name].value
        if ns == '/':
            return None
        ns = ns[:ns.rstrip('/').rfind('/') + 1]


def topic(n, name):
    """A node's relative topic name resolved in its namespace, its remappings applied."""
    remaps = {a: b for a, b in n.remap_args}
    name = remaps.get(name, name)
    return name if name.startswith('/') else n.namespace + name


def prefixed(prefix, frame):
    return '%s/%s' % (prefix.strip('/'), frame) if prefix and prefix.strip('/') else frame


def burger_tree(urdf=None):
    """(links, {child link: (parent link, joint type)}) of ROBOTIS's burger URDF: ``urdf``, the
    robot_description xacro made, where xacro is installed; else the xacro file itself. Its
    links and joints are written out literally (no xacro macro makes them), so reading the
    xacro's XML gives what xacro would."""
    root = ET.fromstring(urdf) if urdf else ET.parse(BURGER).getroot()
    links = [el.get('name') for el in root if el.tag == 'link']
    assert links and not any('$' in n for n in links), links
    tree = {}
    for j in root:
        if j.tag == 'joint':
            tree[j.find('child').get('link')] = (j.find('parent').get('link'), j.get('type'))
    return links, tree


def fixed_chain(tree, parent, child):
    """The links from ``child`` up to ``parent`` through fixed joints only (robot_state_publisher
    publishes them on /tf_static whatever the joint states), or None."""
    chain = [child]
    while chain[-1] != parent:
        up = tree.get(chain[-1])
        if up is None or up[1] != 'fixed':
            return None
        chain.append(up[0])
    return chain


def robotis_robot(robot, lds_model):
    """What ROBOTIS's robot-side bringup publishes for ``robot`` (the README's command)."""
    os.environ['LDS_MODEL'] = lds_model
    cfg = resolve(os.path.join(BRINGUP, 'turtlebot3_robot.launch'),
                  ['multi_robot_name:=%s' % robot, 'set_lidar_frame_id:=%s/base_scan' % robot], ns=robot)
    core = node(cfg, 'serial_node.py')
    tf_prefix = private(cfg, core, 'tf_prefix') or ''
    out = {'odom_frame': prefixed(tf_prefix, 'odom'), 'base_frame': prefixed(tf_prefix, 'base_footprint'),
           'joint_states_frame': prefixed(tf_prefix, 'base_link'),
           'odom_topic': topic(core, 'odom'), 'joint_states_topic': topic(core, 'joint_states')}
    if lds_model == 'LDS-02':
        lds = node(cfg, 'ld08_driver')
        out['scan_frame'] = 'base_scan'          # hard-coded in ld08_driver (noetic)
        assert private(cfg, lds, 'frame_id') == '%s/base_scan' % robot   # given, and ignored
    else:
        lds = node(cfg, 'hlds_laser_publisher')
        out['scan_frame'] = private(cfg, lds, 'frame_id')
    out['scan_topic'] = topic(lds, 'scan')
    return out


def robotis_remote(robot):
    """robot_state_publisher as ROBOTIS's turtlebot3_remote.launch multi_robot_name:=<robot>
    starts it, in the robot's namespace: its tf_prefix and joint_states topic. Where xacro is
    not installed (Debian) the file is loaded without its description include (the only
    element that runs xacro), which the test checks is all that is left out."""
    path = os.path.join(BRINGUP, 'turtlebot3_remote.launch')
    root = ET.parse(path).getroot()
    text = None
    try:
        rospkg.RosPack().get_path('xacro')
    except rospkg.ResourceNotFound:
        (inc,) = [e for e in root if e.tag == 'include']
        assert inc.get('file').endswith('/launch/includes/description.launch.xml')
        root.remove(inc)
        assert [e.tag for e in root] == ['arg', 'arg', 'node']
        text = ET.tostring(root, encoding='unicode')
    group = ('<launch><group ns="%s"><include file="%s"><arg name="multi_robot_name" value="%s"/>'
             '</include></group></launch>')
    if text is None:
        cfg = resolve(None, [], text=group % (robot, path, robot))
    else:
        cfg = resolve(None, ['multi_robot_name:=%s' % robot], ns=robot, text=text)
    rsp = node(cfg, 'robot_state_publisher')
    desc = search_param(cfg, rsp, 'robot_description')
    assert (desc is not None) == (text is None)       # made by xacro exactly when it ran
    return search_param(cfg, rsp, 'tf_prefix'), topic(rsp, 'joint_states'), desc


def our_robot(robot, *args):
    cfg = resolve(OURS, ['robot_count:=1', 'first_tb3:=%s' % robot, 'urdf_file:=%s' % BURGER] + list(args))
    g = node(cfg, 'slam_gmapping')
    rsp = node(cfg, 'robot_state_publisher')
    frames = {k: private(cfg, g, k) for k in ('base_frame', 'odom_frame', 'map_frame')}
    gm_scan = topic(g, 'scan')
    relays = [n for n in cfg.nodes if n.type == 'scan_frame_relay']
    scan_frame = None          # the frame of what gmapping reads: the driver's, or the relay's
    relay_in = None
    if relays:
        (relay,) = relays
        assert topic(relay, private(cfg, relay, 'dst') or 'scan_framed') == gm_scan
        relay_in = topic(relay, private(cfg, relay, 'src') or 'scan')
        scan_frame = private(cfg, relay, 'frame_id')
    return dict(frames, scan_topic=gm_scan, relay_in=relay_in, scan_frame=scan_frame,
                tf_prefix=search_param(cfg, rsp, 'tf_prefix'), joint_states_topic=topic(rsp, 'joint_states'),
                robots=cfg.params['/map_merge/robots'].value)


def frames_published(robot, lds_model):
    """Every frame ROBOTIS's nodes publish for the robot: odometry's, robot_state_publisher's."""
    tf_prefix, js_topic, urdf = robotis_remote(robot)
    links, tree = burger_tree(urdf)
    r = robotis_robot(robot, lds_model)
    assert js_topic == r['joint_states_topic'] == '/%s/joint_states' % robot
    assert r['joint_states_frame'] in {prefixed(tf_prefix, n) for n in links}
    return r, tf_prefix, links, tree


@pytest.mark.parametrize('robot', ['tb3_0', 'scout'])
def test_gmapping_frames_are_what_robotis_nodes_publish(robotis_env, robot):
    r, tf_prefix, links, tree = frames_published(robot, 'LDS-02')
    assert tf_prefix == robot
    ours = our_robot(robot)
    assert ours['robots'] == robot
    # odometry: turtlebot3_core's own odom -> base_footprint
    assert ours['odom_frame'] == r['odom_frame'] == '%s/odom' % robot
    assert ours['base_frame'] == r['base_frame'] == '%s/base_footprint' % robot
    assert ours['map_frame'] == '%s/map' % robot
    # our robot_state_publisher is ROBOTIS's remote one: same prefix, same joint states
    assert ours['tf_prefix'] == tf_prefix and ours['joint_states_topic'] == r['joint_states_topic']
    # the laser: the robot's scans reach gmapping in a frame robot_state_publisher publishes,
    # fixed to the base frame gmapping is given (its laser pose)
    assert ours['relay_in'] == r['scan_topic'] == '/%s/scan' % robot
    assert ours['scan_topic'] == '/%s/scan_framed' % robot
    base = ours['base_frame'][len(robot) + 1:]
    laser = ours['scan_frame'][len(robot) + 1:]
    assert ours['scan_frame'] == prefixed(tf_prefix, laser) and laser in links
    assert ours['base_frame'] == prefixed(tf_prefix, base) and base in links
    assert fixed_chain(tree, base, laser) == ['base_scan', 'base_link', 'base_footprint']


def test_without_the_relay_the_lds02_scans_have_no_laser_pose(robotis_env):
    """What the relay is for, shown the same way: ld08_driver's frame is not one of the robot's."""
    r, tf_prefix, links, _ = frames_published('tb3_0', 'LDS-02')
    ours = our_robot('tb3_0', 'fix_scan_frame:=false')
    assert ours['relay_in'] is None and ours['scan_topic'] == r['scan_topic'] == '/tb3_0/scan'
    published = {prefixed(tf_prefix, n) for n in links}
    assert r['scan_frame'] == 'base_scan' and r['scan_frame'] not in published


def test_lds01_scans_need_no_relay(robotis_env):
    r, tf_prefix, links, tree = frames_published('tb3_1', 'LDS-01')
    ours = our_robot('tb3_1', 'fix_scan_frame:=false')
    assert ours['scan_topic'] == r['scan_topic'] == '/tb3_1/scan'
    assert r['scan_frame'] == 'tb3_1/base_scan' in {prefixed(tf_prefix, n) for n in links}
    assert ours['base_frame'] == r['base_frame'] and ours['odom_frame'] == r['odom_frame']
