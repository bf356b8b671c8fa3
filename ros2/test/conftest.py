"""A real ROS 2 graph for the node's tests: the merger node in a process of its own
(``python -m multi_map_merge_ros2.map_merge_node``, its log captured), and in the test's process
one rclpy node holding the robots' map publishers (transient-local, as map servers publish) and
listeners on the merged map, /tf and /diagnostics, spun by an executor thread.

The robots' maps are cut from the project's own home (:func:`multi_map_merge.lab.home.home_grid`,
drawn by our code) at poses the test chooses: the truth of every TF.

Runs in the venv of ``make ros2-env`` (``make test-ros2``); skips where rclpy is missing.
"""
from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from typing import Callable, Dict, List, Optional

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy', reason='no rclpy: run through `make test-ros2` (the ROS 2 venv)')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from nav_msgs.msg import OccupancyGrid  # noqa: E402
from rclpy.executors import MultiThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402

from multi_map_merge.core.grid import Grid  # noqa: E402
from multi_map_merge.core.transforms import se2  # noqa: E402
from multi_map_merge_ros2.convert import grid_from_msg, grid_to_msg, quaternion_yaw  # noqa: E402
from multi_map_merge_ros2.outputs import LATCHED  # noqa: E402


def wait_until(predicate: Callable[[], object], timeout: float, step: float = 0.1):
    """``predicate()``'s first truthy value within ``timeout`` seconds, else None."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value:
            return value
        time.sleep(step)
    return None


class Graph:
    """The test's side of the graph (see the module docstring)."""

    def __init__(self):
        rclpy.init()
        self.node = Node('map_merge_test')
        self.pubs: Dict[str, object] = {}
        self.maps: List[tuple] = []          # (wall time, OccupancyGrid) of the merged map
        self.tf: Dict[str, tuple] = {}       # child frame -> (wall time, parent, 3x3 pose, stamp s)
        self.diagnostics: List[tuple] = []   # (wall time, DiagnosticArray)
        self.tf_stamps: List[float] = []     # stamp (s) of each /tf message received, in order
        self._lock = threading.Lock()
        self.node.create_subscription(OccupancyGrid, '/map', self._on_map, LATCHED)
        self.node.create_subscription(TFMessage, '/tf', self._on_tf, 100)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)
        self.executor = MultiThreadedExecutor()
        self.executor.add_node(self.node)
        self._spin = threading.Thread(target=self.executor.spin, daemon=True)
        self._spin.start()

    def _on_map(self, msg):
        with self._lock:
            self.maps.append((time.time(), msg))

    def _on_tf(self, msg):
        with self._lock:
            if msg.transforms:
                st = msg.transforms[0].header.stamp
                self.tf_stamps.append(st.sec + st.nanosec * 1e-9)
                del self.tf_stamps[:-2000]
            for t in msg.transforms:
                tr = t.transform
                self.tf[t.child_frame_id] = (time.time(), t.header.frame_id,
                                             se2(tr.translation.x, tr.translation.y, quaternion_yaw(tr.rotation)),
                                             t.header.stamp.sec + t.header.stamp.nanosec * 1e-9)

    def _on_diagnostics(self, msg):
        with self._lock:
            self.diagnostics.append((time.time(), msg))
            del self.diagnostics[:-50]

    def publish(self, robot: str, grid: Grid, qos=LATCHED) -> None:
        """``grid`` as ``/<robot>/map`` (transient-local: the merger gets it whenever it subscribes)."""
        if robot not in self.pubs:
            self.pubs[robot] = self.node.create_publisher(OccupancyGrid, '/%s/map' % robot, qos)
        self.pubs[robot].publish(grid_to_msg(grid, self.node.get_clock().now().to_msg()))

    def publish_msg(self, robot: str, msg: OccupancyGrid) -> None:
        if robot not in self.pubs:
            self.pubs[robot] = self.node.create_publisher(OccupancyGrid, '/%s/map' % robot, LATCHED)
        self.pubs[robot].publish(msg)

    def transform(self, child: str, since: float = 0.0) -> Optional[np.ndarray]:
        """The latest pose of ``child`` in the merged frame "map" received on /tf after ``since``."""
        with self._lock:
            got = self.tf.get(child)
        return got[2] if got and got[0] > since and got[1] == 'map' else None

    def tf_rate(self, start: float, end: float, timeout: float = 10.0) -> Optional[float]:
        """The rate (Hz) of /tf messages stamped in [start, end) (wall seconds), counted by the
        publisher's stamps once one stamped after ``end`` came: a busy subscriber takes messages
        late and in bursts, so counting arrivals would give the wrong window its messages."""
        def after_end():
            with self._lock:
                return bool(self.tf_stamps) and self.tf_stamps[-1] >= end
        if not wait_until(after_end, max(0.0, end - time.time()) + timeout):
            return None
        with self._lock:
            n = sum(1 for s in self.tf_stamps if start <= s < end)
        return n / (end - start)

    def stamp(self, child: str, since: float = 0.0) -> Optional[float]:
        """The stamp (seconds) of the latest TF of ``child`` received after ``since``."""
        with self._lock:
            got = self.tf.get(child)
        return got[3] if got and got[0] > since else None

    def latest_map(self, since: float = 0.0) -> Optional[Grid]:
        with self._lock:
            got = self.maps[-1] if self.maps else None
        return grid_from_msg(got[1], 10 ** 9) if got and got[0] > since else None

    def robot_status(self, robot: str, since: float = 0.0) -> Optional[Dict[str, str]]:
        """The values of ``robot``'s latest status on /diagnostics after ``since`` (hardware id
        = the robot, as the ROS 1 node writes it), plus its message as ``message``."""
        with self._lock:
            arrays = [a for t, a in self.diagnostics if t > since]
        for a in reversed(arrays):
            for s in a.status:
                if s.hardware_id == robot:
                    return dict({kv.key: kv.value for kv in s.values}, message=s.message)
        return None

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()


class MergerProcess:
    """The merger node, a process of its own, its output in ``log_path``."""

    def __init__(self, log_path: str, *params: str):
        self.log_path = log_path
        self._log = open(log_path, 'w')
        args = [sys.executable, '-m', 'multi_map_merge_ros2.map_merge_node', '--ros-args']
        for p in params:
            args += ['-p', p]
        env = dict(os.environ, RCUTILS_LOGGING_BUFFERED_STREAM='0', PYTHONUNBUFFERED='1')
        self.proc = subprocess.Popen(args, stdout=self._log, stderr=subprocess.STDOUT, env=env)

    def lines(self, containing: str) -> List[str]:
        with open(self.log_path) as f:
            return [line for line in f if containing in line]

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> None:
        if self.alive():
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
