#!/usr/bin/env python3
"""A stand-in for static_transform_publisher (Debian 12 ships no tf/tf2_ros binaries):
``tf_sender.py PARENT CHILD [--static] [--delay S]`` sends the identity PARENT -> CHILD on /tf
every 0.1 s (as tf's ``static_transform_publisher ... 100`` in ROBOTIS's multi_map_merge.launch
does), or once, latched, on /tf_static (as tf2_ros's does); from S wall seconds after its start
(default 0). ``tf_sender.py X Y Z YAW PITCH ROLL PARENT CHILD PERIOD_MS`` takes tf's
``static_transform_publisher`` arguments as they are and does what it does: that transform on
/tf every PERIOD_MS milliseconds (test/ros/test_robotis_gazebo_launch.py runs ROBOTIS's lines
with only their pkg and type changed to this)."""
import math
import sys
import time

import rospy
import tf2_ros
from geometry_msgs.msg import TransformStamped


def main():
    args = rospy.myargv(sys.argv)[1:]
    delay = 0.0
    if '--delay' in args:
        i = args.index('--delay')
        delay = float(args[i + 1])
        del args[i:i + 2]
    static = '--static' in args
    args = [a for a in args if a != '--static']
    t = TransformStamped()
    period = 0.1
    if len(args) == 9:   # static_transform_publisher x y z yaw pitch roll frame_id child_frame_id period_in_ms
        x, y, z, yaw, pitch, roll = (float(a) for a in args[:6])
        # (tf's broadcaster strips a leading slash, as ROBOTIS's /map and /tb3_0/map have)
        parent, child, period = args[6].lstrip('/'), args[7].lstrip('/'), float(args[8]) / 1000.0
        tr = t.transform
        tr.translation.x, tr.translation.y, tr.translation.z = x, y, z
        cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
        cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
        cr, sr = math.cos(roll / 2), math.sin(roll / 2)
        tr.rotation.w = cr * cp * cy + sr * sp * sy
        tr.rotation.x = sr * cp * cy - cr * sp * sy
        tr.rotation.y = cr * sp * cy + sr * cp * sy
        tr.rotation.z = cr * cp * sy - sr * sp * cy
    else:
        parent, child = args
        t.transform.rotation.w = 1.0
    rospy.init_node('tf_sender')
    time.sleep(delay)
    t.header.frame_id, t.child_frame_id = parent, child
    if static:
        t.header.stamp = rospy.Time.now()
        tf2_ros.StaticTransformBroadcaster().sendTransform(t)
        rospy.spin()
        return
    br = tf2_ros.TransformBroadcaster()
    rate = rospy.Rate(1.0 / period)
    while not rospy.is_shutdown():
        t.header.stamp = rospy.Time.now()
        br.sendTransform(t)
        rate.sleep()


if __name__ == '__main__':
    main()
