"""The relays (ros/relays.py: scan_frame_relay, tf_relay, frame_prefix_relay) stay light for a
robot's computer: their import chain holds no OpenCV, numpy or scipy, and every relay script
answers --help with its usage and starts nothing (no master needed)."""
import os
import subprocess
import sys

import pytest

REPO = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..'))
SRC = os.path.join(REPO, 'src')
HEAVY = ('cv2', 'numpy', 'scipy')
RELAYS = ('scan_frame_relay', 'tf_relay', 'frame_prefix_relay')


def run_python(code):
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get('PYTHONPATH', ''))
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, env=env, timeout=60)


def test_importing_the_relays_loads_no_cv2_numpy_scipy():
    r = run_python('import sys; import multi_map_merge.ros.relays, multi_map_merge.core.scans\n'
                   'print(sorted(k for k in %r if sys.modules.get(k) is not None))' % (HEAVY,))
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == '[]'


def test_a_relay_process_with_rospy_and_its_messages_loads_none_either():
    pytest.importorskip('rospy', reason='rospy is not installed')
    # what a relay's *_main imports before it spins (genpy's optional numpy refused)
    r = run_python('import sys\nfrom multi_map_merge.ros import relays\nrelays.keep_numpy_out()\n'
                   'import rospy, rosbag\nfrom sensor_msgs.msg import LaserScan\nfrom nav_msgs.msg import Odometry\n'
                   'from tf2_msgs.msg import TFMessage\n'
                   'm = LaserScan(ranges=[1.0, float("inf")]); import io; b = io.BytesIO(); m.serialize(b)\n'
                   'print(sorted(k for k in %r if sys.modules.get(k) is not None))' % (HEAVY,))
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == '[]'


def test_keep_numpy_out_leaves_a_process_that_has_numpy_alone():
    r = run_python('import numpy, sys\nfrom multi_map_merge.ros import relays\nrelays.keep_numpy_out()\n'
                   'import numpy as np; print(np.zeros(2).sum())')
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == '0.0'


@pytest.mark.parametrize('script', RELAYS)
def test_every_relay_answers_help_and_starts_nothing(script):
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get('PYTHONPATH', ''),
               ROS_MASTER_URI='http://127.0.0.1:1')     # no master there: a start would hang or fail
    for flag in ('--help', '-h'):
        r = subprocess.run([sys.executable, os.path.join(REPO, 'scripts', script), flag], capture_output=True,
                           text=True, env=env, timeout=30)
        assert r.returncode == 0, r.stderr
        assert r.stdout.startswith('usage: %s' % script)
        assert 'ROS parameters' in r.stdout and 'Example:' in r.stdout
        assert 'ERROR' not in r.stderr and 'Unable to' not in r.stderr
    r = subprocess.run([sys.executable, os.path.join(REPO, 'scripts', script), '--no-such-option'],
                       capture_output=True, text=True, env=env, timeout=30)
    assert r.returncode == 2 and 'unrecognized arguments' in r.stderr
