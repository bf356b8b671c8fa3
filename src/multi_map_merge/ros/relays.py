"""The relays, light enough for a robot's computer: ``scan_frame_relay`` (a robot's scans in its
own laser frame, resampled for gmapping), ``tf_relay`` (a bag's /tf without its recorded SLAM
``map -> odom``) and ``frame_prefix_relay`` (single-robot bags played as one team).

Their import chain has no OpenCV, numpy or scipy (test/unit/ros/test_relays_light.py): this
module imports only the standard library and :mod:`multi_map_merge.core.scans` (itself
standard library only) at load, and rospy and the message modules when a relay starts. genpy
(every rospy process) imports numpy when it can, only to accept numpy scalars in messages; the
relays' entry points refuse that optional import (:func:`keep_numpy_out`), so a relay holds
about 15 MB less (docs/measurements.md, "The robot side's memory").
"""
from __future__ import annotations

import argparse
import fnmatch
import inspect
import sys
from typing import List, Optional

from ..core.scans import (
    LDS02,
    LDS02_BEAMS,
    LDS02_RANGE_MAX,
    LDS02_RANGE_MIN,
    Scan,
    ScanGrid,
    describe_change,
    normalise_scan,
)


def keep_numpy_out() -> None:
    """Make ``import numpy`` fail in this process unless numpy is loaded already. Only for the
    relays' own processes (their ``*_main``): genpy's ``try: import numpy`` (genpy/message.py)
    then falls back to plain Python types, which is all a relay's messages hold."""
    if 'numpy' not in sys.modules:
        sys.modules['numpy'] = None  # type: ignore[assignment]   # Python: None there = not importable


def node_argv(argv: Optional[List[str]] = None) -> List[str]:
    """The command line without ROS remappings (``name:=value``, which roslaunch adds), as
    rospy.myargv does, without importing rospy (a --help must start nothing)."""
    return [a for a in (sys.argv[1:] if argv is None else argv) if ':=' not in a]


def parse_help(prog: str, doc: str, argv: Optional[List[str]] = None) -> None:
    """Answer ``-h``/``--help`` with ``doc`` (the node's full usage) and exit; exit 2 on any other
    argument (the relays take ROS parameters, not options)."""
    ap = argparse.ArgumentParser(prog=prog, description=inspect.cleandoc(doc),
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.parse_args(node_argv(argv))


def bag_start(path: str) -> float:
    """Bag time (s) of a bag's first message."""
    import rosbag
    with rosbag.Bag(path) as bag:
        return bag.get_start_time()


# ---------------------------------------------------------------------------------- tf_relay
def run_tf_relay(src: str = '/tf_bag', dst: str = '/tf', drop_parent: str = '*/map',
                 drop_child: str = '*/odom') -> None:
    """Republish ``src`` (tf2_msgs/TFMessage) on ``dst`` without the transforms whose parent
    and child match ``drop_parent`` and ``drop_child`` (fnmatch patterns): a recorded bag's own
    SLAM ``map -> odom`` must not fight the live gmapping that replaces it."""
    import rospy
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


# ------------------------------------------------------------------------ frame_prefix_relay
def run_frame_prefix_relay(prefix: str, time_offset: float) -> None:
    """One robot of a team made of single-robot bags (each names its frames ``odom``,
    ``base_link``, ``laser`` on the one ``/tf``): republish ``scan_raw``, ``odom_raw`` and
    ``tf_raw`` (relative to the node's namespace) as ``scan``, ``odom`` and ``/tf`` with every
    frame id prefixed (``<prefix>/odom`` ...) and every stamp moved by ``time_offset`` seconds,
    so that runs recorded minutes apart play at once under one ``/clock``."""
    import rospy
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


# -------------------------------------------------------------------------- scan_frame_relay
def scan_of_msg(msg) -> Scan:
    """A sensor_msgs/LaserScan's fields as a :class:`multi_map_merge.core.scans.Scan`."""
    return Scan(msg.angle_min, msg.angle_max, msg.angle_increment, msg.time_increment, msg.scan_time,
                msg.range_min, msg.range_max, msg.ranges, msg.intensities)


def fill_msg(msg, scan: Scan) -> None:
    """Write ``scan``'s fields into the LaserScan ``msg`` (its header stays)."""
    (msg.angle_min, msg.angle_max, msg.angle_increment, msg.time_increment, msg.scan_time,
     msg.range_min, msg.range_max) = scan[:7]
    msg.ranges, msg.intensities = list(scan.ranges), list(scan.intensities)


def run_scan_frame_relay(frame_id: str, src: str = 'scan', dst: str = 'scan_framed',
                         grid: Optional[ScanGrid] = LDS02) -> None:
    """Republish a robot's ``src`` (sensor_msgs/LaserScan, relative to the node's namespace)
    on ``dst`` with ``header.frame_id`` set to ``frame_id`` and, unless ``grid`` is None, its
    readings resampled onto ``grid`` (:func:`multi_map_merge.core.scans.normalise_scan`).

    ROBOTIS's ``ld08_driver`` (the LDS-02's, noetic branch) stamps every scan ``base_scan``
    whatever ``frame_id`` it is given, so a robot in a team cannot have its scans in
    ``<robot>/base_scan`` where its robot_state_publisher puts the laser; gmapping then finds no
    laser pose. It also sizes each scan to its revolution's points, with 0 for no point,
    ``range_min`` 0 and ``range_max`` 100: gmapping would use only the scans as long as its
    first. A scan in the fixed form already passes with its readings unchanged. What is
    changed is logged once, and again only when a scan needs another kind of change."""
    import rospy
    from sensor_msgs.msg import LaserScan
    pub = rospy.Publisher(dst, LaserScan, queue_size=5)
    seen = set()
    said = set()

    def on_scan(msg):
        got = msg.header.frame_id
        if got != frame_id and got not in seen:
            seen.add(got)
            rospy.loginfo('scan_frame_relay: scans of %s in frame "%s" republished on %s in "%s"',
                          rospy.resolve_name(src), got, rospy.resolve_name(dst), frame_id)
        msg.header.frame_id = frame_id
        if grid is not None:
            scan = scan_of_msg(msg)
            out = normalise_scan(scan, grid)
            # a driver's scan lengths vary: one line for that, not one per length
            kind = (out is scan, len(scan.ranges) == grid.beams, scan.range_min, scan.range_max)
            if kind not in said:
                said.add(kind)
                change = describe_change(scan, grid)
                if change:
                    (rospy.logwarn if out is scan else rospy.loginfo)(
                        'scan_frame_relay: %s for gmapping: %s', rospy.resolve_name(src), change)
            if out is not scan:
                fill_msg(msg, out)
        pub.publish(msg)

    rospy.Subscriber(src, LaserScan, on_scan, queue_size=5)
    rospy.spin()


# ------------------------------------------------------------------------------ the scripts
def tf_relay_main(argv: Optional[List[str]] = None) -> int:
    """``tf_relay``: a bag's /tf republished without its recorded SLAM map -> odom, for
    slam:=gmapping replays (launch/bag_replay.launch), where a live gmapping publishes it.

    ROS parameters (private):
      ~src          TFMessage topic to read (default /tf_bag)
      ~dst          topic to publish on (default /tf)
      ~drop_parent  fnmatch pattern of the parent frames to drop (default */map)
      ~drop_child   fnmatch pattern of their child frames (default */odom)
    Example: rosrun multi_map_merge tf_relay _src:=/tf_bag"""
    parse_help('tf_relay', tf_relay_main.__doc__, argv)
    keep_numpy_out()
    import rospy
    rospy.init_node('tf_relay')
    run_tf_relay(rospy.get_param('~src', '/tf_bag'), rospy.get_param('~dst', '/tf'),
                 rospy.get_param('~drop_parent', '*/map'), rospy.get_param('~drop_child', '*/odom'))
    return 0


def frame_prefix_relay_main(argv: Optional[List[str]] = None) -> int:
    """``frame_prefix_relay``: one robot of a team of single-robot bags: its scan, odom and tf,
    played into the node's namespace as scan_raw, odom_raw and tf_raw, republished as scan, odom
    and /tf with every frame prefixed and every stamp moved onto the team's clock
    (launch/team_bags_gmapping.launch).

    ROS parameters (private):
      ~prefix       frame prefix (default: the node's namespace, e.g. tb3_1 -> tb3_1/odom)
      ~bag          this robot's bag, and
      ~clock_bag    the bag whose clock the team plays on: stamps move by
                    start(clock_bag) - start(bag)
      ~time_offset  seconds to move the stamps by, when ~bag and ~clock_bag are not both set (0)
    Example: ROS_NAMESPACE=tb3_1 rosrun multi_map_merge frame_prefix_relay _time_offset:=-120"""
    parse_help('frame_prefix_relay', frame_prefix_relay_main.__doc__, argv)
    keep_numpy_out()
    import rospy
    rospy.init_node('frame_prefix_relay')
    prefix = rospy.get_param('~prefix', rospy.get_namespace().strip('/'))
    offset = float(rospy.get_param('~time_offset', 0.0))
    bag, clock_bag = rospy.get_param('~bag', ''), rospy.get_param('~clock_bag', '')
    if bag and clock_bag:
        offset = bag_start(clock_bag) - bag_start(bag)
    run_frame_prefix_relay(prefix, offset)
    return 0


def scan_frame_relay_main(argv: Optional[List[str]] = None) -> int:
    """``scan_frame_relay``: a robot's scans (``scan``) republished on ``scan_framed`` in its own
    laser frame and in one fixed form for gmapping (launch/includes/tb3_robot_base.launch).

    ROBOTIS's LDS-02 driver (ld08_driver, Noetic) stamps its scans base_scan whatever it is told,
    sizes each to its revolution's points (the length varies), writes 0 for no point and says
    range 0-100 m; gmapping drops every scan whose length differs from its first one. The relay
    resamples each scan onto ~beams beams over ~angle_span rad from ~angle_min (each reading to
    the beam nearest its angle), makes readings of 0 or outside ~range_min..~range_max "no
    return" (inf, which gmapping neither maps nor clears along), and sets range_min/range_max to
    those. A scan in that form already passes with its readings unchanged. What it changes is
    logged once.

    ROS parameters (private):
      ~frame_id     frame of the republished scans (default <namespace>/base_scan)
      ~src          scan topic to read (default scan, in the node's namespace)
      ~dst          topic to publish on (default scan_framed)
      ~resample     resample as above (default true; false: only the frame changes)
      ~beams        beams of the fixed form (default %d: the LDS-02's 1 degree)
      ~angle_min    angle of the first beam, rad (default 0.0)
      ~angle_span   angles covered, rad (default 2 pi: a full turn, wrapping)
      ~range_min    shortest valid reading, m (default %.2f: the LDS-02's datasheet)
      ~range_max    longest valid reading, m (default %.1f: the LDS-02's datasheet;
                    an LDS-01: range_min 0.12, range_max 3.5)
    Example: ROS_NAMESPACE=tb3_0 rosrun multi_map_merge scan_frame_relay _frame_id:=tb3_0/base_scan"""
    parse_help('scan_frame_relay', scan_frame_relay_main.__doc__ % (LDS02_BEAMS, LDS02_RANGE_MIN, LDS02_RANGE_MAX),
               argv)
    keep_numpy_out()
    import rospy
    rospy.init_node('scan_frame_relay')
    ns = rospy.get_namespace().strip('/')
    frame_id = str(rospy.get_param('~frame_id', '%s/base_scan' % ns if ns else 'base_scan')).strip()
    if not frame_id:
        rospy.logerr('scan_frame_relay: ~frame_id is empty; using base_scan')
        frame_id = 'base_scan'
    grid: Optional[ScanGrid] = None
    if rospy.get_param('~resample', True):
        d = LDS02
        grid = ScanGrid(int(rospy.get_param('~beams', d.beams)), float(rospy.get_param('~angle_min', d.angle_min)),
                        float(rospy.get_param('~angle_span', d.span)),
                        float(rospy.get_param('~range_min', d.range_min)),
                        float(rospy.get_param('~range_max', d.range_max)))
        if grid.beams < 1 or not 0.0 < grid.span <= d.span + 1e-6 or not 0.0 <= grid.range_min < grid.range_max:
            rospy.logerr('scan_frame_relay: ~beams %d, ~angle_span %.4f, ~range_min %.3f, ~range_max %.3f make no '
                         'scan; using the LDS-02\'s %s', grid.beams, grid.span, grid.range_min, grid.range_max, d)
            grid = d
    run_scan_frame_relay(frame_id, rospy.get_param('~src', 'scan'), rospy.get_param('~dst', 'scan_framed'), grid)
    return 0
