"""The merger's state file (``state_file``): its verified links and, for people, the placements
made of them, saved to YAML on change and read back at start; a link and a placement as plain
data.

On reload the links are *restored, not trusted*: each is verified again on the robots' grids
when both maps have arrived, and dropped if it no longer agrees. The file is written
atomically (temporary file + rename), so a crash never leaves half a file.

Not to be confused with the transforms report that ``merge_maps --transforms`` writes
(:mod:`report`, read by ``evaluate_map --transforms``): every map frame's pose in the merged
frame, for people and scripts; the merger never reads it back.
"""
from __future__ import annotations

import os
import tempfile
from typing import Any, Dict, Optional

import numpy as np
import yaml

from . import covariance
from .links import Link
from .placement import Placement
from .transforms import se2, xyyaw


def link_dict(e: Link) -> Dict[str, Any]:
    """A verified link as plain data (the state file's ``edges``): x, y, yaw (metres, radians:
    the pose of the child's map frame in the parent's), parent, child, inlier_ratio,
    agreement, inliers, matches, bend (metres its overlap's halves land apart, :mod:`bend`; 0
    unknown), centre (x, y of its overlap's centre, metres in the parent's frame, :mod:`drift`;
    None unknown), parent_turn and child_turn (radians each map turned from its origin to the
    overlap, :func:`drift.turn`; None unread), and how well the grids pin it (:func:`cov_fields`)."""
    x, y, yaw = xyyaw(e.T)
    return {'x': float(x), 'y': float(y), 'yaw': float(yaw), 'parent': e.parent, 'child': e.child,
            'inlier_ratio': float(e.inlier_ratio), 'agreement': float(e.agreement),
            'inliers': int(e.inliers), 'matches': int(e.matches), 'bend': float(e.bend),
            'centre': None if e.centre is None else [float(v) for v in e.centre],
            'parent_turn': _optional_float(e.parent_turn), 'child_turn': _optional_float(e.child_turn),
            **cov_fields(e.cov)}


def _optional_float(v: Optional[float]) -> Optional[float]:
    return None if v is None else float(v)


def link_from_dict(d: Dict[str, Any], stamp: float) -> Link:
    """The link of :func:`link_dict`'s data (received at ``stamp``); files written before the
    inlier ratio had its name say ``reliability``: both are read. Raises KeyError, TypeError
    or ValueError when ``d`` is not such data."""
    ratio = d['inlier_ratio'] if 'inlier_ratio' in d else d['reliability']
    e = Link(str(d['parent']), str(d['child']), se2(float(d['x']), float(d['y']), float(d['yaw'])),
             float(ratio), float(d['agreement']), int(d['inliers']), int(d.get('matches', 0)), stamp)
    if d.get('cov') is not None:   # files written before links had a covariance have none
        e.cov = np.array([float(v) for v in d['cov']]).reshape(3, 3)
    e.bend = float(d.get('bend', 0.0))   # (files written before bends were measured have none)
    if d.get('centre') is not None:      # (nor before the drift's model error)
        e.centre = (float(d['centre'][0]), float(d['centre'][1]))
    # (nor, before the maps' turns were read, turns)
    e.parent_turn, e.child_turn = _optional_float(d.get('parent_turn')), _optional_float(d.get('child_turn'))
    return e


def placement_dict(pl: Placement) -> Dict[str, Any]:
    """A placement as plain data, the one form of it everywhere (the state file, merge_maps'
    transforms report, /diagnostics): x, y, yaw (metres, radians: the pose of the robot's map
    frame in the merged frame), inlier_ratio, agreement, inliers (the weakest along its chain),
    via (the robot it is linked through, '' for the reference), chain (reference ... robot),
    weak (2-sigma position over ``max_position_sigma``) and its covariance (:func:`cov_fields`)."""
    x, y, yaw = xyyaw(pl.T)
    return {'x': float(x), 'y': float(y), 'yaw': float(yaw), 'inlier_ratio': float(pl.inlier_ratio),
            'agreement': float(pl.agreement), 'inliers': int(pl.inliers), 'via': pl.via,
            'chain': list(pl.path), 'weak': bool(pl.weak), **cov_fields(pl.cov)}


def cov_fields(cov: Optional[np.ndarray]) -> Dict[str, Any]:
    """A covariance as plain data: ``cov`` (9 floats, row-major, of x, y, yaw: metres^2,
    radians^2) and ``sigma_position`` (metres, the worst direction's standard deviation); nothing
    when unknown."""
    if cov is None:
        return {}
    return {'cov': [float(v) for v in np.asarray(cov).ravel()],
            'sigma_position': covariance.position_sigma(cov)}


def save_state(path: str, state: Dict[str, Any]) -> None:
    """Write ``state`` (:meth:`MapMerger.export_state`) to ``path`` atomically."""
    d = os.path.dirname(os.path.abspath(path))
    os.makedirs(d, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix='.state-', suffix='.yaml', dir=d)
    try:
        with os.fdopen(fd, 'w') as f:
            yaml.safe_dump(state, f, sort_keys=False)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def load_state(path: str) -> Dict[str, Any]:
    """Read a state file; {} when it does not exist. Raises ValueError when it is not valid."""
    if not os.path.exists(path):
        return {}
    try:
        with open(path) as f:
            data = yaml.safe_load(f) or {}
    except (OSError, yaml.YAMLError) as e:
        raise ValueError('%s: cannot read the state file: %s' % (path, e)) from None
    if not isinstance(data, dict) or not isinstance(data.get('edges', []), list):
        raise ValueError('%s: not a multi_map_merge state file (its verified links)' % path)
    return data


class StateFile:
    """A merger's links kept in ``path`` across runs (the ``state_file``): read once at start,
    written again whenever they or the placements changed (``merger.state_version``, bumped by
    :class:`MapMerger`). ``merger``: a :class:`MapMerger`."""

    def __init__(self, path: str, merger):
        self.path = path
        self.merger = merger
        self._saved = -1   # the merger's state_version last read or written

    def restore(self) -> int:
        """Give the merger the links saved in the file (each is verified again on the grids
        before use); returns how many. ValueError when the file is not a state file."""
        try:
            return self.merger.restore_state(load_state(self.path))
        finally:
            self._saved = self.merger.state_version   # (what is in the file need not be written back)

    def save(self) -> bool:
        """Write the merger's state when it changed since last read or written; True when it
        was written. OSError when it cannot be."""
        version = self.merger.state_version
        if version == self._saved:
            return False
        save_state(self.path, self.merger.export_state())
        self._saved = version
        return True
