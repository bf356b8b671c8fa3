"""Markers for rviz, as a plain function of the placements and the kept links (no node, no
rospy): where every merged robot started (its map frame's origin) in the merged frame, labelled,
with its placement's 2-sigma position ellipse, and a line per kept link between two placed
robots, coloured by how well it verified."""
from __future__ import annotations

import math
from typing import Dict, Iterable, List, Optional, Tuple

import numpy as np
from geometry_msgs.msg import Point, Quaternion
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray

from ..core.links import Link
from ..core.placement import Placement
from ..core.transforms import xyyaw

ARROW_M = 0.6      # length of a robot's arrow
TEXT_M = 0.35      # height of the labels
LINE_M = 0.05      # width of a link's line
ELLIPSE_M = 0.01   # height of a position ellipse (a flat cylinder)
ELLIPSE_SIGMAS = 2.0   # the ellipse's half-axes: this many standard deviations


def link_colour(agreement: float, min_agreement: float) -> ColorRGBA:
    """Red for a link that barely verified (wall agreement at ``min_agreement``), green at 1.0."""
    span = max(1e-6, 1.0 - min_agreement)
    c = min(1.0, max(0.0, (agreement - min_agreement) / span))
    return ColorRGBA(1.0 - c, c, 0.0, 1.0)


def ellipse_axes(cov: np.ndarray) -> Tuple[float, float, float]:
    """(full length along the major axis, along the minor axis, angle of the major axis in
    radians) of the 2-sigma ellipse of a 3x3 covariance's x, y block: half-axes of
    ELLIPSE_SIGMAS * sqrt(eigenvalue), along the eigenvectors."""
    w, v = np.linalg.eigh(np.asarray(cov, float)[:2, :2])
    w = np.maximum(w, 0.0)
    major, minor = (2.0 * ELLIPSE_SIGMAS * math.sqrt(w[1]), 2.0 * ELLIPSE_SIGMAS * math.sqrt(w[0]))
    return major, minor, math.atan2(v[1, 1], v[0, 1])


def _ellipse(frame: str, stamp, mid: int, x: float, y: float, cov: np.ndarray, weak: bool) -> Marker:
    m = _marker(frame, stamp, 'robot_ellipses', mid, Marker.CYLINDER)
    major, minor, angle = ellipse_axes(cov)
    m.pose.position.x, m.pose.position.y = x, y
    m.pose.orientation = Quaternion(0.0, 0.0, math.sin(angle / 2.0), math.cos(angle / 2.0))
    # rviz draws a cylinder of diameter scale.x along its x axis: a degenerate axis still shows
    m.scale.x, m.scale.y, m.scale.z = max(major, 1e-3), max(minor, 1e-3), ELLIPSE_M
    m.color = ColorRGBA(1.0, 0.1, 0.1, 0.5) if weak else ColorRGBA(0.2, 0.8, 1.0, 0.35)
    return m


def _marker(frame: str, stamp, ns: str, mid: int, kind: int) -> Marker:
    m = Marker()
    m.header.frame_id, m.header.stamp = frame, stamp
    m.ns, m.id, m.type, m.action = ns, mid, kind, Marker.ADD
    m.pose.orientation.w = 1.0
    return m


def markers_msg(placements: Dict[str, Placement], links: Iterable[Link], frame: str, stamp,
                min_agreement: float) -> MarkerArray:
    """The whole marker set: first a DELETEALL (robots and links that are gone disappear), then
    per placed robot an arrow at its map frame's origin along its x axis (ns ``robots``) and its
    name (ns ``robot_names``) and, when its placement has a covariance, its 2-sigma position
    ellipse (ns ``robot_ellipses``, :func:`ellipse_axes`, red when weakly pinned); per kept link
    whose two robots are placed a line between their origins (ns ``links``,
    :func:`link_colour`) labelled with its inlier ratio and agreement (ns ``link_labels``). Ids
    are the robots' and links' ranks by name."""
    arr = MarkerArray()
    clear = _marker(frame, stamp, '', 0, Marker.ARROW)
    clear.action = Marker.DELETEALL
    arr.markers.append(clear)
    where: Dict[str, Tuple[float, float]] = {}
    for i, robot in enumerate(sorted(placements)):
        pl = placements[robot]
        x, y, yaw = xyyaw(pl.T)
        where[robot] = (x, y)
        colour = ColorRGBA(1.0, 1.0, 1.0, 1.0) if not pl.via else ColorRGBA(0.2, 0.8, 1.0, 1.0)
        a = _marker(frame, stamp, 'robots', i, Marker.ARROW)
        a.pose.position.x, a.pose.position.y = x, y
        a.pose.orientation = Quaternion(0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))
        a.scale.x, a.scale.y, a.scale.z = ARROW_M, 0.1, 0.1
        a.color = colour
        t = _marker(frame, stamp, 'robot_names', i, Marker.TEXT_VIEW_FACING)
        t.pose.position.x, t.pose.position.y, t.pose.position.z = x, y + 0.4, 0.2
        t.scale.z = TEXT_M
        t.color = colour
        t.text = robot if pl.via else '%s (reference)' % robot
        arr.markers += [a, t]
        cov: Optional[np.ndarray] = pl.cov
        if cov is not None:
            arr.markers.append(_ellipse(frame, stamp, i, x, y, cov, pl.weak))
    shown: List[Link] = sorted((e for e in links if e.parent in where and e.child in where),
                               key=lambda e: (e.parent, e.child))
    for j, e in enumerate(shown):
        (xa, ya), (xb, yb) = where[e.parent], where[e.child]
        line = _marker(frame, stamp, 'links', j, Marker.LINE_LIST)
        line.points = [Point(xa, ya, 0.0), Point(xb, yb, 0.0)]
        line.scale.x = LINE_M
        line.color = link_colour(e.agreement, min_agreement)
        label = _marker(frame, stamp, 'link_labels', j, Marker.TEXT_VIEW_FACING)
        label.pose.position.x, label.pose.position.y, label.pose.position.z = (xa + xb) / 2, (ya + yb) / 2, 0.2
        label.scale.z = TEXT_M * 0.8
        label.color = line.color
        label.text = '%s-%s: inlier ratio %.2f, agreement %.2f' % (e.parent, e.child, e.inlier_ratio, e.agreement)
        arr.markers += [line, label]
    return arr


def markers_key(placements: Dict[str, Placement], links: Iterable[Link]) -> tuple:
    """What the markers are drawn from: they are published again only when this changes."""
    return (tuple(sorted((r, pl.T.tobytes(), pl.via, None if pl.cov is None else np.asarray(pl.cov).tobytes(),
                          pl.weak) for r, pl in placements.items())),
            tuple(sorted((e.parent, e.child, e.inlier_ratio, e.agreement) for e in links)))
