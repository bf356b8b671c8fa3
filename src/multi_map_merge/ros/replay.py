"""Bags: robots' runs written as a rosbag as real Turtlebot3s record them, the maps of a bag
read back, and a replay through the merger recorded (trajectories through the merged TF)."""
from __future__ import annotations

import os
import sys
import time
from typing import Dict, List, Optional, Sequence

import numpy as np
import rospy
import tf2_ros
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rospy.numpy_msg import numpy_msg

from ..core.grid import Grid, GridError
from ..core.mapio import save_map
from ..core.transforms import compose, relative, se2
from .convert import NumpyGrid, grid_from_msg, grid_to_msg, quaternion_yaw, set_yaw, transform_msg
from .diagnostics import diagnostics_by_robot

BAG_EPOCH = 1_600_000_000.0   # bag time of a simulated run's t = 0 (fixed: bags are reproducible)


def write_robot_bag(path: str, runs, clock_rate: float = 10.0, slam: bool = True,
                    scan_frame: Optional[str] = None) -> Dict[str, int]:
    """Write robots' runs (:class:`multi_map_merge.lab.simulate.RobotRun`) to a rosbag as real
    Turtlebot3s running gmapping record them, each robot under ``/<name>/``:
    ``/<name>/scan`` (LaserScan, frame ``<name>/base_scan``, or ``scan_frame`` for every robot
    when given: ``ld08_driver`` stamps ``base_scan`` whatever it is asked; shaped as the run's
    scans are: fixed beams, or ``ld08_driver``'s with :class:`multi_map_merge.lab.simulate.DriverScans`),
    ``/<name>/odom`` (Odometry),
    ``/<name>/map`` (OccupancyGrid, frame ``<name>/map``), ``/tf`` (``<name>/odom ->
    <name>/base_footprint`` at the odometry rate, ``<name>/base_footprint -> <name>/base_scan``
    with every scan, gmapping's ``<name>/map -> <name>/odom``), and ``/clock``. With ``slam``
    False, only what the robot's own sensors record: no map and no ``map -> odom`` (for a live
    SLAM to make them). Returns the number of messages per topic. lz4-compressed."""
    import rosbag
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage

    NumpyScan = numpy_msg(LaserScan)
    counts: Dict[str, int] = {}
    records = []   # (time s, order, topic, msg): sorted before writing

    def add(t, topic, msg, order=0):
        records.append((t, order, topic, msg))
        counts[topic] = counts.get(topic, 0) + 1

    def stamp(t):
        return rospy.Time.from_sec(BAG_EPOCH + t)

    end = 0.0
    for run in runs:
        n = run.name
        f_map, f_odom, f_base, f_scan = n + '/map', n + '/odom', n + '/base_footprint', n + '/base_scan'
        dt = run.t[1] - run.t[0] if len(run.t) > 1 else 0.05
        v = np.hypot(*np.diff(run.odom[:, :2], axis=0).T) / dt
        w = np.diff(np.unwrap(run.odom[:, 2])) / dt
        map_odom = compose(run.slam, relative(run.odom, np.zeros_like(run.odom)))   # slam ⊕ odom^-1
        scan_at = set(int(s) for s in run.scans.steps)
        for i, t in enumerate(run.t):
            st = stamp(t)
            od = Odometry()
            od.header.stamp, od.header.frame_id, od.child_frame_id = st, f_odom, f_base
            x, y, yaw = run.odom[i]
            od.pose.pose.position.x, od.pose.pose.position.y = x, y
            set_yaw(od.pose.pose.orientation, yaw)
            if i > 0:
                od.twist.twist.linear.x, od.twist.twist.angular.z = v[i - 1], w[i - 1]
            add(t, '/%s/odom' % n, od)
            tfs = [transform_msg(se2(*run.odom[i]), f_odom, f_base, st)]
            if i in scan_at:
                o = run.scans.offset
                tr = transform_msg(se2(o[0], o[1], 0.0), f_base, f_scan, st)
                tr.transform.translation.z = o[2]
                tfs.append(tr)
            add(t, '/tf', TFMessage(tfs))
            if slam:
                add(t, '/tf', TFMessage([transform_msg(se2(*map_odom[i]), f_map, f_odom, st)]), 1)
        sc = run.scans
        for k, step in enumerate(sc.steps):
            t = float(run.t[step])
            m = NumpyScan()
            m.header.stamp, m.header.frame_id = stamp(t), scan_frame or f_scan
            amin, ainc, ranges = sc.scan(k)
            m.angle_min, m.angle_increment = amin, ainc
            m.angle_max = amin + ainc * (len(ranges) - 1)
            m.scan_time = 1.0 / 5.0
            m.time_increment = m.scan_time / len(ranges)
            m.range_min, m.range_max = sc.range_min, sc.range_max
            m.ranges = np.ascontiguousarray(ranges, np.float32)
            m.intensities = np.zeros(0, np.float32)
            add(t, '/%s/scan' % n, m, 2)
        for t, grid in run.maps if slam else ():
            add(t, '/%s/map' % n, grid_to_msg(grid, stamp(t), f_map), 3)
        end = max(end, float(run.t[-1]))
    for t in np.arange(0.0, end + 1e-9, 1.0 / clock_rate):
        c = Clock()
        c.clock = stamp(float(t))
        add(float(t), '/clock', c, -1)
    records.sort(key=lambda r: (r[0], r[1]))
    with rosbag.Bag(path, 'w', compression='lz4') as bag:
        for t, _, topic, msg in records:
            bag.write(topic, msg, stamp(t))
    return counts


def read_stamps_and_poses(path: str, stamp_topics: Sequence[str],
                          odom_topics: Sequence[str]) -> Dict[str, list]:
    """From a bag: per topic of ``stamp_topics`` its messages' header stamps (seconds), per topic
    of ``odom_topics`` its nav_msgs/Odometry as [stamp, x, y, yaw] (seconds, metres, radians)."""
    import rosbag
    out: Dict[str, list] = {t: [] for t in list(stamp_topics) + list(odom_topics)}
    odom = set(odom_topics)
    with rosbag.Bag(path) as bag:
        for topic, msg, _ in bag.read_messages(topics=list(out)):
            s = msg.header.stamp.to_sec()
            if topic in odom:
                p = msg.pose.pose.position
                out[topic].append([s, p.x, p.y, quaternion_yaw(msg.pose.pose.orientation)])
            else:
                out[topic].append(s)
    return out


def read_bag_maps(path: str, max_cells: int = 100_000_000) -> Dict[str, List[Grid]]:
    """Every OccupancyGrid in a bag, per topic, in order (numpy all the way)."""
    import rosbag
    out: Dict[str, List[Grid]] = {}
    with rosbag.Bag(path) as bag:
        topics = [t for t, i in bag.get_type_and_topic_info().topics.items() if i.msg_type == 'nav_msgs/OccupancyGrid']
        for topic, msg, _ in bag.read_messages(topics=topics):
            out.setdefault(topic, []).append(grid_from_msg(msg, max_cells))
    return out


def record_replay(robots: Sequence[str], period: float = 0.5, idle: float = 4.0,
                  timeout: float = 3600.0, merged_frame: str = 'map', start_timeout: float = 60.0,
                  base_frame: str = 'base_footprint') -> Dict:
    """Watch a replay through the merger until the bag ends (``/clock`` still for ``idle``
    wall seconds after it moved, or no ``/clock`` at all within ``start_timeout``, or
    ``timeout``, or shutdown). Every ``period`` wall seconds it looks up, by tf2, each robot's
    ``<robot>/<base_frame>`` in its ``<robot>/map`` frame (its trajectory), that map frame in
    ``merged_frame`` (the merged TF), and the base frame in ``merged_frame`` (through both).
    Returns {'map': last merged Grid or None, 'robots': {name: {'trajectory': [[t, x, y, yaw] in
    <robot>/map, ...], 'tf': [x, y, yaw] of <robot>/map in the merged frame, or None, 'base':
    [x, y, yaw] of its base frame in the merged frame, or None, 'diagnostics': {...}}},
    'robot_maps': {name: the robot's last
    /<name>/map Grid}, 'clock': last /clock seconds}."""
    from rosgraph_msgs.msg import Clock
    state: Dict = {'map': None, 'clock': None, 'clock_wall': None, 'diag': {}, 'robot_maps': {}}

    def on_map(msg, robot=None):
        try:
            grid = grid_from_msg(msg, 10 ** 9)
        except (GridError, ValueError):
            return
        if robot is None:
            state['map'] = grid
        else:
            state['robot_maps'][robot] = grid

    def on_clock(msg):
        c = msg.clock.to_sec()
        if state['clock'] is None or c > state['clock']:
            state['clock'], state['clock_wall'] = c, time.time()

    subs = [rospy.Subscriber('/map', NumpyGrid, on_map, queue_size=1, buff_size=2 ** 26),
            rospy.Subscriber('/clock', Clock, on_clock, queue_size=10),
            rospy.Subscriber('/diagnostics', DiagnosticArray, diagnostics_by_robot, callback_args=state['diag'],
                             queue_size=10)]
    subs += [rospy.Subscriber('/%s/map' % r, NumpyGrid, on_map, callback_args=r, queue_size=1, buff_size=2 ** 26)
             for r in robots]
    buf = tf2_ros.Buffer(cache_time=rospy.Duration(3600.0))
    tf2_ros.TransformListener(buf)
    traj: Dict[str, List] = {r: [] for r in robots}
    last_tf: Dict[str, Optional[List[float]]] = {r: None for r in robots}
    last_base: Dict[str, Optional[List[float]]] = {r: None for r in robots}
    end = time.time() + timeout
    while not rospy.is_shutdown() and time.time() < end:
        time.sleep(period)              # wall time: the sim clock stops when the bag ends
        if state['clock_wall'] is not None and time.time() - state['clock_wall'] > idle:
            break
        if state['clock_wall'] is None and time.time() > end - timeout + start_timeout:
            rospy.logerr('record_replay: no /clock within %.0f s: is the bag playing?', start_timeout)
            break
        for r in robots:
            # the trajectory in the robot's own map frame (there from its first scan on), and
            # where the merger puts that frame: together, the trajectory through the merged TF
            for parent, child, store in (('%s/map' % r, '%s/%s' % (r, base_frame), 'traj'),
                                         (merged_frame, '%s/map' % r, 'tf'),
                                         (merged_frame, '%s/%s' % (r, base_frame), 'base')):
                try:
                    t = buf.lookup_transform(parent, child, rospy.Time(0))
                except (tf2_ros.LookupException, tf2_ros.ConnectivityException,
                        tf2_ros.ExtrapolationException):
                    continue
                tr = t.transform
                p = [float(tr.translation.x), float(tr.translation.y), float(quaternion_yaw(tr.rotation))]
                if store == 'tf':
                    last_tf[r] = p
                elif store == 'base':
                    last_base[r] = p
                elif not traj[r] or traj[r][-1][0] != t.header.stamp.to_sec():
                    traj[r].append([t.header.stamp.to_sec()] + p)
    for s in subs:
        s.unregister()
    return {'map': state['map'], 'clock': state['clock'], 'robot_maps': state['robot_maps'],
            'robots': {r: {'trajectory': traj[r], 'tf': last_tf[r], 'base': last_base[r],
                           'diagnostics': state['diag'].get(r, {})}
                       for r in robots}}


def bag_start(path: str) -> float:
    """Bag time (s) of a bag's first message."""
    import rosbag
    with rosbag.Bag(path) as bag:
        return bag.get_start_time()


def save_record(rec: Dict, out_dir: str) -> bool:
    """Write a replay's record (see :func:`record_replay`): merged.{yaml,pgm}, each robot's
    last map as <robot>_map.{yaml,pgm}, and record.yaml. False when no merged map was ever
    received."""
    os.makedirs(out_dir, exist_ok=True)
    for robot, grid in (rec.get('robot_maps') or {}).items():
        save_map(grid, os.path.join(out_dir, '%s_map.yaml' % robot))
    doc = {'clock': rec.get('clock'), 'robots': rec['robots']}
    with open(os.path.join(out_dir, 'record.yaml'), 'w') as f:
        yaml.safe_dump(doc, f, sort_keys=False)
    if rec.get('map') is None:
        print('record_replay: no merged map was received on /map', file=sys.stderr)
        return False
    save_map(rec['map'], os.path.join(out_dir, 'merged.yaml'))
    return True


def record_replay_main(argv: Optional[List[str]] = None) -> int:
    """``record_replay -o DIR ROBOT...``: watch a bag replay through the merger and keep what it
    made: DIR/merged.{yaml,pgm} (the last /map) and DIR/record.yaml (each robot's trajectory in
    the merged frame through the merged TF, its map frame's pose, its /diagnostics). Stops when
    /clock has stood still for --idle seconds (the bag ended)."""
    from ..cli.args import parser
    ap = parser('record_replay', record_replay_main.__doc__)
    ap.add_argument('robots', nargs='+')
    ap.add_argument('-o', '--output', required=True)
    ap.add_argument('--idle', type=float, default=4.0, help='wall seconds of a still /clock that end the recording')
    ap.add_argument('--timeout', type=float, default=1800.0)
    ap.add_argument('--period', type=float, default=0.5, help='wall seconds between TF samples')
    ap.add_argument('--base-frame', default='base_footprint', help='each robot\'s base frame, without its namespace')
    a = ap.parse_args(rospy.myargv()[1:] if argv is None else argv)
    rospy.init_node('record_replay', anonymous=True)
    rec = record_replay(a.robots, a.period, a.idle, a.timeout, base_frame=a.base_frame)
    return 0 if save_record(rec, a.output) else 1
