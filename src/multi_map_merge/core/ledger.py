"""The pair ledger: every record the merger keeps per pair of robots, and the schedule's counters.

A pair is ``(parent, child)``, robot names. Its records: the verified link kept (what the
placements are made of), the last result of its alignment or tracking, a link restored from a
state file and not yet verified, the map versions it was last worked on, its last alignment
from features, the known cells of its maps at its last track or alignment and when its
covariance was computed, whether its tracking failed, and its drift's covariance (written by
:func:`placement.pin`). The counters: the estimation cycles planned, and per robot the map
version the last cycle saw and its new versions since its last turn on the slow schedule.

What a change of the team clears is said once, here: :meth:`forget` (a robot's map restarted,
or it left), :meth:`reprior` (its prior changed), :meth:`reset` (every transform forgotten).

Not thread-safe: its owner (:class:`merger.MapMerger`) calls it under its one lock.
"""
from __future__ import annotations

import dataclasses
import math
import time
from typing import Dict, List, Mapping, Optional, Set, Tuple

import numpy as np

from . import schedule
from .links import Link
from .pair import PairResult
from .priors import relative_pose
from .team import TeamListener
from .transforms import pose_distance, within

Pair = schedule.Pair

# a tracked link whose refined pose moved less than this (metres, radians) stays as it is: a
# changed link places the team again (the pose graph, the joint refinement of its two robots)
TRACK_MOVE = (0.01, math.radians(0.1))


class PairLedger(TeamListener):
    """Every per-pair record and the schedule's counters (see the module's docstring)."""

    def __init__(self):
        self.version = 0   # bumped whenever the kept links change (the merger's state_version)
        self.links: Dict[Pair, Link] = {}
        self.results: Dict[Pair, PairResult] = {}
        self.restored: Dict[Pair, Link] = {}
        self.tried: Dict[Pair, Tuple[int, int]] = {}       # map versions it was last worked on
        self.aligned: Dict[Pair, schedule.Aligned] = {}    # its last alignment from features
        self.refreshed: Dict[Pair, Tuple[int, int]] = {}   # known cells at its last track or alignment
        self.pinned: Dict[Pair, Tuple[int, int]] = {}      # known cells when its covariance was computed
        self.track_failed: Set[Pair] = set()               # aligned again from features, not tracked
        self.drift_covs: Dict[Pair, tuple] = {}            # its drift's covariance (placement.pin)
        # a kept link whose covariance search was left for later (pair.pin_later): the link, the
        # result it was made of, the pair's map versions then
        self.unpinned: Dict[Pair, Tuple[Link, PairResult, Tuple[int, int]]] = {}
        self.cycle = 0
        self.seen_versions: Dict[str, int] = {}   # per robot: its map's version the last cycle saw
        self.since_slow: Dict[str, int] = {}      # per robot: new versions since its last slow-schedule turn

    # ------------------------------------------------------------------ what a change clears
    def forget(self, robot: str) -> bool:
        """A robot forgotten (its map restarted, or it left): its links, their drift covariances
        and its restored links go. Its results stay for the status, and its pairs' schedule
        records name map versions that never come again (a new map is a new version), so the
        schedule takes its pairs up anew. Returns whether it had a link."""
        had = any(robot in k for k in self.links)
        for records in (self.links, self.drift_covs, self.restored, self.unpinned):
            for k in [k for k in records if robot in k]:
                del records[k]
        self.version += had
        return had

    def robot_forgotten(self, name: str, reference: bool) -> None:
        self.forget(name)

    def reprior(self, robot: str, priors: Mapping[str, List[float]], tolerance: Tuple[float, float]) -> List[str]:
        """A robot's prior changed (``priors``: all of them now): its pairs are aligned again
        from features, its kept links too (under the new prior another solution may be the right
        one), and those of its kept links that contradict the priors by more than ``tolerance``
        (metres, radians) go. Returns what was dropped."""
        self.version += 1
        for records in (self.tried, self.aligned, self.refreshed):
            for k in [k for k in records if robot in k]:
                del records[k]
        self.track_failed.update(k for k in self.links if robot in k)
        events = []
        for k, e in list(self.links.items()):
            P = relative_pose(priors, e.parent, e.child)
            if robot not in k or P is None:
                continue
            if not within(e.T, P, tolerance):
                d, a = pose_distance(e.T, P)
                del self.links[k]
                events.append('link %s -> %s dropped: it contradicts the new prior of %s by %.2f m, '
                              '%.1f deg' % (e.parent, e.child, robot, d, math.degrees(a)))
        return events

    def reset(self) -> None:
        """Every transform forgotten: links, results and the schedule's records of every pair.
        The restored links stay (each is verified on the grids before it is used), and so do the
        counters (they count the maps, which are kept)."""
        for records in (self.links, self.tried, self.aligned, self.refreshed, self.pinned, self.results, self.unpinned,
                        self.drift_covs):
            records.clear()
        self.track_failed.clear()

    # ------------------------------------------------------------------ the schedule
    def plan(self, facts: Dict[str, schedule.MapFacts], ref: str, versions: Mapping[str, int],
             placed: Dict[str, np.ndarray], via: Dict[str, str], resolution: float) -> schedule.Plan:
        """A new cycle's pair work (:func:`schedule.plan`) on maps of ``versions`` (per robot)."""
        self.cycle += 1
        # (against the last cycle that completed: a cycle that failed leaves its work to the next)
        changed = {n for n, v in versions.items() if self.seen_versions.get(n) != v}
        due = {n for n in versions if self.since_slow.get(n, 0) + (n in changed) >= schedule.SLOW_EVERY}
        return schedule.plan(facts, ref, dict(self.links), dict(self.tried), dict(self.aligned),
                             set(self.track_failed), placed, via, due, resolution, dict(self.refreshed), changed)

    def planned(self, versions: Mapping[str, int], due: Set[str]) -> None:
        """A cycle's plan carried out on maps of ``versions``: they are what the next compares
        against, and the robots whose turn on the slow schedule it was (``due``) count again."""
        for n, v in versions.items():
            if self.seen_versions.get(n) != v:
                self.since_slow[n] = 0 if n in due else self.since_slow.get(n, 0) + 1
            elif n in due:
                self.since_slow[n] = 0
        self.seen_versions.update(versions)

    def uncertain(self) -> Set[Pair]:
        """The kept links without a covariance (their walls said too little when aligned)."""
        return {k for k, e in self.links.items() if e.cov is None}

    # ------------------------------------------------------------------ a pair's result
    def worked(self, key: Pair, versions: Tuple[int, int], known: Tuple[int, int], counted: bool,
               pinned: bool) -> Optional[Link]:
        """A pair worked on, on maps of ``versions`` with ``known`` cells: its growth counts
        from now when ``counted`` (a cycle's or the spare time's work), its covariance too when
        ``pinned`` (the spare time's). Returns its kept link."""
        self.tried[key] = versions
        if counted:
            self.refreshed[key] = known
        if pinned:
            self.pinned[key] = known
        return self.links.get(key)

    def attempted(self, key: Pair, r: PairResult) -> None:
        """A pair aligned from features: its result is the last."""
        self.results[key] = r
        self.track_failed.discard(key)

    def keep(self, key: Pair, old: Optional[Link], link: Link, known: Tuple[int, int],
             r: PairResult, versions: Tuple[int, int]) -> bool:
        """``link`` (made of the result ``r`` on maps of ``versions``) replaces ``old`` as the
        pair's kept link, pinned on maps of ``known`` cells (or waiting for its covariance search:
        ``r.pin_deferred``), unless ``old`` was forgotten meanwhile (a reset, a map restart).
        Returns whether it did."""
        if self.links.get(key) is not old:
            return False
        self.links[key] = link
        self.unpinned.pop(key, None)
        if r.pin_deferred:
            self.unpinned[key] = (link, r, versions)
        else:
            self.pinned[key] = known
        self.version += 1
        return True

    def pinned_later(self, key: Pair, link: Link, r: PairResult, T: np.ndarray, known: Tuple[int, int]) -> bool:
        """The covariance search of ``link`` (:attr:`unpinned`) done: ``r`` is its result pinned
        (:func:`pair.pin_later`; its pose ``T``, metres of the child's frame -> the parent's),
        on maps of ``known`` cells. The link takes it (as a new object, with a new stamp: it
        places the team again) unless it was replaced or forgotten meanwhile. Returns whether it
        did."""
        entry = self.unpinned.pop(key, None)
        if entry is None or entry[0] is not link or self.links.get(key) is not link:
            return False
        self.links[key] = dataclasses.replace(link, T=T, agreement=r.agreement, overlap=r.overlap,
                                              stamp=time.time(), cov=r.cov, bend=r.bend, centre=r.centre,
                                              parent_turn=r.parent_turn, child_turn=r.child_turn)
        if self.results.get(key) is entry[1]:
            self.results[key] = r
        self.pinned[key] = known
        self.version += 1
        return True

    def track(self, key: Pair, r: PairResult, old: Optional[Link], T: np.ndarray) -> bool:
        """A tracked link's result: the link refined on its new maps (its pose ``T``, metres of
        the child's frame -> the parent's, agreement and overlap; its inliers, covariance and
        where it was fitted stay those of its alignment from features), or, when it failed,
        aligned from features next cycle. Returns whether the kept link changed."""
        if old is None:
            return False             # forgotten meanwhile
        if not r.accepted:
            self.track_failed.add(key)
            self.results[key] = dataclasses.replace(
                r, matches=old.matches, inliers=old.inliers, inlier_ratio=old.inlier_ratio,
                reason='tracking the kept link failed (%s): aligned again from features' % r.reason)
            return False
        self.track_failed.discard(key)
        self.results[key] = dataclasses.replace(r, matches=old.matches, inliers=old.inliers,
                                                inlier_ratio=old.inlier_ratio)
        # pinned on its maps now: a link whose walls said too little when aligned, or one refreshed
        # on more overlap (MapMerger.refresh): the pose and its covariance, on the maps as they are
        if r.cov is not None and (old.cov is None or r.overlap > old.overlap):
            self.links[key] = dataclasses.replace(old, T=T, agreement=r.agreement, overlap=r.overlap,
                                                  stamp=time.time(), cov=r.cov, bend=r.bend, centre=r.centre,
                                                  parent_turn=r.parent_turn, child_turn=r.child_turn)
            self.version += 1
            return True
        if r.overlap <= old.overlap:
            return False             # as links.replacement: the pose refined on more overlap only
        if within(T, old.T, TRACK_MOVE):
            return False             # the link stands: placing the team again would move nothing
        self.links[key] = dataclasses.replace(old, T=T, agreement=r.agreement, overlap=r.overlap,
                                              stamp=time.time())
        self.version += 1
        return True

    # ------------------------------------------------------------------ restored links
    def restorable(self, names: Set[str]) -> List[Tuple[Pair, Link]]:
        """The restored links whose two robots are among ``names``."""
        return [(k, e) for k, e in self.restored.items() if k[0] in names and k[1] in names]

    def verified_restored(self, key: Pair, e: Link, ok: bool, agreement: float) -> bool:
        """A restored link verified on the grids (once): kept, with its ``agreement`` now, when
        ``ok`` and the pair has no link yet. Returns whether it was kept."""
        self.restored.pop(key, None)
        if not ok or key in self.links:
            return False
        e.agreement = agreement
        self.links[key] = e
        self.version += 1
        return True
