"""map_server files (``.yaml`` + ``.pgm``) read and written without map_server.

Reading follows map_server's "trinary" mode: with ``p = (255 - pixel) / 255`` (or ``pixel/255``
when ``negate: 1``), ``p > occupied_thresh`` is occupied (100), ``p < free_thresh`` is free (0),
anything else unknown (-1). Writing follows map_saver: occupied 0, free 254, unknown 205.
The image's row 0 is the top of the map, so rows are flipped to OccupancyGrid order here and
only here.
"""
from __future__ import annotations

import os
from typing import Dict, Tuple

import cv2
import numpy as np
import yaml

from .grid import FREE, OCCUPIED, Grid, GridError, validate


class MapFileError(Exception):
    """A map file that cannot be read; the message names the file and the reason."""


def load_map(yaml_path: str, max_cells: int = 100_000_000) -> Grid:
    """Read a map_server map. Raises MapFileError naming the file on any problem."""
    try:
        with open(yaml_path) as f:
            meta = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as e:
        raise MapFileError('%s: cannot read map yaml: %s' % (yaml_path, e)) from None
    if not isinstance(meta, dict) or 'image' not in meta or 'resolution' not in meta:
        raise MapFileError('%s: not a map_server yaml (needs image, resolution, origin)' % yaml_path)
    img_path = str(meta['image'])
    if not os.path.isabs(img_path):
        img_path = os.path.join(os.path.dirname(os.path.abspath(yaml_path)), img_path)
    img = cv2.imread(img_path, cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise MapFileError('%s: cannot read image %s' % (yaml_path, img_path))
    try:
        res = float(meta['resolution'])
        origin = tuple(float(v) for v in (list(meta.get('origin', [0, 0, 0])) + [0, 0, 0])[:3])
        occ_t = float(meta.get('occupied_thresh', 0.65))
        free_t = float(meta.get('free_thresh', 0.196))
        negate = int(meta.get('negate', 0))
    except (TypeError, ValueError) as e:
        raise MapFileError('%s: bad field: %s' % (yaml_path, e)) from None
    p = img.astype(np.float32) / 255.0
    if not negate:
        p = 1.0 - p
    data = np.full(img.shape, -1, np.int8)
    data[p > occ_t] = 100
    data[p < free_t] = 0
    data = np.ascontiguousarray(data[::-1])
    try:
        validate(data, data.shape[1], data.shape[0], res, origin, max_cells)
    except GridError as e:
        raise MapFileError('%s: %s' % (yaml_path, e)) from None
    stem = os.path.splitext(os.path.basename(yaml_path))[0]
    return Grid(data, res, origin, frame_id=stem)


def grid_to_pgm(grid: Grid) -> np.ndarray:
    """Grid -> map_saver image (row 0 at the top): occupied 0, free 254, unknown 205."""
    lv = grid.levels()
    img = np.full(lv.shape, 205, np.uint8)
    img[lv == FREE] = 254
    img[lv == OCCUPIED] = 0
    return np.ascontiguousarray(img[::-1])


def save_map(grid: Grid, yaml_path: str) -> Tuple[str, str]:
    """Write ``grid`` as ``<stem>.pgm`` + ``<stem>.yaml``; returns both paths."""
    base = os.path.splitext(yaml_path)[0]
    pgm = base + '.pgm'
    d = os.path.dirname(os.path.abspath(yaml_path))
    os.makedirs(d, exist_ok=True)
    if not cv2.imwrite(pgm, grid_to_pgm(grid)):
        raise MapFileError('%s: cannot write image' % pgm)
    meta: Dict = {
        'image': os.path.basename(pgm),
        'resolution': float(grid.resolution),
        'origin': [float(grid.origin[0]), float(grid.origin[1]), float(grid.origin[2])],
        'negate': 0,
        'occupied_thresh': 0.65,
        'free_thresh': 0.196,
    }
    with open(yaml_path, 'w') as f:
        yaml.safe_dump(meta, f, default_flow_style=None, sort_keys=False)
    return pgm, yaml_path
