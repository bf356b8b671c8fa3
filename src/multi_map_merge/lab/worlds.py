"""Which world a simulated run takes place in: the project's own home, or a map found in
``../shared/data`` (beside the checkout, not part of the project) when it is there.

- ``home``: :mod:`multi_map_merge.lab.home`, drawn by the project, always available; written
  as a map_server map where a tool needs a file (:func:`world_map`).
- ``aws-small-house``: the AWS RoboMaker small house, read in place from
  ``../shared/data/aws/small_house/map.yaml`` (or ``../shared/data/aws/small_house.yaml``);
  :func:`aws_small_house` is None without it.
- anything else: the path of a map_server ``.yaml``.
"""
from __future__ import annotations

import os
from typing import Optional, Tuple

from ..core.grid import Grid
from ..core.mapio import MapFileError, load_map

HOME = 'home'
AWS_SMALL_HOUSE = 'aws-small-house'
# where the AWS small house may be in ../shared/data, first found wins
AWS_SMALL_HOUSE_FILES = (os.path.join('aws', 'small_house', 'map.yaml'), os.path.join('aws', 'small_house.yaml'))


def checkout() -> Optional[str]:
    """The source checkout this module runs from (the directory holding package.xml), or None
    when it runs from an installed package."""
    root = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..'))
    return root if os.path.isfile(os.path.join(root, 'package.xml')) else None


def shared_data() -> Optional[str]:
    """``../shared/data`` beside the checkout, or None when absent (an installed package has none)."""
    root = checkout()
    if root is None:
        return None
    d = os.path.abspath(os.path.join(root, '..', 'shared', 'data'))
    return d if os.path.isdir(d) else None


def aws_small_house() -> Optional[str]:
    """Path of the AWS small house's map_server ``.yaml`` in ``../shared/data``, or None."""
    data = shared_data()
    if data is None:
        return None
    for rel in AWS_SMALL_HOUSE_FILES:
        p = os.path.join(data, rel)
        if os.path.isfile(p):
            return p
    return None


def world_map(name: str, out_dir: str) -> Tuple[str, Grid]:
    """(path of a map_server ``.yaml``, its grid) of the world ``name`` (see the module
    docstring). The home is written to ``out_dir/home.yaml`` (and ``home.pgm``) so that a truth
    file can name it. Raises MapFileError naming what is missing or unreadable."""
    if name == HOME:
        from .home import home_grid, write_home_map
        grid = home_grid()
        path = os.path.abspath(os.path.join(out_dir, 'home.yaml'))
        write_home_map(path, grid)
        return path, grid
    if name == AWS_SMALL_HOUSE:
        path = aws_small_house()
        if path is None:
            raise MapFileError('the AWS small house is not in ../shared/data (%s): pass its .yaml instead'
                               % ' or '.join(AWS_SMALL_HOUSE_FILES))
        name = path
    path = os.path.abspath(name)
    return path, load_map(path)
