"""The ROS 2 node in a real graph (conftest.py): three robots' maps published transient-local,
the merged map received, each robot's TF within 0.10 m and 1 degree of the truth; a robot that
joins late placed; a malformed map refused with one log line, the node alive; a map that
restarts handled as the ROS 1 node does (test/ros/test_lifecycle.py: one warning, its cells out
of the merged map, its transform forgotten, placed again from its new map); parameters set at
run time taken on or refused with the reason; the services.

The tests run in order on one graph (module fixture): each starts where the last ended."""
from __future__ import annotations

import math
import time

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from conftest import Graph, MergerProcess, wait_until
from nav_msgs.msg import OccupancyGrid
from nav_msgs.srv import GetMap
from rcl_interfaces.srv import DescribeParameters, SetParameters
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger

from multi_map_merge.core.grid import Grid
from multi_map_merge.core.transforms import pose_distance
from multi_map_merge.lab.home import home_grid
from multi_map_merge.lab.pieces import cut_piece, split_rects
from multi_map_merge_ros2.convert import grid_to_msg
from multi_map_merge_ros2.outputs import LATCHED

# where each robot's map frame lies in the home (x m, y m, yaw rad); tb3_0 (the reference, first
# by name) at the home's origin, the others apart and turned
POSES = [(0.0, 0.0, 0.0), (1.5, -0.8, 0.6), (-1.2, 0.9, -0.9), (0.7, 1.3, 2.0)]
MAX_DISTANCE = 0.10           # m
MAX_ANGLE = math.radians(1.0)
PLACE_TIMEOUT = 60.0          # s: a few estimation cycles on a shared 2-core machine


@pytest.fixture(scope='module')
def home_pieces():
    """Four robots' maps cut out of the home, overlapping, each in its frame: [(Grid, T_home_k)]."""
    home = home_grid()
    rects = split_rects(home, 4, 0.35)
    return [cut_piece(home, rect, pose, 'tb3_%d/map' % k) for k, (rect, pose) in enumerate(zip(rects, POSES))]


@pytest.fixture(scope='module')
def graph(tmp_path_factory):
    log = str(tmp_path_factory.mktemp('ros2') / 'map_merge.log')
    merger = MergerProcess(log, 'estimation_rate:=2.0', 'workers:=1', 'stale_map_timeout:=0.0')
    g = Graph()
    yield g, merger
    g.close()
    merger.stop()


def truth(pieces, k: int) -> np.ndarray:
    """tb3_k's map frame in the merged frame (tb3_0's): T_home_0^-1 T_home_k."""
    return np.linalg.inv(pieces[0][1]) @ pieces[k][1]


def placed_right(g: Graph, robot: str, T_true: np.ndarray, since: float = 0.0):
    """The TF of ``robot`` received after ``since`` when within the tolerances of ``T_true``."""
    T = g.transform('%s/map' % robot, since)
    if T is None:
        return None
    d, a = pose_distance(T, T_true)
    return (d, a) if d < MAX_DISTANCE and a < MAX_ANGLE else None


def call(g: Graph, srv_type, name: str, request, timeout: float = 10.0):
    client = g.node.create_client(srv_type, name)
    assert client.wait_for_service(timeout_sec=timeout), 'no service %s' % name
    future = client.call_async(request)
    assert wait_until(future.done, timeout), 'no answer from %s' % name
    g.node.destroy_client(client)
    return future.result()


def test_1_three_robots_merged_with_their_tf(graph, home_pieces):
    g, merger = graph
    for k in range(3):
        g.publish('tb3_%d' % k, home_pieces[k][0])
    for k in (1, 2):
        got = wait_until(lambda k=k: placed_right(g, 'tb3_%d' % k, truth(home_pieces, k)), PLACE_TIMEOUT)
        assert got, 'tb3_%d not placed within %.2f m, 1 deg: TF %s' % (
            k, MAX_DISTANCE, g.transform('tb3_%d/map' % k))
        print('tb3_%d placed %.3f m, %.2f deg from the truth' % (k, got[0], math.degrees(got[1])))
    # the merged map: received, larger than any robot's own
    merged = wait_until(g.latest_map, 10.0)
    assert merged is not None, 'no merged map on /map'
    assert merged.frame_id == 'map'
    known = int(np.count_nonzero(merged.data >= 0))
    assert known > max(int(np.count_nonzero(p.data >= 0)) for p, _ in home_pieces[:3])
    # transient-local: a subscriber that comes now still gets it
    late = []
    sub = g.node.create_subscription(OccupancyGrid, '/map', late.append, LATCHED)
    assert wait_until(lambda: late, 10.0), 'a late subscriber of /map got nothing (not transient-local?)'
    g.node.destroy_subscription(sub)
    assert merger.alive()


def test_2_a_robot_that_joins_late_is_placed(graph, home_pieces):
    g, merger = graph
    g.publish('tb3_3', home_pieces[3][0])
    got = wait_until(lambda: placed_right(g, 'tb3_3', truth(home_pieces, 3)), PLACE_TIMEOUT)
    assert got, 'tb3_3 (late) not placed: TF %s' % g.transform('tb3_3/map')
    assert wait_until(lambda: (g.robot_status('tb3_3') or {}).get('merged') == 'true', 10.0)


def test_3_a_malformed_map_is_refused_with_one_line_and_the_node_lives_on(graph, home_pieces):
    g, merger = graph
    good = home_pieces[1][0]
    msg = grid_to_msg(good, g.node.get_clock().now().to_msg())
    msg.info.width += 7   # cells no longer width x height
    for _ in range(3):
        g.publish_msg('tb3_9', msg)
        time.sleep(0.5)
    assert wait_until(lambda: merger.lines('ignoring map of tb3_9'), 20.0), 'the malformed map was not refused'
    time.sleep(2.0)
    assert len(merger.lines('ignoring map of tb3_9')) == 1, merger.lines('ignoring map of tb3_9')
    assert merger.alive()
    status = wait_until(lambda: g.robot_status('tb3_9'), 10.0)
    assert status and status['message'].startswith('input ignored'), status
    # the others still merged, their TF still sent
    t = time.time()
    assert wait_until(lambda: placed_right(g, 'tb3_1', truth(home_pieces, 1), t), 5.0)


def test_4_a_map_that_restarts_is_forgotten_and_placed_again(graph, home_pieces):
    g, merger = graph
    before = g.latest_map()
    known_before = int(np.count_nonzero(before.data >= 0))
    g1 = home_pieces[1][0]
    # a SLAM reset: a small new map, a new origin
    small = Grid(g1.data[:60, :60].copy(), g1.resolution, (0.0, 0.0, 0.0), 'tb3_1/map')
    t = time.time()
    g.publish('tb3_1', small)
    assert wait_until(lambda: merger.lines('map of tb3_1 restarted'), 10.0), 'no restart logged'
    assert len(merger.lines('map of tb3_1 restarted')) == 1
    assert wait_until(lambda: (g.robot_status('tb3_1', t) or {}).get('merged') == 'false', 10.0), \
        'the restarted tb3_1 is still said merged'

    def smaller():
        m = g.latest_map(t)
        return m is not None and int(np.count_nonzero(m.data >= 0)) < 0.95 * known_before
    assert wait_until(smaller, 10.0), 'the restarted map\'s cells stayed in /map'
    # the robot maps on from where it restarted: its new map frame lies elsewhere
    new_pose = (2.0, 0.5, -0.4)
    home = home_grid()
    piece, T_home_k = cut_piece(home, split_rects(home, 4, 0.35)[1], new_pose, 'tb3_1/map')
    t = time.time()
    g.publish('tb3_1', piece)
    T_true = np.linalg.inv(home_pieces[0][1]) @ T_home_k
    got = wait_until(lambda: placed_right(g, 'tb3_1', T_true, t), PLACE_TIMEOUT)
    assert got, 'tb3_1 not placed again after its restart: TF %s' % g.transform('tb3_1/map')
    assert merger.alive()


def test_5_parameters_at_run_time_and_services(graph):
    g, merger = graph
    def set_param(name, value):
        req = SetParameters.Request(parameters=[Parameter(name, value=value).to_parameter_msg()])
        return call(g, SetParameters, '/map_merge/set_parameters', req).results[0]

    t = time.time()
    before = g.tf_rate(t, t + 3.0)
    ok = set_param('tf_rate', 4.0)
    assert ok.successful, ok.reason
    t = time.time() + 0.5     # the old timer's last tick may still come
    after = g.tf_rate(t, t + 3.0)
    assert before is not None and after is not None, 'no /tf stamped after the window: %s, %s' % (before, after)
    assert before > 12.0 and 2.0 < after < 6.0, '/tf at %.1f Hz, then %.1f Hz after tf_rate 4' % (before, after)
    ok = set_param('merge_rate', 4.0)
    assert ok.successful, ok.reason
    assert wait_until(lambda: merger.lines('parameter merge_rate set to 4.0'), 5.0)
    zero = set_param('merge_rate', 0.0)   # in the declared range's closed bound, refused by the resolver's rule
    assert not zero.successful and 'must be a number > 0' in zero.reason, zero.reason
    fixed = set_param('min_agreement', 0.5)
    assert not fixed.successful and 'read-only' in fixed.reason, fixed.reason
    desc = call(g, DescribeParameters, '/map_merge/describe_parameters',
                DescribeParameters.Request(names=['min_agreement', 'tf_rate'])).descriptors
    assert desc[0].read_only and desc[0].floating_point_range[0].to_value == 1.0 and desc[0].description
    assert not desc[1].read_only and '[Hz]' in desc[1].description

    got = call(g, GetMap, '/dynamic_map', GetMap.Request())
    assert got.map.info.width > 0 and got.map.header.frame_id == 'map'
    reset = call(g, Trigger, '/map_merge/reset', Trigger.Request())
    assert reset.success
    assert wait_until(lambda: merger.lines('all transforms forgotten'), 5.0)
    assert merger.alive()


def test_6_use_sim_time_stamps_on_the_simulated_clock(graph):
    """use_sim_time set at run time (ROS 2 lets it be): the node's clock, its timers and its
    stamps follow /clock."""
    g, merger = graph
    ok = call(g, SetParameters, '/map_merge/set_parameters', SetParameters.Request(
        parameters=[Parameter('use_sim_time', value=True).to_parameter_msg()])).results[0]
    assert ok.successful, ok.reason
    clock_pub = g.node.create_publisher(Clock, '/clock', 10)
    sim = 1000.0
    t = time.time()

    def sim_stamped():
        nonlocal sim
        sim += 0.05
        clock_pub.publish(Clock(clock=Time(sec=int(sim), nanosec=int((sim % 1) * 1e9))))
        stamp = g.stamp('tb3_1/map', t)
        return stamp if stamp is not None and 1000.0 < stamp <= sim else None
    stamp = wait_until(sim_stamped, 10.0, step=0.05)
    assert stamp, 'no TF stamped on the simulated clock (latest stamp %s)' % g.stamp('tb3_1/map')
    assert merger.alive()
