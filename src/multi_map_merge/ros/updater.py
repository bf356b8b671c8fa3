"""The node's ``diagnostic_updater.Updater``: ``~diagnostic_period`` checked as the node's own
parameters are."""
from __future__ import annotations

import diagnostic_updater
import rospy

from .params import check_library_param


class Updater(diagnostic_updater.Updater):
    """diagnostic_updater's Updater, whose ``~diagnostic_period`` (read again from the parameter
    server 4 times a second) is checked as the node's own parameters are: a bad value ('abc',
    0, a list) is logged once and the last good period kept, where the library would raise at
    every update and /diagnostics go silent."""

    def __init__(self, period: float, given):
        super().__init__()
        self.period = period
        self._given = given     # the value last read (an invalid one is logged once)

    def _check_diagnostic_period(self) -> None:
        now = rospy.Time.now()
        if now < self.last_time_period_checked + rospy.Duration(0.25):
            return
        try:
            given = rospy.get_param_cached('~diagnostic_period', 1.0)
        except Exception:   # the master gone for a moment: keep the period
            return
        self.last_time_period_checked = now
        if repr(given) == repr(self._given):   # (repr: nan is not equal to itself)
            return
        self._given = given
        period, error = check_library_param('diagnostic_period', given)
        if error:
            rospy.logerr('multi_map_merge: %s (keeping %g s)', error, self.period)
        else:
            self.period = period
