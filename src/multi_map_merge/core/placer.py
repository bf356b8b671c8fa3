"""Links to placements: every robot placed in the merged frame from the verified links kept
(:mod:`placement`: the widest chains, the pose graph, the priors, hysteresis against the kept
placements, how well each is pinned), refined against the other placed maps (:mod:`joint`),
and, with ``bend_maps``, every placed map's correction field (:mod:`deform`).

What it holds (under its owner's lock, :class:`merger.MapMerger`'s one lock): the placements,
the links the last pose-graph placement was made of, how the joint refinement last took each
robot, and the bent maps' fields with what they were fitted to. It places from the pair
ledger's kept links, and settles the team's reference once another robot is merged with it.
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
from typing import Callable, Dict, List, NamedTuple, Optional, Set, Tuple

import numpy as np

from . import deform, joint, placement, schedule
from .composite import lattice_for
from .config import MergeConfig
from .cycle import Cycle
from .ledger import PairLedger
from .links import Link
from .placement import Placement
from .priors import Priors
from .robot_map import RobotMap
from .team import Team, TeamListener
from .transforms import within
from .workers import PairWorkers

# with ~refresh_links, a cycle refines a robot whose map changed (its anchor did not move) once
# its known cells grew by this factor since its last refinement; a smaller change waits for
# the spare time between cycles (a grown map moves its walls against the others' rarely)
REFINE_GROWTH = 1.1


class _Refined(NamedTuple):
    """A robot as the joint refinement last took it (:meth:`MapMerger._joint`)."""

    map_key: tuple          # its map's RobotMap.key
    anchor: np.ndarray      # 3x3, the links' pose it was refined from
    pose: np.ndarray        # 3x3, the pose it was refined to
    known: int              # its map's known cells


class Placer(TeamListener):
    """Links to placements, and the bent maps' fields (see the module's docstring)."""

    def __init__(self, config: MergeConfig, workers: PairWorkers, lock: threading.Lock, team: Team,
                 ledger: PairLedger):
        self.config = config
        self._workers = workers      # the worker pool the joint refinement runs in
        self._lock = lock            # the merger's
        self._team = team            # its reference settles once another robot is placed
        self._ledger = ledger        # the kept links, their drift covariances
        # the placement of every merged robot (the reference at identity), per robot
        self.placements: Dict[str, Placement] = {}
        self.version = 0             # bumped whenever the placements change (the merger's state_version)
        self._graph_key = None       # the links the last pose-graph placement was made of
        # how the joint refinement last took each robot (_joint): (the reference, per robot its _Refined)
        self._refined: Optional[Tuple[str, Dict[str, _Refined]]] = None
        # bend_maps: per bent map, (the map's version it was fitted to, its correction field)
        self.fields: Dict[str, Tuple[int, deform.Field]] = {}
        self._fields_key = None      # the maps and placements the fields were fitted to (bend)

    def forget(self, name: Optional[str] = None) -> None:
        """(under the lock) Drop ``name``'s placement; None: every placement (the reference's
        frame moved)."""
        if name is None:
            self.placements.clear()
        else:
            self.placements.pop(name, None)

    def robot_forgotten(self, name: str, reference: bool) -> None:
        self.version += name in self.placements
        # every placement is a pose in the reference's frame, which moves with its map
        self.forget(None if reference else name)

    def reference_moved(self, old: str, new: str, has_map: bool) -> None:
        # Every placement is a pose in the former reference's frame: only the new reference is
        # placed (at identity) until the next cycle places the others under it (a cycle under
        # way with the former one is discarded: Cycle.void)
        self.forget()
        self._graph_key = None
        if old and has_map:
            self.placements[new] = Placement(np.eye(3), 1.0, 1.0, 0, '', (new,), time.time())

    def place(self, cycle: Cycle, priors: Callable[[], Priors], also: Set[str] = frozenset(),
              provisional: bool = False) -> List[str]:
        """(4) Every robot of the ``cycle`` placed from the verified links kept, per robot the
        best placement seen (:meth:`_placed`; ``priors()``: the priors in use, ``also``: robots
        the joint refinement takes if their map changed at all); the reference settled.
        ``provisional``: no joint refinement, and the placements adopted anew are
        :attr:`Placement.provisional` (the next placement without it replaces them). Returns
        the events (merged, improved); none when the cycle is void (:meth:`Cycle.void`)."""
        with self._lock:
            edges = dict(self._ledger.links)
            old = dict(self.placements)
        new, events = self._placed(cycle.maps, cycle.ref, edges, old, priors, self._ledger.drift_covs, set(also),
                                   provisional)
        with self._lock:
            if cycle.void():
                return []            # the reference restarted or changed meanwhile: every placement is void
            # robots forgotten since the cycle began stay unplaced until estimated again
            new = {n: p for n, p in new.items() if not cycle.stale(n)}
            now = self.placements
            if set(new) != set(now) or any(new[n] is not now.get(n) for n in new):
                self.version += 1
            self.placements = new
            self._team.settle(list(new))   # fixed once another robot is merged with it
        return [e for n, e in events.items() if n in new]

    def reset(self) -> None:
        """(under the lock) Every transform forgotten: the placements go and the fields are
        fitted again. The pose graph's and the joint refinement's memos stay: each is keyed by
        what it was made of (the links; each robot's map and anchor), which the next placement
        compares anew."""
        self.placements.clear()
        self.fields.clear()
        self._fields_key = None

    def _placed(self, maps: Dict[str, RobotMap], ref: str, edges: Dict[Tuple[str, str], Link],
              old: Dict[str, Placement], priors: Callable[[], Dict[str, List[float]]],
              drift_covs: Dict[Tuple[str, str], tuple], also: Set[str],
              provisional: bool = False) -> Tuple[Dict[str, Placement], Dict[str, str]]:
        """Every robot of ``maps`` placed from the verified links ``edges``, the kept placements
        ``old`` standing unless the new one is better; (the new placements, the events: per robot
        merged or improved, what to tell). ``priors()``: the priors in use; ``drift_covs``: the links' drift covariances
        (:func:`placement.pin`); ``also``: robots the joint refinement takes if their map changed
        at all (:meth:`_joint`)."""
        c = self.config
        # the chain whose weakest link is most reliable, from the reference
        best = placement.widest_paths(edges, maps, ref)
        # every verified link at once, where they form cycles (kept if every link agrees)
        graph_key = None
        if c.pose_graph:
            graph, key = placement.graph_links(edges, best)
            with self._lock:
                same = key == self._graph_key
            if same:
                graph_key = key              # nothing changed: the kept placements stand
            else:
                poses = placement.graph_poses(best, graph, ref, placement.link_covs(edges, graph))
                if poses is not None:
                    graph_key = key
                    for n in best:
                        best[n].T = poses[n]
        with self._lock:
            regraphed = graph_key is not None and graph_key != self._graph_key
            self._graph_key = graph_key
        # robots with no chain at their initial pose, when trusted
        placement.add_priors(c, best, maps, ref, priors())
        # the kept placement stays unless the new one is better
        new, events = placement.hysteresis(c, best, old, edges, ref, regraphed)
        # every placement refined against every placed map it overlaps, when one was adopted anew
        if not provisional:
            new = self._joint(maps, new, old, ref, also)
        # how well each is pinned: its links' covariances, along its chain or by the graph
        placement.pin(c, new, edges, ref, graph_key is not None, drift_covs)
        if provisional:
            for n, p in new.items():
                if n != ref and (p is not old.get(n) or p.provisional):
                    # (its covariance is that of links not all searched yet: not a weak placement)
                    p.provisional, p.weak_reason = True, ''
        return new, events

    def provisional(self) -> bool:
        """Whether a placement is provisional (:meth:`place`)."""
        with self._lock:
            return any(p.provisional for p in self.placements.values())

    def refinement_pending(self, cycle: Cycle) -> List[str]:
        """The placed robots of the ``cycle`` whose map changed since the joint refinement last
        took them (:meth:`_joint`), those whose known cells grew most since first."""
        maps, ref = cycle.maps, cycle.ref
        with self._lock:
            last = self._refined
            placed = set(self.placements)
        if not self.config.joint_placement or last is None or last[0] != ref:
            return []
        grown = [(-schedule.facts_of(maps[n], self.config).known / float(max(1, r.known)), n)
                 for n, r in last[1].items() if n in placed and n in maps and maps[n].key != r.map_key]
        return [n for _, n in sorted(grown)]

    def _joint(self, maps: Dict[str, RobotMap], new: Dict[str, Placement], old: Dict[str, Placement],
               ref: str, also: Set[str]) -> Dict[str, Placement]:
        """The placements ``new`` (after hysteresis) refined by :mod:`joint` against each other,
        the reference and robots at their prior fixed; a robot it moves gets a new
        :class:`Placement` (its ``graph_T`` the links' pose). Refines only the robots whose
        inputs changed since they were last refined: their map, or their anchor (the links'
        pose) by more than SAME_POSE (the reference's map: its neighbours); the others keep the
        pose they were refined to, so that a team's cost per round of map updates grows with
        the team, not with its square. With ``refresh_links``, a map that changed counts only
        once its known cells grew by REFINE_GROWTH since its last refinement, unless it is one
        of ``also`` (the spare time's placement, :meth:`refresh`, takes the others). A cycle in
        which nothing changed cannot move a robot, and a move smaller than SAME_POSE keeps the
        robot's placement as it was (a map that grew a little does not move its TF)."""
        c = self.config
        if not c.joint_placement:
            return new
        linked = [n for n, p in sorted(new.items()) if n in maps and (n == ref or p.via != placement.PRIOR)]
        robots = {}
        for n in linked:
            r = self._joint_robot(maps[n])
            if r is not None:
                robots[n] = r
        if ref not in robots:
            return new
        anchors = {n: (new[n].graph_T if new[n].graph_T is not None else new[n].T) for n in robots}
        known = {n: schedule.facts_of(maps[n], self.config).known for n in robots}
        with self._lock:
            last = self._refined
        # the whole team refined from its anchors (several rounds), or only the robots moving
        whole = last is None or last[0] != ref or not set(last[1]) <= set(robots)
        moving: Set[str] = set(robots)
        current = {n: new[n].T for n in robots}
        if not whole:
            # the robots whose map, or whose anchor beyond SAME_POSE, changed since they were
            # refined (a robot new among them too); the reference's neighbours for the reference.
            # The others keep the pose they were refined to (a placement adopted anew with an
            # anchor that moved less, as the pose graph is solved again, too)
            moving = {n for n in robots if n not in last[1]
                      or not within(anchors[n], last[1][n].anchor, joint.SAME_POSE)
                      or (last[1][n].map_key != maps[n].key
                          and (n in also or not c.refresh_links or known[n] >= REFINE_GROWTH * last[1][n].known))}
            current.update({n: last[1][n].pose for n in robots if n not in moving})
            if ref in moving:
                moving.update(joint.neighbours(robots, current, ref))
        poses = current
        if whole or moving:
            poses = joint.refine_placements(robots, anchors, ref, lattice_for(maps[ref].grid), c.agreement_tolerance,
                                            current, None if whole else moving, self._workers.runner(maps))
        with self._lock:
            kept = {} if whole else dict(last[1])
            kept.update({n: _Refined(maps[n].key, anchors[n], poses[n], known[n]) for n in moving})
            self._refined = (ref, {n: kept[n] for n in robots if n in kept})
        out = dict(new)
        for n, T in poses.items():
            if not within(T, new[n].T, joint.SAME_POSE):
                moved = not np.array_equal(T, anchors[n])
                out[n] = dataclasses.replace(new[n], T=T, graph_T=anchors[n] if moved else None)
        return out

    def _joint_robot(self, m: RobotMap) -> Optional[joint.Robot]:
        """What the joint refinement needs of a map (:class:`joint.Robot`), once per version."""
        c = self.config
        g = m.grid
        return m.memo('joint', lambda: joint.Robot.of(g, g.levels(c.free_thresh, c.occupied_thresh),
                                                      g.known_values(c.free_thresh, c.occupied_thresh)))

    def bend(self, cycle: Cycle) -> None:
        """(5) past rigid: fit the correction field of every placed map of the ``cycle``
        (:mod:`deform`) when ``bend_maps`` is on and a map or a placement changed since they were
        fitted; a map whose field is not fitted (it pairs with no other) is composited rigidly."""
        c = self.config
        if not c.bend_maps:
            return
        maps, ref = cycle.maps, cycle.ref
        with self._lock:
            placed = {n: p.T for n, p in self.placements.items() if n in maps}
        key = (ref, tuple((n, maps[n].key, T.tobytes()) for n, T in sorted(placed.items())))
        with self._lock:
            if key == self._fields_key:
                return
        walls = {}
        for n in placed:
            g = maps[n].grid
            walls[n] = deform.wall_points(g.levels(c.free_thresh, c.occupied_thresh), g.resolution, g.origin)
        fields = deform.fit_fields(walls, placed, ref, c.bend_node_spacing, c.map_drift,
                                   math.radians(c.map_drift_yaw))
        with self._lock:
            self.fields = {n: (maps[n].version, f) for n, f in fields.items()}
            self._fields_key = key
