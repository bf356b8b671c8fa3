"""The node's /diagnostics as plain functions of the merger's status (no node, no rospy): what
is written for every robot and for the node, and how a reader gets it back per robot.

The node publishes them through ``diagnostic_updater`` (one task per robot, one for the
node): each function fills the status object the updater hands it (a
``DiagnosticStatusWrapper``, which is a ``DiagnosticStatus``) or a new ``DiagnosticStatus``.
The ROS 2 node (``ros2/multi_map_merge_ros2``) writes the same statuses with ROS 2's
diagnostic_msgs, whose messages take keyword arguments only (hence ``KeyValue(key=, value=)``).
"""
from __future__ import annotations

import math
from typing import Dict, List, Optional

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from ..core.deform import REPORT_BENT
from ..core.state import placement_dict
from ..core.status import RobotStatus

# how a placement's numbers (:func:`core.state.placement_dict`) are written on /diagnostics
FORMAT = {'inlier_ratio': '%.3f', 'agreement': '%.3f', 'inliers': '%d', 'x': '%.3f', 'y': '%.3f', 'yaw': '%.4f',
          'sigma_position': '%.4f'}


def map_age(st: RobotStatus, now: float) -> Optional[float]:
    """Seconds since the robot's last map arrived (None before any)."""
    return None if st.map_received is None else max(0.0, now - st.map_received)


def stale_maps(status: Dict[str, RobotStatus], gone: Dict[str, bool], now: float,
               stale_map_timeout: float) -> Dict[str, float]:
    """Robot -> its map's age, for the robots whose publisher is still there but whose last map
    is older than ``stale_map_timeout`` seconds (0: none ever). A robot whose publisher went away
    is said to have vanished instead."""
    if stale_map_timeout <= 0:
        return {}
    out = {}
    for robot, st in status.items():
        age = map_age(st, now)
        if age is not None and age > stale_map_timeout and not gone.get(robot):
            out[robot] = age
    return out


def robot_diagnostic(robot: str, st: RobotStatus, gone: bool, now: float,
                     out: Optional[DiagnosticStatus] = None,
                     stale_map_timeout: float = 0.0) -> DiagnosticStatus:
    """One robot's status: merged or not, via which robot, the placement, its quality and how
    well it is pinned (``sigma_position``: metres, '0.0000' for the reference, '-' when unknown;
    ``weak``), the last pair attempt, input errors, whether its map publisher is ``gone``, and
    how old its last map is (``map_age_s``). A merged robot weakly pinned is WARN, saying why
    (the placement's ``weak_reason``, :func:`core.placement.pin`), and so is a robot whose publisher
    is there but whose last map is older than ``stale_map_timeout`` seconds (0: off; its last map
    stays merged). The hardware id is the robot (readers key the robots' statuses by it).
    ``now``: wall seconds, for the placement's and the map's ages."""
    s = out if out is not None else DiagnosticStatus()
    s.hardware_id = robot
    kv = [('merged', str(st.merged).lower()), ('reference', str(st.reference).lower()),
          ('linked_to', ' '.join(st.linked_to) or '-'),
          ('publisher', 'gone' if gone else 'ok')]
    age = map_age(st, now)
    if age is not None:
        kv += [('map_age_s', '%.1f' % age)]
    if st.placement is not None:
        d = placement_dict(st.placement)
        kv += [('via', d['via'] or '-'), ('chain', ' -> '.join(d['chain']))]
        kv += [(k, FORMAT[k] % d[k]) for k in ('inlier_ratio', 'agreement', 'inliers', 'x', 'y', 'yaw')]
        sigma = 0.0 if st.reference else d.get('sigma_position')   # the reference is exact
        kv += [('sigma_position', FORMAT['sigma_position'] % sigma if sigma is not None else '-'),
               ('weak', str(d['weak']).lower()), ('provisional', str(st.placement.provisional).lower())]
        kv += [('age_s', '%.1f' % (now - st.placement.stamp))]
    if st.last_attempt is not None:
        a = st.last_attempt
        kv += [('last_pair', st.last_attempt_with), ('last_inlier_ratio', '%.3f' % a.inlier_ratio),
               ('last_agreement', '%.3f' % a.agreement), ('last_inliers', str(a.inliers)),
               ('last_result', 'accepted' if a.accepted else a.reason)]
    if st.error:
        s.level, s.message = DiagnosticStatus.ERROR, 'input ignored: ' + st.error
    elif st.reference:
        s.level, s.message = DiagnosticStatus.OK, 'reference map'
    elif st.merged and st.placement.weak:
        s.level = DiagnosticStatus.WARN
        s.message = 'merged via %s, weakly pinned: %s' % (st.placement.via, st.placement.weak_reason)
    elif st.merged and st.placement.provisional:
        # OK: placed from verified links; its covariance and joint refinement come in the spare time
        s.level = DiagnosticStatus.OK
        s.message = 'merged via %s (first placement: refined before the next cycle)' % st.placement.via
    elif st.merged:
        s.level, s.message = DiagnosticStatus.OK, 'merged via %s' % st.placement.via
    elif st.linked_to:
        s.level = DiagnosticStatus.WARN
        s.message = ('not merged: linked to %s, but no chain of verified links to the '
                     'reference yet' % ', '.join(st.linked_to))
    else:
        s.level = DiagnosticStatus.WARN
        s.message = 'not merged' + (': ' + st.last_attempt.reason if st.last_attempt else '')
    if st.bends:
        # a note, not a level: the bend is in the link's covariance, which sets ``weak``
        s.message += '; ' + '; '.join("%s's map bends %.2f m across its overlap with %s" % (robot, m, other)
                                      for other, m in st.bends)
        kv += [('bends', ' '.join('%s:%.2f' % (other, m) for other, m in st.bends))]
    if st.turns:
        # a note, not a level: the turn is in the placement's covariance, which sets ``weak``; the
        # walls cannot tell a map that turned from a building whose wings do
        s.message += '; ' + '; '.join("%s's map and %s's turn %.0f deg apart between their starts and their "
                                      "overlap (a map turned, or the building does)" % (robot, other, math.degrees(t))
                                      for other, t in st.turns)
        kv += [('turns (deg)', ' '.join('%s:%.1f' % (other, math.degrees(t)) for other, t in st.turns))]
    if st.bent > 0.0:
        # ~bend_maps: how far the merged map moves this map's walls off its (rigid) placement
        kv += [('bent in the merged map (m)', '%.2f' % st.bent)]
        if st.bent >= REPORT_BENT:
            s.message += "; %s's map bent up to %.2f m in the merged map to meet the others" % (robot, st.bent)
    if gone:
        s.message += ' (vanished: no publisher of its map; its last map and transform are kept)'
        s.level = max(s.level, DiagnosticStatus.WARN)
    elif robot in stale_maps({robot: st}, {}, now, stale_map_timeout):
        s.message += '; no map for %.0f s (over ~stale_map_timeout, %g s; its last map is kept)' % (
            age, stale_map_timeout)
        s.level = max(s.level, DiagnosticStatus.WARN)
    s.values = [KeyValue(key=k, value=v) for k, v in kv]
    return s


def node_diagnostic(status: Dict[str, RobotStatus], gone: Dict[str, bool], est_seconds: float,
                    est_error: Optional[BaseException], robots: int, merged: int,
                    out: Optional[DiagnosticStatus] = None, now: Optional[float] = None,
                    stale_map_timeout: float = 0.0,
                    no_map_yet: Optional[Dict[str, float]] = None) -> DiagnosticStatus:
    """The node's own status. ERROR when the last estimation cycle raised ``est_error`` (its
    type and text in the message); else WARN naming the robots that vanished (no publisher of
    their map), whose maps stopped (none for over ``stale_map_timeout`` seconds at wall time
    ``now``, publisher still there), are not merged, are merged but weakly pinned, or whose last
    input was refused, or robots of ``~robots`` that have sent no map at all (``no_map_yet``:
    robot -> seconds waited, given by the caller once that is over ``stale_map_timeout``);
    else OK. Values: the last cycle's seconds (``last_estimation_s``), how many robots and how
    many merged, which are not merged, vanished, stale, without a map yet or weakly pinned, the
    last error. The hardware id is left to the caller (the updater sets the node's)."""
    s = out if out is not None else DiagnosticStatus()
    stale = stale_maps(status, gone, now, stale_map_timeout) if now is not None else {}
    vanished = sorted(r for r, g in gone.items() if g)
    unmerged = sorted(r for r, st in status.items() if not st.merged)
    weak = sorted(r for r, st in status.items() if st.merged and st.placement is not None and st.placement.weak)
    refused = sorted(r for r, st in status.items() if st.error)
    waiting = {r: t for r, t in (no_map_yet or {}).items() if r not in status}
    if est_error is not None:
        s.level = DiagnosticStatus.ERROR
        s.message = 'estimation failed: %s' % error_text(est_error)
    elif vanished or stale or unmerged or weak or refused or waiting or not status:
        s.level = DiagnosticStatus.WARN
        parts: List[str] = []
        if not status:
            parts.append('no robot map yet')
        if unmerged:
            parts.append('not merged: %s' % ', '.join(unmerged))
        if weak:
            parts.append('weakly pinned: %s' % ', '.join(weak))
        if vanished:
            parts.append('vanished: %s' % ', '.join(vanished))
        if stale:
            parts.append('stale: %s' % ', '.join('%s (no map for %.0f s)' % (r, stale[r]) for r in sorted(stale)))
        if refused:
            parts.append('input ignored: %s' % ', '.join(refused))
        if waiting:
            parts.append('no map yet: %s' % ', '.join('%s (waited %.0f s)' % (r, waiting[r]) for r in sorted(waiting)))
        s.message = '; '.join(parts)
    else:
        s.level = DiagnosticStatus.OK
        s.message = '%d robots merged; estimation cycle %.2f s' % (merged, est_seconds)
    s.values = [KeyValue(key='last_estimation_s', value='%.3f' % est_seconds),
                KeyValue(key='robots', value=str(robots)),
                KeyValue(key='merged', value=str(merged)),
                KeyValue(key='not_merged', value=' '.join(unmerged) or '-'),
                KeyValue(key='vanished', value=' '.join(vanished) or '-'),
                KeyValue(key='stale', value=' '.join(sorted(stale)) or '-'),
                KeyValue(key='no_map_yet', value=' '.join(sorted(waiting)) or '-'),
                KeyValue(key='weakly_pinned', value=' '.join(weak) or '-'),
                KeyValue(key='last_error', value=error_text(est_error) if est_error is not None else '-')]
    return s


def error_text(e: BaseException) -> str:
    """``Type: text`` of an exception (the type alone when it has no text)."""
    text = str(e)
    return '%s: %s' % (type(e).__name__, text) if text else type(e).__name__


def diagnostics_by_robot(msg, out: Dict[str, Dict[str, str]]) -> None:
    """Store the statuses of ``msg`` in ``out`` by hardware id (the merger's per-robot statuses:
    robot -> its key/values plus 'message')."""
    for st in msg.status:
        if st.hardware_id:
            d = {kv.key: kv.value for kv in st.values}
            d['message'] = st.message
            out[st.hardware_id] = d
