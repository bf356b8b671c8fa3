"""What the merger's status shows per robot (:meth:`merger.MapMerger.status`): merged or not,
its placement, its last pair attempt, its last input error, its links and how they bend and turn."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Mapping, Optional, Tuple

import numpy as np

from . import bend, deform, drift
from .links import Link
from .pair import PairResult
from .placement import Placement
from .robot_map import RobotMap

Pair = Tuple[str, str]


@dataclass
class RobotStatus:
    """What diagnostics show for one robot."""

    merged: bool
    reference: bool
    placement: Optional[Placement]
    last_attempt: Optional[PairResult] = None
    last_attempt_with: str = ''
    error: str = ''
    linked_to: Tuple[str, ...] = ()   # robots it has verified links with
    # its verified links: (parent, child, 3x3 covariance of (x, y, yaw) of the child's map
    # frame in the parent's, x, y in metres of the parent's frame, yaw in radians; None if unknown)
    link_covariances: Tuple[Tuple[str, str, Optional[np.ndarray]], ...] = ()
    # seconds (time.time()) when its last map arrived (republished unchanged included); None
    # before any
    map_received: Optional[float] = None
    # its verified links whose overlap bends (core/bend.py): (the other robot, metres the
    # overlap's halves land apart), at least bend.REPORT_BEND, largest first
    bends: Tuple[Tuple[str, float], ...] = ()
    # bend_maps: metres the merged map moves its map's walls at most off its placement to meet
    # the others' (core/deform.py: its field's largest node move); 0 when not bent
    bent: float = 0.0
    # its verified links across whose overlap its map and the other's turned apart from their
    # origins, as both maps' walls show (core/drift.py): (the other robot, radians: its map's
    # turn less the other's), at least drift.REPORT_TURN, largest first
    turns: Tuple[Tuple[str, float], ...] = ()


def _turns_apart(robot: str, edges: Dict[Tuple[str, str], Link]) -> Tuple[Tuple[str, float], ...]:
    """Per verified link of ``robot`` whose two maps' turns were both read: the other robot and
    what ``robot``'s map turned less the other's (radians), where that reaches
    :data:`drift.REPORT_TURN`; largest first."""
    out = []
    for (parent, child), link in edges.items():
        if robot not in (parent, child) or link.parent_turn is None or link.child_turn is None:
            continue
        apart = drift.link_turn(link.parent_turn, link.child_turn)
        other, apart = (child, apart) if robot == parent else (parent, -apart)
        if abs(apart) >= drift.REPORT_TURN:
            out.append((other, apart))
    return tuple(sorted(out, key=lambda x: -abs(x[1])))


def robot_statuses(maps: Mapping[str, RobotMap], errors: Mapping[str, str], results: Mapping[Pair, PairResult],
                   links: Mapping[Pair, Link], placements: Mapping[str, Placement],
                   fields: Mapping[str, Tuple[int, deform.Field]], ref: str) -> Dict[str, RobotStatus]:
    """Per robot with a map or an input error, by name: its :class:`RobotStatus` from the team's
    ``maps`` and ``errors``, the pairs' last ``results`` and kept ``links``, the ``placements``
    and the bent maps' correction ``fields`` (per robot: (map version, field)); ``ref`` the
    reference robot."""
    out = {}
    for n in sorted(set(maps) | set(errors)):
        last, other = None, ''
        for (a, b), e in results.items():
            if n in (a, b) and (last is None or e.stamp > last.stamp):
                last, other = e, (b if a == n else a)
        pl = placements.get(n)
        linked = tuple(sorted({b if a == n else a for (a, b) in links if n in (a, b)}))
        covs = tuple((a, b, e.cov) for (a, b), e in sorted(links.items()) if n in (a, b))
        bends = tuple(sorted(((b if a == n else a, e.bend) for (a, b), e in links.items()
                              if n in (a, b) and e.bend >= bend.REPORT_BEND), key=lambda x: -x[1]))
        m = maps.get(n)
        field = fields.get(n)
        out[n] = RobotStatus(pl is not None, n == ref, pl, last, other, errors.get(n, ''), linked,
                             covs, m.received if m is not None else None, bends,
                             field[1].largest() if field is not None else 0.0, _turns_apart(n, links))
    return out
