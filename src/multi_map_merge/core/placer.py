"""Links to placements: every robot placed in the merged frame from the verified links kept
(:mod:`placement`: the widest chains, the pose graph, the priors, hysteresis against the kept
placements, how well each is pinned), refined against the other placed maps (:mod:`joint`),
and, with ``bend_maps``, every placed map's correction field (:mod:`deform`).

What it remembers between cycles (under its owner's lock, :class:`merger.MapMerger`'s one
lock): the links the last pose-graph placement was made of, how the joint refinement last took
each robot, and the bent maps' fields with what they were fitted to.
"""
from __future__ import annotations

import dataclasses
import math
import threading
from typing import Callable, Dict, List, NamedTuple, Optional, Set, Tuple

import numpy as np

from . import deform, joint, placement, schedule
from .composite import lattice_for
from .config import MergeConfig
from .links import Link
from .placement import Placement
from .robot_map import RobotMap
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


class Placer:
    """Links to placements, and the bent maps' fields (see the module's docstring)."""

    def __init__(self, config: MergeConfig, workers: PairWorkers, lock: threading.Lock):
        self.config = config
        self._workers = workers      # the worker pool the joint refinement runs in
        self._lock = lock            # the merger's
        self._graph_key = None       # the links the last pose-graph placement was made of
        # how the joint refinement last took each robot (_joint): (the reference, per robot its _Refined)
        self._refined: Optional[Tuple[str, Dict[str, _Refined]]] = None
        # bend_maps: per bent map, (the map's version it was fitted to, its correction field)
        self.fields: Dict[str, Tuple[int, deform.Field]] = {}
        self._fields_key = None      # the maps and placements the fields were fitted to (bend)

    def forget_graph(self) -> None:
        """(under the lock) The reference changed: the pose graph is solved again."""
        self._graph_key = None

    def forget_fields(self) -> None:
        """(under the lock) Every transform forgotten: the fields are fitted again."""
        self.fields.clear()
        self._fields_key = None

    def place(self, maps: Dict[str, RobotMap], ref: str, edges: Dict[Tuple[str, str], Link],
              old: Dict[str, Placement], priors: Callable[[], Dict[str, List[float]]],
              drift_covs: Dict[Tuple[str, str], tuple], also: Set[str]) -> Tuple[Dict[str, Placement], List[str]]:
        """Every robot of ``maps`` placed from the verified links ``edges``, the kept placements
        ``old`` standing unless the new one is better; (the new placements, the events: merged,
        improved). ``priors()``: the priors in use; ``drift_covs``: the links' drift covariances
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
        new = self._joint(maps, new, old, ref, also)
        # how well each is pinned: its links' covariances, along its chain or by the graph
        placement.pin(c, new, edges, ref, graph_key is not None, drift_covs)
        return new, events

    def refinement_pending(self, maps: Dict[str, RobotMap], ref: str, placed: Set[str]) -> List[str]:
        """The placed robots whose map changed since the joint refinement last took them
        (:meth:`_joint`), those whose known cells grew most since first."""
        with self._lock:
            last = self._refined
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
        moving = None                  # every robot, from its anchor
        current = {n: new[n].T for n in robots}
        if last is not None and last[0] == ref and set(last[1]) <= set(robots):
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
            if not moving:
                moving = set()
        poses = joint.refine_placements(robots, anchors, ref, lattice_for(maps[ref].grid), c.agreement_tolerance,
                                        current, moving, self._workers.runner(maps)) if moving != set() else current
        with self._lock:
            kept = {} if moving is None or last is None else dict(last[1])
            kept.update({n: _Refined(maps[n].key, anchors[n], poses[n], known[n])
                         for n in robots if moving is None or n in moving})
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

    def bend(self, maps: Dict[str, RobotMap], ref: str, placements: Dict[str, Placement]) -> None:
        """Fit the correction field of every placed map (:mod:`deform`) when ``bend_maps`` is
        on and a map or a placement changed since they were fitted; a map whose field is not
        fitted (it pairs with no other) is composited rigidly."""
        c = self.config
        if not c.bend_maps:
            return
        placed = {n: p.T for n, p in placements.items() if n in maps}
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
