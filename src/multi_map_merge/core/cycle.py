"""One cycle's view of the team: the maps and the reference as a cycle found them, and whether
what it derives from them is still valid when it comes to keep it (:meth:`Cycle.stale`).

A cycle (``estimate``, ``refresh``) computes outside the merger's lock, on this snapshot, while
maps arrive, robots restart or leave, priors change and the reference settles. What it derives
is kept only if nothing it was derived from changed meanwhile.
"""
from __future__ import annotations

from typing import Dict

from .prior_book import PriorBook
from .robot_map import RobotMap
from .team import Team


class Cycle:
    """The reference ``ref`` and its team's ``maps`` (at the reference's resolution; empty
    before the reference has a map) at the start of a cycle, under the priors' ``epoch``."""

    def __init__(self, team: Team, priors: PriorBook):
        """(under the merger's lock) A snapshot of ``team`` and ``priors``."""
        self._team = team
        self._priors = priors
        self.ref = team.reference
        self.epoch = priors.epoch
        maps = dict(team.maps)
        res = maps[self.ref].raw.resolution if self.ref in maps else None
        self.maps: Dict[str, RobotMap] = {} if res is None else {
            n: m.set_working_resolution(res) for n, m in maps.items()}

    def stale(self, *robots: str) -> bool:
        """(under the merger's lock) Whether a prior changed since the snapshot (what the cycle
        aligned was gated by the former priors), or one of ``robots`` was forgotten meanwhile
        (its map restarted, or it left: its former map must not come back)."""
        return self._priors.epoch != self.epoch or any(
            self._team.from_former_life(self.maps[r]) for r in robots if r in self.maps)

    def void(self) -> bool:
        """(under the merger's lock) Whether placements made in this cycle are void: :meth:`stale`
        for the reference, or another robot became the reference (placements are poses in the
        reference's frame)."""
        return self.stale(self.ref) or self.ref != self._team.reference
