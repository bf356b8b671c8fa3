"""The merger for a team of N robots: ``ros2 launch multi_map_merge_ros2 map_merge_team.launch.py
robot_count:=3``. Each robot publishes its map on /<prefix><k>/map (k = 0 .. N-1, e.g. tb3_0's
slam_toolbox in namespace tb3_0); the node merges them into /map and broadcasts map -> <robot>/map.

Arguments: robot_count (N), robot_prefix (tb3_), reference_robot (empty: the first by name with a
map), use_sim_time, params_file (a ROS 2 parameters YAML for the node, empty: none)."""
from launch_ros.actions import Node

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration


def _merger(context):
    count = int(LaunchConfiguration('robot_count').perform(context))
    if count < 1:
        raise ValueError('robot_count must be at least 1, not %d' % count)
    prefix = LaunchConfiguration('robot_prefix').perform(context)
    params = [{'robots': ['%s%d' % (prefix, k) for k in range(count)],
               'reference_robot': LaunchConfiguration('reference_robot').perform(context),
               'use_sim_time': LaunchConfiguration('use_sim_time').perform(context).lower() == 'true'}]
    params_file = LaunchConfiguration('params_file').perform(context)
    if params_file:
        params.insert(0, params_file)   # (the arguments above win over the file)
    return [Node(package='multi_map_merge_ros2', executable='map_merge_node', name='map_merge',
                 output='screen', parameters=params)]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument('robot_count', default_value='3', description='how many robots (N)'),
        DeclareLaunchArgument('robot_prefix', default_value='tb3_',
                              description='robot k is the namespace <robot_prefix><k>'),
        DeclareLaunchArgument('reference_robot', default_value='',
                              description="the robot whose map frame is the merged frame (empty: the first by name)"),
        DeclareLaunchArgument('use_sim_time', default_value='false', description="the node's clock is /clock"),
        DeclareLaunchArgument('params_file', default_value='', description='a parameters YAML for the node'),
        OpaqueFunction(function=_merger),
    ])
