#!/usr/bin/env python3
"""rostest: move_base for one robot on the merged map, as the README ("Navigating on the merged
map") runs it, live.

Two Turtlebot3s' LDS-02 sensors (test_tb3_real_launch's bag) play through
``turtlebot3_multi_slam.launch slam:=rbpf`` (test_tb3_real_launch's SLAM) and the merger; move_base for tb3_1 starts
with them (move_base_merged.launch: ROBOTIS's turtlebot3_navigation YAMLs, then the README's
lines), before tb3_1 is merged, so it waits for ``map -> tb3_1/base_footprint``. While the bag
plays the test times tb3_1's first merge and the first non-empty plan of ``move_base/make_plan``
into tb3_0's part of the merged map. When the bag has ended the robots stand still where it left
them: the test goes on publishing ``/clock`` and each robot's last ``odom -> base_footprint``, so
that move_base's timers, gmapping's and the merger's keep running. Then it asserts:

* the global costmap is in frame ``map`` with the merged ``/map``'s size, resolution and origin;
  every occupied cell of ``/map`` is lethal in it, and its unknown cells stay unknown
  (``track_unknown_space``, which explore_lite's frontiers need);
* ``make_plan`` from tb3_1's pose (TF ``map -> tb3_1/base_footprint``) to a free cell of ``/map``
  that only tb3_0 mapped returns a path, every pose in frame ``map`` (move_base leaves the Path's
  own header empty), from there to there, on no occupied cell;
* a goal sent to the ``move_base`` action server is accepted and the controller publishes
  ``/tb3_1/cmd_vel``.

Skips where ROS has no move_base or turtlebot3_navigation (and, with SLAM gmapping, no gmapping)."""
import math
import os
import subprocess
import threading
import time
import unittest

import cv2
import numpy as np
import rospkg
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import OccupancyGrid
from nav_msgs.srv import GetPlan
from rosgraph_msgs.msg import Clock
from rospy.numpy_msg import numpy_msg
from rostest_helpers import lookup, shared_file, stop_launch
from test_tb3_real_launch import SLAM, two_robot_lds02_bag
from tf2_msgs.msg import TFMessage

from multi_map_merge.core.transforms import apply, cell_to_metric, inverse, xyyaw
from multi_map_merge.ros.convert import quaternion_yaw
from multi_map_merge.ros.tools import init_node

NumpyGrid = numpy_msg(OccupancyGrid)
ROBOTS = ['tb3_0', 'tb3_1']
ROBOT, OTHER = 'tb3_1', 'tb3_0'          # move_base's robot; the one whose part it plans into
MOVE_BASE = '/%s/move_base' % ROBOT
COSTMAP = MOVE_BASE + '/global_costmap/costmap'
CLEARANCE = 0.3                           # m from the goal to the nearest wall or unknown cell


def values(msg):
    """int8 (height, width) OccupancyGrid values of a message, row 0 at the origin."""
    return np.asarray(msg.data, np.int8).reshape(msg.info.height, msg.info.width)


def origin_of(msg):
    o = msg.info.origin
    return (o.position.x, o.position.y, quaternion_yaw(o.orientation))


def sample(msg, pts):
    """Values of grid ``msg`` at points (N, 2) of its frame; -1 outside it."""
    a = values(msg)
    c = np.floor(apply(inverse(cell_to_metric(msg.info.resolution, origin_of(msg))), pts) + 0.5).astype(int)
    ok = (c[:, 0] >= 0) & (c[:, 0] < a.shape[1]) & (c[:, 1] >= 0) & (c[:, 1] < a.shape[0])
    out = np.full(len(pts), -1, np.int16)
    out[ok] = a[c[ok, 1], c[ok, 0]]
    return out


def other_part_goal(merged, own, T_map_own, other, T_map_other):
    """(x, y) in the merged frame of the free cell of ``merged`` farthest from walls and unknown
    cells among those free in ``other``'s map and unknown to ``own``'s map (the other robot's
    part), with that clearance in metres; None if no such cell has CLEARANCE."""
    a = values(merged)
    res = merged.info.resolution
    clear = cv2.distanceTransform((a == 0).astype(np.uint8), cv2.DIST_L2, 5) * res
    jj, ii = np.nonzero(clear >= CLEARANCE)
    if not len(ii):
        return None
    pts = apply(cell_to_metric(res, origin_of(merged)), np.stack([ii, jj], 1).astype(float))
    keep = (sample(own, apply(inverse(T_map_own), pts)) < 0) & (sample(other, apply(inverse(T_map_other), pts)) == 0)
    if not keep.any():
        return None
    k = np.flatnonzero(keep)[np.argmax(clear[jj[keep], ii[keep]])]
    return (float(pts[k, 0]), float(pts[k, 1])), float(clear[jj[k], ii[k]])


def pose_msg(x, y, yaw=0.0, frame='map'):
    p = PoseStamped()
    p.header.frame_id = frame
    p.pose.position.x, p.pose.position.y = x, y
    p.pose.orientation.z, p.pose.orientation.w = math.sin(yaw / 2.0), math.cos(yaw / 2.0)
    return p


def path_length(poses):
    xy = np.array([[p.pose.position.x, p.pose.position.y] for p in poses])
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0


class Watch:
    """Latest messages the test needs: /map, each robot's map, /clock, each robot's odom ->
    base_footprint from /tf, the cmd_vel count."""

    def __init__(self):
        self.lock = threading.Lock()
        self.map = None
        self.robot_maps = {}
        self.clock = None
        self.odom = {}
        self.cmd_vel = []
        self.subs = [rospy.Subscriber('/map', NumpyGrid, self._set, callback_args='map', queue_size=1,
                                      buff_size=2 ** 26),
                     rospy.Subscriber('/clock', Clock, self._clock, queue_size=10),
                     rospy.Subscriber('/tf', TFMessage, self._tf, queue_size=100),
                     rospy.Subscriber('/%s/cmd_vel' % ROBOT, Twist, self._cmd_vel, queue_size=100)]
        self.subs += [rospy.Subscriber('/%s/map' % r, NumpyGrid, self._robot_map, callback_args=r,
                                       queue_size=1, buff_size=2 ** 26) for r in ROBOTS]

    def _set(self, msg, name):
        with self.lock:
            setattr(self, name, msg)

    def _robot_map(self, msg, robot):
        with self.lock:
            self.robot_maps[robot] = msg

    def _clock(self, msg):
        with self.lock:
            c = msg.clock.to_sec()
            if self.clock is None or c > self.clock:
                self.clock = c

    def _tf(self, msg):
        with self.lock:
            for t in msg.transforms:
                for r in ROBOTS:
                    if t.child_frame_id == '%s/base_footprint' % r and t.header.frame_id == '%s/odom' % r:
                        self.odom[r] = t

    def _cmd_vel(self, msg):
        with self.lock:
            self.cmd_vel.append((time.time(), msg.linear.x, msg.angular.z))


class Hold(threading.Thread):
    """After the bag: /clock from its last second on at wall speed, and each robot's last odom ->
    base_footprint stamped with it (the robots stand still)."""

    def __init__(self, watch):
        super().__init__(daemon=True)
        self.watch = watch
        self.stop = threading.Event()
        self.clock_pub = rospy.Publisher('/clock', Clock, queue_size=10)
        self.tf = tf2_ros.TransformBroadcaster()

    def run(self):
        with self.watch.lock:
            c0 = self.watch.clock
            odom = dict(self.watch.odom)
        w0, n = time.time(), 0
        while not self.stop.is_set():
            now = rospy.Time.from_sec(c0 + time.time() - w0)
            self.clock_pub.publish(Clock(clock=now))
            if n % 5 == 0:
                for t in odom.values():
                    t.header.stamp = now
                self.tf.sendTransform(list(odom.values()))
            n += 1
            self.stop.wait(0.01)


def requirements(test):
    rp = rospkg.RosPack()
    needs = [('move_base', 'Ubuntu: ros-noetic-navigation; Debian has none'),
             ('turtlebot3_navigation', "Ubuntu: ros-noetic-turtlebot3-navigation (ROBOTIS's parameter files)")]
    if SLAM == 'gmapping':
        needs.insert(0, ('gmapping', 'Ubuntu: ros-noetic-gmapping'))
    for pkg, why in needs:
        try:
            rp.get_path(pkg)
        except rospkg.ResourceNotFound:
            test.skipTest('no %s (%s)' % (pkg, why))
    return rp


class TestMoveBaseMerged(unittest.TestCase):

    def test_move_base_plans_on_the_merged_map(self):
        rp = requirements(self)
        pkg = rp.get_path('multi_map_merge')
        params = os.path.join(rp.get_path('turtlebot3_navigation'), 'param')
        tmp, bag = two_robot_lds02_bag(self, pkg, 'mmm_move_base_')
        init_node('test_move_base_merged')
        buf = tf2_ros.Buffer(rospy.Duration(60.0))
        tf2_ros.TransformListener(buf)
        watch = Watch()
        urdf = shared_file('robotis', 'turtlebot3', 'turtlebot3_description', 'urdf', 'turtlebot3_burger.urdf')
        logs = os.environ.get('ROS_LOG_DIR', tmp)
        t0 = time.time()
        procs = []
        hold = Hold(watch)
        try:
            launches = (['multi_map_merge', 'turtlebot3_multi_slam.launch', 'robot_count:=2', 'rviz:=false',
                         'urdf_file:=' + urdf, 'output:=log', 'slam:=' + SLAM],
                        [os.path.join(pkg, 'test', 'ros', 'move_base_merged.launch'), 'param_dir:=' + params,
                         'robot:=' + ROBOT])
            for i, args in enumerate(launches):
                with open(os.path.join(logs, 'move_base_merged_%d.log' % i), 'w') as out:
                    procs.append(subprocess.Popen(['roslaunch'] + args, stdout=out, stderr=subprocess.STDOUT,
                                                  start_new_session=True))
            play = subprocess.Popen(['rosbag', 'play', '--clock', '-r', '1.5', '-d', '3', bag],
                                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
            procs.append(play)
            merged_at, planned_at, first_plan = None, None, None
            # while the bag plays: tb3_1's merge, then the first plan into tb3_0's part
            while play.poll() is None and time.time() - t0 < 400:
                time.sleep(0.5)
                if merged_at is None and buf.can_transform('map', '%s/map' % ROBOT, rospy.Time(0)):
                    merged_at = time.time() - t0
                if merged_at is None or planned_at is not None:
                    continue
                plan, _ = self.plan_into_other_part(buf, watch, timeout=0.5, check=False)
                if plan is not None and plan.poses:
                    planned_at, first_plan = time.time() - t0, plan
            self.assertIsNotNone(play.poll(), 'the bag did not end')
            self.assertIsNotNone(merged_at, '%s was never merged' % ROBOT)
            self.assertIsNotNone(planned_at, 'no plan into %s\'s part while the bag played' % OTHER)
            self.assertIsNotNone(watch.clock, 'no /clock: the bag did not play')
            hold.start()
            time.sleep(5.0)
            self.check_costmap(watch)
            self.check_local_costmap()
            plan, goal = self.plan_into_other_part(buf, watch, timeout=10.0, check=True)
            self.check_goal(watch, goal)
        finally:
            hold.stop.set()
            for p in reversed(procs):
                if p.poll() is None:    # the player has ended by itself
                    stop_launch(p)
        print('move_base on the merged map: %s merged %.1f s after the launch, first plan into %s\'s part '
              '%.1f s (%d poses, %.2f m); after the bag: plan %d poses %.2f m from (%.2f, %.2f) to '
              '(%.2f, %.2f); costmap %s; local costmap %d lethal cells; cmd_vel %s'
              % (ROBOT, merged_at, OTHER, planned_at, len(first_plan.poses), path_length(first_plan.poses),
                 len(plan.poses), path_length(plan.poses), *self.start_xy, *goal, self.costmap_summary,
                 self.local_lethal, self.cmd_vel_summary))

    def plan_into_other_part(self, buf, watch, timeout, check):
        """make_plan from ROBOT's pose in ``map`` to the free cell of /map farthest from walls
        that only OTHER mapped: (plan or None, goal (x, y) or None). ``check``: assert on it."""
        with watch.lock:
            merged, maps = watch.map, dict(watch.robot_maps)
        T_own = lookup(buf, 'map', '%s/map' % ROBOT, timeout)
        T_other = lookup(buf, 'map', '%s/map' % OTHER, timeout)
        T_base = lookup(buf, 'map', '%s/base_footprint' % ROBOT, timeout)
        if check:
            self.assertIsNotNone(merged, 'no /map')
            self.assertIsNotNone(T_base, 'map -> %s/base_footprint does not resolve' % ROBOT)
        if merged is None or T_own is None or T_other is None or T_base is None or len(maps) < 2:
            return None, None
        found = other_part_goal(merged, maps[ROBOT], T_own, maps[OTHER], T_other)
        if check:
            self.assertIsNotNone(found, 'no free cell with %.2f m clearance that only %s mapped' % (CLEARANCE, OTHER))
        if found is None:
            return None, None
        goal, _ = found
        sx, sy, syaw = xyyaw(T_base)
        try:
            rospy.wait_for_service(MOVE_BASE + '/make_plan', timeout=timeout)
            resp = rospy.ServiceProxy(MOVE_BASE + '/make_plan', GetPlan)(
                start=pose_msg(sx, sy, syaw), goal=pose_msg(*goal), tolerance=0.0)
        except (rospy.ROSException, rospy.ServiceException) as e:
            if check:
                self.fail('make_plan: %s' % e)
            return None, None
        if not check:
            return resp.plan, goal
        plan = resp.plan
        self.start_xy = (sx, sy)
        self.assertGreater(len(plan.poses), 10, 'make_plan to %s gave %d poses' % (goal, len(plan.poses)))
        # every pose in the merged frame (move_base's make_plan leaves the Path's own header empty)
        self.assertEqual({p.header.frame_id for p in plan.poses}, {'map'})
        first, last = plan.poses[0].pose.position, plan.poses[-1].pose.position
        self.assertLess(math.hypot(first.x - sx, first.y - sy), 0.1, 'the plan does not start at the robot')
        self.assertLess(math.hypot(last.x - goal[0], last.y - goal[1]), 0.1, 'the plan does not end at the goal')
        self.assertGreaterEqual(path_length(plan.poses), math.hypot(goal[0] - sx, goal[1] - sy) - 0.1)
        xy = np.array([[p.pose.position.x, p.pose.position.y] for p in plan.poses])
        self.assertEqual(int((sample(merged, xy) == 100).sum()), 0, 'the plan crosses occupied cells of /map')
        return plan, goal

    def check_costmap(self, watch):
        """The global costmap (a new subscription gets it whole) against the latest /map."""
        cm = rospy.wait_for_message(COSTMAP, NumpyGrid, timeout=20.0)
        with watch.lock:
            merged = watch.map
        self.assertEqual(cm.header.frame_id, 'map')
        mi, ci = merged.info, cm.info
        self.assertEqual((ci.width, ci.height), (mi.width, mi.height), 'costmap size differs from /map')
        self.assertAlmostEqual(ci.resolution, mi.resolution, places=6)
        for a, b in zip(origin_of(cm), origin_of(merged)):
            self.assertAlmostEqual(a, b, places=4, msg='costmap origin differs from /map')
        m, c = values(merged), values(cm)
        occ, unk, free = m == 100, m == -1, m == 0
        lethal_of_occ = float((c[occ] == 100).mean())
        unknown_kept = float((c[unk] == -1).mean())
        extra_lethal = int(((c == 100) & ~occ).sum())
        self.costmap_summary = ('%dx%d at (%.2f, %.2f), %d occupied cells of /map: %.4f lethal; %d unknown: '
                                '%.4f unknown; %d free: %d lethal (scans)'
                                % (ci.width, ci.height, ci.origin.position.x, ci.origin.position.y, int(occ.sum()),
                                   lethal_of_occ, int(unk.sum()), unknown_kept, int(free.sum()), extra_lethal))
        self.assertEqual(lethal_of_occ, 1.0, self.costmap_summary)
        self.assertGreater(unknown_kept, 0.9, self.costmap_summary)
        self.assertLess(extra_lethal, 0.01 * free.sum(), self.costmap_summary)

    def check_local_costmap(self):
        """The local costmap, in the robot's odom frame, has the walls the robot's laser sees
        (ROBOTIS's ``scan`` source, frame ``base_scan``, sees nothing here: no such frame)."""
        cm = rospy.wait_for_message(MOVE_BASE + '/local_costmap/costmap', NumpyGrid, timeout=20.0)
        self.assertEqual(cm.header.frame_id, '%s/odom' % ROBOT)
        self.local_lethal = int((values(cm) == 100).sum())
        self.assertGreater(self.local_lethal, 0, 'no obstacle from the scans in the local costmap')

    def check_goal(self, watch, goal):
        """A goal into OTHER's part: accepted (ACTIVE), and the controller publishes cmd_vel."""
        # imported here, past the skip: where move_base is installed, so are these (Debian's
        # make test, which skips this test, does not install them)
        import actionlib
        from actionlib_msgs.msg import GoalStatus
        from move_base_msgs.msg import MoveBaseAction, MoveBaseGoal
        client = actionlib.SimpleActionClient(MOVE_BASE, MoveBaseAction)
        self.assertTrue(client.wait_for_server(rospy.Duration(10.0)), 'no move_base action server')
        with watch.lock:
            n0 = len(watch.cmd_vel)
        t = time.time()
        client.send_goal(MoveBaseGoal(target_pose=pose_msg(*goal)))
        while client.get_state() == GoalStatus.PENDING and time.time() - t < 10.0:
            time.sleep(0.1)
        state = client.get_state()
        time.sleep(5.0)
        with watch.lock:
            sent = watch.cmd_vel[n0:]
        final = client.get_state()
        client.cancel_all_goals()
        self.cmd_vel_summary = ('%d messages in the %.1f s after the goal, %d non-zero, goal state %d then %d'
                                % (len(sent), time.time() - t, sum(1 for _, v, w in sent if v or w), state, final))
        self.assertIn(state, (GoalStatus.ACTIVE, GoalStatus.SUCCEEDED), 'goal not accepted: ' + self.cmd_vel_summary)
        self.assertGreaterEqual(len(sent), 10, 'the controller does not run: ' + self.cmd_vel_summary)


if __name__ == '__main__':
    rostest.rosrun('multi_map_merge', 'move_base_merged', TestMoveBaseMerged)
