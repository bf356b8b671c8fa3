"""The env loader a robot's nodes start through (turtlebot3_multi_slam.launch slam_on:=robot, its
default env_loader): <devel>/lib/multi_map_merge/env_loader, made by CMakeLists.txt, run here as
roslaunch runs it over ssh (an empty environment but PATH, HOME and the ROS_MASTER_URI roslaunch
passes). It must make the nodes announce an address the others reach without resolving the
robot's host name, or say why it cannot.

The last test runs under a host name that resolves nowhere (.ci/unresolvable_host: a UTS
namespace of its own, root only; skipped elsewhere): an XML-RPC server of rosgraph's, which every
ROS node and roslaunch runs, cannot be reached at the URI it announces (roslaunch's "Unable to
contact my own server") without the loader, and is with it."""
import os
import shutil
import subprocess
import sys

import pytest
from conftest import REPO

from multi_map_merge.ros.env_loader import EnvLoaderError, master_host_port, master_route_address

UNRESOLVABLE = os.path.join(REPO, '.ci', 'unresolvable_host')
NAME = 'import rosgraph.network as n; print(n.get_host_name())'
OWN_SERVER = '''
import time, xmlrpc.client
import rosgraph.xmlrpc as rx
class H(rx.XmlRpcHandler):
    def ping(self):
        return 1
node = rx.XmlRpcNode(0, H())
node.start()
while not node.uri:
    time.sleep(0.01)
try:
    xmlrpc.client.ServerProxy(node.uri).ping()
    print('reached', node.uri)
except Exception as e:
    print('unreachable', node.uri, type(e).__name__)
node.shutdown('done')
'''


def test_the_route_to_a_master_by_address():
    assert master_route_address('http://127.0.0.1:11311') == '127.0.0.1'
    assert master_route_address('http://127.0.0.1') == '127.0.0.1'
    assert master_route_address('http://localhost:11311/') == '127.0.0.1'
    assert master_host_port('http://192.168.0.10:11311') == ('192.168.0.10', 11311)


@pytest.mark.parametrize('uri,words', [
    ('http://base-station.invalid:11311', ['"base-station.invalid"', 'does not resolve',
                                           'ROS_MASTER_URI=http://<its IP address>:11311']),
    ('', ['ROS_MASTER_URI is not set']),
    ('http://:11311', ['names no host']),
    ('http://192.168.0.10:port', ['is not a URI like']),
])
def test_no_address_says_why(uri, words):
    with pytest.raises(EnvLoaderError) as e:
        master_route_address(uri)
    for w in words:
        assert w in str(e.value), str(e.value)


def workspace_loader():
    """The env loader of the sourced workspace that holds this package, or skip."""
    for prefix in os.environ.get('CMAKE_PREFIX_PATH', '').split(os.pathsep):
        path = os.path.join(prefix, 'lib', 'multi_map_merge', 'env_loader')
        if prefix and os.path.isfile(path):
            return path
    pytest.skip('no built workspace sourced (make unit builds and sources it)')


def as_over_ssh(cmd, **env):
    """cmd in the environment roslaunch's ssh child gets: PATH, HOME and what it passes."""
    base = {'PATH': '/usr/bin:/bin', 'HOME': os.environ.get('HOME', '/tmp')}
    base.update(env)
    return subprocess.run(cmd, env=base, capture_output=True, text=True, timeout=60)


def test_the_workspace_loader_sets_ros_ip_from_the_route_to_the_master():
    loader = workspace_loader()
    assert os.access(loader, os.X_OK), loader
    r = as_over_ssh([loader, 'python3', '-c', NAME], ROS_MASTER_URI='http://127.0.0.1:11311')
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == '127.0.0.1'
    # and the workspace is sourced: this package and its scripts are found
    r = as_over_ssh([loader, 'rospack', 'find', 'multi_map_merge'], ROS_MASTER_URI='http://127.0.0.1:11311')
    assert r.returncode == 0 and os.path.isfile(os.path.join(r.stdout.strip(), 'package.xml')), r


@pytest.mark.parametrize('given', [{'ROS_IP': '10.1.2.3'}, {'ROS_HOSTNAME': 'robot1.local'}])
def test_an_address_set_by_the_user_is_kept(given):
    r = as_over_ssh([workspace_loader(), 'python3', '-c', NAME], ROS_MASTER_URI='http://127.0.0.1:11311', **given)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == list(given.values())[0]


def test_a_master_name_that_does_not_resolve_stops_it_with_the_reason():
    r = as_over_ssh([workspace_loader(), 'python3', '-c', 'print("started")'],
                    ROS_MASTER_URI='http://base-station.invalid:11311')
    assert r.returncode == 1 and r.stdout == '', r
    assert r.stderr.startswith('env_loader: the master\'s host "base-station.invalid"'), r.stderr
    assert 'does not resolve' in r.stderr


def test_help_and_no_command():
    loader = workspace_loader()
    r = as_over_ssh([loader, '--help'])
    assert r.returncode == 0 and 'env_loader COMMAND [ARGS...]' in r.stdout, r
    r = as_over_ssh([loader])
    assert r.returncode == 2 and 'env_loader COMMAND [ARGS...]' in r.stdout, r


def test_the_module_prints_the_address():
    env = dict(os.environ, PYTHONPATH=os.path.join(REPO, 'src'), ROS_MASTER_URI='http://127.0.0.1:11311')
    r = subprocess.run([sys.executable, '-m', 'multi_map_merge.ros.env_loader'], env=env,
                       capture_output=True, text=True, timeout=60)
    assert (r.returncode, r.stdout) == (0, '127.0.0.1\n'), r


def test_under_a_host_name_that_resolves_nowhere():
    loader = workspace_loader()
    if os.geteuid() != 0 or shutil.which('unshare') is None or subprocess.run(
            ['unshare', '--uts', 'true'], capture_output=True).returncode != 0:
        pytest.skip('no UTS namespace here (root and unshare needed): .ci/unresolvable_host would keep '
                    'this machine\'s host name')
    # without the loader: the announced URI holds the host name, and nothing reaches it
    env = {'ROS_MASTER_URI': 'http://127.0.0.1:11311'}
    python = '/usr/bin/python3'
    r = as_over_ssh([UNRESOLVABLE, 'bash', '-c', 'source "$1" && exec "$2" -c "$3"', 'x',
                     os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(loader))), 'setup.bash'),
                     python, OWN_SERVER], **env)
    assert 'with hostname mmm-ci-unresolvable (does not resolve)' in r.stdout, r
    assert r.stdout.strip().splitlines()[-1].startswith('unreachable http://mmm-ci-unresolvable:'), r
    # with it: by the address on the route to the master
    r = as_over_ssh([UNRESOLVABLE, loader, python, '-c', OWN_SERVER], **env)
    assert 'with hostname mmm-ci-unresolvable (does not resolve)' in r.stdout, r
    assert r.stdout.strip().splitlines()[-1].startswith('reached http://127.0.0.1:'), r
