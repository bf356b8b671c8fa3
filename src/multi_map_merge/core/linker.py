"""Pairs to links: which pairs of maps a cycle works on, their alignment or tracking in the
worker pool, and each result kept as the pair's verified link or not (steps (1)-(4) of
:mod:`merger`'s flowchart, for the pairs).

- A cycle's plan (:func:`schedule.plan`): the pairs whose maps changed since they were last
  worked on, every pair of robots (a robot that misses the reference can chain through
  another); kept links are tracked on their new maps, the others aligned from features.
- :meth:`Linker.keep`: a verified result replaces the kept link by the paper's more-reliable
  rule, refined (:func:`links.replacement`).
- Links restored from a state file are verified on the grids before they are used; links of
  little evidence that corroborate each other are kept (:mod:`corroborate`); the spare time
  between cycles tracks again the links whose maps grew most (:meth:`Linker.refresh`).

Its records are the pair ledger's (:class:`ledger.PairLedger`), under the merger's lock.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from typing import Dict, FrozenSet, List, Optional, Tuple

import numpy as np

from ..runtime.pool import workers_count
from . import corroborate, links, schedule, verify
from .config import MergeConfig
from .cycle import Cycle
from .ledger import PairLedger
from .links import Link
from .pair import PairResult
from .placer import Placer
from .robot_map import RobotMap
from .transforms import image_to_pose, inverse, pose_to_image, se2
from .workers import PairWorkers

Pair = schedule.Pair

# refresh: a kept link is tracked again with its covariance once its maps' known cells (the
# product of the two) grew by this factor since the covariance was computed
REFRESH_GROWTH = 1.1
# refresh: links tracked at once, per worker
REFRESH_BATCH = 4
#: what a pair's result kept by Linker.keep comes of: a cycle's plan, the spare time's
#: refresh, or links of little evidence that corroborate each other
PLANNED, REFRESHED, CORROBORATED = 'planned', 'refreshed', 'corroborated'


class Linker:
    """The pairs' work and their kept links (see the module's docstring)."""

    def __init__(self, config: MergeConfig, lock: threading.Lock, workers: PairWorkers, placer: Placer,
                 ledger: PairLedger):
        self.config = config
        self._lock = lock              # the merger's
        self._workers = workers        # crops and features of the maps, the worker pool
        self._placer = placer          # the placements (read: what a pair is expected to overlap)
        self.ledger = ledger           # every per-pair record, the schedule's counters

    # ------------------------------------------------------------------ a cycle's pairs
    def verify_restored(self, cycle: Cycle) -> List[str]:
        """(0) Restored links whose two maps are here verified on the grids: kept or dropped,
        each once. Returns the events."""
        c = self.config
        events = []
        with self._lock:
            pending = self.ledger.restorable(set(cycle.maps))
        for key, e in pending:
            ag, ov = self._verified(cycle.maps[key[0]], cycle.maps[key[1]], e.T)
            ok = ov >= c.min_overlap_cells and ag >= c.min_agreement
            with self._lock:
                self.ledger.verified_restored(key, e, ok, ag)
            events.append('restored link %s -> %s %s (agreement %.3f, overlap %d cells)'
                          % (key[0], key[1], 'verified' if ok else 'REJECTED', ag, ov))
        return events

    def plan(self, cycle: Cycle) -> schedule.Plan:
        """The cycle's pair work (:func:`schedule.plan`)."""
        maps = cycle.maps
        facts = {n: schedule.facts_of(m, self.config) for n, m in maps.items()}
        with self._lock:
            placements = self._placer.placements
            placed = {n: p.T for n, p in placements.items() if n in maps}
            via = {n: p.via for n, p in placements.items()}
            return self.ledger.plan(facts, cycle.ref, _versions(maps), placed, via, maps[cycle.ref].grid.resolution)

    def align(self, cycle: Cycle, plan: schedule.Plan,
              defer_pins: FrozenSet[str] = frozenset()) -> List[Optional[PairResult]]:
        """(1) AKAZE features of the maps that changed, (2) match, (3) rigid RANSAC + inlier
        ratio, (4) verify on the grids and refine: the plan's pairs in the worker processes,
        within the cycle's budget (a pair not reached: None); a tracked link refined and
        verified on its new maps (with its covariance when it has none). ``defer_pins``: robots
        not placed yet, whose pairs with no kept link leave their covariance search for
        :meth:`complete_pins`."""
        with self._lock:
            uncertain = self.ledger.uncertain()
            defer = frozenset(k for k in plan.todo if k not in self.ledger.links
                              and (k[0] in defer_pins or k[1] in defer_pins))
        return self._workers.align_pairs(cycle.maps, plan.todo, _as_tracks(cycle.maps, plan.track, uncertain),
                                         self.config.estimation_budget, defer)

    def pins_pending(self) -> bool:
        """Whether a kept link waits for its covariance search (:meth:`complete_pins`)."""
        with self._lock:
            return bool(self.ledger.unpinned)

    def complete_pins(self, cycle: Cycle) -> bool:
        """The covariance searches the cycles left for later (:meth:`align` with
        ``defer_pins``), of the kept links whose maps are still the versions they were aligned
        on (a link whose map changed since is tracked, with its covariance, by the next cycle):
        each link takes its pinned result, as the cycle would have kept it. Whether a link
        changed."""
        maps = cycle.maps
        with self._lock:
            pending = dict(self.ledger.unpinned)
            for k, (_, _, versions) in pending.items():
                if k[0] not in maps or k[1] not in maps or versions != (maps[k[0]].version, maps[k[1]].version):
                    del self.ledger.unpinned[k]
            current = dict(self.ledger.unpinned)
        jobs = {k: r for k, (_, r, _) in current.items()}
        changed = False
        for (a, b), r in self._workers.pin_results(maps, jobs).items():
            pa, ch = maps[a], maps[b]
            T = image_to_pose(r.A, pa.grid.resolution, pa.grid.origin, ch.grid.resolution, ch.grid.origin)
            known = (schedule.facts_of(pa, self.config).known, schedule.facts_of(ch, self.config).known)
            with self._lock:
                if not cycle.stale(a, b):
                    changed |= self.ledger.pinned_later((a, b), pending[(a, b)][0], r, T, known)
        return changed

    def keep_planned(self, cycle: Cycle, plan: schedule.Plan, results: List[Optional[PairResult]]) -> None:
        """(4) Each pair's result kept as its link if verified and more reliable than the kept
        one (or tracked); the plan carried out: the maps it saw are the ones the next compares
        against, and the robots whose turn on the slow schedule it was start counting again."""
        done = dict(zip(plan.todo, results))
        for a, b in schedule.pairs_of(cycle.maps, cycle.ref):
            if done.get((a, b)) is not None:
                self.keep(cycle, a, b, done[(a, b)], PLANNED)
        with self._lock:
            self.ledger.planned(_versions(cycle.maps), plan.due)

    def keep(self, cycle: Cycle, a: str, b: str, r: PairResult, source: str) -> None:
        """(4) Keep the result ``r`` of pair (``a``, ``b``) if it is verified and replaces the
        kept link (:func:`links.replacement`); a tracked link (``r.tracked``) takes its refined
        pose, or is aligned from features next. ``source``: what the result comes of
        (:data:`PLANNED`, :data:`REFRESHED` or :data:`CORROBORATED`)."""
        pa, ch = cycle.maps[a], cycle.maps[b]
        key = (a, b)
        r.stamp = time.time()
        known = (schedule.facts_of(pa, self.config).known, schedule.facts_of(ch, self.config).known)
        with self._lock:
            if cycle.stale(a, b):
                return               # a map restarted (or robot removed, a prior changed) since
            old = self.ledger.worked(key, (pa.version, ch.version), known, source != CORROBORATED,
                                     source == REFRESHED)
            if r.tracked:
                T = image_to_pose(r.A, pa.grid.resolution, pa.grid.origin, ch.grid.resolution, ch.grid.origin)
                self.ledger.track(key, r, old, T)
                return
            self.ledger.attempted(key, r)
            placed = {n: p.T for n, p in self._placer.placements.items()}
        if source == PLANNED:
            facts = {n: schedule.facts_of(m, self.config) for n, m in ((a, pa), (b, ch))}
            expected = schedule.expected_overlap(facts, placed, key, pa.grid.resolution)
            with self._lock:
                self.ledger.aligned[key] = schedule.Aligned(self.ledger.cycle, expected, known)
        if not r.accepted:
            return
        T = image_to_pose(r.A, pa.grid.resolution, pa.grid.origin, ch.grid.resolution, ch.grid.origin)
        # (the kept link's score on the current grids is computed outside the lock: it warps a grid)
        kept = links.replacement(self.config, old, T, r, lambda: self._verified(pa, ch, old.T)[0])
        if kept is None:
            return
        inlier_ratio, inliers = kept
        link = Link(a, b, T, inlier_ratio, r.agreement, inliers, r.matches, time.time(), r.overlap,
                    r.cov, r.bend, r.centre, r.parent_turn, r.child_turn)
        with self._lock:
            # (not when forgotten meanwhile: a reset, a restart)
            self.ledger.keep(key, old, link, known, r, (pa.version, ch.version))

    def corroborate(self, cycle: Cycle) -> bool:
        """Keep the pair results refused only for too little evidence that corroborate each
        other (:mod:`corroborate`); whether any was kept."""
        maps = cycle.maps
        with self._lock:
            results = {k: r for k, r in self.ledger.results.items()
                       if k not in self.ledger.links and k[0] in maps and k[1] in maps}
            placed = {n: p.T for n, p in self._placer.placements.items()}
        poses = corroborate.poses_of(results, lambda k, r: image_to_pose(
            r.A, maps[k[0]].grid.resolution, maps[k[0]].grid.origin, maps[k[1]].grid.resolution,
            maps[k[1]].grid.origin))
        keys, _ = corroborate.corroborated(poses, placed, _prior_poses(self._workers.config.initial_poses, placed,
                                                                      cycle.ref))
        for a, b in sorted(keys):
            self.keep(cycle, a, b, dataclasses.replace(results[(a, b)], accepted=True, reason=''), CORROBORATED)
        return bool(keys)

    def refresh(self, cycle: Cycle, deadline: float) -> Tuple[bool, int]:
        """The spare time's links: the kept links whose maps grew by REFRESH_GROWTH or more since
        their covariance was computed, those grown most first, tracked again with their
        covariance (:func:`pair.track_pair` with ``pin``) until ``deadline`` (time.monotonic()).
        Returns (whether a prior changed meanwhile: nothing kept, the batch size)."""
        maps = cycle.maps
        facts = {n: schedule.facts_of(m, self.config) for n, m in maps.items()}
        with self._lock:
            kept = {k: e for k, e in self.ledger.links.items()
                    if k[0] in maps and k[1] in maps and k not in self.ledger.track_failed}
            pinned = dict(self.ledger.pinned)
        grown = sorted((-schedule.growth(facts, k, pinned.get(k)), k) for k in kept)
        stale = [k for g, k in grown if -g >= REFRESH_GROWTH]
        batch = REFRESH_BATCH * workers_count(self.config.workers)
        while stale and time.monotonic() < deadline:
            todo, stale = stale[:batch], stale[batch:]
            results = self._workers.align_pairs(maps, todo, _as_tracks(maps, {k: kept[k].T for k in todo}, set(todo)))
            with self._lock:
                if cycle.stale():
                    return True, batch    # a prior changed meanwhile: these were gated by the old one
            for (a, b), r in zip(todo, results):
                if r is not None:
                    self.keep(cycle, a, b, r, REFRESHED)
        return False, batch

    def _verified(self, pa: RobotMap, ch: RobotMap, T: np.ndarray) -> Tuple[float, int]:
        """(agreement, overlap) of a link ``T`` (metres of ``ch``'s frame -> ``pa``'s) on the
        pair's current grids."""
        return verify.pose_on_grids(self.config, pa.grid, ch.grid, T)


def _versions(maps: Dict[str, RobotMap]) -> Dict[str, int]:
    return {n: m.version for n, m in maps.items()}


def _as_tracks(maps: Dict[str, RobotMap], poses: Dict[Pair, np.ndarray],
               pin: set) -> Dict[Pair, Tuple[np.ndarray, bool]]:
    """Links to track (pair -> its pose, metres of the child's frame -> the parent's) as
    :meth:`PairWorkers.align_pairs` takes them: transforms between the pairs' current grids'
    cells, and whether to compute the covariance (the pairs of ``pin``)."""
    out = {}
    for (a, b), T in poses.items():
        pa, ch = maps[a].grid, maps[b].grid
        out[(a, b)] = (pose_to_image(T, pa.resolution, pa.origin, ch.resolution, ch.origin), (a, b) in pin)
    return out


def _prior_poses(priors: Optional[Dict[str, List[float]]], placed: Dict[str, np.ndarray],
                 ref: str) -> Dict[str, np.ndarray]:
    """Per robot with an initial pose that is not placed, its map frame in the merged frame by
    the initial poses (``priors``: robot -> [x, y, yaw] in one frame), relative to the placed
    robot with an initial pose the reference first, else the first by name; {} with none."""
    if not priors:
        return {}
    anchors = [n for n in [ref] + sorted(placed) if n in placed and n in priors]
    if not anchors:
        return {}
    z = anchors[0]
    to_merged = placed[z] @ inverse(se2(*priors[z]))
    return {n: to_merged @ se2(*p) for n, p in priors.items() if n not in placed}
