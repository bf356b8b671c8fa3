"""Which pairs of robots an estimation cycle works on, and how (no ROS in here).

A pair's work costs what its maps changed, not what the team holds:

* a pair with a verified link whose maps changed is *tracked*: the kept link followed onto the
  new maps (:func:`pair.track_pair`: ICP and verification, milliseconds), as a scan matcher
  tracks. A robot's links that are tracked are its :data:`TRACKED_PER_ROBOT` links of the
  largest overlap and the one its placement goes through; the others stand as they are until
  the slow schedule aligns them again;
* full alignment from features (:func:`pair.align_pair`, a tenth of a second or more) runs for
  a link whose tracking failed; for a pair without a link, when one of the two robots is not
  placed yet (its map changed), or when both are placed and their maps, where they are placed,
  can overlap (their known boxes meet in the merged frame) and that overlap grew by
  :data:`GROWTH` since the pair was last aligned; and on a slow schedule: per robot, every
  :data:`SLOW_EVERY` new versions of its map, its link aligned longest ago (so that a better
  link can still be found: the paper's rule of the most reliable link holds);
* the alignments go in priority order (:class:`Plan`): failed tracks, then pairs that can place
  a robot not placed yet (with a placed robot first, by the overlap they can have), then placed
  pairs by expected overlap, then the slow schedule. The merger gives the worker pool a time
  budget per cycle (``estimation_budget``); what it does not start waits for a later cycle.

Frames and units: boxes are in metres of the merged frame; overlaps in cells of the working
resolution.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Iterable, List, Mapping, Optional, Set, Tuple

import numpy as np

Pair = Tuple[str, str]

# links per robot tracked when its map changes: its largest overlaps (and its placement's own)
TRACKED_PER_ROBOT = 3
# a pair without a link is aligned again when the overlap its placed maps can have grew by this
# factor since it was last aligned
GROWTH = 1.2

# the slow schedule: a robot's link aligned longest ago is aligned again from features once per
# this many new versions of its map
SLOW_EVERY = 4

# priority classes of an alignment (lower first)
FAILED_TRACK, PLACES_ROBOT, PLACES_ROBOT_UNPLACED, PLACED_PAIR, SLOW_SCHEDULE = range(5)


@dataclass
class MapFacts:
    """What the schedule needs of one robot's map: its version, known cells (count) and the
    corners (4, 2) of its known box in metres of its map frame (None when nothing is known)."""

    version: int
    known: int
    corners: Optional[np.ndarray]


@dataclass
class Aligned:
    """A pair's last alignment from features: the estimation cycle it ran in and the overlap
    (cells) the pair's placed maps could have then (None: a robot was not placed)."""

    cycle: int
    expected: Optional[float]


@dataclass
class Plan:
    """One cycle's pair work: ``todo`` in priority order, those of ``track`` (pair -> the kept
    link's pose, metres of the child's frame -> the parent's) tracked, the rest aligned;
    ``why``: per aligned pair, its priority class."""

    todo: List[Pair] = field(default_factory=list)
    track: Dict[Pair, np.ndarray] = field(default_factory=dict)
    why: Dict[Pair, int] = field(default_factory=dict)


def pairs_of(names: Iterable[str], ref: str) -> List[Pair]:
    """Every pair of robots, (parent, child): the first by name the parent, the reference always
    the parent (so that a robot that misses the reference can chain through another)."""
    names = sorted(names)
    out = []
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            out.append((a, b) if b != ref else (b, a))
    return out


def placed_box(corners: Optional[np.ndarray], T: Optional[np.ndarray]) -> Optional[Tuple[float, float, float, float]]:
    """(x0, y0, x1, y1) metres: the axis-aligned box in the merged frame of a map's known box
    placed at ``T`` (3x3); None when either is unknown."""
    if corners is None or T is None:
        return None
    p = corners @ T[:2, :2].T + T[:2, 2]
    return float(p[:, 0].min()), float(p[:, 1].min()), float(p[:, 0].max()), float(p[:, 1].max())


def box_overlap(a, b, resolution: float) -> float:
    """Cells (at ``resolution`` metres) where two boxes of :func:`placed_box` meet; 0 apart."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    return w * h / (resolution * resolution) if w > 0 and h > 0 else 0.0


def tracked_links(links: Mapping[Pair, object], via: Mapping[str, str],
                  per_robot: int = TRACKED_PER_ROBOT) -> Set[Pair]:
    """The links that are tracked: per robot, its ``per_robot`` links of the largest overlap
    (``link.overlap``; ties by name) and the link to the robot its placement goes through
    (``via``: robot -> the robot it is placed through, '' for none)."""
    by_robot: Dict[str, List[Tuple[int, Pair]]] = {}
    for k, e in links.items():
        for n in k:
            by_robot.setdefault(n, []).append((int(getattr(e, 'overlap', 0)), k))
    out: Set[Pair] = set()
    for ks in by_robot.values():
        ks.sort(key=lambda t: (-t[0], t[1]))
        out.update(k for _, k in ks[:per_robot])
    for n, v in via.items():
        if v and (v, n) in links:
            out.add((v, n))
        elif v and (n, v) in links:
            out.add((n, v))
    return out


def plan(facts: Mapping[str, MapFacts], ref: str, links: Mapping[Pair, object],
         tried: Mapping[Pair, Tuple[int, int]], aligned: Mapping[Pair, Aligned], failed: Set[Pair],
         placements: Mapping[str, np.ndarray], via: Mapping[str, str], due: Set[str],
         resolution: float) -> Plan:
    """The cycle's pair work (module docstring). ``facts``: every robot's map; ``links``: the
    kept links; ``tried``: per pair, the map versions last worked on; ``aligned``: per pair, its
    last alignment from features; ``failed``: links whose last tracking failed;
    ``placements``: robot -> pose (3x3) in the merged frame of the placed robots; ``via``: robot
    -> the robot its placement goes through; ``due``: robots whose turn on the slow schedule
    it is (:data:`SLOW_EVERY`); ``resolution``: metres per cell."""
    boxes = {n: placed_box(f.corners, placements.get(n)) for n, f in facts.items()}
    tracked = tracked_links(links, via)
    # the slow schedule: per robot due, its link aligned longest ago
    slow: Set[Pair] = set()
    for n in sorted(due):
        mine = [k for k in links if n in k and k not in slow]
        if mine:
            slow.add(min(mine, key=lambda k: (aligned[k].cycle if k in aligned else -1, k)))
    work: List[Tuple[tuple, Pair]] = []
    track: Dict[Pair, np.ndarray] = {}
    for k in pairs_of(facts, ref):
        a, b = k
        if tried.get(k) == (facts[a].version, facts[b].version):
            continue                       # nothing new since it was last worked on
        if k in links:
            if k in failed:
                work.append(((FAILED_TRACK, 0.0), k))
            elif k in slow:
                work.append(((SLOW_SCHEDULE, aligned[k].cycle if k in aligned else -1), k))
            elif k in tracked:
                track[k] = links[k].T
            continue                       # (an untracked link stands until the slow schedule)
        if a in placements and b in placements:
            expected = box_overlap(boxes[a], boxes[b], resolution) if boxes[a] and boxes[b] else 0.0
            last = aligned.get(k)
            if expected <= 0 or (last is not None and last.expected is not None
                                 and expected < GROWTH * last.expected):
                continue                   # cannot overlap, or no more than when last aligned
            work.append(((PLACED_PAIR, -expected), k))
        else:
            # the overlap it can have: at most the smaller map's known cells
            cls = PLACES_ROBOT if (a in placements or b in placements) else PLACES_ROBOT_UNPLACED
            never = 0 if k not in aligned else 1
            work.append(((cls, never, -min(facts[a].known, facts[b].known)), k))
    work.sort(key=lambda t: (t[0], t[1]))
    out = Plan(track=track)
    out.todo = list(track) + [k for _, k in work]
    out.why = {k: p[0] for p, k in work}
    return out


def expected_overlap(facts: Mapping[str, MapFacts], placements: Mapping[str, np.ndarray], k: Pair,
                     resolution: float) -> Optional[float]:
    """Cells the pair's placed maps can overlap by (their placed known boxes'), None when one of
    them is not placed."""
    a, b = k
    if a not in placements or b not in placements:
        return None
    ba = placed_box(facts[a].corners, placements[a])
    bb = placed_box(facts[b].corners, placements[b])
    return box_overlap(ba, bb, resolution) if ba and bb else 0.0
