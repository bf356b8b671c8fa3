"""The merger: the paper's flowchart as one class (no ROS in here).

    maps --(1) image + AKAZE--> features --(2) match pairs--> matches --(3) rigid RANSAC-->
    transform + inlier ratio --(4) verify, keep the most reliable--> placements
    --(5) warp + composite--> merged grid, --(6) poses--> TF of every robot's map frame

Frames: the merged frame is the reference robot's map frame (the paper's Map 1; which robot
that is: :func:`team.decide_reference`). A robot's
*placement* is the pose ``T_merged_k`` of its map frame in the merged frame (metres, radians).
It is expressed between frames, not grids, so it stays valid while gmapping grows the grid.

Thread safety: ``update_map`` / ``remove_robot`` may be called from any thread while
``estimate`` runs in another and ``compose`` in a third; each takes a snapshot under a lock
and computes outside it.
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
from typing import Dict, List, Optional, Sequence, Set, Tuple

import numpy as np

from ..runtime.pool import workers_count
from . import corroborate, links, placement, schedule, spawn, verify
from .compositor import Compositor
from .config import MergeConfig
from .grid import DEFAULT_FREE_THRESH, DEFAULT_OCC_THRESH, Grid
from .ledger import PairLedger
from .links import Link
from .pair import PairResult, align_pair
from .placement import Placement
from .placer import Placer
from .priors import PriorRefused, in_priors_frame
from .robot_map import RobotMap
from .state import link_dict, link_from_dict, placement_dict
from .status import RobotStatus, robot_statuses
from .team import ReferenceChoice, Team
from .transforms import image_to_pose, pose_to_image
from .workers import PairWorkers

# refresh: a kept link is tracked again with its covariance once its maps' known cells (the
# product of the two) grew by this factor since the covariance was computed
REFRESH_GROWTH = 1.1
# refresh: links tracked at once, per worker
REFRESH_BATCH = 4
#: what a pair's result kept by MapMerger._keep comes of: a cycle's plan, the spare time's
#: refresh, or links of little evidence that corroborate each other
PLANNED, REFRESHED, CORROBORATED = 'planned', 'refreshed', 'corroborated'


class MapMerger:
    """Merges N robots' occupancy grids into one (see module docstring)."""

    def __init__(self, config: Optional[MergeConfig] = None):
        self.config = config or MergeConfig()
        c = self.config
        self._lock = threading.Lock()
        self._team = Team(c.reference_robot)   # the maps, their restarts, errors, the reference
        self._workers = PairWorkers(c)   # crops and features of the maps, the worker pool
        self._ledger = PairLedger()      # every per-pair record, the schedule's counters
        self._placements: Dict[str, Placement] = {}
        self._compositor = Compositor(c)   # the patch cache, the last merged grid
        # links to placements: the pose graph, the joint refinement, the bent maps' fields
        self._placer = Placer(c, self._workers, self._lock)
        self.state_version = 0    # bumped whenever links or placements change (for persistence)
        self._prior_epoch = 0     # bumped when a prior changes: a cycle begun before is discarded
        # the priors in use (:meth:`priors`): the configured ones until some are given while running
        self._priors: Dict[str, List[float]] = {n: list(p) for n, p in c.initial_poses.items()}
        # a prior's compound changes (read the priors, relate, set) one at a time; taken before _lock
        self._prior_lock = threading.RLock()
        self._implicit_ref_prior = ''   # the reference given [0, 0, 0] for priors in the merged frame
        # m-explore's init_pose_* as given (robot -> [x, y, yaw]) while they may still be spawn
        # poses in one frame the maps share (check_spawn_poses); once the grids say so, _spawn_shared
        self._spawn_poses: Dict[str, List[float]] = {}
        self._spawn_checked = None      # the grids the last check saw
        self._spawn_shared = False
        if c.robots:
            # the robots are listed: the first by name is the reference unless one is configured
            self.propose_reference(sorted(r.strip('/') for r in c.robots)[0])

    # ------------------------------------------------------------------ inputs
    @property
    def reference(self) -> str:
        """The reference robot: ``reference_robot``, or one proposed, or else the first robot
        by name among those with a map until another robot is merged with it
        (:func:`team.decide_reference`); '' before any map."""
        with self._lock:
            return self._team.reference

    def reference_choice(self) -> ReferenceChoice:
        with self._lock:
            return self._team.choice()

    def propose_reference(self, name: str) -> str:
        """Make ``name`` the reference for good unless one is fixed already (``reference_robot``,
        or a previous choice: the merged frame never changes once fixed). Returns the
        reference."""
        with self._lock:
            if self._team.propose():
                self._set_reference_locked(name)
            return self._team.reference

    def _set_reference_locked(self, name: str) -> None:
        if name == self._team.reference:
            return
        # Every placement is a pose in the former reference's frame: only the new reference is
        # placed (at identity) until the next cycle places the others under it (a cycle under
        # way with the former one is discarded, see _place)
        old, self._team.reference = self._team.reference, name
        self._placements.clear()
        self._compositor.forget()
        self._placer.forget_graph()
        if old and name in self._team.maps:
            self._placements[name] = Placement(np.eye(3), 1.0, 1.0, 0, '', (name,), time.time())

    def _settle_reference_locked(self) -> None:
        self._set_reference_locked(self._team.settle(list(self._placements)))

    def update_map(self, name: str, grid: Grid) -> Optional[str]:
        """Take a robot's new grid (already validated, see :func:`grid.make_grid`).

        Returns a message when the map restarted (gmapping reset: the grid shrank, or lost
        most of what it knew); the robot's links are then forgotten and re-estimated, and the
        merged map shows only the new map's cells.
        """
        with self._lock:
            if self._team.republished(name, grid):
                return None           # nothing to recompute
            new = name not in self._team.maps
            event = self._team.restart(name, grid)
            if event:
                self._forget_locked(name)
            self._team.take(name, grid)
            if new:
                self._settle_reference_locked()
        if self._default_thresholds():
            # Classify the map once, as it arrives, outside the lock (a big canvas takes a
            # while): estimation and compositing find its levels, known box and values ready.
            grid.known_values()
        return event

    def _forget_locked(self, name: str) -> None:
        # an estimation cycle under way still holds the maps of the robot's former life: what
        # it derives from them must not come back (see _from_former_life_locked)
        self._team.forget(name)
        had = self._ledger.forget(name) or name in self._placements
        if name == self._team.reference:
            # Every placement is a pose in the reference's frame, which just moved.
            self._placements.clear()
            self._compositor.forget()
        self._placements.pop(name, None)
        self._compositor.forget(name)
        if had:
            self.state_version += 1

    def report_error(self, name: str, reason: str) -> None:
        """Remember why a robot's last input was refused (shown in status)."""
        with self._lock:
            self._team.errors[name] = reason

    def remove_robot(self, name: str) -> None:
        """Forget a robot entirely: its map leaves the merge, its links are dropped."""
        with self._lock:
            self._team.maps.pop(name, None)
            self._forget_locked(name)
            self._settle_reference_locked()

    # ------------------------------------------------------------------ priors
    def priors(self) -> Dict[str, List[float]]:
        """The priors in use, robot -> ``[x, y, yaw]`` (metres, radians: its map frame in the
        priors' frame, :mod:`priors`): ``initial_poses`` as configured, with those given or
        cleared while running. The config itself is never changed."""
        with self._lock:
            return dict(self._priors)

    def set_prior(self, name: str, pose: Optional[Sequence[float]]) -> List[str]:
        """Set (``[x, y, yaw]`` in the priors' frame, the meaning of ``initial_poses``) or remove
        (None) one robot's prior while running. Its pairs are estimated again under the new prior
        (the gate of :func:`pair.contradicts_prior`), its kept links that contradict it are dropped
        now, and the placements made from priors (``trust_initial_poses``) are made again. An
        estimation cycle that began before the change is discarded. Returns what was dropped."""
        with self._lock:
            priors = dict(self._priors)
            if pose is None:
                priors.pop(name, None)
            else:
                priors[name] = [float(v) for v in pose]
            self._use_priors_locked(priors)
            self._prior_epoch += 1
            events = self._ledger.reprior(name, priors, self.config.initial_pose_tolerance)
            for n in [n for n, pl in self._placements.items() if pl.via == placement.PRIOR]:
                del self._placements[n]
            self.state_version += 1
        return events

    def _use_priors_locked(self, priors: Dict[str, List[float]]) -> None:
        # new objects, not updates: the estimation thread may be reading the old ones. The pairs'
        # alignment (in the worker processes) reads the priors as its config's initial_poses
        self._priors = priors
        self._workers.config = dataclasses.replace(self.config, initial_poses=priors)

    def set_prior_in_merged_frame(self, name: str, T: np.ndarray) -> List[str]:
        """Give ``name`` the prior ``T``: the 3x3 pose of its map frame in the merged frame (rviz's
        2D Pose Estimate), carried into the priors' frame (:func:`priors.in_priors_frame`; with no
        other prior given, the merged frame becomes the priors' frame and the reference's prior
        [0, 0, 0] until :meth:`clear_prior` leaves it alone). Returns what was dropped
        (:meth:`set_prior`); raises :class:`priors.PriorRefused` saying why it cannot be used."""
        with self._prior_lock:
            ref = self.reference
            pose, ref_too = in_priors_frame(name, T, ref, self.priors())
            if ref_too:
                self._implicit_ref_prior = ref
                self.set_prior(ref, [0.0, 0.0, 0.0])
            return self.set_prior(name, pose)

    def clear_prior(self, name: str) -> bool:
        """Remove ``name``'s prior (:meth:`set_prior` with None), and the reference's [0, 0, 0]
        given by :meth:`set_prior_in_merged_frame` once it is the only prior left. False when
        ``name`` had none."""
        with self._prior_lock:
            if name not in self.priors():
                return False
            self.set_prior(name, None)
            ref = self._implicit_ref_prior
            if ref and set(self.priors()) <= {ref}:
                self.set_prior(ref, None)
                self._implicit_ref_prior = ''
            return True

    def wants_init_pose(self, name: str) -> bool:
        """Whether m-explore's ``init_pose_*`` of ``name`` are to be read: ``known_init_poses``,
        and it has no prior yet."""
        return self.config.known_init_poses and name not in self.priors()

    def add_init_pose(self, name: str, pose: Sequence[float]) -> bool:
        """Take m-explore's ``init_pose_*`` of ``name`` (``[x, y, yaw]``, metres, radians: its map
        frame in a common frame) as its prior; or, once the grids said that these are spawn poses
        in one frame all maps share (:meth:`check_spawn_poses`), give it [0, 0, 0]. Returns True
        in the second case; raises :class:`priors.PriorRefused` when a number is not finite."""
        pose = [float(v) for v in pose]
        if not all(math.isfinite(v) for v in pose):
            raise PriorRefused('not finite %s' % pose)
        with self._prior_lock:
            self._spawn_poses[name] = pose
            if self._spawn_shared:
                self.set_prior(name, [0.0, 0.0, 0.0])
                return True
            with self._lock:
                # as if configured: read before the robot's maps are estimated, nothing to redo
                self._use_priors_locked(dict(self._priors, **{name: pose}))
        return False

    def check_spawn_poses(self) -> Optional[Tuple[List[str], spawn.SharedFrame, List[str]]]:
        """Until decided, whether the priors from :meth:`add_init_pose` are spawn poses of
        robots whose maps share one frame (ROBOTIS's Gazebo set-up, :mod:`spawn`), on the maps
        as they are; priors changed since (rviz) are left out. When the grids say so, every such
        robot's prior becomes [0, 0, 0] (its map frame is the shared frame) and this returns
        (those robots, the verdict, the links dropped); else None. The check runs again only
        when the maps changed."""
        with self._prior_lock:
            if self._spawn_shared or len(self._spawn_poses) < 2:
                return None
            given = self.priors()
            with self._lock:
                grids = {r: self._team.maps[r].raw for r, p in self._spawn_poses.items()
                         if given.get(r) == p and r in self._team.maps}
            priors = {r: self._spawn_poses[r] for r in grids}
            seen = tuple(sorted((r, id(g)) for r, g in grids.items()))
            if seen == self._spawn_checked:
                return None
            self._spawn_checked = seen
        verdict = spawn.spawn_poses_in_one_frame(self.config, grids, priors)
        if verdict is None:
            return None
        events = []
        with self._prior_lock:
            self._spawn_shared = True
            # (robots whose maps have not come yet too: the set-up is one)
            given = self.priors()
            changed = [r for r in sorted(self._spawn_poses) if given.get(r) == self._spawn_poses[r]]
            for r in changed:
                events += self.set_prior(r, [0.0, 0.0, 0.0])
        return changed, verdict, events

    def reset(self) -> None:
        """Forget every transform (maps are kept)."""
        with self._lock:
            self._ledger.reset()
            self._placements.clear()
            self._compositor.forget()
            self._placer.forget_fields()

    def _snapshot(self) -> Tuple[str, Dict[str, RobotMap]]:
        """(reference, maps at the reference's resolution); maps empty before the reference
        has a map (nothing can be placed without it)."""
        with self._lock:
            ref = self._team.reference
            maps = dict(self._team.maps)
        if ref not in maps:
            return ref, {}
        res = maps[ref].raw.resolution
        return ref, {n: m.set_working_resolution(res) for n, m in maps.items()}

    # ------------------------------------------------------------------ the algorithm
    def estimate(self) -> List[str]:
        """One estimation cycle; returns human-readable events (merges, improvements)."""
        ref, maps = self._snapshot()
        if not maps:
            return []
        epoch = self._prior_epoch
        # (0) links saved by an earlier run are used only once the grids confirm them
        events = self._verify_restored(maps)
        # the pairs whose maps changed: kept links tracked, the others aligned by priority
        plan = self._plan(maps, ref)
        # (1) AKAZE features of the maps that changed, (2) match, (3) rigid RANSAC + inlier
        # ratio, (4) verify on the grids and refine: the pairs in the worker processes, within
        # the cycle's budget; a tracked link is refined and verified on its new maps
        results = self._workers.align_pairs(maps, plan.todo, self._tracks(maps, plan), self.config.estimation_budget)
        if epoch != self._prior_epoch:
            return events     # a prior changed meanwhile: these were gated by the old one
        # (4) keep each pair's link if verified and more reliable than the kept one (or tracked)
        done = dict(zip(plan.todo, results))
        for key in schedule.pairs_of(maps, ref):
            if done.get(key) is not None:
                self._keep(maps[key[0]], maps[key[1]], done[key], PLANNED)
        self._planned(maps, plan)
        # (4) place every robot through its most reliable links; (6) that is its TF
        events += self._place(maps, ref)
        # links of little evidence that corroborate each other (a cycle closes): kept, placed again
        if self._corroborate(maps):
            events += self._place(maps, ref)
        # (5) past rigid: every placed map bent onto the walls of the others, for the merged map
        self._placer.bend(maps, ref, self.placements())
        return events

    def refresh(self, budget: float) -> List[str]:
        """Spare time between cycles spent on the kept links whose maps grew most since their
        covariance was computed: each tracked again on the maps as they are now, with its
        covariance (:func:`pair.track_pair` with ``pin``), until ``budget`` seconds have passed;
        then every robot placed again if a link changed, or if time is left and a robot's map
        changed too little since its last joint refinement for a cycle to refine it again
        (REFINE_GROWTH: the spare time does). A cycle tracks a robot's few links only when its
        map changes, so the others stand as they were found on smaller maps; the pose graph
        weighs them by what their overlap was then. Returns the events (none when nothing
        needed it: the maps grew by less than REFRESH_GROWTH since, no refinement pending)."""
        ref, maps = self._snapshot()
        if not maps or budget <= 0 or not self.config.refresh_links:
            return []
        epoch = self._prior_epoch
        deadline = time.monotonic() + budget
        facts = {n: self._map_facts(m) for n, m in maps.items()}
        with self._lock:
            kept = {k: e for k, e in self._ledger.links.items()
                    if k[0] in maps and k[1] in maps and k not in self._ledger.track_failed}
            pinned = dict(self._ledger.pinned)
            version = self.state_version
        grown = sorted((-schedule.growth(facts, k, pinned.get(k)), k) for k in kept)
        stale = [k for g, k in grown if -g >= REFRESH_GROWTH]
        batch = REFRESH_BATCH * workers_count(self.config.workers)
        while stale and time.monotonic() < deadline:
            todo, stale = stale[:batch], stale[batch:]
            results = self._workers.align_pairs(maps, todo, _as_tracks(maps, {k: kept[k].T for k in todo}, set(todo)))
            if epoch != self._prior_epoch:
                return []     # a prior changed meanwhile: these were gated by the old one
            for (a, b), r in zip(todo, results):
                if r is not None:
                    self._keep(maps[a], maps[b], r, REFRESHED)
        with self._lock:
            moved = self.state_version != version
        # robots whose map changed too little for a cycle to refine them (REFINE_GROWTH), a
        # batch of them
        with self._lock:
            placed = set(self._placements)
        pending = self._placer.refinement_pending(maps, ref, placed)[:batch] if time.monotonic() < deadline else []
        if not moved and not pending:
            return []
        events = self._place(maps, ref, also=set(pending))
        self._placer.bend(maps, ref, self.placements())
        return events

    def _corroborate(self, maps: Dict[str, RobotMap]) -> List[str]:
        """Keep the pair results refused only for too little evidence that corroborate each
        other (:mod:`corroborate`); returns their events (none: nothing changed)."""
        with self._lock:
            results = {k: r for k, r in self._ledger.results.items()
                       if k not in self._ledger.links and k[0] in maps and k[1] in maps}
            placed = {n: p.T for n, p in self._placements.items()}
        poses = corroborate.poses_of(results, lambda k, r: image_to_pose(
            r.A, maps[k[0]].grid.resolution, maps[k[0]].grid.origin, maps[k[1]].grid.resolution,
            maps[k[1]].grid.origin))
        keys, events = corroborate.corroborated(poses, placed)
        for a, b in sorted(keys):
            r = dataclasses.replace(results[(a, b)], accepted=True, reason='')
            self._keep(maps[a], maps[b], r, CORROBORATED)
        return events if keys else []

    def compose(self) -> Optional[Grid]:
        """(5) Warp every placed map into the merged frame and composite; None before any map
        of the reference arrived."""
        ref, maps = self._snapshot()
        with self._lock:
            placements = dict(self._placements)
            fields = dict(self._placer.fields)
        if not maps:
            return None
        return self._compositor.compose(maps, placements, fields, ref)

    def placements(self) -> Dict[str, Placement]:
        """Placement of every merged robot (the reference included, at identity)."""
        with self._lock:
            return dict(self._placements)

    def links(self) -> Dict[Tuple[str, str], Link]:
        """The verified links kept, per pair (parent, child): what the placements are made of
        (a :class:`Link` maps metres of the child's frame to the parent's)."""
        with self._lock:
            return dict(self._ledger.links)

    def pair_results(self) -> Dict[Tuple[str, str], PairResult]:
        """The last result of every pair aligned, per pair (parent, child): accepted or not,
        with its scores and the reason it was refused (what the status shows per robot)."""
        with self._lock:
            return dict(self._ledger.results)

    def frames(self) -> Dict[str, str]:
        """Map frame id of every robot (from its grid's header)."""
        with self._lock:
            return self._team.frames()

    def status(self) -> Dict[str, RobotStatus]:
        """Per robot: merged or not, placement, last pair attempt, last input error."""
        with self._lock:
            return robot_statuses(self._team.maps, self._team.errors, self._ledger.results, self._ledger.links,
                                  self._placements, self._placer.fields, self._team.reference)

    def export_state(self) -> Dict:
        """Verified links and placements as plain data: what the state file holds
        (:mod:`state`)."""
        with self._lock:
            edges = [link_dict(e) for e in self._ledger.links.values()]
            placements = {n: placement_dict(p) for n, p in self._placements.items()}
            return {'reference': self._team.reference, 'edges': edges, 'placements': placements}

    def restore_state(self, state: Dict) -> int:
        """Take links saved by :meth:`export_state`; each is verified again on the grids before
        it is used. Returns how many were taken. Links saved under another reference robot
        are still valid (they are pairwise); a link that is not one (:func:`state.link_from_dict`)
        is skipped."""
        n = 0
        with self._lock:
            for d in state.get('edges', []) or []:
                try:
                    e = link_from_dict(d, time.time())
                except (KeyError, TypeError, ValueError):
                    continue
                if all(math.isfinite(v) for v in e.T.ravel()):
                    self._ledger.restored[(e.parent, e.child)] = e
                    n += 1
        return n

    # ------------------------------------------------------------------ steps
    def _verify_restored(self, maps: Dict[str, RobotMap]) -> List[str]:
        """Re-verify restored links whose two maps are here; keep or drop each, once."""
        c = self.config
        events = []
        with self._lock:
            pending = self._ledger.restorable(set(maps))
        for key, e in pending:
            ag, ov = self._verified(maps[key[0]], maps[key[1]], e.T)
            ok = ov >= c.min_overlap_cells and ag >= c.min_agreement
            with self._lock:
                if self._ledger.verified_restored(key, e, ok, ag):
                    self.state_version += 1
            events.append('restored link %s -> %s %s (agreement %.3f, overlap %d cells)'
                          % (key[0], key[1], 'verified' if ok else 'REJECTED', ag, ov))
        return events

    def _from_former_life_locked(self, m: RobotMap) -> bool:
        return self._team.from_former_life(m)

    def _default_thresholds(self) -> bool:
        c = self.config
        return c.free_thresh == DEFAULT_FREE_THRESH and c.occupied_thresh == DEFAULT_OCC_THRESH

    def _verified(self, pa: RobotMap, ch: RobotMap, T: np.ndarray) -> Tuple[float, int]:
        """(agreement, overlap) of a link ``T`` (metres of ``ch``'s frame -> ``pa``'s) on the
        pair's current grids."""
        return verify.pose_on_grids(self.config, pa.grid, ch.grid, T)

    def _map_facts(self, m: RobotMap) -> schedule.MapFacts:
        """What the schedule needs of a map (:class:`schedule.MapFacts`), once per version."""
        return schedule.facts_of(m, self.config)

    def _plan(self, maps: Dict[str, RobotMap], ref: str) -> schedule.Plan:
        """The cycle's pair work (:func:`schedule.plan`): pairs (parent, child) whose maps changed
        since they were last worked on, every pair of robots (so a robot that misses the
        reference can chain through another)."""
        facts = {n: self._map_facts(m) for n, m in maps.items()}
        with self._lock:
            placed = {n: p.T for n, p in self._placements.items() if n in maps}
            via = {n: p.via for n, p in self._placements.items()}
            return self._ledger.plan(facts, ref, _versions(maps), placed, via, maps[ref].grid.resolution)

    def _planned(self, maps: Dict[str, RobotMap], plan: schedule.Plan) -> None:
        """A cycle's plan carried out: the maps it saw are the ones the next compares against,
        and the robots whose turn on the slow schedule it was start counting again."""
        with self._lock:
            self._ledger.planned(_versions(maps), plan.due)

    def _tracks(self, maps: Dict[str, RobotMap], plan: schedule.Plan) -> Dict[Tuple[str, str], Tuple[np.ndarray, bool]]:
        """The kept links to track, as transforms between the pairs' current grids' cells, and
        whether to compute their covariance (a link without one: its walls said too little)."""
        with self._lock:
            uncertain = self._ledger.uncertain()
        return _as_tracks(maps, plan.track, uncertain)

    def _keep(self, pa: RobotMap, ch: RobotMap, r: PairResult, source: str) -> None:
        """(4) keep the pair's result if it is verified and replaces the kept link
        (:func:`links.replacement`: the paper's more-reliable rule, refined); a tracked link
        (``r.tracked``) takes its refined pose, or is aligned from features next. ``source``:
        what the result comes of (:data:`PLANNED`, :data:`REFRESHED` or :data:`CORROBORATED`)."""
        key = (pa.name, ch.name)
        r.stamp = time.time()
        with self._lock:
            if self._from_former_life_locked(pa) or self._from_former_life_locked(ch):
                return               # a map restarted (or robot removed) since the cycle began
            known = (self._map_facts(pa).known, self._map_facts(ch).known)
            old = self._ledger.worked(key, (pa.version, ch.version), known, source != CORROBORATED,
                                      source == REFRESHED)
            if r.tracked:
                T = image_to_pose(r.A, pa.grid.resolution, pa.grid.origin, ch.grid.resolution, ch.grid.origin)
                if self._ledger.track(key, r, old, T):
                    self.state_version += 1
                return
            self._ledger.attempted(key, r)
            placed = {n: p.T for n, p in self._placements.items()}
        if source == PLANNED:
            facts = {n: self._map_facts(m) for n, m in ((pa.name, pa), (ch.name, ch))}
            expected = schedule.expected_overlap(facts, placed, key, pa.grid.resolution)
            with self._lock:
                self._ledger.aligned[key] = schedule.Aligned(self._ledger.cycle, expected,
                                                             (facts[pa.name].known, facts[ch.name].known))
        if not r.accepted:
            return
        T = image_to_pose(r.A, pa.grid.resolution, pa.grid.origin, ch.grid.resolution, ch.grid.origin)
        # (the kept link's score on the current grids is computed outside the lock: it warps a grid)
        kept = links.replacement(self.config, old, T, r, lambda: self._verified(pa, ch, old.T)[0])
        if kept is None:
            return
        inlier_ratio, inliers = kept
        link = Link(pa.name, ch.name, T, inlier_ratio, r.agreement, inliers, r.matches, time.time(), r.overlap,
                    r.cov, r.bend, r.centre, r.parent_turn, r.child_turn)
        with self._lock:
            if self._ledger.keep(key, old, link, known):   # (not when forgotten meanwhile: a reset, a restart)
                self.state_version += 1

    def align_robots(self, pa: RobotMap, ch: RobotMap, seed: int = 0) -> PairResult:
        """Steps (2)-(4) for two robots' maps, here in this process (:func:`pair.align_pair` of
        their crops and features): cells of ``ch`` -> cells of ``pa``."""
        return align_pair(self.config, self._workers.input(pa), self._workers.input(ch), seed)

    def _place(self, maps: Dict[str, RobotMap], ref: str, also: Optional[Set[str]] = None) -> List[str]:
        """Place every robot from the verified links (see :mod:`placement`) and keep, per
        robot, the best placement seen; returns the events (merged, improved). ``also``:
        robots the joint refinement takes if their map changed at all (:meth:`_joint`)."""
        with self._lock:
            edges = dict(self._ledger.links)
            old = dict(self._placements)
        new, events = self._placer.place(maps, ref, edges, old, self.priors, self._ledger.drift_covs, also or set())
        with self._lock:
            if ref in maps and self._from_former_life_locked(maps[ref]):
                return []            # the reference restarted meanwhile: every placement is void
            if ref != self._team.reference:
                return []            # another robot became the reference meanwhile: as void
            # robots forgotten since the cycle began stay unplaced until estimated again
            gone = {n for n in new if n in maps and self._from_former_life_locked(maps[n])}
            new = {n: p for n, p in new.items() if n not in gone}
            events = [e for e in events if e.split(' ', 1)[0] not in gone]
            if set(new) != set(self._placements) or any(new[n] is not self._placements.get(n) for n in new):
                self.state_version += 1
            self._placements = new
            self._settle_reference_locked()   # fixed once another robot is merged with it
        return events



def _versions(maps: Dict[str, RobotMap]) -> Dict[str, int]:
    return {n: m.version for n, m in maps.items()}


def _as_tracks(maps: Dict[str, RobotMap], poses: Dict[Tuple[str, str], np.ndarray],
               pin: set) -> Dict[Tuple[str, str], Tuple[np.ndarray, bool]]:
    """Links to track (pair -> its pose, metres of the child's frame -> the parent's) as
    :meth:`PairWorkers.align_pairs` takes them: transforms between the pairs' current grids'
    cells, and whether to compute the covariance (the pairs of ``pin``)."""
    out = {}
    for (a, b), T in poses.items():
        pa, ch = maps[a].grid, maps[b].grid
        out[(a, b)] = (pose_to_image(T, pa.resolution, pa.origin, ch.resolution, ch.origin), (a, b) in pin)
    return out
