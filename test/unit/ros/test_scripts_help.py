"""Every script of scripts/ answers --help and -h with its whole usage, exit code 0, and starts
nothing (issue 32). scan_frame_relay, tf_relay and frame_prefix_relay are not covered here.

Each script runs as a user runs it, in a subprocess, on a master URI nobody serves: a script
that ignored --help and went on would wait for that master (or start the demo) and be stopped
by the timeout; one whose text was cut (a docstring's first line only) misses its last words.
"""
import os
import shutil
import socket
import subprocess

import pytest
from conftest import REPO

SCRIPTS = os.path.join(REPO, 'scripts')
NOT_HERE = {'scan_frame_relay', 'tf_relay', 'frame_prefix_relay'}   # another change covers them
# per script: words its --help must end its description with (or hold), whitespace normalised
LAST_WORDS = {
    'evaluate_map': 'coverage of the free space and wrongly occupied area',
    'make_robot_bags': 'Exit status 2 names a bad input file.',
    'map_merge_node': 'rosrun multi_map_merge map_merge_node _estimation_rate:=0.5 __name:=map_merge',
    'merge_maps': '2 bad arguments or a bad input file (the message names it).',
    'publish_maps': 'as gmapping robots would (latched, growing), for demos and tests without robots.',
    'record_replay': 'Stops when /clock has stood still for --idle seconds (the bag ended).',
    'robots_rviz': 'from roslaunch are passed on to rviz).',
    'run_demo': 'Starts its own roscore on a free port (from 11700) and stops everything it started on exit.',
    'save_map': 'save the next OccupancyGrid on a topic as map_server files (map_saver is not in Debian).',
}


def free_port():
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def run(script, *args, cwd=None, **extra_env):
    env = dict(os.environ, ROS_MASTER_URI='http://127.0.0.1:%d' % free_port(), **extra_env)
    env.pop('DEMO_OUTPUT', None)
    p = subprocess.run([os.path.join(SCRIPTS, script)] + list(args), stdout=subprocess.PIPE,
                       stderr=subprocess.PIPE, universal_newlines=True, env=env, cwd=cwd, timeout=60)
    return p.returncode, p.stdout, p.stderr


def test_every_script_is_covered():
    assert set(os.listdir(SCRIPTS)) - NOT_HERE == set(LAST_WORDS)


@pytest.mark.parametrize('flag', ['--help', '-h'])
@pytest.mark.parametrize('script', sorted(LAST_WORDS))
def test_help_is_whole_and_starts_nothing(script, flag, tmp_path):
    if script != 'run_demo':
        pytest.importorskip('rospy')
    rc, out, err = run(script, flag, cwd=str(tmp_path))
    assert rc == 0, (rc, out, err)
    assert out.startswith('usage: %s' % script), out
    text = ' '.join(out.split())
    assert ' '.join(LAST_WORDS[script].split()) in text, out
    assert '``' not in out and ':mod:' not in out, out     # reST markup made plain
    assert os.listdir(str(tmp_path)) == [], os.listdir(str(tmp_path))   # wrote nothing


def test_run_demo_refuses_an_unknown_argument(tmp_path):
    rc, out, err = run('run_demo', '--rate', cwd=str(tmp_path))
    assert rc == 2 and "unknown argument '--rate'" in err and out == '', (rc, out, err)
    assert os.listdir(str(tmp_path)) == []


def test_map_merge_node_refuses_an_unknown_option():
    pytest.importorskip('rospy')
    rc, out, err = run('map_merge_node', '--rate', '2')
    assert rc == 2 and 'unrecognized arguments: --rate 2' in err, (rc, out, err)


def test_run_demo_refuses_a_slam_it_cannot_run(tmp_path):
    """DEMO_SLAM names each robot's SLAM: a value not among rbpf and gmapping, and gmapping where
    ROS cannot find it, are errors that say why, before anything starts or is written."""
    rc, out, err = run('run_demo', cwd=str(tmp_path), DEMO_SLAM='cartographer')
    assert rc == 2 and 'DEMO_SLAM=cartographer is not one of: rbpf, gmapping' in err and out == '', (rc, out, err)
    assert os.listdir(str(tmp_path)) == []
    if shutil.which('rospack') and subprocess.run(['rospack', 'find', 'gmapping'], capture_output=True).returncode == 0:
        pytest.skip('ROS has gmapping here: DEMO_SLAM=gmapping would run')
    rc, out, err = run('run_demo', cwd=str(tmp_path), DEMO_SLAM='gmapping')
    assert rc == 1 and 'DEMO_SLAM=gmapping needs the ROS package gmapping' in err and 'DEMO_SLAM=rbpf' in err \
        and out == '', (rc, out, err)
    assert os.listdir(str(tmp_path)) == []
