"""package.xml declares what the code imports and what the launch files start, by the rosdep
keys that resolve on Noetic / Ubuntu 20.04 (checked against rosdistro's noetic/distribution.yaml
and rosdep/python.yaml; the table below says which key provides which module). No ROS needed:
the code is read, not imported."""
import ast
import glob
import importlib.util
import os
import re
import sys
import sysconfig
import xml.etree.ElementTree as ET

import pytest
from conftest import REPO

# top-level module -> the rosdep key that provides it on Noetic / Ubuntu 20.04
MODULE_KEYS = {
    'numpy': 'python3-numpy', 'cv2': 'python3-opencv', 'yaml': 'python3-yaml',
    'scipy': 'python3-scipy', 'pytest': 'python3-pytest', 'rospkg': 'python3-rospkg',
    'setuptools': 'python3-setuptools', 'catkin_pkg': 'catkin',
    'rospy': 'rospy', 'rosgraph': 'rosgraph', 'rosbag': 'rosbag', 'roslaunch': 'roslaunch',
    'rostest': 'rostest', 'rosnode': 'rosnode', 'roslib': 'roslib', 'tf2_ros': 'tf2_ros',
    'tf2_msgs': 'tf2_msgs', 'nav_msgs': 'nav_msgs', 'map_msgs': 'map_msgs',
    'geometry_msgs': 'geometry_msgs', 'sensor_msgs': 'sensor_msgs', 'rosgraph_msgs': 'rosgraph_msgs',
    'diagnostic_msgs': 'diagnostic_msgs', 'diagnostic_updater': 'diagnostic_updater', 'std_srvs': 'std_srvs',
    'visualization_msgs': 'visualization_msgs', 'std_msgs': 'std_msgs',
    'rviz': 'rviz', 'python_qt_binding': 'python_qt_binding', 'paramiko': 'python3-paramiko',
    'actionlib': 'actionlib', 'actionlib_msgs': 'actionlib_msgs', 'move_base_msgs': 'move_base_msgs',
}
# optional: imported only where ImportError is handled, and deliberately not declared. Dask
# (only with ~dask_scheduler set, runtime/cluster.py) has no rosdep key: Debian and Ubuntu's
# python3-distributed (and its python3-dask), or pip
OPTIONAL = {'open3d': 'python3-open3d-pip', 'distributed': 'python3-distributed', 'dask': 'python3-dask'}
ENV = {'ROS_PYTHON_VERSION': '3', 'ROS_DISTRO': 'noetic'}     # what rosdep sees on Noetic
# ... and on a robot (README: MULTI_MAP_MERGE_SIDE=robot rosdep install ...)
ROBOT_ENV = dict(ENV, MULTI_MAP_MERGE_SIDE='robot')
OWN = 'multi_map_merge'
# what a robot runs of ours: the relays (their scripts and their whole import chain) and the env
# loader roslaunch starts its nodes through (slam_on:=robot)
ROBOT_CODE = ['scripts/scan_frame_relay', 'scripts/tf_relay', 'scripts/frame_prefix_relay',
              'src/multi_map_merge/ros/relays.py', 'src/multi_map_merge/core/scans.py',
              'src/multi_map_merge/ros/env_loader.py']
# the keys a robot needs, all of them (issue 32: 39 keys before, rviz, OpenCV, scipy, xvfb among them)
ROBOT_KEYS = {'catkin', 'python3-setuptools', 'rospy', 'sensor_msgs', 'nav_msgs', 'tf2_msgs', 'rosbag',
              'roslaunch', 'gmapping', 'robot_state_publisher', 'rostest',
              # rbpf_slam, the SLAM of our own a robot may run (slam:=rbpf), built from C++
              'roscpp', 'message_filters', 'tf2', 'tf2_ros', 'rosbag_storage', 'mrpt2'}


def condition_holds(cond, env):
    """A package.xml condition of clauses ``$VAR == word`` / ``$VAR != word`` joined by ``and``,
    evaluated as rosdep does (an unset variable is the empty string)."""
    for clause in re.split(r'\s+and\s+', cond.strip()):
        m = re.fullmatch(r'\s*\$(\w+)\s*(==|!=)\s*(\w+)\s*', clause)
        assert m, 'condition this test cannot evaluate: %r' % cond
        if (env.get(m.group(1), '') == m.group(3)) != (m.group(2) == '=='):
            return False
    return True


def declared(env=None):
    """{tag: set of keys} of package.xml, conditions evaluated as on Noetic (or in ``env``)."""
    root = ET.parse(os.path.join(REPO, 'package.xml')).getroot()
    assert root.tag == 'package' and root.get('format') == '3'
    deps = {}
    for el in root:
        if not el.tag.endswith('depend'):
            continue
        cond = el.get('condition')
        if cond is not None and not condition_holds(cond, ENV if env is None else env):
            continue
        tags = {'depend': ['build_depend', 'exec_depend']}.get(el.tag, [el.tag])
        for t in tags:
            deps.setdefault(t, set()).add(el.text.strip())
    return deps


def python_files(*dirs):
    """Python sources under REPO/dir (by extension or by a python shebang)."""
    out = []
    for d in dirs:
        for p in sorted(glob.glob(os.path.join(REPO, d, '**', '*'), recursive=True)):
            if not os.path.isfile(p):
                continue
            if p.endswith('.py'):
                out.append(p)
            elif '.' not in os.path.basename(p):
                with open(p, 'rb') as f:
                    if re.match(rb'#!.*python', f.readline()):
                        out.append(p)
    return out


def imports(path):
    """[(top-level module, guarded by an ImportError handler)] of one file's absolute imports."""
    with open(path) as f:
        tree = ast.parse(f.read(), path)
    found = []

    def visit(node, guarded):
        if isinstance(node, ast.Try):
            catches = any(h.type is None or any(
                isinstance(n, ast.Name) and n.id in ('ImportError', 'ModuleNotFoundError', 'Exception')
                for n in ast.walk(h.type)) for h in node.handlers)
            for n in node.body:
                visit(n, guarded or catches)
            for n in node.handlers + node.orelse + node.finalbody:
                visit(n, guarded)
            return
        if isinstance(node, ast.Import):
            found.extend((a.name.split('.')[0], guarded) for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.module.split('.')[0], guarded))
        for n in ast.iter_child_nodes(node):
            visit(n, guarded)

    visit(tree, False)
    return found


_STDLIB = os.path.realpath(sysconfig.get_paths()['stdlib'])


def is_stdlib(name):
    names = getattr(sys, 'stdlib_module_names', None)      # Python 3.10+
    if names is not None:
        return name in names
    if name in sys.builtin_module_names:
        return True
    spec = importlib.util.find_spec(name)
    if spec is None or spec.origin in (None, 'frozen', 'built-in'):
        return spec is not None
    origin = os.path.realpath(spec.origin)
    return origin.startswith(_STDLIB + os.sep) and 'packages' not in origin[len(_STDLIB):]


def local_modules():
    """Modules of the repository itself (test helpers, bench scripts, the package)."""
    names = {OWN}
    for p in python_files('test', 'bench', 'src'):
        names.add(os.path.splitext(os.path.basename(p))[0])
    return names


def third_party(paths):
    """{module: [files]} of imports that are neither the standard library nor the repository's."""
    own = local_modules()
    out = {}
    for p in paths:
        for mod, guarded in imports(p):
            if mod in own or is_stdlib(mod):
                continue
            out.setdefault(mod, []).append((os.path.relpath(p, REPO), guarded))
    return out


def test_the_table_covers_the_imports_of_the_installed_code():
    mods = third_party(python_files('src', 'scripts'))
    unknown = sorted(set(mods) - set(MODULE_KEYS) - set(OPTIONAL))
    assert not unknown, 'imported but not in MODULE_KEYS (add its rosdep key here and to package.xml): %s' % {
        m: mods[m] for m in unknown}
    # sanity: the scan sees what the node is known to import
    assert {'rospy', 'tf2_ros', 'cv2', 'numpy', 'scipy', 'rosbag'} <= set(mods)


def test_every_import_of_the_installed_code_is_an_exec_depend():
    deps = declared()
    run = deps.get('exec_depend', set())
    missing = {m: MODULE_KEYS[m] for m in third_party(python_files('src', 'scripts'))
               if m in MODULE_KEYS and MODULE_KEYS[m] not in run}
    assert not missing, 'imported by src/ or scripts/ but not an exec_depend in package.xml: %s' % missing


def test_build_imports_are_build_depends():
    deps = declared()
    build = deps.get('build_depend', set()) | deps.get('buildtool_depend', set())
    missing = {m: MODULE_KEYS[m] for m in third_party([os.path.join(REPO, 'setup.py')])
               if MODULE_KEYS.get(m) not in build}
    assert not missing, missing


def test_every_import_of_the_tests_is_declared():
    deps = declared()
    have = deps.get('exec_depend', set()) | deps.get('test_depend', set())
    mods = third_party(python_files('test'))
    unknown = sorted(set(mods) - set(MODULE_KEYS) - set(OPTIONAL))
    assert not unknown, {m: mods[m] for m in unknown}
    missing = {m: MODULE_KEYS[m] for m in mods if m in MODULE_KEYS and MODULE_KEYS[m] not in have}
    assert not missing, 'imported by tests but neither an exec_depend nor a test_depend: %s' % missing


def test_open3d_and_dask_are_optional_and_guarded():
    """Ubuntu 20.04 has no Open3D package (rosdep: only python3-open3d-pip), and rosdep has no
    key for Dask: each is imported only under an ImportError handler (evaluation says what to
    install; a cluster that cannot be used leaves the work to the local workers) and not
    declared."""
    deps = declared()
    everything = set().union(*deps.values())
    for mod, key in OPTIONAL.items():
        assert key not in everything and mod not in everything
        uses = third_party(python_files('src', 'scripts')).get(mod, [])
        assert uses, '%s is no longer imported: drop it from OPTIONAL' % mod
        assert all(guarded for _, guarded in uses), uses


def test_launch_and_rostest_files_start_declared_packages():
    deps = declared()
    run = deps.get('exec_depend', set())
    have = run | deps.get('test_depend', set())
    for pattern, allowed in (('launch/**/*.launch', run), ('test/**/*.test', have)):
        files = glob.glob(os.path.join(REPO, pattern), recursive=True)
        assert files, pattern
        for f in files:
            root = ET.parse(f).getroot()
            for el in root.iter():
                pkg = el.get('pkg')
                if el.tag in ('node', 'test') and pkg and pkg != OWN:
                    assert pkg in allowed, '%s starts %s/%s: not declared in package.xml' % (
                        os.path.relpath(f, REPO), pkg, el.get('type'))


def test_license_urls_and_maintainer():
    root = ET.parse(os.path.join(REPO, 'package.xml')).getroot()
    assert root.findtext('license') == 'BSD-3-Clause'
    with open(os.path.join(REPO, 'LICENSE')) as f:
        assert f.readline().strip() == 'BSD 3-Clause License'
    urls = {u.get('type'): u.text for u in root.findall('url')}
    assert {'repository', 'bugtracker'} <= set(urls) and all(u.startswith('https://') for u in urls.values())
    for m in root.findall('maintainer'):
        email = m.get('email', '')
        assert re.fullmatch(r'[^@\s]+@[^@\s]+\.[a-z]{2,}', email) and not email.endswith(('.invalid', '.example'))
        assert m.text.strip()


@pytest.mark.parametrize('condition,expected', [('$ROS_PYTHON_VERSION == 3', True),
                                                ('$ROS_PYTHON_VERSION == 2', False),
                                                ('$ROS_PYTHON_VERSION != 2', True),
                                                ('$MULTI_MAP_MERGE_SIDE != robot', True),
                                                ('$ROS_PYTHON_VERSION == 3 and $MULTI_MAP_MERGE_SIDE != robot', True),
                                                ('$ROS_PYTHON_VERSION == 2 and $MULTI_MAP_MERGE_SIDE != robot', False)])
def test_the_condition_reader(tmp_path, monkeypatch, condition, expected):
    """The evaluator above drops a dependency whose condition is false on Noetic."""
    (tmp_path / 'package.xml').write_text(
        '<package format="3"><exec_depend condition="%s">python3-numpy</exec_depend></package>' % condition)
    monkeypatch.setattr(sys.modules[__name__], 'REPO', str(tmp_path))
    assert ('python3-numpy' in declared().get('exec_depend', set())) == expected


def all_keys(deps):
    return set().union(*deps.values())


def test_a_robot_needs_only_the_keys_of_what_it_runs():
    """MULTI_MAP_MERGE_SIDE=robot: rosdep sees the relays', gmapping's and robot_state_publisher's
    keys, none of the base station's (rviz, OpenCV, numpy, scipy, xvfb, ...); unset (every other
    machine, bloom, the build farm) it sees them all."""
    robot, base = declared(ROBOT_ENV), declared()
    assert all_keys(robot) == ROBOT_KEYS
    assert ROBOT_KEYS < all_keys(base)
    for heavy in ('rviz', 'python3-opencv', 'python3-numpy', 'python3-scipy', 'xvfb', 'python_qt_binding',
                  'xacro', 'turtlebot3_description', 'python3-pytest'):
        assert heavy in all_keys(base) and heavy not in all_keys(robot), heavy
    # building the package on a robot: catkin_make needs its buildtool, build (rbpf_slam's C++:
    # roscpp, tf2, MRPT 2, the messages) and (CMakeLists.txt's find_package(rostest) under
    # CATKIN_ENABLE_TESTING) rostest
    assert robot['buildtool_depend'] == {'catkin'}
    assert robot['build_depend'] == {'python3-setuptools', 'roscpp', 'message_filters', 'tf2', 'tf2_ros',
                                     'rosbag_storage', 'mrpt2', 'sensor_msgs', 'nav_msgs', 'tf2_msgs'}
    assert robot['test_depend'] == {'rostest'}


def test_what_a_robot_runs_imports_only_its_keys():
    paths = [os.path.join(REPO, p) for p in ROBOT_CODE]
    assert all(os.path.isfile(p) for p in paths), paths
    run = declared(ROBOT_ENV)['exec_depend']
    mods = third_party(paths)
    unknown = sorted(set(mods) - set(MODULE_KEYS))
    assert not unknown, {m: mods[m] for m in unknown}
    missing = {m: MODULE_KEYS[m] for m in mods if MODULE_KEYS[m] not in run}
    assert not missing, 'a robot runs code importing these, not declared for MULTI_MAP_MERGE_SIDE=robot: %s' % missing
    # the relays' chain imports only its own package's modules besides these
    own = {m for p in paths for m, _ in imports(p) if m == OWN}
    assert own == {OWN}


def test_the_nodes_started_on_a_robot_are_robot_keys():
    """Every <node machine="..."> of the launch files (slam_on:=robot starts it on the robot over
    ssh) is of a package a robot has, and of ours only the relays and, with slam:=rbpf, our
    compiled SLAM node rbpf_slam (built on the robot with the package)."""
    run = declared(ROBOT_ENV)['exec_depend']
    relays = {os.path.basename(p) for p in ROBOT_CODE if p.startswith('scripts/')} | {'rbpf_slam'}
    seen = set()
    for f in glob.glob(os.path.join(REPO, 'launch', '**', '*.launch'), recursive=True):
        for el in ET.parse(f).getroot().iter('node'):
            if el.get('machine') is None:
                continue
            seen.add((el.get('pkg'), el.get('type')))
            if el.get('pkg') == OWN:
                assert el.get('type') in relays, (f, el.attrib)
            else:
                assert el.get('pkg') in run, '%s starts %s/%s on a robot: not a robot-side key' % (
                    os.path.relpath(f, REPO), el.get('pkg'), el.get('type'))
    assert {('gmapping', 'slam_gmapping'), (OWN, 'rbpf_slam'), ('robot_state_publisher', 'robot_state_publisher'),
            (OWN, 'scan_frame_relay')} <= seen, seen


def test_rosdep_evaluates_the_conditions_as_this_test_does():
    """catkin_pkg's own evaluation (what rosdep calls: Package.evaluate_conditions(os.environ))
    gives the same two lists."""
    package = pytest.importorskip('catkin_pkg.package', reason='catkin_pkg is not installed')
    for env in (ENV, ROBOT_ENV):
        pkg = package.parse_package(os.path.join(REPO, 'package.xml'))
        pkg.evaluate_conditions(env)
        keys = {d.name for d in pkg.buildtool_depends + pkg.build_depends + pkg.exec_depends + pkg.test_depends
                if d.evaluated_condition}
        assert keys == all_keys(declared(env)), env
