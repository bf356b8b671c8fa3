"""Verified links between robots' map frames, and when a pair's new result replaces a kept link.

The paper keeps the most reliable transform (the highest inlier ratio). Two refinements of
that rule, because inlier ratios fall as maps grow (more features, more outliers):

* the kept link, found again on grown maps (within SAME_LINK), takes the new pose when it was
  found on more overlap: the same solution, refined; otherwise early links on small maps stay
  a degree off for ever;
* a different solution replaces the kept link only if the grids, now larger, clearly prefer it
  (:func:`clearly_better`): on a corridor the first link found on small maps can be a
  look-alike a metre along it, whose early inlier ratio the right link never beats.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional, Tuple

import numpy as np

from .config import MergeConfig
from .pair import PairResult
from .transforms import inverse, within

# a link re-estimated within this of the kept one (metres, radians) is the same link refined
SAME_LINK = (0.3, math.radians(3.0))
# a different solution replaces a kept link when it verifies this much better on the grids,
# or when it at least halves the kept link's disagreement (and gains SWITCH_MIN): near 1.0 a
# fixed margin cannot be met even by a clearly better link (0.995 against 0.973)
SWITCH_AGREEMENT = 0.03
SWITCH_MIN = 0.01


@dataclass
class Link:
    """A verified transform between two robots' map frames: ``T`` maps metres in ``child``'s
    frame to metres in ``parent``'s frame. ``cov``: 3x3 covariance of (x, y, yaw) of ``T``
    (metres^2, radians^2; x, y in ``parent``'s frame), from the grids (:mod:`covariance`);
    None when not known (a restored link, walls too few to say)."""

    parent: str
    child: str
    T: np.ndarray
    inlier_ratio: float
    agreement: float
    inliers: int
    matches: int
    stamp: float
    overlap: int = 0      # cells known in both grids when it was estimated
    cov: Optional[np.ndarray] = None
    bend: float = 0.0     # metres the halves of its overlap land apart (core/bend.py); 0 = unknown
    # where it was fitted: the overlap's centre (x, y), metres in the parent's frame (core/drift.py); None = unknown
    centre: Optional[Tuple[float, float]] = None
    # radians each map turned between its origin and the overlap, read off its walls (core/drift.py); None = unread
    parent_turn: Optional[float] = None
    child_turn: Optional[float] = None

    def towards(self, parent: str) -> np.ndarray:
        """Pose of the other robot's frame in ``parent``'s frame."""
        return self.T if parent == self.parent else inverse(self.T)


def replacement(config: MergeConfig, old: Optional[Link], T: np.ndarray, r: PairResult,
                agreement_now: Callable[[], float]) -> Optional[Tuple[float, int]]:
    """Whether an accepted pair result ``r`` (pose ``T`` in metres) replaces the kept link ``old``:
    None to keep ``old``, else the (inlier ratio, inliers) the new link is kept with.
    ``agreement_now()``: the kept link's verification score on the pair's current grids (its
    recorded one was measured on the grids of its time); called only when needed."""
    if old is None or r.inlier_ratio > old.inlier_ratio + config.replace_margin:
        return r.inlier_ratio, r.inliers      # the paper's rule: more reliable
    if same_link(T, old.T):
        if r.overlap <= old.overlap:
            return None
        # the kept link, refined on more overlap: its pose (a small correction, not a jump),
        # the best inlier ratio seen
        return old.inlier_ratio, max(old.inliers, r.inliers)
    if r.overlap >= 0.9 * old.overlap and clearly_better(r.agreement, agreement_now()):
        return r.inlier_ratio, r.inliers      # a different solution the grids clearly prefer
    return None


def clearly_better(new: float, kept: float) -> bool:
    """A new link's agreement beats the kept link's (both on the current grids) by enough to
    switch: SWITCH_AGREEMENT more, or half the disagreement and SWITCH_MIN more."""
    return new >= kept + SWITCH_AGREEMENT or (new >= kept + SWITCH_MIN and 1.0 - new <= 0.5 * (1.0 - kept))


def same_link(T1: np.ndarray, T2: np.ndarray) -> bool:
    """Two estimates of one link that differ by a refinement, not by a different solution."""
    return within(T1, T2, SAME_LINK)
