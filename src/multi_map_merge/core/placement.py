"""Where every robot's map frame sits in the merged frame, from the verified links.

Five steps, in this order (:meth:`merger.MapMerger._place` runs them):

1. :func:`widest_paths`: each robot chained to the reference through the path whose weakest
   link has the highest inlier ratio (a robot that misses the reference chains through another).
2. :func:`graph_poses`: where the links form cycles, an SE(2) pose graph places every robot by
   all verified links at once (a chain adds up its links' errors, the graph averages them,
   each link weighed by the information of its covariance), used only if every link agrees
   with its solution: within GRAPH_GATE, or within its own covariance (GRAPH_GATE_CHI2).
3. :func:`add_priors`: robots with no chain, placed at their prior when those are trusted.
4. :func:`hysteresis`: per robot the kept placement stays unless the new one is more reliable
   by ``replace_margin``, its chain broke, or the pose graph moved everyone.
   Then :mod:`joint` refines every placement against every placed map it overlaps.
5. :func:`pin`: each placement's covariance (its links' propagated along its chain, or
   combined by the pose graph), whether it is weakly pinned (``max_position_sigma``) and why.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Dict, Iterable, List, Optional, Tuple

import numpy as np

from . import drift, posegraph
from .config import MergeConfig
from .covariance import position_sigma
from .links import SAME_LINK, Link
from .transforms import inverse, se2, within, xyyaw

# a pose graph whose result disagrees with one of its links by more than this (metres,
# radians) is not used: the chain of most reliable links places the robots instead
GRAPH_GATE = (0.3, math.radians(3.0))
# ... unless the link has a covariance that explains the disagreement: its squared Mahalanobis
# distance under this (chi-square, 3 dof, 99.9%). A link through a corridor is loose along it:
# the graph pulls it along by the other links' pinning, which is what weighing by information
# is for; a link wrong across its walls stays far outside its covariance and still vetoes
GRAPH_GATE_CHI2 = 16.27
# the via of a robot placed at its configured initial pose
PRIOR = 'initial_pose'
# why a robot placed at its prior is weakly pinned
AT_PRIOR = 'placed at its prior, no link pins it'

Links = Dict[Tuple[str, str], Link]


@dataclass
class Placement:
    """Where a robot's map frame sits in the merged frame, and how well we know it."""

    T: np.ndarray                 # 3x3 pose of the robot's map frame in the merged frame
    inlier_ratio: float           # weakest inlier ratio along the chain (1.0 for the reference)
    agreement: float              # weakest verification score along the chain
    inliers: int                  # fewest inliers along the chain
    via: str                      # the robot it is linked through ('' for the reference)
    path: Tuple[str, ...]         # reference ... robot
    stamp: float                  # seconds when this placement was adopted
    # 3x3 covariance of (x, y, yaw) of T (metres^2, radians^2; x, y in the merged frame): the
    # links' covariances propagated along its chain, or combined by the pose graph; None when
    # not known (the reference, a robot at its prior, a link without one)
    cov: Optional[np.ndarray] = None
    # why it is weakly pinned, for people ('' when it is not; :func:`pin`): 2-sigma position
    # (worst direction) over ``max_position_sigma``, or placed at its prior (no link pins it),
    # or its covariance unknown
    weak_reason: str = ''
    # 3x3 pose its chain of links gives (T before the pose graph moved it): what
    # :func:`chain_holds` checks the links against later
    chain_T: Optional[np.ndarray] = None
    # 3x3 pose the links gave (chain or pose graph) before the joint refinement moved T
    # (:mod:`joint`): the centre of its search window; None when not refined
    graph_T: Optional[np.ndarray] = None
    # placed by a cycle that left the joint refinement and its links' covariance searches for
    # the spare time (:meth:`merger.MapMerger.estimate` with ``defer_refinement``): the spare
    # time's placement replaces it, whatever its reliability
    provisional: bool = False

    @property
    def weak(self) -> bool:
        """Weakly pinned: there is a :attr:`weak_reason`."""
        return bool(self.weak_reason)


def widest_paths(edges: Links, names: Iterable[str], ref: str) -> Dict[str, Placement]:
    """Every robot of ``names`` reachable from ``ref``, placed through the chain whose weakest
    link has the highest inlier ratio (widest path, maximin)."""
    names = set(names)
    best: Dict[str, Placement] = {ref: Placement(np.eye(3), 1.0, 1.0, 0, '', (ref,), time.time())}
    # per robot, its links (in ``edges``' order) and the robot at their other end
    around: Dict[str, List[Tuple[str, Link]]] = {}
    for (a, b), e in edges.items():
        if a == b:
            around.setdefault(a, []).append((a, e))
            continue
        around.setdefault(a, []).append((b, e))
        around.setdefault(b, []).append((a, e))
    frontier = [ref]
    # N is small, so a simple loop does
    while frontier:
        frontier.sort(key=lambda n: best[n].inlier_ratio)
        u = frontier.pop()
        for v, e in around.get(u, ()):
            if v not in names:
                continue
            ratio = min(best[u].inlier_ratio, e.inlier_ratio)
            if v in best and best[v].inlier_ratio >= ratio:
                continue
            T = best[u].T @ e.towards(u)
            best[v] = Placement(T, ratio, min(best[u].agreement, e.agreement),
                                min(best[u].inliers or e.inliers, e.inliers), u,
                                best[u].path + (v,), time.time(), chain_T=T)
            if v not in frontier:
                frontier.append(v)
    return best


def graph_links(edges: Links, placed: Iterable[str]) -> Tuple[list, tuple]:
    """(the pose graph's links among the ``placed`` robots: (parent, child, T, weight), the key
    that identifies them: a graph of the same key gives the same placements)."""
    placed = set(placed)
    links = [(e.parent, e.child, e.T, float(min(e.inliers, 50))) for e in edges.values()
             if e.parent in placed and e.child in placed]
    key = tuple(sorted((a, b, edges[(a, b)].stamp) for a, b, _, _ in links))
    return links, key


def link_covs(edges: Links, links: list) -> List[Optional[np.ndarray]]:
    """The covariance of each of ``links`` (as :func:`graph_links` gives them), None where unknown."""
    return [edges[(a, b)].cov for a, b, _, _ in links]


def drift_covs(config: MergeConfig, edges: Links, links: list,
               cache: Optional[dict] = None) -> List[Optional[np.ndarray]]:
    """:func:`link_covs` with each map's drift between its origin and the link's overlap added
    (:func:`drift.link_covariance` at ``map_drift``, ``map_drift_yaw``, and the turns read off
    the maps' walls; none for a link whose overlap's centre is unknown). ``cache``: pair ->
    (link, its drift's covariance), kept by the caller across cycles (a kept link is not
    computed again; a link replaced is a new object)."""
    rate, yaw_rate = config.map_drift, math.radians(config.map_drift_yaw)
    out = []
    for (a, b, _, _), C in zip(links, link_covs(edges, links)):
        e = edges[(a, b)]
        if C is None or e.centre is None or not (rate > 0 or yaw_rate > 0):
            out.append(C)
            continue
        hit = cache.get((a, b)) if cache is not None else None
        if hit is not None and hit[0] is e and hit[1] == (rate, yaw_rate):
            D = hit[2]
        else:
            D = drift.link_covariance(e.centre, e.T, rate, yaw_rate, e.parent_turn, e.child_turn)
            if cache is not None:
                cache[(a, b)] = (e, (rate, yaw_rate), D)
        out.append(C + D)
    return out


def graph_poses(best: Dict[str, Placement], links: list, ref: str,
                covs: Optional[List[Optional[np.ndarray]]] = None) -> Optional[Dict[str, np.ndarray]]:
    """Every placed robot's pose by all ``links`` at once (the reference held fixed), or None
    when there is no cycle or a link disagrees with the solution (by more than GRAPH_GATE and,
    for a link with a covariance, by more than it explains: GRAPH_GATE_CHI2).
    ``covs``: the links' covariances (:func:`link_covs`): each link weighed by its information."""
    if len(links) < len(best):
        return None
    opt = posegraph.optimise({n: p.T for n, p in best.items()}, links, ref, covs=covs)
    covs = covs if covs is not None else [None] * len(links)
    inside = [k for k, (a, b, _, _) in enumerate(links) if a in opt and b in opt]
    errors = posegraph.link_errors(opt, [links[k] for k in inside])
    beyond = (np.hypot(errors[:, 0], errors[:, 1]) > GRAPH_GATE[0]) | (np.abs(errors[:, 2]) > GRAPH_GATE[1])
    for k, e in zip(np.asarray(inside, int)[beyond], errors[beyond]):
        if covs[k] is None or posegraph.mahalanobis2(e, links[k][2], covs[k]) > GRAPH_GATE_CHI2:
            return None
    return opt


def pin(config: MergeConfig, placements: Dict[str, Placement], edges: Links, ref: str,
        graph: bool, cache: Optional[dict] = None) -> None:
    """Set every placement's covariance and weak flag (in place): by all links among the placed
    robots when the pose graph placed them (``graph``), else along each robot's chain. Only
    links with a covariance count: a robot that only links without one reach (too few walls
    to search, a link from an older state file) has no covariance and is weakly pinned. Each
    link's covariance has the maps' drift from their origins to its overlap added
    (:func:`drift_covs`): what the placement's frame is known to, not how well the walls pin
    the overlap (which weighs the links when they are solved). ``cache``: as
    :func:`drift_covs`'."""
    linked = {n: p for n, p in placements.items() if p.via != PRIOR}
    if graph:
        keys = [k for k in edges if k[0] in linked and k[1] in linked]
    else:
        keys = set()
        for p in linked.values():
            for a, b in zip(p.path, p.path[1:]):
                keys.add((a, b) if (a, b) in edges else (b, a))
        keys = sorted(k for k in keys if k in edges)
    keys = [k for k in keys if edges[k].cov is not None]
    # the robots those links tie to the reference (the others' information would be singular)
    tied, grew = {ref}, True
    while grew:
        grew = False
        for a, b in keys:
            if (a in tied) != (b in tied):
                tied.update((a, b))
                grew = True
    keys = [k for k in keys if k[0] in tied]
    links = [(a, b, edges[(a, b)].T, 1.0) for a, b in keys]
    covs = posegraph.covariances({n: p.T for n, p in linked.items() if n in tied}, links, ref,
                                 drift_covs(config, edges, links, cache))
    for n, p in placements.items():
        if n == ref:
            p.cov, p.weak_reason = None, ''
            continue
        p.cov = covs.get(n)
        p.weak_reason = weak_reason(p, config.max_position_sigma)


def weak_reason(p: Placement, max_position_sigma: float) -> str:
    """Why a placement (not the reference's) is weakly pinned, for people; '' when it is not:
    placed at its prior, or its covariance unknown, or its 2-sigma position (worst direction,
    metres) over ``max_position_sigma`` (metres)."""
    if p.via == PRIOR:
        return AT_PRIOR
    if p.cov is None:
        return 'its covariance is unknown (a link on its chain has none)'
    sigma = position_sigma(p.cov)
    if 2.0 * sigma > max_position_sigma:
        return '2-sigma %.3f m > max_position_sigma %.3f m' % (2.0 * sigma, max_position_sigma)
    return ''


def add_priors(config: MergeConfig, best: Dict[str, Placement], names: Iterable[str], ref: str,
               priors: Dict[str, List[float]]) -> None:
    """Robots of ``names`` with no placement, placed at their prior (``priors``: robot ->
    ``[x, y, yaw]``, the priors in use, :meth:`MapMerger.priors`) relative to the reference's,
    when ``trust_initial_poses`` is set."""
    if config.trust_initial_poses and ref in priors:
        for n in names:
            if n not in best and n in priors:
                T = inverse(se2(*priors[ref])) @ se2(*priors[n])
                best[n] = Placement(T, 0.0, 0.0, 0, PRIOR, (ref, n), time.time(),
                                    weak_reason=AT_PRIOR)


def hysteresis(config: MergeConfig, best: Dict[str, Placement], old: Dict[str, Placement],
               edges: Links, ref: str,
               regraphed: bool) -> Tuple[Dict[str, Placement], Dict[str, str]]:
    """(the placements to adopt, events: per robot merged or improved, what to tell): per robot
    the kept placement stays while its chain holds, unless the new one is more reliable by
    ``replace_margin`` or the pose graph was solved anew (it moves every robot it places); a
    :attr:`Placement.provisional` one never stays."""
    new: Dict[str, Placement] = {}
    events: Dict[str, str] = {}
    for n, pl in best.items():
        prev = old.get(n)
        still_linked = prev is not None and (prev.via == PRIOR or chain_holds(prev, edges))
        if (prev is not None and still_linked and not prev.provisional
                and pl.inlier_ratio <= prev.inlier_ratio + config.replace_margin
                and not (regraphed and pl.via != PRIOR)):
            new[n] = prev
            continue
        new[n] = pl
        if n == ref:
            continue
        x, y, yaw = xyyaw(pl.T)
        what = ('merged' if prev is None else 'placement refined' if prev.provisional
                else 'transform improved')
        events[n] = ('%s %s via %s: x=%.3f m y=%.3f m yaw=%.2f deg, inlier ratio %.3f, agreement %.3f, '
                     'inliers %d' % (n, what, pl.via, x, y, math.degrees(yaw), pl.inlier_ratio, pl.agreement,
                                     pl.inliers))
    return new, events


def chain_holds(pl: Placement, edges: Links) -> bool:
    """The links a placement was made of are all still kept and still say where it is: a link
    replaced by a different solution (a look-alike corrected) moves the robot. The tolerance
    allows for links estimated again as their maps grow. A placement the pose graph moved off
    its chain is checked against the pose the chain gave then (``chain_T``)."""
    T = np.eye(3)
    for p, q in zip(pl.path, pl.path[1:]):
        e = edges.get((p, q)) or edges.get((q, p))
        if e is None:
            return False
        T = T @ e.towards(p)
    return within(T, pl.chain_T if pl.chain_T is not None else pl.T,
                  (GRAPH_GATE[0] + SAME_LINK[0], GRAPH_GATE[1] + SAME_LINK[1]))
