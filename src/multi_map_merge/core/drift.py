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

Where a map's heading can be read off its walls, it is measured rather than assumed
(:func:`wall_direction`, :func:`turn`): most buildings are drawn on two perpendicular wall
directions, so the walls' dominant direction modulo 90 degrees near the map's origin and near
an overlap differ by what the map turned on the way there. It is read only where the walls
around both places hold one direction clearly (:data:`MIN_COHERENCE`; a building of many wall
directions, or a disc of clutter, says nothing), and a measured turn adds its square to the
turn's variance on top of the rate's: the drift model covers the unmeasured, the measurement
the heavy tail (a long corridor drawn turned by tens of degrees). Only what the two maps of a
link turned apart counts: a building whose wings are drawn at another angle reads as the same
turn in both maps when they start in one place.

Frames: metres and radians of the parent's map frame; the link's pose ``T`` (3x3) maps the
child's map frame into the parent's, and its covariance is that of (x, y, yaw) of ``T``, as in
:func:`covariance.metric_covariance`. :func:`wall_direction` works in a grid's cells (col, row);
a turn is the same in cells and metres (a grid's cells are its frame's axes, scaled).
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

import cv2
import numpy as np

from .grid import OCCUPIED

# metres around a place whose walls give its direction: a room or a stretch of corridor
DIRECTION_RADIUS = 4.0
# the walls' direction is read where its coherence (the resultant of the walls' gradient
# directions modulo 90 degrees, weighted by strength, over their total: 1 for walls all on one
# pair of perpendicular directions, 0 for walls in every direction) reaches this at both places
MIN_COHERENCE = 0.3
# wall cells a disc needs for its direction
MIN_DIRECTION_CELLS = 40
# a turn read beyond this (radians) is taken as unreadable: modulo 90 degrees, a turn near 45
# is as likely its opposite
MAX_TURN = math.radians(30.0)
# a turn reported on /diagnostics from this size (radians)
REPORT_TURN = math.radians(5.0)


def link_covariance(centre: Sequence[float], T: np.ndarray, rate: float, yaw_rate: float,
                    parent_turn: Optional[float] = None, child_turn: Optional[float] = None) -> np.ndarray:
    """The drift's covariance (3x3, of (x, y, yaw) of ``T``: metres^2 in the parent's frame,
    radians^2) of a link whose overlap is centred at ``centre`` ((2,), metres in the parent's
    map frame). The parent's origin is (0, 0) there, the child's ``T``'s translation.
    ``rate``: metres off per metre from a map's origin, ``yaw_rate``: radians turned per
    square root of a metre (1 sigma); ``parent_turn``, ``child_turn``: radians each map was
    measured to have turned between its origin and the overlap (:func:`turn`; None unmeasured).

    Each map's way from its origin to the overlap is taken straight, of length ``L``; its
    heading a random walk ``a(s)``. At the overlap the map is turned by ``a(L)`` and shifted
    sideways by the integral of ``a`` (:func:`_heading_walk`), the two correlated; the link
    inherits both, the parent's as they are, the child's undone about the overlap
    (:func:`_stretch_jacobians`). What the two maps were measured to turn apart
    (:func:`link_turn`: what both read alike is the building's own geometry, or a turn both
    made, and does not move one frame against the other) adds its square to the heading and, in
    position, the overlap's shift by a turn that happened anywhere on the longer of the two ways
    (a pivot uniform between the origin and the overlap: ``turn^2 L^2 / 3``)."""
    c = np.asarray(centre, np.float64)
    t = np.asarray(T, np.float64)[:2, 2]
    far_parent, far_child = float(np.hypot(*c)), float(np.hypot(*(c - t)))
    J_parent, J_child = _stretch_jacobians(c, t)
    cov = (J_parent @ _heading_walk(far_parent, yaw_rate) @ J_parent.T
           + J_child @ _heading_walk(far_child, yaw_rate) @ J_child.T)
    apart = link_turn(parent_turn, child_turn)
    var_xy = rate ** 2 * (far_parent ** 2 + far_child ** 2) + (apart * max(far_parent, far_child)) ** 2 / 3.0
    # a measured turn: the overlap turned about its centre, which moves the child's origin sideways
    lever = t - c
    G = np.array([[-lever[1]], [lever[0]], [1.0]])
    return cov + np.diag([var_xy, var_xy, 0.0]) + apart ** 2 * (G @ G.T)


def _heading_walk(length: float, yaw_rate: float) -> np.ndarray:
    """The covariance (2x2) of a heading random walk's end, ``a(L)`` (radians), and of its
    integral along the way, ``b = int_0^L a(s) ds`` (metres: the sideways shift it puts into
    the way's end), for a walk of ``yaw_rate^2`` radians^2 per metre over ``length`` metres."""
    q, L = yaw_rate ** 2, float(length)
    return q * np.array([[L, L * L / 2.0], [L * L / 2.0, L ** 3 / 3.0]])


def _stretch_jacobians(centre: np.ndarray, t: np.ndarray):
    """How each map's (turn at the overlap, sideways shift at the overlap) moves the link's
    (x, y, yaw) (3x2 each; see :func:`link_covariance` for the frames). The parent's overlap is
    drawn turned about its centre and shifted across its way from (0, 0): the child, fitted onto
    it, follows both. The child's is undone about the overlap: its origin swings about the
    overlap's centre by the turn, less its own sideways shift, and its heading turns back."""
    def across(v: np.ndarray) -> np.ndarray:
        n = float(np.hypot(*v))
        return np.array([-v[1], v[0]]) / n if n > 0 else np.zeros(2)
    swing = np.array([-(t - centre)[1], (t - centre)[0]])         # the child's origin turned about the overlap
    J_parent = np.array([[swing[0], across(centre)[0]], [swing[1], across(centre)[1]], [1.0, 0.0]])
    J_child = np.array([[-swing[0], -across(centre - t)[0]], [-swing[1], -across(centre - t)[1]], [-1.0, 0.0]])
    return J_parent, J_child


def wall_direction(levels: np.ndarray, resolution: float, cell: Sequence[float]) -> Optional[float]:
    """The walls' direction (radians, modulo 90 degrees, in [-45, 45)) within
    :data:`DIRECTION_RADIUS` of ``cell`` ((col, row) of ``levels``, a grid's levels or a crop of
    them; ``resolution`` metres per cell); None where too few walls lie there or they hold no
    one direction (:data:`MIN_COHERENCE`). Per cell of the disc, the gradient of the (lightly
    smoothed) wall mask is taken as a vector at four times its angle, so that walls along x and
    along y add up instead of cancelling; only the disc's box is differentiated."""
    col, row = float(cell[0]), float(cell[1])
    rc = DIRECTION_RADIUS / float(resolution)
    h, w = levels.shape
    # the disc's box and a margin for the smoothing and the gradient
    r0, r1 = max(0, int(math.floor(row - rc)) - 3), min(h, int(math.ceil(row + rc)) + 4)
    c0, c1 = max(0, int(math.floor(col - rc)) - 3), min(w, int(math.ceil(col + rc)) + 4)
    if r1 - r0 < 3 or c1 - c0 < 3:
        return None
    walls = levels[r0:r1, c0:c1] == OCCUPIED
    yy, xx = np.mgrid[r0:r1, c0:c1]
    disc = (yy - row) ** 2 + (xx - col) ** 2 <= rc * rc
    if int(walls[disc].sum()) < MIN_DIRECTION_CELLS:
        return None
    smooth = cv2.GaussianBlur(walls.astype(np.float32), (0, 0), 1.0)
    gx = cv2.Sobel(smooth, cv2.CV_32F, 1, 0, ksize=3)[disc].astype(np.float64)
    gy = cv2.Sobel(smooth, cv2.CV_32F, 0, 1, ksize=3)[disc].astype(np.float64)
    strength = np.hypot(gx, gy)
    angle4 = 4.0 * np.arctan2(gy, gx)
    c, s = float((strength * np.cos(angle4)).sum()), float((strength * np.sin(angle4)).sum())
    total = float(strength.sum())
    if total <= 0.0 or math.hypot(c, s) < MIN_COHERENCE * total:
        return None
    return math.atan2(s, c) / 4.0


def turn(levels: np.ndarray, resolution: float, origin_cell: Sequence[float],
         place_cell: Sequence[float]) -> Optional[float]:
    """How far (radians, counter-clockwise) a map turned between its frame's origin and a place,
    both (col, row) of ``levels``: the walls' direction there less the one at the origin
    (:func:`wall_direction`), modulo 90 degrees; None where either cannot be read or the turn
    is too near 45 degrees to tell from its opposite (:data:`MAX_TURN`)."""
    a, b = wall_direction(levels, resolution, origin_cell), wall_direction(levels, resolution, place_cell)
    if a is None or b is None:
        return None
    d = (b - a + math.pi / 4.0) % (math.pi / 2.0) - math.pi / 4.0
    return d if abs(d) <= MAX_TURN else None


def link_turn(parent_turn: Optional[float], child_turn: Optional[float]) -> float:
    """How far (radians) two maps turned apart between their origins and their overlap, from
    each one's :func:`turn` (an unmeasured one counts 0: the rate covers it): the error the
    maps' turns put into the link's heading as a pose between their origins."""
    return (parent_turn or 0.0) - (child_turn or 0.0)
