"""multi_map_merge_ros2, an ament_python package (colcon). It installs the node's package and the
ROS-free core it shells (the repository's src/multi_map_merge: core, runtime, and the ROS 1
node's ROS-agnostic texts it reuses), so a colcon workspace needs only this folder."""
import os
from glob import glob

from setuptools import setup

PACKAGE = 'multi_map_merge_ros2'
HERE = os.path.dirname(os.path.abspath(__file__))
# the core, two folders up (the repository's src/); relative, as setuptools wants package_dir
CORE = os.path.relpath(os.path.join(HERE, '..', '..', 'src', 'multi_map_merge'), HERE)
CORE_PACKAGES = ['multi_map_merge', 'multi_map_merge.core', 'multi_map_merge.runtime', 'multi_map_merge.ros',
                 'multi_map_merge.lab']

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=[PACKAGE] + CORE_PACKAGES,
    package_dir=dict({PACKAGE: PACKAGE},
                     **{p: os.path.join(CORE, *p.split('.')[1:]) for p in CORE_PACKAGES}),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
        ('share/' + PACKAGE + '/launch', glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='multi_map_merge maintainers',
    maintainer_email='multi-map-merge@users.noreply.github.com',
    description="multi_map_merge's ROS 2 node: merged map and every robot's TF, no initial poses needed",
    license='BSD-3-Clause',
    tests_require=['pytest'],
    entry_points={'console_scripts': ['map_merge_node = multi_map_merge_ros2.map_merge_node:main',
                                      'home_team = multi_map_merge_ros2.home_team:main']},
)
