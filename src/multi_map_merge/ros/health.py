"""What the node says of its inputs and of its estimation: robots whose map publisher went away
(vanished) or whose maps stopped (stale, none for over ``~stale_map_timeout``), in the log once
each, and on /diagnostics (through :class:`updater.Updater`) the node's own status and one per
robot (the texts: :mod:`diagnostics`)."""
from __future__ import annotations

import functools
import time
from typing import Container, Dict, Optional

import rospy

from ..core.merger import MapMerger
from ..node_config import NodeConfig
from .diagnostics import node_diagnostic, robot_diagnostic, stale_maps
from .updater import Updater


class NodeHealth:
    """The robots' and the node's status for ``merger``; ``diagnostic_period`` and
    ``given_period``: :class:`updater.Updater`'s."""

    def __init__(self, merger: MapMerger, config: NodeConfig, diagnostic_period: float = 1.0,
                 given_period=1.0):
        self.merger = merger
        self.cfg = config
        self.gone: Dict[str, bool] = {}   # robot -> its map publisher went away
        self._stale: set = set()          # robots whose maps stopped (logged once)
        self._started = time.time()       # (wall seconds: how long a robot of ~robots has been silent)
        self.est_seconds = 0.0            # how long the last estimation cycle took
        self.est_error: Optional[BaseException] = None   # what the last estimation cycle raised
        # /diagnostics: the node's status and one per robot (added as robots appear), at
        # ~diagnostic_period (the updater's parameter, 1 s by default)
        self._updater = Updater(diagnostic_period, given_period)
        self._updater.setHardwareID(rospy.get_name().lstrip('/'))
        self._updater.add('node', self._node_diagnostic)
        self._robots: set = set()

    def start(self) -> None:
        """Publish /diagnostics from now on."""
        rospy.Timer(rospy.Duration(0.2), self._update)

    def estimated(self, seconds: float, error: Optional[BaseException]) -> None:
        """An estimation cycle took ``seconds`` and raised ``error`` (None: it did not)."""
        failed_before = self.est_error is not None
        self.est_error = error
        self.est_seconds = seconds
        if (error is not None) != failed_before:
            self._updater.force_update()   # the node's status changed level: say so now

    def watch(self, map_subs: Dict[str, rospy.Subscriber], with_map: Container[str]) -> None:
        """Log a robot whose map publisher went away, or whose maps stopped, and its return
        (``map_subs``: robot -> the subscriber of its map; ``with_map``: the robots a map of which
        was accepted). Its last map and transform stay in the merge: what it mapped is still
        true."""
        for robot, map_sub in map_subs.items():
            gone = map_sub.get_num_connections() == 0 and robot in with_map
            if gone and not self.gone.get(robot):
                rospy.logwarn('multi_map_merge: robot %s vanished (no publisher of %s): keeping its '
                              'last map and transform', robot, map_sub.name)
            elif not gone and self.gone.get(robot):
                rospy.loginfo('multi_map_merge: robot %s is back', robot)
            self.gone[robot] = gone
        stale = stale_maps(self.merger.status(), self.gone, time.time(), self.cfg.stale_map_timeout)
        for robot, age in sorted(stale.items()):
            if robot not in self._stale:
                rospy.logwarn('multi_map_merge: no map of robot %s for %.0f s (over ~stale_map_timeout, %g s), '
                              'though %s still has a publisher: keeping its last map and transform',
                              robot, age, self.cfg.stale_map_timeout, map_subs[robot].name if robot in map_subs
                              else 'its map topic')
        for robot in sorted(self._stale - set(stale)):
            if not self.gone.get(robot):
                rospy.loginfo('multi_map_merge: maps of robot %s arrive again', robot)
        self._stale = set(stale)

    def _update(self, _event) -> None:
        """Give every robot seen a status of its own, then let the updater publish (it does at
        ~diagnostic_period)."""
        for robot in self.merger.status():
            if robot not in self._robots:
                self._robots.add(robot)
                self._updater.add(robot, functools.partial(self._robot_diagnostic, robot))
        self._updater.update()

    def _robot_diagnostic(self, robot: str, stat):
        st = self.merger.status().get(robot)
        if st is None:   # (robots are never forgotten by the node: kept for completeness)
            stat.summary(stat.WARN, 'no longer known')
            stat.hardware_id = robot
            return stat
        return robot_diagnostic(robot, st, bool(self.gone.get(robot)), time.time(), stat,
                                stale_map_timeout=self.cfg.stale_map_timeout)

    def _node_diagnostic(self, stat):
        now = time.time()
        waited = now - self._started
        # robots of ~robots that never sent a map, once that is as long as a stopped map's
        silent = {r: waited for r in self.cfg.robots} if (
            self.cfg.stale_map_timeout > 0 and waited > self.cfg.stale_map_timeout) else {}
        return node_diagnostic(self.merger.status(), self.gone, self.est_seconds, self.est_error,
                               len(self.merger.frames()), len(self.merger.placements()), stat,
                               now, self.cfg.stale_map_timeout, silent)
