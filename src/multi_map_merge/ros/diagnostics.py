"""The node's /diagnostics, as plain functions of the merger's status (no node, no rospy):
what is written for every robot, and how a reader gets it back per robot."""
from __future__ import annotations

from typing import Dict

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ..core.merger import RobotStatus
from ..core.state import placement_dict

# how a placement's numbers (:func:`core.state.placement_dict`) are written on /diagnostics
FORMAT = {'inlier_ratio': '%.3f', 'agreement': '%.3f', 'inliers': '%d', 'x': '%.3f', 'y': '%.3f', 'yaw': '%.4f'}


def diagnostics_msg(status: Dict[str, RobotStatus], gone: Dict[str, bool], cycle_seconds: float,
                    robots: int, merged: int, stamp, now: float) -> DiagnosticArray:
    """The node's /diagnostics: one status per robot (its :class:`RobotStatus`, and whether its
    map publisher is ``gone``) and one for the node (the last estimation cycle's seconds, how
    many robots and how many merged). ``stamp``: the header's time; ``now``: wall seconds, for
    the placements' ages."""
    arr = DiagnosticArray()
    arr.header.stamp = stamp
    for robot, st in status.items():
        s = DiagnosticStatus()
        s.name = 'multi_map_merge: %s' % robot
        s.hardware_id = robot
        kv = [('merged', str(st.merged).lower()), ('reference', str(st.reference).lower()),
              ('linked_to', ' '.join(st.linked_to) or '-'),
              ('publisher', 'gone' if gone.get(robot) else 'ok')]
        if st.placement is not None:
            d = placement_dict(st.placement)
            kv += [('via', d['via'] or '-'), ('chain', ' -> '.join(d['chain']))]
            kv += [(k, FORMAT[k] % d[k]) for k in ('inlier_ratio', 'agreement', 'inliers', 'x', 'y', 'yaw')]
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
        elif st.merged:
            s.level, s.message = DiagnosticStatus.OK, 'merged via %s' % st.placement.via
        elif st.linked_to:
            s.level = DiagnosticStatus.WARN
            s.message = ('not merged: linked to %s, but no chain of verified links to the '
                         'reference yet' % ', '.join(st.linked_to))
        else:
            s.level = DiagnosticStatus.WARN
            s.message = 'not merged' + (': ' + st.last_attempt.reason if st.last_attempt else '')
        s.values = [KeyValue(k, v) for k, v in kv]
        arr.status.append(s)
    s = DiagnosticStatus()
    s.name, s.hardware_id = 'multi_map_merge: node', 'map_merge'
    s.level, s.message = DiagnosticStatus.OK, 'estimation cycle %.2f s' % cycle_seconds
    s.values = [KeyValue('last_estimation_s', '%.3f' % cycle_seconds),
                KeyValue('robots', str(robots)),
                KeyValue('merged', str(merged))]
    arr.status.append(s)
    return arr


def diagnostics_by_robot(msg, out: Dict[str, Dict[str, str]]) -> None:
    """Store the merger's per-robot diagnostics of ``msg`` in ``out``: robot -> its key/values
    plus 'message'."""
    for st in msg.status:
        if st.hardware_id:
            d = {kv.key: kv.value for kv in st.values}
            d['message'] = st.message
            out[st.hardware_id] = d
