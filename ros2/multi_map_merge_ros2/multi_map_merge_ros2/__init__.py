"""multi_map_merge's ROS 2 (Jazzy) node: the ROS 1 node's topics, TF, parameters, services and
diagnostics over rclpy, around the same ROS-free core (:mod:`multi_map_merge.core`)."""
