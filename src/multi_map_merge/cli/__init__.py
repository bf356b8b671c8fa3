"""The command-line front ends: argument parsing and a script's main(), over the ROS-free
library in :mod:`multi_map_merge.core`."""
