"""How far a SLAM map drifts from its frame's origin: a link's model error.

A robot's map frame is pinned where its SLAM started, at the robot's start; every wall further
away sits where the robot's accumulated error put it. gmapping has no global loop closure
beyond its particles' own, so a map's far parts sit a little shifted and turned against the
frame they are drawn in. A link is fitted on an overlap: it ties the two frames through two
stretches of drifted map, the parent's from its origin to the overlap and the child's from its
own. The walls' likelihood (:mod:`covariance`) and the overlap's bend (:mod:`bend`) say how
well the overlap pins the link; neither sees those stretches. Here each stretch adds a model
error: the overlap's place in that map off by ``rate`` (``MergeConfig.map_drift``) times its
distance ``L`` from the map's origin (metres, both axes), and its heading by ``yaw_rate``
(``map_drift_yaw``) times ``sqrt(L)`` (a random walk of heading along the way). The two maps'
errors are independent and add. It widens what a placement is known to (its covariance, and
so *weakly pinned*), not the links' weights when they are solved: how well the walls pin each
overlap says which link to trust.

The default rates are calibrated on real gmapping maps of real laser logs (``make bend-sweep``, the
link errors against the robots' true starts: docs/measurements.md); a map that does not drift
(a map cut from a ground truth) is covered the more loosely.

Frames: metres and radians of the parent's map frame; the link's pose ``T`` (3x3) maps the
child's map frame into the parent's, and its covariance is that of (x, y, yaw) of ``T``, as in
:func:`covariance.metric_covariance`.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np


def link_covariance(centre: Sequence[float], T: np.ndarray, rate: float, yaw_rate: float) -> np.ndarray:
    """The drift's covariance (3x3, of (x, y, yaw) of ``T``: metres^2 in the parent's frame,
    radians^2) of a link whose overlap is centred at ``centre`` ((2,), metres in the parent's
    map frame). The parent's origin is (0, 0) there, the child's ``T``'s translation.
    ``rate``: metres off per metre from a map's origin, ``yaw_rate``: radians turned per
    square root of a metre (1 sigma)."""
    c = np.asarray(centre, np.float64)
    t = np.asarray(T, np.float64)[:2, 2]
    far_parent, far_child = float(np.hypot(*c)), float(np.hypot(*(c - t)))
    var_xy = rate ** 2 * (far_parent ** 2 + far_child ** 2)
    var_yaw = yaw_rate ** 2 * (far_parent + far_child)
    # the overlap shifted and turned about its centre: a turn moves the child's origin sideways
    lever = t - c
    G = np.array([[1.0, 0.0, -lever[1]], [0.0, 1.0, lever[0]], [0.0, 0.0, 1.0]])
    return G @ np.diag([var_xy, var_xy, var_yaw]) @ G.T
