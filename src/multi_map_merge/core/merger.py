"""The merger: the paper's flowchart as one class (no ROS in here).

    maps --(1) image + AKAZE--> features --(2) match pairs--> matches --(3) rigid RANSAC-->
    transform + inlier ratio --(4) verify, keep the most reliable--> placements
    --(5) warp + composite--> merged grid, --(6) poses--> TF of every robot's map frame

Frames: the merged frame is the reference robot's map frame (the paper's Map 1). A robot's
*placement* is the pose ``T_merged_k`` of its map frame in the merged frame (metres, radians).
It is expressed between frames, not grids, so it stays valid while gmapping grows the grid.

Thread safety: ``update_map`` / ``remove_robot`` may be called from any thread while
``estimate`` runs in another and ``compose`` in a third; each takes a snapshot under a lock
and computes outside it.
"""
from __future__ import annotations

import itertools
import math
import os
import threading
import time
import zlib
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

import numpy as np

from . import matching as est
from . import posegraph, verify
from .composite import Lattice, Patch, composite, lattice_for, warp_patch
from .config import MergeConfig
from .features import Features
from .grid import DEFAULT_FREE_THRESH, DEFAULT_OCC_THRESH, Grid, known_bbox, known_values, rescale
from .pair import PairInput, compute_features, crop_known, estimate_pair
from .transforms import image_to_pose, inverse, pose_distance, pose_to_image, se2, xyyaw

# a pose graph whose result disagrees with one of its links by more than this (metres,
# radians) is not used: the chain of most reliable links places the robots instead
GRAPH_GATE = (0.3, math.radians(3.0))
# a link re-estimated within this of the kept one (metres, radians) is the same link refined
SAME_LINK = (0.3, math.radians(3.0))
# a different solution replaces a kept link when it verifies this much better on the grids,
# or when it at least halves the kept link's disagreement (and gains SWITCH_MIN): near 1.0 a
# fixed margin cannot be met even by a clearly better link (0.995 against 0.973)
SWITCH_AGREEMENT = 0.03
SWITCH_MIN = 0.01


@dataclass
class RobotMap:
    """The latest grid of one robot. ``grid`` is at the merger's working resolution (the
    reference's): a map of another resolution is rescaled, not rejected."""

    name: str
    raw: Grid           # as received
    version: int
    received: float     # seconds (time.time()) when it arrived
    grid: Grid = None   # type: ignore[assignment]  # working-resolution grid, set by _working

    def at(self, resolution: float) -> 'RobotMap':
        if self.grid is None or abs(self.grid.resolution - resolution) > 1e-9:
            self.grid = rescale(self.raw, resolution)
        return self


@dataclass
class Edge:
    """A verified transform between two robots' map frames: ``T`` maps metres in ``child``'s
    frame to metres in ``parent``'s frame."""

    parent: str
    child: str
    T: np.ndarray
    reliability: float
    agreement: float
    inliers: int
    matches: int
    stamp: float
    overlap: int = 0      # cells known in both grids when it was estimated

    def towards(self, parent: str) -> np.ndarray:
        """Pose of the other robot's frame in ``parent``'s frame."""
        return self.T if parent == self.parent else inverse(self.T)


@dataclass
class Placement:
    """Where a robot's map frame sits in the merged frame, and how well we know it."""

    T: np.ndarray                 # 3x3 pose of the robot's map frame in the merged frame
    reliability: float            # weakest inlier ratio along the chain (1.0 for the reference)
    agreement: float              # weakest verification score along the chain
    inliers: int                  # fewest inliers along the chain
    via: str                      # the robot it is linked through ('' for the reference)
    path: Tuple[str, ...]         # reference ... robot
    stamp: float                  # seconds when this placement was adopted


@dataclass
class RobotStatus:
    """What diagnostics show for one robot."""

    merged: bool
    reference: bool
    placement: Optional[Placement]
    last_attempt: Optional[est.PairEstimate] = None
    last_attempt_with: str = ''
    error: str = ''
    linked_to: Tuple[str, ...] = ()   # robots it has verified links with


class MapMerger:
    """Merges N robots' occupancy grids into one (see module docstring)."""

    def __init__(self, config: Optional[MergeConfig] = None):
        self.config = config or MergeConfig()
        c = self.config
        self._lock = threading.Lock()
        self._maps: Dict[str, RobotMap] = {}
        self._version = 0
        self._reference: str = c.reference_robot
        self._features: Dict[str, Tuple[tuple, Features]] = {}   # in the crops' cells
        self._crops: Dict[str, Tuple[tuple, np.ndarray, Tuple[int, int]]] = {}
        self._edges: Dict[Tuple[str, str], Edge] = {}
        self._tried: Dict[Tuple[str, str], Tuple[int, int]] = {}
        self._attempts: Dict[Tuple[str, str], est.PairEstimate] = {}
        self._placements: Dict[str, Placement] = {}
        self._patches: Dict[str, Tuple[tuple, Optional[Patch]]] = {}
        self._errors: Dict[str, str] = {}
        self._restored: Dict[Tuple[str, str], Edge] = {}
        self._merged = None       # (patch identities, merged grid) of the last compose
        self._graph_key = None    # the links the last pose-graph placement was made of
        self._uid = '%d-%d' % (os.getpid(), next(_MERGERS))   # names its maps in worker caches
        self.state_version = 0    # bumped whenever links or placements change (for persistence)

    # ------------------------------------------------------------------ inputs
    @property
    def reference(self) -> str:
        """The reference robot: ``reference_robot`` or, if empty, the first robot by name."""
        with self._lock:
            return self._reference_locked()

    def _reference_locked(self) -> str:
        if not self._reference and self._maps:
            self._reference = sorted(self._maps)[0]
        return self._reference

    def propose_reference(self, name: str) -> str:
        """Make ``name`` the reference unless one is set already (``reference_robot``, or a
        previous choice: the merged frame never changes once chosen). Returns the reference."""
        with self._lock:
            if not self._reference:
                self._reference = name
            return self._reference

    def update_map(self, name: str, grid: Grid) -> Optional[str]:
        """Take a robot's new grid (already validated, see :func:`grid.make_grid`).

        Returns a message when the map restarted (gmapping reset: the grid shrank, or lost
        most of what it knew); the robot's links are then forgotten and re-estimated, and the
        merged map shows only the new map's cells.
        """
        with self._lock:
            prev = self._maps.get(name)
            if prev is not None and _same_grid(prev.raw, grid):
                prev.received = time.time()   # republished unchanged: nothing to recompute
                self._errors.pop(name, None)
                return None
            event = None
            if prev is not None and _restarted(prev.raw, grid):
                event = ('map of %s restarted (%dx%d cells -> %dx%d): its transform is forgotten '
                         'and will be estimated again' % (name, prev.raw.width, prev.raw.height,
                                                           grid.width, grid.height))
                self._forget_locked(name)
            self._version += 1
            self._maps[name] = RobotMap(name, grid, self._version, time.time())
            self._errors.pop(name, None)
        if self._default_thresholds():
            # Classify the map once, as it arrives, outside the lock (a big canvas takes a
            # while): estimation and compositing find its levels, known box and values ready.
            grid.known_values()
        return event

    def _forget_locked(self, name: str) -> None:
        had = name in self._placements or any(name in k for k in self._edges)
        if name == self._reference:
            # Every placement is a pose in the reference's frame, which just moved.
            self._placements.clear()
            self._patches.clear()
        self._placements.pop(name, None)
        self._patches.pop(name, None)
        for k in [k for k in self._edges if name in k]:
            del self._edges[k]
        for k in [k for k in self._restored if name in k]:
            del self._restored[k]
        if had:
            self.state_version += 1

    def report_error(self, name: str, reason: str) -> None:
        """Remember why a robot's last input was refused (shown in status)."""
        with self._lock:
            self._errors[name] = reason

    def remove_robot(self, name: str) -> None:
        """Forget a robot entirely: its map leaves the merge, its links are dropped."""
        with self._lock:
            self._maps.pop(name, None)
            self._features.pop(name, None)
            self._crops.pop(name, None)
            self._forget_locked(name)

    def reset(self) -> None:
        """Forget every transform (maps are kept)."""
        with self._lock:
            self._edges.clear()
            self._tried.clear()
            self._attempts.clear()
            self._placements.clear()
            self._patches.clear()

    def _snapshot(self) -> Tuple[str, Dict[str, RobotMap]]:
        """(reference, maps at the reference's resolution); maps empty before the reference
        has a map (nothing can be placed without it)."""
        with self._lock:
            ref = self._reference_locked()
            maps = dict(self._maps)
        if ref not in maps:
            return ref, {}
        res = maps[ref].raw.resolution
        return ref, {n: m.at(res) for n, m in maps.items()}

    # ------------------------------------------------------------------ the algorithm
    def estimate(self) -> List[str]:
        """One estimation cycle; returns human-readable events (merges, improvements)."""
        ref, maps = self._snapshot()
        if not maps:
            return []
        # (0) links saved by an earlier run are used only once the grids confirm them
        events = self._verify_restored(maps)
        # (1) grid -> image -> AKAZE features, only for maps that changed, and (2) match,
        # (3) rigid RANSAC + inlier ratio, (4) verify on the grids, for every pair whose maps
        # changed (in worker processes; a pair starts as soon as its two maps have features)
        todo = self._pairs(maps, ref)
        for (a, b), r in zip(todo, self._estimate_pairs(maps, todo)):
            self._keep(maps[a], maps[b], r)
        # (4) per robot keep the most reliable placement; (6) it gives the robot's TF
        return events + self._place(maps, ref)

    def compose(self) -> Optional[Grid]:
        """(5) Warp every placed map into the merged frame and composite; None before any map
        of the reference arrived."""
        ref, maps = self._snapshot()
        with self._lock:
            placements = dict(self._placements)
        if not maps:
            return None
        lattice = lattice_for(maps[ref].grid)
        patches = []
        for name, pl in sorted(placements.items()):
            m = maps.get(name)
            if m is not None:
                patches.append(self._patch(m, pl.T, lattice))
        key = tuple(id(p) for p in patches)
        if self._merged is not None and self._merged[0] == key:
            return self._merged[1]   # nothing moved or changed: the same merged grid
        grid = composite(patches, lattice, self.config.merged_map_frame, self.config.max_cells)
        self._merged = (key, grid)
        return grid

    def placements(self) -> Dict[str, Placement]:
        """Placement of every merged robot (the reference included, at identity)."""
        with self._lock:
            return dict(self._placements)

    def frames(self) -> Dict[str, str]:
        """Map frame id of every robot (from its grid's header)."""
        with self._lock:
            return {n: (m.raw.frame_id or n + '/map') for n, m in self._maps.items()}

    def status(self) -> Dict[str, RobotStatus]:
        """Per robot: merged or not, placement, last pair attempt, last input error."""
        with self._lock:
            ref = self._reference_locked()
            out = {}
            for n in sorted(set(self._maps) | set(self._errors)):
                last, other = None, ''
                for (a, b), e in self._attempts.items():
                    if n in (a, b) and (last is None or e.extra.get('t', 0) > last.extra.get('t', 0)):
                        last, other = e, (b if a == n else a)
                pl = self._placements.get(n)
                links = tuple(sorted({b if a == n else a for (a, b) in self._edges if n in (a, b)}))
                out[n] = RobotStatus(pl is not None, n == ref, pl, last, other, self._errors.get(n, ''), links)
            return out

    def export_state(self) -> Dict:
        """Verified links and placements as plain data (see :mod:`persist`)."""
        with self._lock:
            edges = [dict(zip(('x', 'y', 'yaw'), xyyaw(e.T)), parent=e.parent, child=e.child,
                          reliability=float(e.reliability), agreement=float(e.agreement),
                          inliers=int(e.inliers), matches=int(e.matches))
                     for e in self._edges.values()]
            placements = {n: dict(zip(('x', 'y', 'yaw'), xyyaw(p.T)), reliability=float(p.reliability),
                                  agreement=float(p.agreement), via=p.via, chain=list(p.path))
                          for n, p in self._placements.items()}
            return {'reference': self._reference_locked(), 'edges': edges, 'placements': placements}

    def restore_state(self, state: Dict) -> int:
        """Take links saved by :meth:`export_state`; each is verified again on the grids before
        it is used. Returns how many were taken. Links saved under another reference robot
        are still valid (they are pairwise)."""
        n = 0
        with self._lock:
            for d in state.get('edges', []) or []:
                try:
                    e = Edge(str(d['parent']), str(d['child']), se2(float(d['x']), float(d['y']), float(d['yaw'])),
                             float(d['reliability']), float(d['agreement']), int(d['inliers']),
                             int(d.get('matches', 0)), time.time())
                except (KeyError, TypeError, ValueError):
                    continue
                if all(math.isfinite(v) for v in e.T.ravel()):
                    self._restored[(e.parent, e.child)] = e
                    n += 1
        return n

    # ------------------------------------------------------------------ steps
    def _verify_restored(self, maps: Dict[str, RobotMap]) -> List[str]:
        """Re-verify restored links whose two maps are here; keep or drop each, once."""
        c = self.config
        events = []
        with self._lock:
            pending = [(k, e) for k, e in self._restored.items() if k[0] in maps and k[1] in maps]
        for key, e in pending:
            pa, ch = maps[key[0]], maps[key[1]]
            A = pose_to_image(e.T, pa.grid.resolution, pa.grid.origin, ch.grid.resolution, ch.grid.origin)
            ag, ov = verify.agreement(pa.grid.levels(c.free_thresh, c.occupied_thresh),
                                   ch.grid.levels(c.free_thresh, c.occupied_thresh), A,
                                   c.agreement_tolerance)
            ok = ov >= c.min_overlap_cells and ag >= c.min_agreement
            with self._lock:
                self._restored.pop(key, None)
                if ok and key not in self._edges:
                    e.agreement = ag
                    self._edges[key] = e
                    self.state_version += 1
            events.append('restored link %s -> %s %s (agreement %.3f, overlap %d cells)'
                          % (key[0], key[1], 'verified' if ok else 'REJECTED', ag, ov))
        return events

    def _crop(self, m: RobotMap) -> Tuple[np.ndarray, Tuple[int, int]]:
        """The known part of a map's levels and its (col, row) offset, once per map version:
        what features are computed on and what goes to the worker processes."""
        key = (m.version, m.grid.resolution)
        cached = self._crops.get(m.name)
        if cached is None or cached[0] != key:
            c = self.config
            lv = m.grid.levels(c.free_thresh, c.occupied_thresh)
            cached = self._crops[m.name] = (key,) + crop_known(lv, self._known_box(m))
        return cached[1], cached[2]

    def _known_box(self, m: RobotMap) -> Optional[Tuple[int, int, int, int]]:
        """Known cells' box of a map's working grid, grown by a cell (cached on the grid for the
        default thresholds)."""
        if self._default_thresholds():
            return m.grid.known_box()
        c = self.config
        return known_bbox(m.grid.levels(c.free_thresh, c.occupied_thresh), 1)

    def _known_values(self, m: RobotMap) -> Optional[Tuple[Tuple[int, int, int, int], np.ndarray]]:
        """(known box, its OccupancyGrid values) of a map's working grid, what compositing warps
        (cached on the grid for the default thresholds); None when nothing is known."""
        if self._default_thresholds():
            return m.grid.known_values()
        box = self._known_box(m)
        return None if box is None else (box, known_values(m.grid.levels(self.config.free_thresh,
                                                                         self.config.occupied_thresh), box))

    def _default_thresholds(self) -> bool:
        c = self.config
        return c.free_thresh == DEFAULT_FREE_THRESH and c.occupied_thresh == DEFAULT_OCC_THRESH

    def _features_of(self, m: RobotMap) -> Features:
        """(1) features of a map (in its crop's cells), computed once per map version."""
        cached = self._features.get(m.name)
        if cached is None or cached[0] != (m.version, m.grid.resolution):
            self._features[m.name] = ((m.version, m.grid.resolution), compute_features(self.config, self._crop(m)[0]))
        return self._features[m.name][1]

    def _features_all(self, maps: Dict[str, RobotMap]) -> None:
        """Features of every map that changed, in the worker processes."""
        todo = [m for m in maps.values()
                if self._features.get(m.name, (None,))[0] != (m.version, m.grid.resolution)]
        if not todo:
            return
        c = self.config
        levels = [self._crop(m)[0] for m in todo]
        for m, f in zip(todo, self._map(compute_features, [c] * len(todo), levels)):
            self._features[m.name] = ((m.version, m.grid.resolution), f)

    def _estimate_pairs(self, maps: Dict[str, RobotMap], todo: List[Tuple[str, str]]) -> List[est.PairEstimate]:
        """Features of the maps that changed, then the pairs' estimates, in ``todo``'s order.

        With a worker pool the two stages overlap: waiting for every map's features before
        the first pair would leave a worker idle while the slowest map is described."""
        c = self.config
        seeds = {ab: zlib.crc32(('%s|%s' % ab).encode()) for ab in todo}
        stale = [m for m in maps.values()
                 if self._features.get(m.name, (None,))[0] != (m.version, m.grid.resolution)]
        # the biggest maps first: the last task to start should be a short one
        stale.sort(key=lambda m: -m.grid.width * m.grid.height)
        pool = _pool(c.workers)
        if pool is None or not stale:
            self._features_all(maps)
            inputs = {n: self._input(maps[n]) for n in {x for ab in todo for x in ab}}
            return self._map(estimate_pair, [c] * len(todo), [inputs[a] for a, _ in todo],
                             [inputs[b] for _, b in todo], [seeds[ab] for ab in todo])
        from concurrent.futures import as_completed
        waiting = {pool.submit(compute_features, c, self._crop(m)[0]): m for m in stale}
        ready = set(maps) - {m.name for m in stale}
        queued: Dict[Tuple[str, str], object] = {}
        inputs: Dict[str, PairInput] = {}

        def submit_ready() -> None:
            for ab in todo:
                if ab not in queued and ab[0] in ready and ab[1] in ready:
                    for n in ab:
                        if n not in inputs:
                            inputs[n] = self._input(maps[n])
                    queued[ab] = pool.submit(estimate_pair, c, inputs[ab[0]], inputs[ab[1]], seeds[ab])

        submit_ready()
        for fut in as_completed(waiting):
            m = waiting[fut]
            self._features[m.name] = ((m.version, m.grid.resolution), fut.result())
            ready.add(m.name)
            submit_ready()
        return [queued[ab].result() for ab in todo]

    def _map(self, fn, *iterables):
        """fn over the arguments in the worker pool (in this process when workers == 1)."""
        pool = _pool(self.config.workers)
        return list(pool.map(fn, *iterables)) if pool is not None else list(map(fn, *iterables))

    def _pairs(self, maps: Dict[str, RobotMap], ref: str) -> List[Tuple[str, str]]:
        """Pairs (parent, child) whose maps changed since they were last tried: every pair of
        robots (so a robot that misses the reference can chain through another)."""
        names = sorted(maps)
        out = []
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                pa, ch = (a, b) if b != ref else (b, a)
                key = (pa, ch)
                if self._tried.get(key) != (maps[pa].version, maps[ch].version):
                    out.append(key)
        return out

    def _keep(self, pa: RobotMap, ch: RobotMap, r: est.PairEstimate) -> None:
        """(4) keep the pair's estimate if it is verified and more reliable than the kept one."""
        c = self.config
        key = (pa.name, ch.name)
        r.extra['t'] = time.time()
        with self._lock:
            self._tried[key] = (pa.version, ch.version)
            self._attempts[key] = r
            old = self._edges.get(key)
        if not r.accepted:
            return
        T = image_to_pose(r.A, pa.grid.resolution, pa.grid.origin, ch.grid.resolution, ch.grid.origin)
        reliability, inliers = r.reliability, r.inliers
        if old is None or r.reliability > old.reliability + c.replace_margin:
            pass                     # the paper's rule: more reliable
        elif _same_link(T, old.T):
            if r.overlap <= old.overlap:
                return
            # The kept link, found again on grown maps: the same solution, now refined on
            # more overlap. Take its pose (a small correction, not a jump); keep the best
            # reliability seen. Early links on small maps are otherwise stuck a degree off.
            reliability, inliers = old.reliability, max(old.inliers, r.inliers)
        elif not (r.overlap >= 0.9 * old.overlap
                  and _clearly_better(r.agreement, self._agreement_now(pa, ch, old.T))):
            # Another solution replaces the kept link only if the grids, now larger, clearly
            # prefer it: on a corridor the first link found on small maps can be a look-alike
            # a metre along it. Inlier ratios are not compared here: they fall as maps grow
            # (more features, more outliers), so the early look-alike would keep its lead for
            # ever. (The kept link's score is computed outside the lock: it warps a grid.)
            return
        with self._lock:
            if self._edges.get(key) is not old:
                return               # forgotten (reset, map restart) meanwhile
            self._edges[key] = Edge(pa.name, ch.name, T, reliability, r.agreement, inliers, r.matches,
                                    time.time(), r.overlap)
            self.state_version += 1

    def _agreement_now(self, pa: RobotMap, ch: RobotMap, T: np.ndarray) -> float:
        """Verification score of a kept link on the pair's current grids (its recorded score
        was measured on the grids of its time)."""
        c = self.config
        A = pose_to_image(T, pa.grid.resolution, pa.grid.origin, ch.grid.resolution, ch.grid.origin)
        ag, _ = verify.agreement(pa.grid.levels(c.free_thresh, c.occupied_thresh),
                              ch.grid.levels(c.free_thresh, c.occupied_thresh), A, c.agreement_tolerance)
        return ag

    def _input(self, m: RobotMap) -> PairInput:
        levels, offset = self._crop(m)
        return PairInput(m.name, m.version, levels, m.grid.resolution, m.grid.origin,
                         self._features_of(m), self._uid, offset)

    def estimate_grids(self, pa: RobotMap, ch: RobotMap, seed: int = 0) -> est.PairEstimate:
        """Steps (2)-(4) for one pair, here in this process: cells of ``ch`` -> cells of ``pa``."""
        return estimate_pair(self.config, self._input(pa), self._input(ch), seed)

    def _place(self, maps: Dict[str, RobotMap], ref: str) -> List[str]:
        """Chain every robot to the reference through its most reliable links (the path whose
        weakest link has the highest inlier ratio) and keep, per robot, the best placement seen."""
        c = self.config
        events: List[str] = []
        with self._lock:
            edges = dict(self._edges)
            old = dict(self._placements)
        best: Dict[str, Placement] = {
            ref: Placement(np.eye(3), 1.0, 1.0, 0, '', (ref,), time.time())}
        frontier = [ref]
        # Widest-path (maximin) search from the reference; N is small, so a simple loop does.
        while frontier:
            frontier.sort(key=lambda n: best[n].reliability)
            u = frontier.pop()
            for (a, b), e in edges.items():
                if u not in (a, b):
                    continue
                v = b if u == a else a
                if v not in maps:
                    continue
                rel = min(best[u].reliability, e.reliability)
                if v in best and best[v].reliability >= rel:
                    continue
                T = best[u].T @ e.towards(u)
                best[v] = Placement(T, rel, min(best[u].agreement, e.agreement),
                                    min(best[u].inliers or e.inliers, e.inliers), u,
                                    best[u].path + (v,), time.time())
                if v not in frontier:
                    frontier.append(v)
        graph_key = None
        if c.pose_graph:
            # every verified link at once: a chain adds up its links' errors, the graph
            # averages them over every cycle (kept only if every link agrees with it)
            links = [(e.parent, e.child, e.T, float(min(e.inliers, 50))) for e in edges.values()
                     if e.parent in best and e.child in best]
            key = tuple(sorted((a, b, edges[(a, b)].stamp) for a, b, _, _ in links))
            with self._lock:
                same = key == self._graph_key
            if same:
                graph_key = key              # nothing changed: the kept placements stand
            elif len(links) >= len(best):
                opt = posegraph.optimise({n: p.T for n, p in best.items()}, links, ref)
                worst = posegraph.worst_residual(opt, links)
                if worst is not None and worst[0] <= GRAPH_GATE[0] and worst[1] <= GRAPH_GATE[1]:
                    graph_key = key
                    for n in best:
                        best[n].T = opt[n]
        with self._lock:
            regraphed = graph_key is not None and graph_key != self._graph_key
            self._graph_key = graph_key
        priors = c.initial_poses
        if c.trust_initial_poses and ref in priors:
            for n in maps:
                if n not in best and n in priors:
                    T = inverse(se2(*priors[ref])) @ se2(*priors[n])
                    best[n] = Placement(T, 0.0, 0.0, 0, 'initial_pose', (ref, n), time.time())
        new = {}
        for n, pl in best.items():
            prev = old.get(n)
            still_linked = prev is not None and (prev.via == 'initial_pose' or _chain_holds(prev, edges))
            if (prev is not None and still_linked and pl.reliability <= prev.reliability + c.replace_margin
                    and not (regraphed and pl.via != 'initial_pose')):
                new[n] = prev
                continue
            new[n] = pl
            if n == ref:
                continue
            x, y, yaw = xyyaw(pl.T)
            what = 'merged' if prev is None else 'transform improved'
            events.append('%s %s via %s: x=%.3f m y=%.3f m yaw=%.2f deg, inlier ratio %.3f, '
                          'agreement %.3f, inliers %d' % (n, what, pl.via, x, y, math.degrees(yaw),
                                                          pl.reliability, pl.agreement, pl.inliers))
        with self._lock:
            if set(new) != set(self._placements) or any(new[n] is not self._placements.get(n) for n in new):
                self.state_version += 1
            self._placements = new
        return events

    def _patch(self, m: RobotMap, T: np.ndarray, lattice: Lattice) -> Optional[Patch]:
        key = (m.version, T.tobytes(), lattice.key())
        cached = self._patches.get(m.name)
        if cached is not None and cached[0] == key:
            return cached[1]
        c = self.config
        kv = self._known_values(m)
        p = None if kv is None else warp_patch(kv[1], kv[0], m.grid.resolution, m.grid.origin, T,
                                               lattice, c.max_cells)
        self._patches[m.name] = (key, p)
        return p


def _chain_holds(pl: Placement, edges: Dict[Tuple[str, str], Edge]) -> bool:
    """The links a placement was made of are all still kept and still say where it is: a link
    replaced by a different solution (a look-alike corrected) moves the robot. The tolerance
    allows for the pose graph, which moves a placement off its chain by up to GRAPH_GATE."""
    T = np.eye(3)
    for p, q in zip(pl.path, pl.path[1:]):
        e = edges.get((p, q)) or edges.get((q, p))
        if e is None:
            return False
        T = T @ e.towards(p)
    d, a = pose_distance(T, pl.T)
    return d <= GRAPH_GATE[0] + SAME_LINK[0] and a <= GRAPH_GATE[1] + SAME_LINK[1]


def _clearly_better(new: float, kept: float) -> bool:
    """A new link's agreement beats the kept link's (both on the current grids) by enough to
    switch: SWITCH_AGREEMENT more, or half the disagreement and SWITCH_MIN more."""
    return new >= kept + SWITCH_AGREEMENT or (new >= kept + SWITCH_MIN and 1.0 - new <= 0.5 * (1.0 - kept))


def _same_link(T1: np.ndarray, T2: np.ndarray) -> bool:
    """Two estimates of one link that differ by a refinement, not by a different solution."""
    d, a = pose_distance(T1, T2)
    return d <= SAME_LINK[0] and a <= SAME_LINK[1]


def _restarted(old: Grid, new: Grid) -> bool:
    """gmapping only ever grows its grid (same or larger, origin moving outwards) and keeps
    what it knew, so a grid that shrank or lost most of its known cells is a new map."""
    if new.width < old.width or new.height < old.height:
        return True
    known_old = int(np.count_nonzero(old.data >= 0))
    known_new = int(np.count_nonzero(new.data >= 0))
    return known_old > 1000 and known_new < 0.5 * known_old


def _same_grid(a: Grid, b: Grid) -> bool:
    return (a.data.shape == b.data.shape and a.resolution == b.resolution and a.origin == b.origin
            and a.frame_id == b.frame_id and np.array_equal(a.data, b.data))


_MERGERS = itertools.count()
_POOL = None
_POOL_SIZE = 0


def _worker_init() -> None:
    """One OpenCV thread and one BLAS thread per worker: the pool already keeps every core
    busy, and the libraries' own threads on top of it only contend (AKAZE on a house map:
    14 ms with two threads alone, but two workers each running two threads are slower than
    two workers with one each)."""
    import cv2
    cv2.setNumThreads(1)
    _one_blas_thread()


def _one_blas_thread() -> None:
    """numpy's BLAS to one thread in this process where it is OpenBLAS (Debian's libblas.so.3
    once libopenblas is installed). RANSAC scores hypotheses by matrix products, and
    OpenBLAS's threads spin after each one: two workers with two BLAS threads each took 10%
    more CPU per house cycle than with one (measured). Other BLAS builds are left as they are."""
    import ctypes
    for name in ('libblas.so.3', 'libopenblas.so.0'):
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        set_threads = getattr(lib, 'openblas_set_num_threads', None)
        if set_threads is not None:
            set_threads(1)
            return


def _pool(workers: int):
    """The process pool shared by every merger in this process (None: work inline).

    Processes, not threads: estimation is partly pure Python, and in threads it would hold the
    GIL that the node's /map and TF timers need. 'forkserver' starts clean workers that do not
    inherit the ROS node's threads."""
    global _POOL, _POOL_SIZE
    n = workers or os.cpu_count() or 1
    if n <= 1:
        return None
    if _POOL is None or _POOL_SIZE != n:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        if _POOL is not None:
            _POOL.shutdown(wait=False)
        _POOL = ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context('forkserver'),
                                    initializer=_worker_init)
        _POOL_SIZE = n
    return _POOL
