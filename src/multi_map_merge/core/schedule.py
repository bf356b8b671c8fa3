"""Which pairs of robots an estimation cycle works on, and how (no ROS in here).

A pair's work costs what its maps changed, not what the team holds:

* a pair with a verified link whose maps changed is *tracked*: the kept link followed onto the
  new maps (:func:`pair.track_pair`: ICP and verification, milliseconds), as a scan matcher
  tracks. When a robot's map changed, its links that are tracked are the one its placement
  goes through and its :data:`TRACKED_PER_ROBOT` links whose maps grew most since they were
  last tracked or aligned (in turn, so that a link found on the small maps of a team's start is
  refined on what they grew to, while a robot's cost per new map stays bounded); the others
  stand as they are;
* full alignment from features (:func:`pair.align_pair`, a tenth of a second or more) runs for
  a link whose tracking failed; for a pair without a link when one of the two robots is not
  placed yet (its map changed); and on a slow schedule, one pair per robot every
  :data:`SLOW_EVERY` new versions of its map: of its pairs with a placed robot but without a
  link, the one whose maps, where they are placed, can overlap most (their known boxes meet in
  the merged frame; a pair aligned before only once that overlap grew by :data:`GROWTH`), or
  else its link whose maps grew most since it was aligned (so that a better link can still be
  found: the paper's rule of the most reliable link holds; and a link found on the small maps
  of a team's start is found again on what they grew to). A robot's pairs with placed robots
  cost a bounded share of its new maps, so a round of map updates costs what the team's size
  calls for, not its square;
* the alignments go in priority order (:class:`Plan`): failed tracks, then pairs that can place
  a robot not placed yet (with a placed robot first, by the overlap they can have), then the
  slow schedule's (pairs without a link by expected overlap, then links). The merger gives the worker pool a time
  budget per cycle (``estimation_budget``); what it does not start waits for a later cycle.

Frames and units: boxes are in metres of the merged frame; overlaps in cells of the working
resolution.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Iterable, List, Mapping, Optional, Set, Tuple

import numpy as np

from .config import MergeConfig
from .grid import Grid
from .robot_map import RobotMap
from .transforms import cell_to_metric

Pair = Tuple[str, str]

# links per robot tracked when its map changes: those whose maps grew most (and its placement's own)
TRACKED_PER_ROBOT = 2
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
    """A pair's last alignment from features: the estimation cycle it ran in, the overlap
    (cells) the pair's placed maps could have then (None: a robot was not placed) and the two
    maps' known cells then (parent's, child's)."""

    cycle: int
    expected: Optional[float]
    known: Tuple[int, int] = (0, 0)


def growth(facts: Mapping[str, MapFacts], k: Pair, then: Optional[Tuple[int, int]]) -> float:
    """How much a pair's maps grew since ``then`` (their known cells, parent's and child's):
    the product of the two maps' known cells now over then (infinite when not known)."""
    if then is None or min(then) <= 0:
        return float('inf')
    return facts[k[0]].known / float(then[0]) * facts[k[1]].known / float(then[1])


@dataclass
class Plan:
    """One cycle's pair work: ``todo`` in priority order, those of ``track`` (pair -> the kept
    link's pose, metres of the child's frame -> the parent's) tracked, the rest aligned;
    ``why``: per aligned pair, its priority class."""

    todo: List[Pair] = field(default_factory=list)
    track: Dict[Pair, np.ndarray] = field(default_factory=dict)
    why: Dict[Pair, int] = field(default_factory=dict)
    due: Set[str] = field(default_factory=set)   # the robots whose turn on the slow schedule it was


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


def tracked_links(links: Mapping[Pair, object], via: Mapping[str, str], grown: Mapping[Pair, float],
                  per_robot: int = TRACKED_PER_ROBOT, robots: Optional[Set[str]] = None) -> Set[Pair]:
    """The links that are tracked: per robot of ``robots`` (those whose map changed; None:
    every robot), its ``per_robot`` links whose maps grew most (``grown``: pair -> growth since
    it was last tracked or aligned, as :func:`growth`; ties: the larger ``link.overlap``, then by
    name) and the link to the robot its placement goes through (``via``: robot -> the robot it
    is placed through, '' for none)."""
    by_robot: Dict[str, List[Tuple[float, int, Pair]]] = {}
    for k, e in links.items():
        for n in k:
            if robots is None or n in robots:
                by_robot.setdefault(n, []).append((grown.get(k, 1.0), int(getattr(e, 'overlap', 0)), k))
    out: Set[Pair] = set()
    for ks in by_robot.values():
        ks.sort(key=lambda t: (-t[0], -t[1], t[2]))
        out.update(k for _, _, k in ks[:per_robot])
    for n, v in via.items():
        if robots is not None and n not in robots:
            continue
        if v and (v, n) in links:
            out.add((v, n))
        elif v and (n, v) in links:
            out.add((n, v))
    return out


def linked_to(ref: str, links: Iterable[Pair]) -> Set[str]:
    """The robots a chain of ``links`` joins to ``ref`` (``ref`` included)."""
    nbrs: Dict[str, List[str]] = {}
    for a, b in links:
        nbrs.setdefault(a, []).append(b)
        nbrs.setdefault(b, []).append(a)
    seen, todo = {ref}, [ref]
    while todo:
        for o in nbrs.get(todo.pop(), ()):
            if o not in seen:
                seen.add(o)
                todo.append(o)
    return seen


def plan(facts: Mapping[str, MapFacts], ref: str, links: Mapping[Pair, object],
         tried: Mapping[Pair, Tuple[int, int]], aligned: Mapping[Pair, Aligned], failed: Set[Pair],
         placements: Mapping[str, np.ndarray], via: Mapping[str, str], due: Set[str],
         resolution: float, refreshed: Optional[Mapping[Pair, Tuple[int, int]]] = None,
         changed: Optional[Set[str]] = None) -> Plan:
    """The cycle's pair work (module docstring). ``facts``: every robot's map; ``links``: the
    kept links; ``tried``: per pair, the map versions last worked on; ``aligned``: per pair, its
    last alignment from features; ``failed``: links to align again from features rather than
    track (their last tracking failed, or a prior changed);
    ``placements``: robot -> pose (3x3) in the merged frame of the placed robots (those a chain
    of ``links`` joins to ``ref`` count as placed); ``via``: robot
    -> the robot its placement goes through; ``due``: robots whose turn on the slow schedule
    it is (:data:`SLOW_EVERY`); ``resolution``: metres per cell; ``refreshed``: per link, its
    maps' known cells when it was last tracked or aligned; ``changed``: the robots whose map is
    new since the previous cycle, whose links are tracked (None: every robot)."""
    # placed by links: a robot at its prior (or placed by a link dropped since) still needs one
    reach = linked_to(ref, links)
    placements = {n: T for n, T in placements.items() if n in reach}
    if ref in facts:
        placements.setdefault(ref, np.eye(3))   # (the reference is placed from its first map on)
    boxes = {n: placed_box(f.corners, placements.get(n)) for n, f in facts.items()}
    refreshed = refreshed or {}
    tracked = tracked_links(links, via, {k: growth(facts, k, refreshed.get(k)) for k in links},
                            TRACKED_PER_ROBOT, changed)
    work: List[Tuple[tuple, Pair]] = []
    track: Dict[Pair, np.ndarray] = {}
    unlinked: Dict[Pair, float] = {}   # placed pairs without a link that may be aligned: their expected overlap
    for k in pairs_of(facts, ref):
        a, b = k
        if k in links and k in failed:
            work.append(((FAILED_TRACK, 0.0), k))   # (on these maps too: tracking is not alignment)
            continue
        if tried.get(k) == (facts[a].version, facts[b].version):
            continue                       # nothing new since it was last worked on
        if k in links:
            if k in tracked:
                track[k] = links[k].T
            continue                       # (an untracked link stands until the slow schedule)
        if a in placements and b in placements:
            expected = box_overlap(boxes[a], boxes[b], resolution) if boxes[a] and boxes[b] else 0.0
            last = aligned.get(k)
            if expected <= 0 or (last is not None and last.expected is not None
                                 and expected < GROWTH * last.expected):
                continue                   # cannot overlap, or no more than when last aligned
            unlinked[k] = expected
        else:
            # the overlap it can have: at most the smaller map's known cells
            cls = PLACES_ROBOT if (a in placements or b in placements) else PLACES_ROBOT_UNPLACED
            never = 0 if k not in aligned else 1
            work.append(((cls, never, -min(facts[a].known, facts[b].known)), k))
    # the slow schedule: per robot due, one alignment: its placed pair without a link that can
    # overlap most, else its link whose maps grew most since it was aligned
    slots: Set[Pair] = set()
    for n in sorted(due):
        mine = sorted((-e, k) for k, e in unlinked.items() if n in k and k not in slots)
        if mine:
            slots.add(mine[0][1])
            work.append(((PLACED_PAIR, mine[0][0]), mine[0][1]))
            continue
        mine = [k for k in links if n in k and k not in slots and k not in failed
                and tried.get(k) != (facts[k[0]].version, facts[k[1]].version)]
        if mine:
            k = min(mine, key=lambda k: (-growth(facts, k, aligned[k].known if k in aligned else None),
                                         aligned[k].cycle if k in aligned else -1, k))
            slots.add(k)
            track.pop(k, None)
            work.append(((SLOW_SCHEDULE, aligned[k].cycle if k in aligned else -1), k))
    work.sort(key=lambda t: (t[0], t[1]))
    out = Plan(track=track, due=set(due))
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


def facts_of(m: RobotMap, config: MergeConfig) -> MapFacts:
    """What the schedule needs of a map (:class:`MapFacts`), once per map version."""
    return m.memo('facts', lambda: _facts(m.grid, m.version, config))


def _facts(g: Grid, version: int, c: MergeConfig) -> MapFacts:
    """What the schedule needs of a grid of map ``version`` (:class:`schedule.MapFacts`)."""
    box = g.known_box(c.free_thresh, c.occupied_thresh)
    corners = None
    if box is not None:
        r0, r1, c0, c1 = box
        W = cell_to_metric(g.resolution, g.origin)
        cells = np.array([[c0, r0], [c1, r0], [c0, r1], [c1, r1]], np.float64)
        corners = cells @ W[:2, :2].T + W[:2, 2]
    known = int(np.count_nonzero(g.levels(c.free_thresh, c.occupied_thresh)))
    return MapFacts(version, known, corners)
