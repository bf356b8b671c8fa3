"""The ROS shell around the core: message conversions, the node, its diagnostics, tools, bags.

The only part of the package that imports rospy, tf2_ros or rosbag.
"""
