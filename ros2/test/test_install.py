"""The colcon package installs as colcon's ament_python build does (``setup.py build`` then
``install --prefix``, run here by hand: colcon is not on PyPI's Jazzy wheels) and its installed
node answers ``--help`` from the installed copy, the core with it; its launch file compiles."""
from __future__ import annotations

import os
import py_compile
import subprocess
import sys

PACKAGE_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', 'multi_map_merge_ros2')


def test_the_package_installs_as_colcon_does_and_its_node_runs(tmp_path):
    prefix = tmp_path / 'install'
    out = subprocess.run(
        [sys.executable, 'setup.py', '-q', 'egg_info', '--egg-base', str(tmp_path), 'build',
         '--build-base', str(tmp_path / 'build'), 'install', '--prefix', str(prefix),
         '--record', str(tmp_path / 'record.txt'), '--single-version-externally-managed'],
        cwd=PACKAGE_DIR, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    site = prefix / 'lib' / ('python%d.%d' % sys.version_info[:2]) / 'site-packages'
    for installed in ('multi_map_merge_ros2/node.py', 'multi_map_merge/core/merger.py',
                      'multi_map_merge/ros/diagnostics.py'):
        assert (site / installed).is_file(), installed
    share = prefix / 'share' / 'multi_map_merge_ros2'
    assert (share / 'package.xml').is_file() and (share / 'launch' / 'map_merge_team.launch.py').is_file()
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' / 'multi_map_merge_ros2').is_file()
    node = prefix / 'lib' / 'multi_map_merge_ros2' / 'map_merge_node'
    # the installed copy only: the checkout's folders (the venv's .pth puts them on the path) dropped
    checkout = os.path.abspath(os.path.join(PACKAGE_DIR, '..', '..'))
    dropped = [os.path.join(checkout, 'src'), os.path.join(checkout, 'ros2', 'multi_map_merge_ros2')]
    env = dict(os.environ, PYTHONPATH=str(site))
    code = ('import sys; sys.path[:] = [p for p in sys.path if p.rstrip("/") not in %r]; '
            'import multi_map_merge, multi_map_merge_ros2.map_merge_node as m; '
            'assert multi_map_merge.__file__.startswith(%r), multi_map_merge.__file__; '
            'sys.exit(m.main(["map_merge_node", "--help"]))' % (dropped, str(site)))
    run = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr[-2000:]
    assert 'map_merge_node' in run.stdout and 'transient-local' in run.stdout
    assert node.is_file() and os.access(str(node), os.X_OK)


def test_the_launch_file_compiles(tmp_path):
    py_compile.compile(os.path.join(PACKAGE_DIR, 'launch', 'map_merge_team.launch.py'),
                       cfile=str(tmp_path / 'launch.pyc'), doraise=True)
