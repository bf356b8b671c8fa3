#!/usr/bin/env python3
"""A stand-in for static_transform_publisher (Debian 12 ships no tf/tf2_ros binaries):
``tf_sender.py PARENT CHILD [--static] [--delay S]`` sends the identity PARENT -> CHILD on /tf
every 0.1 s (as tf's ``static_transform_publisher ... 100`` in ROBOTIS's multi_map_merge.launch
does), or once, latched, on /tf_static (as tf2_ros's does); from S wall seconds after its start
(default 0)."""
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
    parent, child = [a for a in args if a != '--static']
    rospy.init_node('tf_sender')
    time.sleep(delay)
    t = TransformStamped()
    t.header.frame_id, t.child_frame_id = parent, child
    t.transform.rotation.w = 1.0
    if static:
        t.header.stamp = rospy.Time.now()
        tf2_ros.StaticTransformBroadcaster().sendTransform(t)
        rospy.spin()
        return
    br = tf2_ros.TransformBroadcaster()
    rate = rospy.Rate(10)
    while not rospy.is_shutdown():
        t.header.stamp = rospy.Time.now()
        br.sendTransform(t)
        rate.sleep()


if __name__ == '__main__':
    main()
