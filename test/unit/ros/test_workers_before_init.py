"""ros/before_init.py's workers_before_init: the node's ~workers read before rospy.init_node, so that
the worker pool is forked at the node's start with the size the user asked for (a pool resized
later comes from a forkserver that imports OpenCV again). No master here: the argument form,
and what happens when no master answers (test/ros/node_status.test reads it from a master)."""
import time

import pytest

pytest.importorskip('rospy')   # the ROS shell: not on a stack without ROS (make test-focal)
pytest.importorskip('diagnostic_updater')

from multi_map_merge.ros.before_init import workers_before_init  # noqa: E402


@pytest.fixture
def no_master(monkeypatch):
    """A ROS_MASTER_URI where nothing listens (port 9 of this host)."""
    monkeypatch.setenv('ROS_MASTER_URI', 'http://127.0.0.1:9/')


def test_the_argument_form_is_read(no_master):
    assert workers_before_init(['map_merge_node', '_workers:=3']) == 3
    assert workers_before_init(['map_merge_node', '__name:=merger', '_workers:=1']) == 1


def test_an_invalid_value_is_the_default(no_master):
    assert workers_before_init(['map_merge_node', '_workers:=-2']) == 0
    assert workers_before_init(['map_merge_node', '_workers:=many']) == 0


def test_no_master_is_the_default_at_once(no_master):
    t = time.monotonic()
    assert workers_before_init(['map_merge_node']) == 0
    assert time.monotonic() - t < 2.5   # (refused at once; an unanswering host: 2 s)
