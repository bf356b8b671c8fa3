"""A bag replay paced by the live SLAM nodes it feeds (not a test itself), for the rostests that
play a bag into ``rbpf_slam`` or ``slam_gmapping``, and their verdict on whether each SLAM kept up.

A live SLAM takes its scans from a subscriber queue of 5 and drops the oldest while it is busy.
On a robot it keeps up; a replay on a loaded machine (a parallel compile, other tests) plays
faster than the SLAM can follow, the SLAM drops scans and its map, and the merge of such maps,
are not a robot's: a test of the merger then fails for the machine's load. :class:`ReplayPacer`
holds the playback (``rosbag play``'s ``~pause_playback`` service) while a robot's SLAM has
:data:`MAX_LAG` or more of the scans played since it was last idle still to take, and lets it go
on once each lagging SLAM has taken them or gone idle. A SLAM's progress is read from its own
lines, ``update frame N`` per processed scan (N: the scans that reached its update rule, before
this one), in the stdout log roslaunch writes with ``output="log"``; whether it is busy, from its
process's CPU time (``/proc/<pid>/stat``), over the last :data:`BUSY_WINDOW_S`.

:func:`keep_up_failures` then says, from the same logs and the bag, which SLAM could not keep up
anyway (``lab.scans_processed``'s counts), in the line a test fails with before it judges the
merge: ``SLAM could not keep up: tb3_1 processed 180 of the 266 scans its update rule asks for``."""
import glob
import os
import re
import threading
import time
import xmlrpc.client
from typing import Dict, List, Optional, Sequence

import rosgraph
import rospy
from std_srvs.srv import SetBool

from multi_map_merge.lab.scans_processed import SLAM_NODES, report

#: scans played since a SLAM was last idle and not yet taken by it, at which the playback is held
#: (its queue holds 5: at 2 none is dropped, with scans to spare for the hold to take effect)
MAX_LAG = 2
#: wall seconds of CPU history that tell a busy SLAM from an idle one
BUSY_WINDOW_S = 0.25
#: the share of one core a SLAM uses over BUSY_WINDOW_S when busy (idle, its TF thread uses ~1 %)
BUSY_SHARE = 0.08
POLL_S = 0.02
#: wall seconds the playback is held at most at once: a SLAM that hangs must not stall the test
MAX_HOLD_S = 20.0
#: the least share of the scans its update rule asks for that a SLAM must process (as run_demo's)
MIN_SHARE = 0.9
UPDATE_LINE = re.compile(rb'^update frame (\d+)\s*$')
CLOCK_TICK_S = 1.0 / os.sysconf('SC_CLK_TCK')


class _Slam:
    """One robot's SLAM as the pacer sees it: scans played to it, its log read so far, its CPU."""

    def __init__(self, robot: str):
        self.robot = robot
        self.played = 0          # scans the bag played on its topic (seen by the pacer)
        self.received = 0        # scans that reached its update rule (its last line's N + 1)
        self.processed = 0       # its update lines
        self.baseline = 0        # played - received when it was last idle: never to be received
        self.log = None          # (file, its unread tail)
        self.pid = None
        self.pid_asked = 0.0     # when the master was last asked for its process (monotonic s)
        self.cpu = []            # (wall s, CPU s) samples within BUSY_WINDOW_S

    def lag(self) -> int:
        return self.played - self.received - self.baseline


class ReplayPacer:
    """Holds the playback of ``players`` (rosbag play nodes, all at once: bags played as one
    team stay together) while a robot's SLAM lags (see the module). ``log_dir``: the ROS_LOG_DIR of
    the launch that runs the SLAM nodes; ``scan_topic``: the bag's scans, with ``{robot}``. Use as
    a context manager around the replay; :attr:`holds` and :attr:`held_s` say how often and how
    long it held the playback."""

    def __init__(self, robots: Sequence[str], log_dir: str, players: Sequence[str] = ('/rosbag_play',),
                 scan_topic: str = '/{robot}/scan', topics: Optional[Dict[str, str]] = None):
        self.slams = {r: _Slam(r) for r in robots}
        self.log_dir = log_dir
        self.services = [p.rstrip('/') + '/pause_playback' for p in players]
        # robot -> the bag's topic of its scans (``topics``: a SLAM fed another robot's, e.g. tb3_0_norelay)
        self.topics = {r: (topics or {}).get(r, scan_topic.format(robot=r)) for r in robots}
        self.holds = 0
        self.held_s = 0.0
        self.longest_hold_s = 0.0
        self.gave_up = 0          # holds ended by MAX_HOLD_S
        self._held_since: Optional[float] = None
        self._pause = {}          # service -> its proxy
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wake = threading.Event()   # a scan played while its SLAM lags: look now
        self._subs = []
        self._thread = threading.Thread(target=self._run, name='replay-pacer', daemon=True)

    def __enter__(self):
        from rospy import AnyMsg
        for r, s in self.slams.items():
            self._subs.append(rospy.Subscriber(self.topics[r], AnyMsg, self._on_scan,
                                               callback_args=s, queue_size=100))
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._wake.set()
        self._thread.join(5.0)
        for sub in self._subs:
            sub.unregister()
        if self._held_since is not None:
            self._set_paused(False)
        return False

    def summary(self) -> str:
        seen = ', '.join('%s %d played, %d reached its SLAM%s' % (s.robot, s.played, s.received,
                                                                  '' if s.pid else ' (no process found)')
                         for s in self.slams.values())
        return ('replay paced by its SLAM nodes: playback held %d times, %.1f s in all (longest %.1f s%s); %s'
                % (self.holds, self.held_s, self.longest_hold_s,
                   '; %d holds ended after %.0f s' % (self.gave_up, MAX_HOLD_S) if self.gave_up else '', seen))

    # -- what the pacer reads
    def _on_scan(self, _msg, slam: _Slam) -> None:
        with self._lock:
            slam.played += 1
            lagging = slam.lag() >= MAX_LAG
        if lagging and self._held_since is None:
            self._wake.set()      # hold at once, not at the next poll: at a high rate scans come faster

    def _read_log(self, s: _Slam) -> None:
        if s.log is None:
            paths = [p for node in SLAM_NODES
                     for p in glob.glob(os.path.join(self.log_dir, '**', '%s-%s-*-stdout.log' % (s.robot, node)),
                                        recursive=True)]
            if not paths:
                return
            s.log = [open(sorted(paths, key=os.path.getmtime)[-1], 'rb'), b'']
        f, tail = s.log
        data = tail + f.read()
        lines = data.split(b'\n')
        s.log[1] = lines.pop()     # an unfinished last line waits for its end
        for line in lines:
            m = UPDATE_LINE.match(line)
            if m:
                s.received = int(m.group(1)) + 1
                s.processed += 1

    def _busy(self, s: _Slam, now: float) -> bool:
        if s.pid is None:
            if now - s.pid_asked < 1.0:     # (not registered yet: the master is asked once a second)
                return False
            s.pid_asked = now
            s.pid = _node_pid(['/%s/%s' % (s.robot, n) for n in SLAM_NODES])
            if s.pid is None:
                return False
        try:
            with open('/proc/%d/stat' % s.pid) as f:
                fields = f.read().rsplit(')', 1)[1].split()
            cpu = (int(fields[11]) + int(fields[12])) * CLOCK_TICK_S      # utime + stime
        except (OSError, IndexError, ValueError):
            return False
        s.cpu.append((now, cpu))
        while len(s.cpu) > 2 and now - s.cpu[1][0] >= BUSY_WINDOW_S:
            s.cpu.pop(0)
        (t0, c0), (t1, c1) = s.cpu[0], s.cpu[-1]
        return t1 - t0 > 0 and (c1 - c0) / (t1 - t0) >= BUSY_SHARE

    def _set_paused(self, paused: bool) -> None:
        done = 0
        for name in self.services:
            try:
                if name not in self._pause:
                    rospy.wait_for_service(name, timeout=1.0)
                    self._pause[name] = rospy.ServiceProxy(name, SetBool)
                self._pause[name](paused)
                done += 1
            except (rospy.ROSException, rospy.ServiceException):
                self._pause.pop(name, None)    # the player is not (or no longer) there: nothing to hold
        if not done:
            return
        now = time.monotonic()
        if paused:
            self.holds += 1
            self._held_since = now
        elif self._held_since is not None:
            held = now - self._held_since
            self.held_s += held
            self.longest_hold_s = max(self.longest_hold_s, held)
            self._held_since = None

    def _run(self) -> None:
        while not self._stop.is_set() and not rospy.is_shutdown():
            self._wake.wait(POLL_S)
            self._wake.clear()
            now = time.monotonic()
            lagging = False
            for s in self.slams.values():
                try:
                    self._read_log(s)
                except OSError:
                    continue
                busy = self._busy(s, now)
                with self._lock:
                    if not busy:      # what it has not taken by now, it never will (dropped, or no line)
                        s.baseline = s.played - s.received
                    lagging |= s.lag() >= MAX_LAG
            if self._held_since is None and lagging:
                self._set_paused(True)
            elif self._held_since is not None and (not lagging or now - self._held_since > MAX_HOLD_S):
                self.gave_up += lagging
                self._set_paused(False)


def _node_pid(names: Sequence[str]) -> Optional[int]:
    """The process id of the first of ``names`` (ROS nodes) the master knows; None if none."""
    master = rosgraph.Master('/replay_pacer')
    for n in names:
        try:
            return int(xmlrpc.client.ServerProxy(master.lookupNode(n)).getPid('/replay_pacer')[2])
        except Exception:     # not registered (yet), or gone
            continue
    return None


def keep_up_failures(bag: str, log_dir: str, robots: Sequence[str], rule: Dict[str, float], label: str = '',
                     scan_topic: str = '/{robot}/scan', odom_topic: str = '/{robot}/odom',
                     need_log: bool = True) -> List[str]:
    """Per robot whose SLAM processed under MIN_SHARE of the scans its update rule asks for (or
    left no log under ``log_dir``, unless not ``need_log``: a SLAM run elsewhere), the line a test
    fails with; empty when every SLAM kept up. Prints each robot's counts
    (:func:`lab.scans_processed.report`)."""
    return [keep_up_line(row['robot'], row['processed'], row['expected'], row['received'], row['scans'])
            for row in report(bag, log_dir, robots, rule, MIN_SHARE, label, scan_topic, odom_topic)
            if not row['kept_up'] and (need_log or row['processed'] is not None)]


def keep_up_line(robot: str, processed: Optional[int], expected: int, received: Optional[int], played: int) -> str:
    """The line a test fails with when ``robot``'s SLAM processed under MIN_SHARE of the
    ``expected`` scans (None: it left no log)."""
    return ('SLAM could not keep up: %s processed %s of the %d scans its update rule asks for (%s of the %d '
            'played reached it): the machine is too busy for this replay; the merge was not judged'
            % (robot, processed, expected, received, played))
