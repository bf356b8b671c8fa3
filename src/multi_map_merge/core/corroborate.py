"""Links of little evidence that corroborate each other: a cycle that closes.

A link of fewer than ``few_inliers`` RANSAC inliers must agree at least
``few_inliers_min_agreement`` on the grids (:func:`pair._judge`): a look-alike room yields a
handful of agreeing matches. A gmapping map bends, so a right link between two real maps may
agree a little less than that (0.95 where the gate asks 0.96) and the robot stays unmerged. Two
such links of one robot, to two other robots already placed relative to each other, that put it
at the same pose are evidence no single one of them is: two look-alikes would have to be wrong
in the same way. Those links are then accepted (``pair.PairResult.few_evidence``: refused only
by that gate, every other gate passed). A robot's initial pose (``initial_poses``, relative to a
placed robot's) is such a second source too: a link of little evidence that puts the robot where
its initial pose does is accepted, as a look-alike would have to fall where the robot was said
to start.

Frames: placements and links are 3x3 SE(2) matrices in metres (:mod:`placement`, :mod:`links`).
"""
from __future__ import annotations

import math
from typing import Callable, Dict, List, Optional, Set, Tuple

import numpy as np

from .transforms import inverse, pose_distance, within

# two poses of a robot closer than this (metres at its map frame's origin, radians) are one
AGREE = (0.15, math.radians(1.5))

Key = Tuple[str, str]


def corroborated(candidates: Dict[Key, np.ndarray], placed: Dict[str, np.ndarray],
                 priors: Optional[Dict[str, np.ndarray]] = None) -> Tuple[Set[Key], List[str]]:
    """The links of ``candidates`` ((parent, child) -> pose of the child's map frame in the
    parent's, metres; links refused only for too little evidence) that corroborate each other:
    for a robot not in ``placed`` (robot -> placement in the merged frame), two of its links to
    two placed robots whose poses of it agree within :data:`AGREE`, or one whose pose of it
    agrees within :data:`AGREE` with its pose in ``priors`` (robot -> its map frame in the
    merged frame by the initial poses). Returns those links and one line per link or pair of
    links saying so."""
    by_robot: Dict[str, List[Tuple[Key, str, np.ndarray]]] = {}
    for (a, b), T in sorted(candidates.items()):
        for x, y, T_yx in ((b, a, T), (a, b, inverse(T))):
            if x not in placed and y in placed:
                by_robot.setdefault(x, []).append(((a, b), y, placed[y] @ T_yx))
    keys: Set[Key] = set()
    events = []
    for x, links in sorted(by_robot.items()):
        if priors and x in priors:
            for k1, y1, P1 in links:
                if within(P1, priors[x], AGREE):
                    d, a = pose_distance(P1, priors[x])
                    keys.add(k1)
                    events.append('%s: link of little evidence with %s agrees with its initial pose '
                                  '(%.3f m %.2f deg apart)' % (x, y1, d, math.degrees(a)))
        for i, (k1, y1, P1) in enumerate(links):
            for k2, y2, P2 in links[i + 1:]:
                if y1 == y2:
                    continue
                if within(P1, P2, AGREE):
                    d, a = pose_distance(P1, P2)
                    keys.update((k1, k2))
                    events.append('%s: links of little evidence with %s and %s corroborate each other '
                                  '(%.3f m %.2f deg apart)' % (x, y1, y2, d, math.degrees(a)))
    return keys, events


def poses_of(results: Dict[Key, object], to_pose: Callable[[Key, object], np.ndarray]) -> Dict[Key, np.ndarray]:
    """The candidates of :func:`corroborated` among pair ``results`` (key -> PairResult):
    refused only for too little evidence, with a transform; ``to_pose`` turns one into metres."""
    return {k: to_pose(k, r) for k, r in results.items()
            if getattr(r, 'few_evidence', False) and not r.accepted and r.A is not None}
