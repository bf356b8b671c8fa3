#!/usr/bin/env python3
"""rostest: ``turtlebot3_multi_slam.launch slam_on:=robot`` for real, the "robots" reached over
ssh on this machine. Runs only where ``MMM_SSH_LOCALHOST=user@127.0.0.1:port`` says an sshd
there takes key auth for ``user`` (``tools/ssh_robot_localhost test`` sets one up, runs this and
tears it down); skips otherwise. Not in ``make test``: it needs an sshd and a second user.

The user must not be the one running the test: roslaunch starts a <machine> whose address is
this machine's and whose user is the launching user locally, without ssh. roslaunch's ssh client
(paramiko) reads ``$HOME/.ssh`` (config, known_hosts) as on a base station.

The same run as tb3_real_launch.test (two Turtlebot3s' LDS-02 scans, slam:=rbpf), with
``slam_on:=robot``, both robots at 127.0.0.1, ``robot_user``, ``robot_ssh_port`` and the
workspace's own env loader (the launch's default, ``<devel>/lib/multi_map_merge/env_loader``,
which finds ``ROS_IP`` itself; nothing else sets it). Asserts, besides everything tb3_real_launch
asserts (both mapped and merged within 0.25 m and 6 degrees): roslaunch started its child through
ssh; each robot's SLAM, robot_state_publisher and scan relay ran as the ssh user under sshd,
with the ``ROS_IP`` the loader set, announcing that address; all of them are gone once the launch
is stopped. Run under ``.ci/unresolvable_host`` (``.ci/unresolvable_host tools/ssh_robot_localhost
test``), the host name resolves nowhere, so this shows the loader needs no name resolution."""
import getpass
import os
import pwd
import re
import stat
import tempfile
import time
import unittest
from xmlrpc.client import ServerProxy

import rosgraph
import roslaunch.core
import rostest
from test_tb3_real_launch import ROBOTS, SLAM, run_tb3_launch

# the SLAM node slam_robot.launch starts for SLAM, then the others of tb3_robot_base.launch
NODES = [{'gmapping': 'slam_gmapping', 'rbpf': 'rbpf_slam'}[SLAM], 'robot_state_publisher', 'scan_frame_relay']


def ssh_target():
    """(user, address, port) from MMM_SSH_LOCALHOST, or None where it is unset."""
    v = os.environ.get('MMM_SSH_LOCALHOST', '')
    if not v:
        return None
    m = re.fullmatch(r'([^@]+)@([^:]+):(\d+)', v)
    if not m:
        raise ValueError('MMM_SSH_LOCALHOST=%r: expected user@address:port' % v)
    return m.group(1), m.group(2), int(m.group(3))


def check_ssh(user, address, port):
    """None if roslaunch's own ssh code reaches user@address:port, else why not."""
    import paramiko
    from roslaunch.remoteprocess import ssh_check_known_hosts
    ssh = paramiko.SSHClient()
    err = ssh_check_known_hosts(ssh, address, port, username=user)
    if err:
        return err
    cfg = paramiko.SSHConfig()
    path = os.path.expanduser('~/.ssh/config')
    if os.path.exists(path):
        with open(path) as f:
            cfg.parse(f)
    key = cfg.lookup(address).get('identityfile')
    try:
        ssh.connect(address, port, user, timeout=10, key_filename=[os.path.expanduser(k) for k in key or []] or None)
    except Exception as e:   # whatever paramiko raises is the reason
        return '%s: %s' % (type(e).__name__, e)
    finally:
        ssh.close()
    return None


def env_loader(directory):
    """The env loader the launch uses by default: the workspace's own
    (<devel>/lib/multi_map_merge/env_loader), which sets ROS_IP itself from the route to the
    master; nothing here sets it. Where gmapping comes from a workspace overlaid on ours
    (`make gmapping` builds one), a wrapper runs our loader first, then sources that overlay,
    which keeps ROS_IP. Returns (the loader roslaunch is given, ours)."""
    spaces = [p for p in os.environ.get('CMAKE_PREFIX_PATH', '').split(':')
              if os.path.isfile(os.path.join(p, 'setup.bash'))]
    ours = [i for i, p in enumerate(spaces) if os.path.isfile(os.path.join(p, 'lib', 'multi_map_merge', 'env_loader'))]
    if not ours:
        raise AssertionError('no <devel>/lib/multi_map_merge/env_loader in CMAKE_PREFIX_PATH: build the workspace')
    loader = os.path.join(spaces[ours[0]], 'lib', 'multi_map_merge', 'env_loader')
    overlays = spaces[:ours[0]]
    if not overlays:
        return loader, loader
    lines = ['#!/bin/bash', '# our env loader, then the overlays above our workspace (gmapping); no ROS_IP here',
             'exec %s bash -c \'source %s/setup.bash && exec "$@"\' overlays "$@"' % (loader, overlays[0]), '']
    path = os.path.join(directory, 'mmm_env.sh')
    with open(path, 'w') as f:
        f.write('\n'.join(lines))
    os.chmod(directory, 0o755)
    os.chmod(path, stat.S_IRWXU | stat.S_IRGRP | stat.S_IXGRP | stat.S_IROTH | stat.S_IXOTH)
    return path, loader


def ancestors(pid):
    """The command names of pid's ancestors, its parent first."""
    names = []
    while pid > 1:
        with open('/proc/%d/stat' % pid) as f:
            pid = int(f.read().rsplit(')', 1)[1].split()[1])
        with open('/proc/%d/comm' % pid) as f:
            names.append(f.read().strip())
    return names


class TestRemoteSlamLocalhost(unittest.TestCase):

    def test_slam_on_robot_over_ssh(self):
        target = ssh_target()
        if target is None:
            self.skipTest('MMM_SSH_LOCALHOST unset: no sshd on localhost to reach the robots through '
                          '(tools/ssh_robot_localhost test runs this with a throwaway one)')
        user, address, port = target
        machine = roslaunch.core.Machine('robot', address, user=user, ssh_port=port)
        self.assertFalse(roslaunch.core.is_machine_local(machine),
                         '%s@%s is this machine and this user: roslaunch would start the nodes without ssh'
                         % (user, address))
        err = check_ssh(user, address, port)
        self.assertIsNone(err, 'MMM_SSH_LOCALHOST=%s: roslaunch could not reach it: %s'
                               % (os.environ['MMM_SSH_LOCALHOST'], err))
        uid = pwd.getpwnam(user).pw_uid
        tmp = tempfile.mkdtemp(prefix='mmm_remote_')
        loader, ours = env_loader(tmp)
        print('env_loader: %s (ours: %s)' % (loader, ours))
        log = os.path.join(tmp, 'roslaunch.log')
        pids = {}

        def remote_nodes():
            master = rosgraph.Master('/test_remote_slam')
            for r in ROBOTS:
                for n in NODES:
                    name = '/%s/%s' % (r, n)
                    code, msg, pid = ServerProxy(master.lookupNode(name)).getPid('/test_remote_slam')
                    self.assertEqual(code, 1, '%s: %s' % (name, msg))
                    pids[name] = pid
                    self.assertEqual(os.stat('/proc/%d' % pid).st_uid, uid,
                                     '%s (pid %d) does not run as %s' % (name, pid, user))
                    self.assertIn('sshd', ancestors(pid), '%s (pid %d) was not started through ssh' % (name, pid))
                    # announced by the address the env loader found, not by the host name
                    uri = master.lookupNode(name)
                    self.assertTrue(uri.startswith('http://%s:' % address), '%s announces %s' % (name, uri))
                    with open('/proc/%d/environ' % pid, 'rb') as f:
                        environ = dict(v.split(b'=', 1) for v in f.read().split(b'\0') if b'=' in v)
                    self.assertEqual(environ.get(b'ROS_IP'), address.encode(), name)

        run_tb3_launch(self, ['slam_on:=robot', 'first_tb3_address:=' + address, 'second_tb3_address:=' + address,
                              'robot_user:=' + user, 'robot_ssh_port:=%d' % port, 'env_loader:=' + loader],
                       launch_log=log, before_stop=remote_nodes)
        with open(log) as f:
            text = f.read()
        self.assertIn('remote[%s-0]: ssh connection created' % address, text)
        self.assertEqual(sorted(pids), sorted('/%s/%s' % (r, n) for r in ROBOTS for n in NODES))
        self.assertNotEqual(getpass.getuser(), user)
        end = time.time() + 20.0
        while time.time() < end and any(os.path.exists('/proc/%d' % p) for p in pids.values()):
            time.sleep(0.5)
        left = {n: p for n, p in pids.items() if os.path.exists('/proc/%d' % p)}
        self.assertEqual(left, {}, 'still running on the "robot" after the launch stopped')
        print('slam_on:=robot: %s ran as %s under sshd (pids %s), all gone after the launch'
              % (', '.join(sorted(pids)), user, sorted(pids.values())))


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'remote_slam_localhost', TestRemoteSlamLocalhost)
