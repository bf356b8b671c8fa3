"""Small ROS tools and the helpers tests and the demo use: the map publisher (saved maps
published as growing gmapping maps), waiting for a map / the master / a merge, tf lookups, and
the TF relay of ``slam:=gmapping`` replays."""
from __future__ import annotations

import fnmatch
import sys
import time
from typing import Dict, List, Optional, Sequence

import numpy as np
import rospy
import tf2_ros
from diagnostic_msgs.msg import DiagnosticArray

from ..core.grid import Grid
from ..core.mapio import load_map, save_map
from ..core.transforms import cell_to_metric, se2
from .convert import NumpyGrid, grid_from_msg, grid_to_msg, quaternion_yaw, transform_msg
from .diagnostics import diagnostics_by_robot


def revealed(grid: Grid, radius: float) -> Optional[Grid]:
    """The part of ``grid`` a robot starting at its frame's origin has seen after exploring
    ``radius`` metres, on a grid cropped to it the way gmapping grows its canvas (new size,
    new origin at a whole number of cells)."""
    W = cell_to_metric(grid.resolution, grid.origin)
    rr, cc = np.mgrid[0:grid.height, 0:grid.width]
    x = W[0, 0] * cc + W[0, 1] * rr + W[0, 2]
    y = W[1, 0] * cc + W[1, 1] * rr + W[1, 2]
    seen = np.hypot(x, y) <= radius
    data = np.where(seen, grid.data, -1).astype(np.int8)
    rows = np.flatnonzero((data >= 0).any(axis=1))
    cols = np.flatnonzero((data >= 0).any(axis=0))
    if rows.size == 0:
        return None
    m = 20
    r0, r1 = max(0, rows[0] - m), min(grid.height, rows[-1] + 1 + m)
    c0, c1 = max(0, cols[0] - m), min(grid.width, cols[-1] + 1 + m)
    o = W @ np.array([c0 - 0.5, r0 - 0.5, 1.0])
    return Grid(np.ascontiguousarray(data[r0:r1, c0:c1]), grid.resolution,
                (float(o[0]), float(o[1]), grid.origin[2]), grid.frame_id)


def run_map_publisher(robots: Sequence[str], grids: Sequence[Grid], steps: int, period: float,
                      start_poses: Optional[Sequence[Sequence[float]]] = None,
                      once: bool = False) -> None:
    """Publish each grid on ``/<robot>/map`` (latched, frame ``<robot>/map``) as gmapping would:
    growing in ``steps`` steps from the robot's start (the frame origin), one every ``period``
    seconds, then the whole map again every ``period`` seconds. Also broadcasts the robot's
    own ``<robot>/map -> <robot>/odom -> <robot>/base_footprint`` so TF chains are complete.
    """
    rospy.init_node('map_publisher', anonymous=True)
    pubs = [rospy.Publisher('/%s/map' % r, NumpyGrid, queue_size=1, latch=True) for r in robots]
    tfb = tf2_ros.TransformBroadcaster()
    full_radius = [max(1e-3, float(np.hypot(*np.array([[g.origin[0], g.origin[1]],
                                                        [g.origin[0] + g.width * g.resolution,
                                                         g.origin[1] + g.height * g.resolution]]).T).max()) * 1.5)
                   for g in grids]
    poses = list(start_poses) if start_poses else [(0.0, 0.0, 0.0)] * len(robots)
    k = 0
    next_map = 0.0
    rate = rospy.Rate(10)
    while not rospy.is_shutdown():
        now = rospy.Time.now()
        if time.monotonic() >= next_map:
            k += 1
            for r, g, pub, rad in zip(robots, grids, pubs, full_radius):
                part = g if k >= steps else revealed(g, rad * k / float(steps))
                if part is not None:
                    pub.publish(grid_to_msg(part, now, '%s/map' % r))
            next_map = time.monotonic() + period
            if once and k >= steps:
                rospy.sleep(1.0)
                return
        tfs = []
        for r, p in zip(robots, poses):
            tfs.append(transform_msg(np.eye(3), '%s/map' % r, '%s/odom' % r, now))
            tfs.append(transform_msg(se2(*p), '%s/odom' % r, '%s/base_footprint' % r, now))
        tfb.sendTransform(tfs)
        rate.sleep()


def wait_for_map(topic: str, timeout: float) -> Optional[Grid]:
    """First OccupancyGrid on ``topic`` within ``timeout`` seconds, as a Grid (None if none)."""
    try:
        msg = rospy.wait_for_message(topic, NumpyGrid, timeout=timeout)
    except rospy.ROSException:
        return None
    return grid_from_msg(msg, 10 ** 9)


def wait_for_master(timeout: float) -> bool:
    """True once a ROS master answers at ROS_MASTER_URI (within ``timeout`` seconds)."""
    import rosgraph
    end = time.time() + timeout
    while time.time() < end:
        if rosgraph.is_master_online():
            return True
        time.sleep(0.2)
    return False


def wait_for_merge(robots: Sequence[str], timeout: float, settle: float = 0.0) -> Dict[str, Dict[str, str]]:
    """Per-robot key/values of the merger's /diagnostics once every robot in ``robots`` is
    merged and ``settle`` more seconds have passed (or at ``timeout``)."""
    latest: Dict[str, Dict[str, str]] = {}

    sub = rospy.Subscriber('/diagnostics', DiagnosticArray, diagnostics_by_robot, callback_args=latest)
    end = time.time() + timeout
    merged_since = None
    while time.time() < end and not rospy.is_shutdown():
        done = all(latest.get(r, {}).get('merged') == 'true' for r in robots)
        if done and merged_since is None:
            merged_since = time.time()
        if done and time.time() - merged_since >= settle:
            break
        time.sleep(0.2)
    sub.unregister()
    return dict(latest)


def init_node(name: str) -> None:
    rospy.init_node(name, anonymous=True)


def lookup_transforms(parent: str, children: List[str], timeout: float) -> Dict[str, np.ndarray]:
    """tf2 lookups ``parent -> child`` (3x3 poses, metres); children not found are left out."""
    buf = tf2_ros.Buffer()
    tf2_ros.TransformListener(buf)
    out = {}
    end = time.time() + timeout
    for c in children:
        while time.time() < end and not rospy.is_shutdown():
            try:
                t = buf.lookup_transform(parent, c, rospy.Time(0), rospy.Duration(0.5))
                tr = t.transform
                out[c] = se2(tr.translation.x, tr.translation.y, quaternion_yaw(tr.rotation))
                break
            except (tf2_ros.LookupException, tf2_ros.ConnectivityException,
                    tf2_ros.ExtrapolationException):
                time.sleep(0.1)
    return out


def run_tf_relay(src: str = '/tf_bag', dst: str = '/tf', drop_parent: str = '*/map',
                 drop_child: str = '*/odom') -> None:
    """Republish ``src`` (tf2_msgs/TFMessage) on ``dst`` without the transforms whose parent
    and child match ``drop_parent`` and ``drop_child`` (fnmatch patterns): a recorded bag's own
    SLAM ``map -> odom`` must not fight the live gmapping that replaces it."""
    from tf2_msgs.msg import TFMessage
    pub = rospy.Publisher(dst, TFMessage, queue_size=100)
    dropped = set()

    def on_tf(msg):
        keep = []
        for t in msg.transforms:
            p, c = t.header.frame_id.lstrip('/'), t.child_frame_id.lstrip('/')
            if fnmatch.fnmatch(p, drop_parent) and fnmatch.fnmatch(c, drop_child):
                if (p, c) not in dropped:
                    dropped.add((p, c))
                    rospy.loginfo('tf_relay: dropping the recorded %s -> %s (live SLAM publishes it)', p, c)
                continue
            keep.append(t)
        if keep:
            pub.publish(TFMessage(keep))

    rospy.Subscriber(src, TFMessage, on_tf, queue_size=100)
    rospy.spin()


def run_frame_prefix_relay(prefix: str, time_offset: float) -> None:
    """One robot of a team made of single-robot bags (each names its frames ``odom``,
    ``base_link``, ``laser`` on the one ``/tf``): republish ``scan_raw``, ``odom_raw`` and
    ``tf_raw`` (relative to the node's namespace) as ``scan``, ``odom`` and ``/tf`` with every
    frame id prefixed (``<prefix>/odom`` ...) and every stamp moved by ``time_offset`` seconds,
    so that runs recorded minutes apart play at once under one ``/clock``."""
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import LaserScan
    from tf2_msgs.msg import TFMessage
    shift = rospy.Duration.from_sec(time_offset)

    def frame(f: str) -> str:
        return '%s/%s' % (prefix, f.lstrip('/')) if f else f

    def moved(header) -> None:
        header.stamp = header.stamp + shift
        header.frame_id = frame(header.frame_id)

    pubs = {}

    def relay(name, msg_type, fix, out=None):
        pubs[name] = rospy.Publisher(out or name, msg_type, queue_size=50)

        def on_msg(msg):
            fix(msg)
            pubs[name].publish(msg)
        rospy.Subscriber(name + '_raw', msg_type, on_msg, queue_size=50)

    def fix_odom(msg):
        moved(msg.header)
        msg.child_frame_id = frame(msg.child_frame_id)

    def fix_tf(msg):
        for t in msg.transforms:
            moved(t.header)
            t.child_frame_id = frame(t.child_frame_id)

    relay('scan', LaserScan, lambda m: moved(m.header))
    relay('odom', Odometry, fix_odom)
    relay('tf', TFMessage, fix_tf, '/tf')
    rospy.loginfo('frame_prefix_relay: frames under %s/, stamps %+.3f s', prefix, time_offset)
    rospy.spin()


def run_scan_frame_relay(frame_id: str, src: str = 'scan', dst: str = 'scan_framed') -> None:
    """Republish a robot's ``src`` (sensor_msgs/LaserScan, relative to the node's namespace)
    on ``dst`` with ``header.frame_id`` set to ``frame_id``. ROBOTIS's ``ld08_driver`` (the
    LDS-02's, noetic branch) stamps every scan ``base_scan`` whatever ``frame_id`` it is given,
    so a robot in a team cannot have its scans in ``<robot>/base_scan`` where its
    robot_state_publisher puts the laser; gmapping then finds no laser pose. A scan already in
    ``frame_id`` passes unchanged."""
    from sensor_msgs.msg import LaserScan
    pub = rospy.Publisher(dst, LaserScan, queue_size=5)
    seen = set()

    def on_scan(msg):
        got = msg.header.frame_id
        if got != frame_id and got not in seen:
            seen.add(got)
            rospy.loginfo('scan_frame_relay: scans of %s in frame "%s" republished on %s in "%s"',
                          rospy.resolve_name(src), got, rospy.resolve_name(dst), frame_id)
        msg.header.frame_id = frame_id
        pub.publish(msg)

    rospy.Subscriber(src, LaserScan, on_scan, queue_size=5)
    rospy.spin()


# ---------------------------------------------------------------- the scripts
def publish_maps_main(argv: Optional[List[str]] = None) -> int:
    """``publish_maps tb3_0:A.yaml tb3_1:B.yaml ... [--steps 4] [--period 2]``: publish saved
    maps on /<robot>/map as gmapping robots would (latched, growing), for demos and tests
    without robots."""
    from ..core.cli import parser
    ap = parser('publish_maps', publish_maps_main.__doc__)
    ap.add_argument('maps', nargs='+', help='robot:map.yaml pairs')
    ap.add_argument('--steps', type=int, default=4, help='growth steps before the whole map')
    ap.add_argument('--period', type=float, default=2.0, help='seconds between map messages')
    ap.add_argument('--once', action='store_true', help='stop after the whole map was published')
    a = ap.parse_args(rospy.myargv()[1:] if argv is None else argv)
    robots, grids = [], []
    for item in a.maps:
        robot, _, path = item.partition(':')
        if not path:
            ap.error('%r is not robot:map.yaml' % item)
        robots.append(robot)
        grids.append(load_map(path))
    run_map_publisher(robots, grids, a.steps, a.period, once=a.once)
    return 0


def save_map_main(argv: Optional[List[str]] = None) -> int:
    """``save_map -f merged [--topic /map] [--timeout 30]``: save the next OccupancyGrid on a
    topic as map_server files (map_saver is not in Debian)."""
    from ..core.cli import parser
    ap = parser('save_map', save_map_main.__doc__)
    ap.add_argument('-f', '--file', default='map', help='output base name (writes .pgm and .yaml)')
    ap.add_argument('--topic', default='/map')
    ap.add_argument('--timeout', type=float, default=30.0)
    a = ap.parse_args(rospy.myargv()[1:] if argv is None else argv)
    init_node('save_map')
    grid = wait_for_map(a.topic, a.timeout)
    if grid is None:
        print('save_map: no map on %s within %.0f s' % (a.topic, a.timeout), file=sys.stderr)
        return 1
    pgm, yml = save_map(grid, a.file + '.yaml')
    print('saved %s and %s (%dx%d cells)' % (pgm, yml, grid.width, grid.height))
    return 0


def tf_relay_main() -> int:
    """``tf_relay``: a bag's /tf without its recorded SLAM map -> odom (slam:=gmapping replays).
    Parameters: ~src (/tf_bag), ~dst (/tf), ~drop_parent (*/map), ~drop_child (*/odom)."""
    rospy.init_node('tf_relay')
    run_tf_relay(rospy.get_param('~src', '/tf_bag'), rospy.get_param('~dst', '/tf'),
                 rospy.get_param('~drop_parent', '*/map'), rospy.get_param('~drop_child', '*/odom'))
    return 0


def frame_prefix_relay_main() -> int:
    """``frame_prefix_relay``: one robot of a team of single-robot bags: its scan, odom and tf
    (played into the namespace as scan_raw, odom_raw, tf_raw) republished with frames prefixed
    and stamps moved onto the team's clock. Parameters: ~prefix (default: the namespace), ~bag
    and ~clock_bag (the stamps move by start(clock_bag) - start(bag)) or ~time_offset (s)."""
    from .replay import bag_start
    rospy.init_node('frame_prefix_relay')
    prefix = rospy.get_param('~prefix', rospy.get_namespace().strip('/'))
    offset = float(rospy.get_param('~time_offset', 0.0))
    bag, clock_bag = rospy.get_param('~bag', ''), rospy.get_param('~clock_bag', '')
    if bag and clock_bag:
        offset = bag_start(clock_bag) - bag_start(bag)
    run_frame_prefix_relay(prefix, offset)
    return 0


def scan_frame_relay_main() -> int:
    """``scan_frame_relay``: a robot's ``scan`` republished on ``scan_framed`` in its own laser
    frame. Parameters: ~frame_id (default ``<namespace>/base_scan``), ~src (scan), ~dst
    (scan_framed)."""
    rospy.init_node('scan_frame_relay')
    ns = rospy.get_namespace().strip('/')
    frame_id = str(rospy.get_param('~frame_id', '%s/base_scan' % ns if ns else 'base_scan')).strip()
    if not frame_id:
        rospy.logerr('scan_frame_relay: ~frame_id is empty; using base_scan')
        frame_id = 'base_scan'
    run_scan_frame_relay(frame_id, rospy.get_param('~src', 'scan'), rospy.get_param('~dst', 'scan_framed'))
    return 0
