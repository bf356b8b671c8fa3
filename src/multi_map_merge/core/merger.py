"""The merger: the paper's flowchart as one class (no ROS in here).

    maps --(1) image + AKAZE--> features --(2) match pairs--> matches --(3) rigid RANSAC-->
    transform + inlier ratio --(4) verify, keep the most reliable--> placements
    --(5) warp + composite--> merged grid, --(6) poses--> TF of every robot's map frame

Frames: the merged frame is the reference robot's map frame (the paper's Map 1; which robot
that is: :func:`team.decide_reference`). A robot's
*placement* is the pose ``T_merged_k`` of its map frame in the merged frame (metres, radians).
It is expressed between frames, not grids, so it stays valid while gmapping grows the grid.

Each step is one call to the part that owns it: the team (:mod:`team`: the maps, their
restarts, the reference), the pairs' links (:mod:`linker`, over the pair ledger), the placer
(:mod:`placer`: links to placements), the compositor (:mod:`compositor`), the priors
(:mod:`prior_book`) and the status (:mod:`status`).

Thread safety: ``update_map`` / ``remove_robot`` may be called from any thread while
``estimate`` runs in another and ``compose`` in a third. One lock guards every part's state; a
cycle takes one snapshot under it (:class:`cycle.Cycle`), computes outside it, and keeps what it
derived only while the snapshot is not stale.
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from . import placement, spawn
from .compositor import Compositor
from .config import MergeConfig
from .cycle import Cycle
from .grid import DEFAULT_FREE_THRESH, DEFAULT_OCC_THRESH, Grid
from .ledger import PairLedger
from .linker import Linker
from .links import Link
from .pair import PairResult, align_pair
from .placement import Placement
from .placer import Placer
from .prior_book import PriorBook
from .priors import Priors
from .robot_map import RobotMap
from .state import link_dict, link_from_dict, placement_dict
from .status import RobotStatus, robot_statuses
from .team import ReferenceChoice, Team
from .workers import PairWorkers


class MapMerger:
    """Merges N robots' occupancy grids into one (see module docstring)."""

    def __init__(self, config: Optional[MergeConfig] = None):
        self.config = config or MergeConfig()
        c = self.config
        self._lock = threading.Lock()
        # the maps, their restarts, errors, the reference (the first listed robot by name unless configured)
        self._team = Team(c.reference_robot, c.robots)
        self._workers = PairWorkers(c)   # crops and features of the maps, the worker pool
        ledger = PairLedger()            # every per-pair record, the schedule's counters
        self._placer = Placer(c, self._workers, self._lock, self._team, ledger)   # links to placements
        self._linker = Linker(c, self._lock, self._workers, self._placer, ledger)   # pairs to links
        self._compositor = Compositor(c)   # the patch cache, the last merged grid
        self._priors = PriorBook(c, self._lock, self._apply_priors)   # priors, spawn poses, their epoch
        # what a robot forgotten or a new reference clears, each part clears itself
        self._team.listeners += [ledger, self._placer, self._compositor]

    # ------------------------------------------------------------------ the algorithm
    def estimate(self, defer_refinement: bool = False) -> List[str]:
        """One estimation cycle; returns human-readable events (merges, improvements).

        ``defer_refinement`` (what the nodes do, which have spare time between cycles): a cycle
        that aligned from features a pair of a robot not placed yet (a first placement: a team's
        first cycle, a robot joining) leaves that pair's covariance search, the joint refinement
        and the links corroborated after it for :meth:`refresh` (or the next cycle that has
        nothing new to align): it places the robots from their verified links alone,
        :attr:`Placement.provisional`, sooner. The placements after that are the ones the cycle
        gives without it. Other cycles are the same with or without it."""
        cycle = self._cycle()
        if not cycle.maps:
            return []
        # (0) links saved by an earlier run are used only once the grids confirm them
        events = self._linker.verify_restored(cycle)
        # the pairs whose maps changed: kept links tracked, the others aligned by priority
        plan = self._linker.plan(cycle)
        # robots not placed yet: what a first placement waits for is theirs
        with self._lock:
            first = frozenset(n for n in cycle.maps if n not in self._placer.placements) if defer_refinement \
                else frozenset()
        # (1)-(4) features, matches, rigid RANSAC, verification: in the worker processes
        results = self._linker.align(cycle, plan, first)
        with self._lock:
            if cycle.stale():
                return events     # a prior changed meanwhile: these were gated by the old one
        # (4) keep each pair's link if verified and more reliable than the kept one (or tracked)
        self._linker.keep_planned(cycle, plan, results)
        # a cycle that may place a robot for the first time places it first, refines it later
        provisional = any(r is not None and not r.tracked and (a in first or b in first)
                          for (a, b), r in zip(plan.todo, results))
        if not provisional and (self._linker.pins_pending() or self._placer.provisional()):
            return events + self._complete(cycle)    # nothing new aligned: the work left for later, now
        # (4) place every robot through its most reliable links; (6) that is its TF
        events += self._placer.place(cycle, self._priors.current, provisional=provisional)
        # links of little evidence that corroborate each other (a cycle closes): kept, placed again
        # (after the joint refinement: a provisional cycle leaves them for later too)
        if not provisional and self._linker.corroborate(cycle):
            events += self._placer.place(cycle, self._priors.current)
        # (5) past rigid: every placed map bent onto the walls of the others, for the merged map
        self._placer.bend(cycle)
        return events

    def _complete(self, cycle: Cycle) -> List[str]:
        """What a cycle with ``defer_refinement`` left for later: its new links' covariance
        searches, then every robot placed again (the joint refinement of those placed anew), as
        that cycle would have placed them. The events."""
        self._linker.complete_pins(cycle)
        events = self._placer.place(cycle, self._priors.current)
        if self._linker.corroborate(cycle):
            events += self._placer.place(cycle, self._priors.current)
        self._placer.bend(cycle)
        return events

    def refresh(self, budget: float) -> List[str]:
        """Spare time between cycles, ``budget`` seconds: first what the last cycle left for
        later (``estimate(defer_refinement=True)``: :meth:`_complete`, whatever the budget),
        then the links whose maps grew most tracked again (:meth:`Linker.refresh`), then every
        robot placed again if a link changed or a map is waiting for its joint refinement
        (:meth:`Placer.refinement_pending`). The events."""
        cycle = self._cycle()
        if not cycle.maps or budget <= 0:
            return []
        deadline = time.monotonic() + budget
        events = []
        if self._linker.pins_pending() or self._placer.provisional():
            events = self._complete(cycle)
        if not self.config.refresh_links:
            return events
        return events + self._refresh_links(cycle, deadline)

    def _refresh_links(self, cycle: Cycle, deadline: float) -> List[str]:
        version = self.state_version
        aborted, batch = self._linker.refresh(cycle, deadline)
        if aborted:
            return []
        pending = self._placer.refinement_pending(cycle)[:batch] if time.monotonic() < deadline else []
        if self.state_version == version and not pending:
            return []
        events = self._placer.place(cycle, self._priors.current, set(pending))
        self._placer.bend(cycle)
        return events

    def compose(self) -> Optional[Grid]:
        """(5) Every placed map warped into the merged frame and composited; None before the
        reference has a map."""
        cycle = self._cycle()
        with self._lock:
            placements = dict(self._placer.placements)
            fields = dict(self._placer.fields)
        if not cycle.maps:
            return None
        return self._compositor.compose(cycle.maps, placements, fields, cycle.ref)

    def _cycle(self) -> Cycle:
        with self._lock:
            return Cycle(self._team, self._priors)

    @property
    def state_version(self) -> int:
        """Grows whenever the links or the placements change (what the state file follows)."""
        return self._linker.ledger.version + self._placer.version

    # ------------------------------------------------------------------ the team
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
            return self._team.propose(name)

    def update_map(self, name: str, grid: Grid) -> Optional[str]:
        """Take a robot's new grid (validated: :func:`grid.make_grid`). Returns a message when the
        map restarted (:func:`team.restarted`): its links are then forgotten and estimated again,
        and the merged map shows only the new map's cells."""
        with self._lock:
            new, event = self._team.update(name, grid, self._placer.placements)
        c = self.config
        if new and c.free_thresh == DEFAULT_FREE_THRESH and c.occupied_thresh == DEFAULT_OCC_THRESH:
            # Classify the map once, as it arrives, outside the lock (a big canvas takes a
            # while): estimation and compositing find its levels, known box and values ready.
            grid.known_values()
        return event

    def report_error(self, name: str, reason: str) -> None:
        """Remember why a robot's last input was refused (shown in status)."""
        with self._lock:
            self._team.errors[name] = reason

    def remove_robot(self, name: str) -> None:
        """Forget a robot entirely: its map leaves the merge, its links are dropped."""
        with self._lock:
            self._team.remove(name, self._placer.placements)

    def reset(self) -> None:
        """Forget every transform (maps are kept)."""
        with self._lock:
            self._linker.ledger.reset()
            self._placer.reset()
            self._compositor.forget()

    # ------------------------------------------------------------------ priors (:class:`PriorBook`)
    def priors(self) -> Priors:
        """The priors in use, robot -> ``[x, y, yaw]`` (metres, radians: its map frame in the
        priors' frame, :mod:`priors`): ``initial_poses`` as configured, with those given or
        cleared while running. The config itself is never changed."""
        return self._priors.current()

    def set_prior(self, name: str, pose: Optional[Sequence[float]]) -> List[str]:
        """Set (``[x, y, yaw]`` in the priors' frame, the meaning of ``initial_poses``) or remove
        (None) one robot's prior while running. Its pairs are estimated again under the new prior
        (the gate of :func:`pair.contradicts_prior`), its kept links that contradict it are dropped
        now, and the placements made from priors (``trust_initial_poses``) are made again. An
        estimation cycle that began before the change is discarded. Returns what was dropped."""
        return self._priors.set(name, pose)

    def _apply_priors(self, priors: Priors, changed: Optional[str]) -> List[str]:
        # (under the lock) the pairs' alignment, in the worker processes, reads the priors as its
        # config's initial_poses
        self._workers.config = dataclasses.replace(self.config, initial_poses=priors)
        if changed is None:
            return []
        events = self._linker.ledger.reprior(changed, priors, self.config.initial_pose_tolerance)
        for n in [n for n, pl in self._placer.placements.items() if pl.via == placement.PRIOR]:
            self._placer.forget(n)
        return events

    def set_prior_in_merged_frame(self, name: str, T: np.ndarray) -> List[str]:
        """Give ``name`` the prior ``T``, its map frame in the merged frame (3x3; rviz's 2D Pose
        Estimate): :meth:`PriorBook.set_in_merged_frame`; :class:`priors.PriorRefused` says why not."""
        return self._priors.set_in_merged_frame(name, T, lambda: self.reference)

    def clear_prior(self, name: str) -> bool:
        """Remove ``name``'s prior (:meth:`PriorBook.clear`); False when it had none."""
        return self._priors.clear(name)

    def wants_init_pose(self, name: str) -> bool:
        """Whether m-explore's ``init_pose_*`` of ``name`` are to be read."""
        return self._priors.wants_init_pose(name)

    def add_init_pose(self, name: str, pose: Sequence[float]) -> bool:
        """m-explore's ``init_pose_*`` of ``name`` as its prior (:meth:`PriorBook.add_init_pose`)."""
        return self._priors.add_init_pose(name, pose)

    def check_spawn_poses(self) -> Optional[Tuple[List[str], spawn.SharedFrame, List[str]]]:
        """Whether those priors are spawn poses in one shared frame (:meth:`PriorBook.check_spawn_poses`)."""
        return self._priors.check_spawn_poses(lambda: {r: m.raw for r, m in self._team.maps.items()})

    # ------------------------------------------------------------------ what it holds
    def placements(self) -> Dict[str, Placement]:
        """Placement of every merged robot (the reference included, at identity)."""
        with self._lock:
            return dict(self._placer.placements)

    def links(self) -> Dict[Tuple[str, str], Link]:
        """The verified links kept, per pair (parent, child): what the placements are made of
        (a :class:`Link` maps metres of the child's frame to the parent's)."""
        with self._lock:
            return dict(self._linker.ledger.links)

    def pair_results(self) -> Dict[Tuple[str, str], PairResult]:
        """The last result of every pair aligned, per pair (parent, child): accepted or not,
        with its scores and the reason it was refused (what the status shows per robot)."""
        with self._lock:
            return dict(self._linker.ledger.results)

    def frames(self) -> Dict[str, str]:
        """Map frame id of every robot (from its grid's header)."""
        with self._lock:
            return self._team.frames()

    def status(self) -> Dict[str, RobotStatus]:
        """Per robot: merged or not, placement, last pair attempt, last input error."""
        with self._lock:
            ledger = self._linker.ledger
            return robot_statuses(self._team.maps, self._team.errors, ledger.results, ledger.links,
                                  self._placer.placements, self._placer.fields, self._team.reference)

    def align_robots(self, pa: RobotMap, ch: RobotMap, seed: int = 0) -> PairResult:
        """Steps (2)-(4) for two robots' maps, here in this process (:func:`pair.align_pair` of
        their crops and features): cells of ``ch`` -> cells of ``pa``."""
        return align_pair(self.config, self._workers.input(pa), self._workers.input(ch), seed)

    # ------------------------------------------------------------------ persistence
    def export_state(self) -> Dict:
        """Verified links and placements as plain data: what the state file holds
        (:mod:`state`)."""
        with self._lock:
            edges = [link_dict(e) for e in self._linker.ledger.links.values()]
            placements = {n: placement_dict(p) for n, p in self._placer.placements.items()}
            return {'reference': self._team.reference, 'edges': edges, 'placements': placements}

    def restore_state(self, state: Dict) -> int:
        """Take links saved by :meth:`export_state` (pairwise: valid under any reference), each
        verified on the grids before use; a link that is not one is skipped. How many were taken."""
        n = 0
        with self._lock:
            for d in state.get('edges', []) or []:
                try:
                    e = link_from_dict(d, time.time())
                except (KeyError, TypeError, ValueError):
                    continue
                if all(math.isfinite(v) for v in e.T.ravel()):
                    self._linker.ledger.restored[(e.parent, e.child)] = e
                    n += 1
        return n
