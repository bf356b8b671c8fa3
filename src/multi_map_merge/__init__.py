"""multi_map_merge: live merging of several robots' occupancy grids (see the README).

Subpackages: :mod:`.core` (the merger, no ROS), :mod:`.ros` (the node and ROS tools),
:mod:`.lab` (simulation, evaluation, demo).
"""
