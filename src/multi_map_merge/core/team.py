"""The team: every robot's latest map, its versions and restarts, the last error of its input, and
which robot is the reference (the merged frame is its map frame).

Not thread-safe: its owner (:class:`merger.MapMerger`) calls it under its one lock. What a
robot forgotten (its map restarted, or it left) or a new reference means for the merger's other
parts, each carries out itself: the team tells its :attr:`Team.listeners` (:class:`TeamListener`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from .grid import Grid, same_grid
from .robot_map import RobotMap

#: why the reference robot is the one it is (:meth:`MapMerger.reference_choice`)
REF_PARAMETER = 'parameter'          # config.reference_robot
REF_PROPOSED = 'proposed'            # propose_reference (the first of config.robots by name)
REF_FIRST_BY_NAME = 'first by name'  # decide_reference


def decide_reference(current: str, fixed: bool, with_maps: Sequence[str],
                     placed: Sequence[str]) -> Tuple[str, bool]:
    """(the reference robot, whether it is fixed from now on) when none was given: the first
    by name among the robots ``with_maps`` while the merge is the reference's map alone (none
    of the robots ``placed`` relative to ``current`` is another robot); fixed once another is,
    so that no transform published with a merge ever jumps. The same robots give the same
    reference whichever map came first (a later map of a lower name takes the reference over
    only while nothing else is merged). A ``fixed`` reference stays."""
    if fixed:
        return current, True
    if current and any(n != current for n in placed):
        return current, True
    return (min(with_maps) if with_maps else ''), False


@dataclass
class ReferenceChoice:
    """Which robot is the reference, whether it can still change, and why it is that one."""

    robot: str
    fixed: bool
    why: str                           # REF_PARAMETER, REF_PROPOSED or REF_FIRST_BY_NAME
    with_maps: Tuple[str, ...] = ()    # the robots with a map, by name

    def message(self) -> str:
        """Which robot is the reference (the merged frame is its map frame), why, and how to
        choose it (the node's ``~reference_robot``), for people; '' before there is one."""
        ref = self.robot
        if not ref:
            return ''
        if self.why == REF_PARAMETER:
            return 'reference robot %s (set by ~reference_robot): the merged frame is its map frame' % ref
        if self.why == REF_PROPOSED:
            return ('reference robot %s (the first of ~robots by name; set ~reference_robot to choose '
                    'another): the merged frame is its map frame' % ref)
        others = ', '.join(self.with_maps)
        if not self.fixed:
            return ('reference robot %s for now (the first by name among the robots with a map: %s): the '
                    'merged frame is its map frame; a robot of a lower name whose map comes before another '
                    'robot is merged with %s takes it over; set ~reference_robot to fix it' % (ref, others, ref))
        return ('reference robot %s, fixed now that another robot is merged with it (it was the first by name '
                'among the robots with a map: %s; a robot whose map comes later does not take the merged '
                'frame over): set ~reference_robot: %s for the same merged frame in every run'
                % (ref, others, ref))


class TeamListener:
    """A part of the merger told of the team's changes (under the merger's lock)."""

    def robot_forgotten(self, name: str, reference: bool) -> None:
        """Robot ``name`` was forgotten (its map restarted, or it left); ``reference``: it is the
        reference, whose map frame is the merged frame."""

    def reference_moved(self, old: str, new: str, has_map: bool) -> None:
        """The reference robot is ``new`` now (``old`` before, '' for none); ``has_map``: ``new``
        has a map."""


class Team:
    """The robots' maps and the reference robot (see the module's docstring)."""

    def __init__(self, reference_robot: str = '', robots: Sequence[str] = ()):
        """``reference_robot``: fixed (the parameter); else, with ``robots`` listed, the first of
        them by name; else the first by name among the robots with a map (:meth:`settle`)."""
        self.maps: Dict[str, RobotMap] = {}
        self.errors: Dict[str, str] = {}      # per robot: why its last input was refused
        self.reference = reference_robot
        self.fixed = bool(reference_robot)    # decide_reference: settled for good
        self.why = REF_PARAMETER if reference_robot else REF_FIRST_BY_NAME
        self._version = 0                     # of the last map taken, across the team
        self._lives: Dict[str, int] = {}      # per robot: how often it was forgotten
        self.listeners: List[TeamListener] = []
        if robots:
            self.propose(sorted(r.strip('/') for r in robots)[0])

    def update(self, name: str, grid: Grid, placed: Mapping[str, object]) -> Tuple[bool, Optional[str]]:
        """``grid`` as robot ``name``'s map: (whether it is a new version, not its map republished
        unchanged; what to tell when it is a new map, not its map grown: :meth:`restart`, the
        robot forgotten first). A robot new to the team settles the reference (:meth:`settle`,
        ``placed``: the robots placed)."""
        if self.republished(name, grid):
            return False, None
        new = name not in self.maps
        event = self.restart(name, grid)
        if event:
            self.forget(name)
        self.take(name, grid)
        if new:
            self.settle(list(placed))
        return True, event

    def remove(self, name: str, placed: Mapping[str, object]) -> None:
        """Robot ``name`` leaves the team: forgotten, and the reference settled again."""
        self.maps.pop(name, None)
        self.forget(name)
        self.settle(list(placed))

    def republished(self, name: str, grid: Grid) -> bool:
        """Whether ``grid`` is the robot's map as it is (republished unchanged): then only its
        time of arrival and its input's error change."""
        prev = self.maps.get(name)
        if prev is None or not same_grid(prev.raw, grid):
            return False
        prev.received = time.time()
        self.errors.pop(name, None)
        return True

    def restart(self, name: str, grid: Grid) -> Optional[str]:
        """What to tell when ``grid`` is a new map of the robot, not its map grown (gmapping
        reset: :func:`restarted`); None when it is not."""
        prev = self.maps.get(name)
        if prev is None or not restarted(prev.raw, grid):
            return None
        return ('map of %s restarted (%dx%d cells -> %dx%d): its transform is forgotten and will be '
                'estimated again' % (name, prev.raw.width, prev.raw.height, grid.width, grid.height))

    def take(self, name: str, grid: Grid) -> RobotMap:
        """``grid`` as the robot's latest map, a new version."""
        self._version += 1
        m = self.maps[name] = RobotMap(name, grid, self._version, time.time(), life=self._lives.get(name, 0))
        self.errors.pop(name, None)
        return m

    def forget(self, name: str) -> None:
        """The robot is forgotten (its map restarted, or it left): what a cycle under way derives
        from its former maps must not come back (:meth:`from_former_life`); the listeners are told."""
        self._lives[name] = self._lives.get(name, 0) + 1
        for part in self.listeners:
            part.robot_forgotten(name, name == self.reference)

    def from_former_life(self, m: RobotMap) -> bool:
        """True when ``m`` (from a cycle's snapshot) is a map the robot had before it was
        forgotten (its map restarted, or it was removed) while the cycle ran."""
        return self._lives.get(m.name, 0) != m.life

    def propose(self, name: str) -> str:
        """``name`` as the reference for good, unless one is fixed already. The reference."""
        if not self.fixed:
            self.fixed, self.why = True, REF_PROPOSED
            self._set_reference(name)
        return self.reference

    def settle(self, placed: Sequence[str]) -> None:
        """The reference now that the robots ``placed`` are (:func:`decide_reference`)."""
        ref, self.fixed = decide_reference(self.reference, self.fixed, list(self.maps), placed)
        self._set_reference(ref)

    def _set_reference(self, name: str) -> None:
        if name != self.reference:
            old, self.reference = self.reference, name
            for part in self.listeners:
                part.reference_moved(old, name, name in self.maps)

    def choice(self) -> ReferenceChoice:
        return ReferenceChoice(self.reference, self.fixed, self.why, tuple(sorted(self.maps)))

    def frames(self) -> Dict[str, str]:
        """Map frame id of every robot (from its grid's header)."""
        return {n: (m.raw.frame_id or n + '/map') for n, m in self.maps.items()}


def restarted(old: Grid, new: Grid) -> bool:
    """gmapping only ever grows its grid (same or larger, origin moving outwards) and keeps
    what it knew, so a grid that shrank or lost most of its known cells is a new map."""
    if new.width < old.width or new.height < old.height:
        return True
    known_old = int(np.count_nonzero(old.data >= 0))
    known_new = int(np.count_nonzero(new.data >= 0))
    return known_old > 1000 and known_new < 0.5 * known_old

