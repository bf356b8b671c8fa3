"""Every launch file parses with roslaunch's own loader (no master) and starts what it should.

gmapping and rviz are not in Debian, nor is robot_state_publisher by default: those packages are
tolerated when missing, nothing else is. Each robot's SLAM is checked both ways, slam:=gmapping
(gmapping's slam_gmapping) and slam:=rbpf (this package's rbpf_slam): where ROS has no gmapping,
slam_robot.launch stops roslaunch for slam:=gmapping, so this module parses with a stand-in
package gmapping (a package.xml alone, conftest.gmapping_stand_in) on ROS_PACKAGE_PATH: the
parse of gmapping's launch path, args, parameters, remaps and frames, without gmapping.
Run after sourcing the workspace's devel/setup.bash (``make unit`` does): without it the
package cannot be found and these tests fail rather than pass vacuously.
"""
import glob
import os
import shlex

import pytest
import yaml

roslaunch = pytest.importorskip('roslaunch')
import roslib.packages  # noqa: E402
import rospkg  # noqa: E402
from conftest import BURGER_XACRO, REPO, SHARED, gmapping_stand_in, shared_file  # noqa: E402,F401
from roslaunch.config import ROSLaunchConfig  # noqa: E402
from roslaunch.core import Node  # noqa: E402
from roslaunch.xmlloader import XmlLoader  # noqa: E402

LAUNCH = os.path.join(REPO, 'launch')
RVIZ = os.path.join(REPO, 'rviz', 'multi_map_merge.rviz')
MAY_BE_MISSING = {'gmapping', 'rviz', 'robot_state_publisher'}
SLAM_ROBOT = os.path.join('includes', 'slam_robot.launch')
SLAMS = ['gmapping', 'rbpf']
# slam:=X starts (package, executable = node name); both read the same gmapping YAML
SLAM_NODE = {'gmapping': ('gmapping', 'slam_gmapping'), 'rbpf': ('multi_map_merge', 'rbpf_slam')}
# slam:=X's default settings (slam_robot.launch's config (slam)), as loaded
def _yaml(name):
    with open(os.path.join(REPO, 'config', name)) as f:
        return yaml.safe_load(f)


SLAM_YAML = {'gmapping': _yaml('gmapping_lds02.yaml'), 'rbpf': _yaml('rbpf_lds02.yaml')}
COMPILED = {'rbpf_slam'}      # this package's C++ executables (devel/lib), not scripts/
TB3_BASE = os.path.join('includes', 'tb3_robot_base.launch')
CHECK_ARG = os.path.join('includes', 'check_arg.launch')   # starts nothing: it only checks
CHECK_PACKAGE = os.path.join('includes', 'check_package.launch')   # the same
# ROBOTIS's burger URDF (xacro, in ../shared/data), read as a file where xacro is not installed
# (Debian); a test giving it calls shared_file(BURGER_XACRO) first: skipped where it is absent
BURGER = os.path.join(SHARED, BURGER_XACRO)
URDF = 'urdf_file:=' + BURGER


STAND_IN = []     # the stand-in gmapping's directory, while the module runs without gmapping


@pytest.fixture(scope='module', autouse=True)
def _gmapping_parses(gmapping_stand_in):  # noqa: F811
    STAND_IN[:] = [gmapping_stand_in] if gmapping_stand_in else []
    yield
    STAND_IN[:] = []


def load(name, *args):
    """The ROSLaunchConfig of launch/<name> with roslaunch-style ``arg:=value`` args."""
    try:
        rospkg.RosPack().get_path('multi_map_merge')
    except rospkg.ResourceNotFound:
        pytest.fail('multi_map_merge is not on ROS_PACKAGE_PATH: '
                    'source the workspace devel/setup.bash (make build) first')
    cfg = ROSLaunchConfig()
    XmlLoader().load(os.path.join(LAUNCH, name), cfg, argv=list(args), verbose=False)
    return cfg


def nodes(cfg, type_):
    return [n for n in cfg.nodes if n.type == type_]


def param(cfg, name):
    assert name in cfg.params, 'parameter %s not set' % name
    return cfg.params[name].value


def check_executables(cfg):
    """Every node's package and executable are found (gmapping and rviz excepted, and the
    stand-in gmapping counts as none), ours are executable scripts of this repository or its
    built C++ nodes (rbpf_slam)."""
    rp = rospkg.RosPack()
    for n in cfg.nodes:
        try:
            path = rp.get_path(n.package)
            if path in STAND_IN:
                raise rospkg.ResourceNotFound(n.package)
        except rospkg.ResourceNotFound:
            assert n.package in MAY_BE_MISSING, 'package %s of node %s not found' % (n.package, n.name)
            continue
        assert os.path.isdir(path), path
        if n.package == 'multi_map_merge' and n.type not in COMPILED:
            exe = os.path.join(REPO, 'scripts', n.type)
            assert os.path.isfile(exe) and os.access(exe, os.X_OK), 'not executable: %s' % exe
        found = roslib.packages.find_node(n.package, n.type, rospack=rp)
        assert found, 'executable %s of package %s (node %s) not found' % (n.type, n.package, n.name)


def check_map_merge(cfg, reference=''):
    """Exactly one merger, from our package, with config/map_merge.yaml loaded privately."""
    (node,) = nodes(cfg, 'map_merge_node')
    assert node.package == 'multi_map_merge' and node.name == 'map_merge'
    assert node.namespace == '/'
    with open(os.path.join(REPO, 'config', 'map_merge.yaml')) as f:
        defaults = yaml.safe_load(f)
    assert param(cfg, '/map_merge/estimation_rate') == defaults['estimation_rate']
    assert param(cfg, '/map_merge/merge_rate') == defaults['merge_rate']
    assert param(cfg, '/map_merge/robot_namespace_pattern') == 'tb3_*'
    assert param(cfg, '/map_merge/merged_map_frame') == 'map'
    assert param(cfg, '/map_merge/reference_robot') == reference


def check_slam(cfg, robots, slam='gmapping'):
    """One SLAM node of ``slam`` per robot (gmapping: slam_gmapping, rbpf: rbpf_slam), in
    /<robot>/, with that robot's frames and the LDS-02 values; no node of the other."""
    pkg, exe = SLAM_NODE[slam]
    (other,) = [e for s, (_, e) in SLAM_NODE.items() if s != slam]
    assert nodes(cfg, other) == [], '%s started with slam:=%s' % (other, slam)
    g = nodes(cfg, exe)
    assert sorted(n.namespace for n in g) == sorted('/%s/' % r for r in robots)
    for n in g:
        assert n.package == pkg and n.name == exe
        assert n.output == 'log'        # its "update frame N" lines: lab/scans_processed.py reads them
        assert not n.remap_args or all(t.strip('/') != 'scan' for _, t in n.remap_args), \
            'scan must stay relative (/<robot>/scan)'
    for r in robots:
        p = '/%s/%s/' % (r, exe)
        assert param(cfg, p + 'base_frame') == '%s/base_footprint' % r
        assert param(cfg, p + 'odom_frame') == '%s/odom' % r
        assert param(cfg, p + 'map_frame') == '%s/map' % r
        assert param(cfg, p + 'maxRange') == 8.0
        assert param(cfg, p + 'maxUrange') == 3.0
        # each SLAM's own LDS-02 settings (rbpf_slam keeps a grid per particle: 30, not 100)
        assert param(cfg, p + 'particles') == SLAM_YAML[slam]['particles']
        assert param(cfg, p + 'delta') == 0.05
    return g


def check_rviz(cfg, wanted):
    r = nodes(cfg, 'rviz')
    if not wanted:
        assert r == [], 'rviz started with rviz:=false'
        return
    (node,) = r
    assert node.package == 'rviz'
    argv = shlex.split(node.args)
    assert argv[0] == '-d' and os.path.realpath(argv[1]) == os.path.realpath(RVIZ), node.args


def test_gmapping_config_values():
    with open(os.path.join(REPO, 'config', 'gmapping_lds02.yaml')) as f:
        g = yaml.safe_load(f)
    expected = dict(maxUrange=3.0, maxRange=8.0, map_update_interval=2.0, sigma=0.05, kernelSize=1,
                    lstep=0.05, astep=0.05, iterations=5, lsigma=0.075, ogain=3.0, lskip=0,
                    minimumScore=50, srr=0.1, srt=0.2, str=0.1, stt=0.2, linearUpdate=1.0,
                    angularUpdate=0.2, temporalUpdate=0.5, resampleThreshold=0.5, particles=100,
                    xmin=-10, ymin=-10, xmax=10, ymax=10, delta=0.05, llsamplerange=0.01,
                    llsamplestep=0.01, lasamplerange=0.005, lasamplestep=0.005)
    assert g == expected
    assert not {'base_frame', 'odom_frame', 'map_frame'} & set(g), 'frames are per robot: set in launch'


def test_map_merge_launch_loads_config():
    cfg = load('map_merge.launch', 'reference_robot:=tb3_2')
    check_map_merge(cfg, reference='tb3_2')
    assert len(cfg.nodes) == 1
    check_executables(cfg)


def test_reference_robot_of_the_config_yaml_is_kept_unless_the_arg_is_given(tmp_path):
    """A user's config YAML that names the reference robot is not overwritten by the launch
    file's empty default arg; the arg, when given, wins."""
    with open(os.path.join(REPO, 'config', 'map_merge.yaml')) as f:
        mine = dict(yaml.safe_load(f), reference_robot='tb3_3')
    cfg_file = tmp_path / 'mine.yaml'
    cfg_file.write_text(yaml.safe_dump(mine))
    cfg = load('map_merge.launch', 'config:=%s' % cfg_file)
    assert param(cfg, '/map_merge/reference_robot') == 'tb3_3'
    cfg = load('map_merge.launch', 'config:=%s' % cfg_file, 'reference_robot:=tb3_1')
    assert param(cfg, '/map_merge/reference_robot') == 'tb3_1'
    # its default is "(config)" (roslaunch --ros-args calls an arg with an empty default required);
    # an empty reference_robot:= still means the config's, as it did
    cfg = load('map_merge.launch', 'config:=%s' % cfg_file, 'reference_robot:=')
    assert param(cfg, '/map_merge/reference_robot') == 'tb3_3'
    # robots: "(discover)" or empty leaves the config's list (empty: discovery)
    assert param(load('map_merge.launch', 'robots:='), '/map_merge/robots') == []
    assert param(load('map_merge.launch'), '/map_merge/robots') == []
    assert param(load('map_merge.launch', 'robots:=a b'), '/map_merge/robots') == 'a b'


# what `roslaunch --ros-args FILE` lists under "Required Arguments:" (roslaunch.arg_dump: every
# arg whose default is empty or absent): only what a user must give, and roslaunch's own quirks
REQUIRED = {
    'turtlebot3_multi_slam.launch': set(),
    'map_merge.launch': set(),
    'bag_replay.launch': {'bag'},
    # a bag per robot: tb3_0's is required, the others' empty value means "no such robot";
    # clock_path is a value= arg computed from them, which roslaunch lists whenever it is empty
    'replay_robot_bags.launch': {'bag_0', 'bag_1', 'bag_2', 'bag_3'},
    'team_bags_gmapping.launch': {'bag_0', 'bag_1', 'bag_2', 'bag_3', 'clock_path'},
}


@pytest.mark.parametrize('name', sorted(REQUIRED))
def test_ros_args_lists_as_required_only_what_is(name):
    """issue 32: reference_robot, urdf_file (and robots, particles) have non-empty defaults that
    mean "not given", so --ros-args shows them as optional, with that default."""
    from roslaunch.arg_dump import get_args
    args = get_args([os.path.join(LAUNCH, name)])
    assert {a for a, (_doc, default) in args.items() if not default} == REQUIRED[name]
    for a, default in (('reference_robot', '(config)'), ('urdf_file', '(model)'), ('robots', '(discover)'),
                       ('particles', '(config)')):
        if a in args:
            assert args[a][1] == default and default in args[a][0], (a, args[a])


def test_the_urdf_file_default_is_the_xacro_of_the_model():
    """urdf_file's default "(model)" (and an empty urdf_file:=, as before) is turtlebot3_description's
    xacro of model; a file is read as it is. Where xacro or turtlebot3_description is not installed
    (Debian) the default cannot load: roslaunch names what it did not find."""
    for args in ((), ('urdf_file:=',)):
        try:
            cfg = load(TB3_BASE, 'robot:=tb3_0', 'slam:=rbpf', *args)
        except (roslaunch.core.RLException, rospkg.ResourceNotFound) as e:
            assert 'xacro' in str(e) or 'turtlebot3_description' in str(e), e
            continue
        assert 'turtlebot3_burger.urdf.xacro' in param(cfg, '/tb3_0/robot_description') or \
            '<robot' in param(cfg, '/tb3_0/robot_description')
    shared_file(BURGER_XACRO)
    cfg = load(TB3_BASE, 'robot:=tb3_0', 'slam:=rbpf', URDF, 'model:=not_a_model')   # a file: the model is not checked
    with open(BURGER) as f:
        assert param(cfg, '/tb3_0/robot_description') == f.read()


@pytest.mark.parametrize('slam', SLAMS)
def test_slam_robot_include(slam):
    cfg = load(SLAM_ROBOT, 'ns:=tb3_7', 'slam:=' + slam)
    check_slam(cfg, ['tb3_7'], slam)
    assert len(cfg.nodes) == 1
    check_executables(cfg)


LAUNCHES_WITH_SLAM = [
    ('turtlebot3_multi_slam.launch', [URDF, 'robot_count:=2', 'slam_on:=robot'], ['tb3_0', 'tb3_1']),
    ('bag_replay.launch', ['bag:=/tmp/x.bag', 'robot_count:=3'], ['tb3_0', 'tb3_1', 'tb3_2']),
    ('team_bags_gmapping.launch', ['bag_0:=/tmp/a.bag', 'bag_2:=/tmp/c.bag', 'particles:=12'], ['tb3_0', 'tb3_2']),
    (SLAM_ROBOT, ['ns:=tb3_5', 'scan_topic:=scan_x', 'machine:=', 'base_frame:=base_link'], ['tb3_5']),
]


@pytest.mark.parametrize('name,args,robots', LAUNCHES_WITH_SLAM, ids=[n for n, _, _ in LAUNCHES_WITH_SLAM])
def test_rbpf_gets_what_gmapping_gets(name, args, robots):
    """slam:=rbpf starts rbpf_slam where slam:=gmapping starts slam_gmapping, and nothing else
    changes: the same namespaces, parameters (frames, particles given), remaps, machines; every
    other node and parameter the same. The SLAM YAML is each SLAM's own by default (compared
    apart: check_slam), the one given otherwise."""
    got = {}
    for slam in SLAMS:
        cfg = load(name, 'slam:=' + slam, *args)
        exe = SLAM_NODE[slam][1]
        if name in ('turtlebot3_multi_slam.launch', 'bag_replay.launch'):   # the LDS-02 YAML, base_footprint
            check_slam(cfg, robots, slam)
        slam_nodes = sorted((n.namespace, tuple(map(tuple, n.remap_args)), n.machine_name, n.output)
                            for n in nodes(cfg, exe))
        assert len(slam_nodes) == len(robots)
        params = {k.replace('/%s/' % exe, '/SLAM/'): p.value for k, p in cfg.params.items()}
        if name != 'team_bags_gmapping.launch':    # each SLAM's own default YAML: checked by check_slam
            own = set(SLAM_YAML['gmapping']) | set(SLAM_YAML['rbpf'])
            params = {k: v for k, v in params.items() if not ('/SLAM/' in k and k.rsplit('/', 1)[1] in own)}
        others = sorted((n.package, n.type, n.namespace, n.name, tuple(map(tuple, n.remap_args)))
                        for n in cfg.nodes if n.type != exe)
        got[slam] = (slam_nodes, params, others, sorted(cfg.clear_params))
    assert got['rbpf'][0] == got['gmapping'][0]
    assert got['rbpf'][1] == got['gmapping'][1]
    assert got['rbpf'][2] == got['gmapping'][2]
    g_clear = [c.replace('/slam_gmapping/', '/rbpf_slam/') for c in got['gmapping'][3]]
    assert got['rbpf'][3] == sorted(g_clear)
    assert {'/%s/SLAM/map_frame' % r for r in robots} <= set(got['rbpf'][1])   # compared, not absent
    if name == 'team_bags_gmapping.launch':
        assert {v for k, v in got['rbpf'][1].items() if k.endswith('/SLAM/particles')} == {12}


def check_robots_rviz(cfg, robots):
    """rviz started by robots_rviz for exactly these robots."""
    (node,) = nodes(cfg, 'robots_rviz')
    assert node.package == 'multi_map_merge' and node.name == 'rviz' and node.namespace == '/'
    argv = shlex.split(node.args)
    assert argv[:1] == ['--robots'] and argv[1].split() == list(robots), node.args
    return argv


def check_robot_base(cfg, robots, machine=False, slam='gmapping'):
    """Per robot, in /<robot>/: robot_state_publisher with tf_prefix <robot> (ROBOTIS's
    turtlebot3_remote.launch multi_robot_name), the scan frame relay into the SLAM."""
    for kind in ('robot_state_publisher', 'scan_frame_relay'):
        assert sorted(n.namespace for n in nodes(cfg, kind)) == sorted('/%s/' % r for r in robots), kind
    for r in robots:
        assert param(cfg, '/%s/robot_state_publisher/tf_prefix' % r) == r
        assert param(cfg, '/%s/scan_frame_relay/frame_id' % r) == '%s/base_scan' % r
        assert '/%s/robot_description' % r in cfg.params
        (g,) = [n for n in nodes(cfg, SLAM_NODE[slam][1]) if n.namespace == '/%s/' % r]
        assert g.remap_args == [['scan', 'scan_framed']]
    for n in cfg.nodes:
        if n.namespace != '/':
            robot = n.namespace.strip('/')
            assert n.machine_name == (robot if machine else None), (n.name, n.machine_name)
            if machine:
                m = cfg.machines[robot]
                assert m.env_loader == '/home/ubuntu/catkin_ws/devel/lib/multi_map_merge/env_loader'
                assert m.user == 'ubuntu'


@pytest.mark.parametrize('slam', SLAMS)
@pytest.mark.parametrize('count,rviz', [(1, 'false'), (2, 'true'), (3, 'false'), (4, 'true')])
def test_multi_slam(count, rviz, slam):
    shared_file(BURGER_XACRO)
    cfg = load('turtlebot3_multi_slam.launch', URDF, 'robot_count:=%d' % count, 'rviz:=%s' % rviz, 'slam:=' + slam)
    robots = ['tb3_%d' % i for i in range(count)]
    check_slam(cfg, robots, slam)
    check_robot_base(cfg, robots, slam=slam)
    check_map_merge(cfg)
    assert param(cfg, '/map_merge/robots') == ' '.join(robots)
    if rviz == 'true':
        check_robots_rviz(cfg, robots)
    else:
        assert nodes(cfg, 'robots_rviz') == [] and nodes(cfg, 'rviz') == []
    assert '/use_sim_time' not in cfg.params      # real robots: wall time
    check_executables(cfg)


def test_multi_slam_defaults_and_names():
    shared_file(BURGER_XACRO)
    cfg = load('turtlebot3_multi_slam.launch', URDF)
    check_slam(cfg, ['tb3_0', 'tb3_1', 'tb3_2', 'tb3_3'], 'gmapping')   # slam defaults to gmapping, as ROBOTIS's
    check_robots_rviz(cfg, ['tb3_0', 'tb3_1', 'tb3_2', 'tb3_3'])
    assert cfg.machines.keys() <= {''}            # slam_on:=base: everything on this machine
    cfg = load('turtlebot3_multi_slam.launch', URDF, 'robot_count:=2', 'first_tb3:=alpha',
               'second_tb3:=beta', 'reference_robot:=beta')
    check_slam(cfg, ['alpha', 'beta'])
    check_robot_base(cfg, ['alpha', 'beta'])
    check_map_merge(cfg, reference='beta')


def test_multi_slam_on_the_robots():
    """slam_on:=robot: each robot's nodes on a <machine> of that robot (address, ssh port, user, env
    loader, the time its roslaunch has to register)."""
    shared_file(BURGER_XACRO)
    cfg = load('turtlebot3_multi_slam.launch', URDF, 'robot_count:=2', 'slam_on:=robot',
               'first_tb3_address:=10.0.0.21', 'second_tb3_address:=burger2.local')
    check_robot_base(cfg, ['tb3_0', 'tb3_1'], machine=True)
    check_robot_base(load('turtlebot3_multi_slam.launch', URDF, 'robot_count:=2', 'slam_on:=robot', 'slam:=rbpf'),
                     ['tb3_0', 'tb3_1'], machine=True, slam='rbpf')
    assert cfg.machines['tb3_0'].address == '10.0.0.21'
    assert cfg.machines['tb3_1'].address == 'burger2.local'
    assert [(m.ssh_port, m.timeout) for m in (cfg.machines['tb3_0'], cfg.machines['tb3_1'])] == [(22, 30.0)] * 2
    cfg = load('turtlebot3_multi_slam.launch', URDF, 'robot_count:=2', 'slam_on:=robot', 'robot_ssh_port:=2222',
               'robot_timeout:=45', 'robot_user:=tb3', 'env_loader:=/opt/robot/env.sh')
    for r in ('tb3_0', 'tb3_1'):
        m = cfg.machines[r]
        assert (m.address, m.ssh_port, m.timeout, m.user, m.env_loader) == (r, 2222, 45.0, 'tb3', '/opt/robot/env.sh')
    (merger,) = nodes(cfg, 'map_merge_node')
    assert merger.machine_name is None            # the merger stays on the base station
    # a typo is an error, not SLAM somewhere (includes/check_arg.launch; test_launch_arg_checks.py)
    with pytest.raises(ValueError, match=r'slam_on:=robto is not one of: base, robot'):
        load('turtlebot3_multi_slam.launch', URDF, 'slam_on:=robto')


def test_robot_names_reach_the_merger_and_rviz(tmp_path):
    """Names other than tb3_*: the merger's ~robots (read by the node as its robot list) and
    the rviz config robots_rviz writes (one map display, one prior tool per robot, the
    template's window layout unchanged)."""
    shared_file(BURGER_XACRO)
    import subprocess
    import sys

    from multi_map_merge.ros.params import resolve_params
    cfg = load('turtlebot3_multi_slam.launch', URDF, 'robot_count:=3', 'first_tb3:=alpha',
               'second_tb3:=beta', 'third_tb3:=scout_7')
    names = ['alpha', 'beta', 'scout_7']
    res = resolve_params({k.split('/')[-1]: p.value for k, p in cfg.params.items()
                          if k.startswith('/map_merge/')})
    assert res.errors == [] and res.config.robots == names
    argv = check_robots_rviz(cfg, names)
    out = tmp_path / 'team.rviz'
    script = os.path.join(REPO, 'scripts', 'robots_rviz')
    r = subprocess.run([sys.executable, script] + argv + ['--write-only', '--output', str(out),
                       '__name:=rviz', '__log:=/tmp/x.log'], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    with open(out) as f:
        written = yaml.safe_load(f)
    with open(RVIZ) as f:
        template = yaml.safe_load(f)
    assert written['Window Geometry'] == template['Window Geometry']
    assert written['Panels'] == template['Panels']
    vm = written['Visualization Manager']
    maps = [(d['Name'], d['Topic']) for d in vm['Displays'] if d['Class'] == 'rviz/Map']
    assert maps == [('Merged map', '/map')] + [('%s map' % n, '/%s/map' % n) for n in names]
    tools = [t['Topic'] for t in vm['Tools'] if t['Class'] == 'rviz/SetInitialPose']
    assert tools == ['/%s/map_merge/prior' % n for n in names]
    others = [d for d in vm['Displays'] if not d.get('Topic', '').endswith('/map')]
    assert others == [d for d in template['Visualization Manager']['Displays']
                      if not d.get('Topic', '').endswith('/map')]
    bad = subprocess.run([sys.executable, script, '--robots', 'a-b', '--write-only', '--output',
                          str(tmp_path / 'x.rviz')], capture_output=True, text=True)
    assert bad.returncode == 2 and 'not valid ROS names: a-b' in bad.stderr


def check_play(cfg, bag, rate='1.0', start='0'):
    (play,) = nodes(cfg, 'play')
    assert play.package == 'rosbag'
    argv = shlex.split(play.args)
    assert '--clock' in argv and argv[-1] == bag
    assert argv[argv.index('-r') + 1] == rate and argv[argv.index('-s') + 1] == start
    assert param(cfg, '/use_sim_time') is True


def test_bag_replay_recorded():
    cfg = load('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=recorded', 'rviz:=false')
    check_play(cfg, '/tmp/x.bag')
    assert nodes(cfg, 'slam_gmapping') == [] and nodes(cfg, 'rbpf_slam') == []   # the bag's own /tb3_N/map are merged
    check_map_merge(cfg)
    check_rviz(cfg, False)
    assert sorted(n.type for n in cfg.nodes) == ['map_merge_node', 'play']
    check_executables(cfg)


@pytest.mark.parametrize('slam', SLAMS)
@pytest.mark.parametrize('count', [2, 4])
def test_bag_replay_live_slam(count, slam):
    cfg = load('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=' + slam, 'rviz:=true',
               'robot_count:=%d' % count, 'rate:=2.5', 'start:=30')
    check_play(cfg, '/tmp/x.bag', rate='2.5', start='30')
    check_slam(cfg, ['tb3_%d' % i for i in range(count)], slam)
    check_map_merge(cfg)
    check_rviz(cfg, True)
    check_executables(cfg)


@pytest.mark.parametrize('slam', SLAMS)
def test_bag_replay_live_slam_moves_the_recorded_slam_aside(slam):
    cfg = load('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=' + slam, 'rviz:=false')
    (play,) = nodes(cfg, 'play')
    remaps = dict(play.remap_args)
    assert remaps['/tf'] == '/tf_bag'                   # tf_relay passes it on without map -> odom
    assert all(remaps['/tb3_%d/map' % i] == '/tb3_%d/map_recorded' % i for i in range(4))
    assert len(nodes(cfg, 'tf_relay')) == 1
    cfg = load('bag_replay.launch', 'bag:=/tmp/x.bag', 'slam:=recorded', 'rviz:=false')
    assert dict(nodes(cfg, 'play')[0].remap_args) == {} and nodes(cfg, 'tf_relay') == []


@pytest.mark.parametrize('bags', [['/b/a.bag'], ['/b/a.bag', '/b/b.bag', '/b/c.bag'],
                                  ['/b/a.bag', '/b/b.bag', '/b/c.bag', '/b/d.bag']])
def test_replay_robot_bags(bags):
    cfg = load('replay_robot_bags.launch', 'rate:=4', 'rviz:=false',
               *['bag_%d:=%s' % (i, b) for i, b in enumerate(bags)])
    plays = sorted(nodes(cfg, 'play'), key=lambda n: n.name)
    assert [n.name for n in plays] == ['play_tb3_%d' % i for i in range(len(bags))]
    for i, (n, b) in enumerate(zip(plays, bags)):
        argv = shlex.split(n.args)
        assert argv[-1] == b and argv[argv.index('-r') + 1] == '4' and '--clock' not in argv
        remaps = dict(n.remap_args)
        assert remaps['/map'] == '/tb3_%d/map' % i and remaps['/tf'] == '/tb3_%d/tf_recorded' % i
    assert param(cfg, '/use_sim_time') is False
    check_map_merge(cfg)
    check_rviz(cfg, False)
    check_executables(cfg)


def test_bag_replay_defaults():
    cfg = load('bag_replay.launch', 'bag:=/tmp/x.bag')
    assert nodes(cfg, 'slam_gmapping') == [] and nodes(cfg, 'rbpf_slam') == []   # slam defaults to recorded
    check_rviz(cfg, True)


def test_missing_packages_tolerated_only_for_gmapping_and_rviz():
    for pkg, exe in [('no_such_package_xyz', 'node'), ('multi_map_merge', 'no_such_script'),
                     ('rosbag', 'no_such_executable')]:
        cfg = ROSLaunchConfig()
        cfg.add_node(Node(pkg, exe, name='n'), verbose=False)
        with pytest.raises(AssertionError):
            check_executables(cfg)
    cfg = ROSLaunchConfig()
    for pkg, exe in [('gmapping', 'slam_gmapping'), ('rviz', 'rviz'), ('rosbag', 'play')]:
        cfg.add_node(Node(pkg, exe, name=exe), verbose=False)
    check_executables(cfg)


# Arguments each launch file needs (the rest keep their defaults); a new launch file without an
# entry here is loaded with none.
REQUIRED_ARGS = {
    'bag_replay.launch': ['bag:=/tmp/x.bag'],
    'replay_robot_bags.launch': ['bag_0:=/tmp/x.bag'],
    SLAM_ROBOT: ['ns:=tb3_0', 'slam:=rbpf'],
    'turtlebot3_multi_slam.launch': [URDF],
    TB3_BASE: ['robot:=tb3_0', 'slam:=rbpf', URDF],
    'team_bags_gmapping.launch': ['bag_0:=/tmp/x.bag', 'bag_1:=/tmp/y.bag'],
    CHECK_ARG: ['name:=slam', 'value:=gmapping', 'allowed:=recorded gmapping'],
    CHECK_PACKAGE: ['package:=rosbag', 'needed_by:=a test'],
    os.path.join('includes', 'team_bag_robot.launch'): [
        'ns:=tb3_0', 'bag:=/tmp/x.bag', 'clock:=true', 'clock_path:=/tmp/x.bag', 'rate:=1', 'scan_topic:=/scan',
        'odom_topic:=/odom', 'base_frame:=base_link', 'slam:=rbpf',
        'gmapping_config:=' + os.path.join(LAUNCH, '..', 'config', 'gmapping_default.yaml')],
}
ALL_LAUNCH = sorted(os.path.relpath(p, LAUNCH)
                    for p in glob.glob(os.path.join(LAUNCH, '**', '*.launch'), recursive=True))


def test_launch_files_found():
    assert set(ALL_LAUNCH) >= {'map_merge.launch', 'turtlebot3_multi_slam.launch',
                               'bag_replay.launch', 'team_bags_gmapping.launch', SLAM_ROBOT, CHECK_PACKAGE}


@pytest.mark.parametrize('name', ALL_LAUNCH)
def test_every_launch_file_parses_and_its_nodes_exist(name):
    if URDF in REQUIRED_ARGS.get(name, []):
        shared_file(BURGER_XACRO)
    cfg = load(name, *REQUIRED_ARGS.get(name, []))
    assert cfg.nodes or name in (CHECK_ARG, CHECK_PACKAGE), '%s starts no node' % name
    check_executables(cfg)
    if not name.startswith('includes'):  # every top-level launch file runs the merger
        check_map_merge(cfg)


def rviz_docks(state_hex):
    """{panel name: visible} of the dock widgets in rviz's ``QMainWindow State`` (Qt's saveState:
    each dock is 0xfb, its object name as a QString (UTF-16, length-prefixed), a flags byte whose
    bit 0 is 'visible')."""
    b = bytes.fromhex(state_hex)
    docks, i = {}, b.find(b'\xfb')
    while i >= 0:
        n = int.from_bytes(b[i + 1:i + 5], 'big')
        if 0 < n <= 200 and n % 2 == 0 and i + 5 + n < len(b):
            name = b[i + 5:i + 5 + n].decode('utf-16-be', 'replace')
            if name.isprintable() and '\ufffd' not in name:
                docks[name] = bool(b[i + 5 + n] & 1)
                i = b.find(b'\xfb', i + 6 + n)
                continue
        i = b.find(b'\xfb', i + 1)
    return docks


def test_rviz_config():
    with open(RVIZ) as f:
        cfg = yaml.safe_load(f)
    # a saved layout: without a QMainWindow State rviz 1.14 docks every panel left over ~90% of the
    # window. Only Displays shows (left, narrow); the others are one click away in the Panels menu.
    # test/ros/rviz_screenshot.test checks the picture itself.
    geo = cfg['Window Geometry']
    assert geo['Width'] >= 1024 and geo['Height'] >= 700 and geo['X'] == 0 and geo['Y'] == 0
    docks = rviz_docks(geo['QMainWindow State'])
    assert docks == {'Displays': True, 'Selection': False, 'Tool Properties': False, 'Views': False,
                     'Time': False}, docks
    assert {p['Name'] for p in cfg['Panels']} == set(docks)
    assert {p['Class'] for p in cfg['Panels']} >= {'rviz/Displays', 'rviz/Views'}
    vm = cfg['Visualization Manager']
    assert vm['Class'] == '' and vm['Global Options']['Fixed Frame'] == 'map'
    maps = {d['Topic']: d for d in vm['Displays'] if d['Class'] == 'rviz/Map'}
    assert maps['/map']['Enabled'] is True and maps['/map']['Name'] == 'Merged map'
    for i in range(4):
        d = maps['/tb3_%d/map' % i]
        assert d['Alpha'] == 0.4 and d['Enabled'] is False
    # one "2D Pose Estimate" per robot, publishing its prior for the merger
    assert [t['Topic'] for t in vm['Tools'] if t['Class'] == 'rviz/SetInitialPose'] == [
        '/tb3_%d/map_merge/prior' % i for i in range(4)]
    (tf,) = [d for d in vm['Displays'] if d['Class'] == 'rviz/TF']
    assert tf['Enabled'] is True and tf['Show Names'] is True
    (markers,) = [d for d in vm['Displays'] if d['Class'] == 'rviz/MarkerArray']
    assert markers['Enabled'] is True and markers['Marker Topic'] == '/map_merge/markers'
    assert vm['Views']['Current']['Class'] == 'rviz/TopDownOrtho'


@pytest.mark.parametrize('slam', SLAMS + [None])
def test_team_bags_gmapping_prefixes_each_robot_onto_one_clock(slam):
    cfg = load('team_bags_gmapping.launch', 'bag_0:=/tmp/a.bag', 'bag_1:=/tmp/b.bag', 'bag_2:=/tmp/c.bag',
               'clock_bag:=1', 'rate:=3', 'rviz:=false', *(['slam:=' + slam] if slam else []))
    exe = SLAM_NODE[slam or 'gmapping'][1]      # slam defaults to gmapping
    assert sorted(n.namespace for n in nodes(cfg, exe)) == ['/tb3_0/', '/tb3_1/', '/tb3_2/']
    plays = {n.name: n for n in nodes(cfg, 'play')}
    assert sorted(plays) == ['play_tb3_0', 'play_tb3_1', 'play_tb3_2']
    for k, bag in enumerate(['/tmp/a.bag', '/tmp/b.bag', '/tmp/c.bag']):
        argv = shlex.split(plays['play_tb3_%d' % k].args)
        # only the clock bag's player publishes /clock; every player plays its own bag at the rate
        assert ('--clock' in argv) == (k == 1) and argv[-1] == bag and argv[argv.index('-r') + 1] == '3'
        assert dict(plays['play_tb3_%d' % k].remap_args) == {
            '/scan': '/tb3_%d/scan_raw' % k, '/odom': '/tb3_%d/odom_raw' % k, '/tf': '/tb3_%d/tf_raw' % k}
    relays = {n.namespace.strip('/'): n for n in nodes(cfg, 'frame_prefix_relay')}
    assert sorted(relays) == ['tb3_0', 'tb3_1', 'tb3_2']
    params = {p.key: p.value for p in cfg.params.values()}
    for k, bag in enumerate(['/tmp/a.bag', '/tmp/b.bag', '/tmp/c.bag']):
        assert params['/tb3_%d/frame_prefix_relay/bag' % k] == bag
        assert params['/tb3_%d/frame_prefix_relay/clock_bag' % k] == '/tmp/b.bag'
        assert params['/tb3_%d/%s/base_frame' % (k, exe)] == 'tb3_%d/base_link' % k
        assert params['/tb3_%d/%s/odom_frame' % (k, exe)] == 'tb3_%d/odom' % k
        assert params['/tb3_%d/%s/map_frame' % (k, exe)] == 'tb3_%d/map' % k
        assert params['/tb3_%d/%s/particles' % (k, exe)] == 30      # config/gmapping_default.yaml
    assert params['/use_sim_time'] is True


def _move_base_node(xml_text, robot_arg=None):
    """(node attributes, [(rosparam file name, ns)], [(param, value)], remaps) of the move_base
    node in a launch file's text; ``robot_arg``: the value of $(arg robot), $(arg model) burger."""
    import xml.etree.ElementTree as ET
    if robot_arg is not None:
        xml_text = xml_text.replace('$(arg robot)', robot_arg).replace('$(arg model)', 'burger')
    (node,) = [n for n in ET.fromstring(xml_text).iter('node') if n.get('type') == 'move_base']
    files = [(os.path.basename(r.get('file')), r.get('ns')) for r in node.iter('rosparam')]
    params = [(p.get('name'), p.get('value')) for p in node.iter('param')]
    attrs = {k: v for k, v in node.attrib.items() if k != 'output'}
    return attrs, files, params, [r.attrib for r in node.iter('remap')]


def test_readme_move_base_snippet_is_what_the_rostest_runs():
    """The docs' move_base snippet (docs/real_robots.md, section "Navigating on the merged map",
    moved there from the README) and test/ros/move_base_merged.launch, which
    test/ros/move_base_merged.test runs live where move_base is installed, set the same
    parameters, load the same ROBOTIS files."""
    with open(os.path.join(REPO, 'docs', 'real_robots.md')) as f:
        readme = f.read()
    section = readme[readme.index('### Navigating on the merged map'):]
    snippet = section[section.index('```') + 3:]
    snippet = snippet[:snippet.index('```')]
    with open(os.path.join(REPO, 'test', 'ros', 'move_base_merged.launch')) as f:
        launch = f.read()
    ours = _move_base_node(snippet)
    tested = _move_base_node(launch, robot_arg='tb3_1')
    assert ours == tested
    attrs, files, params, remaps = ours
    assert attrs.get('clear_params') == 'true'
    assert ('costmap_common_params_burger.yaml', 'global_costmap') in files
    assert dict(params)['global_costmap/map_topic'] == '/map'
