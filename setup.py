# Installed by catkin (catkin_python_setup), not by pip.
from setuptools import setup
from catkin_pkg.python_setup import generate_distutils_setup

setup(**generate_distutils_setup(packages=['multi_map_merge'], package_dir={'': 'src'}))
