"""The merger without ROS: grids, features, matching, verification, placement, compositing.

Imports neither :mod:`multi_map_merge.ros` nor :mod:`multi_map_merge.lab`.
"""
