# Installed by catkin (catkin_python_setup), not by pip.
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(
    packages=['multi_map_merge', 'multi_map_merge.runtime', 'multi_map_merge.core', 'multi_map_merge.cli',
              'multi_map_merge.ros', 'multi_map_merge.lab'],
    package_dir={'': 'src'}))
