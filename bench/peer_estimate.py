"""m-explore's cold estimation, comparable to ours' ``cold_ms`` (bench/ours.py), from its real
running node (bench/peer.py ``Session``: a master of its own, the maps latched by a feeder).

M-explore estimates
from scratch every estimation cycle (map_merge.cpp ``poseEstimation`` feeds every grid to
combine_grids' ``MergingPipeline::estimateTransforms``: AKAZE features of every map, every pair
matched, the biggest component, affine estimation and bundle adjustment; nothing is kept between
cycles). Its node is run unmodified with its own DEBUG lines on (a rosconsole config for its logger
``ros.multirobot_map_merge``) stamped with the wall time (``ROSCONSOLE_FORMAT`` ``${walltime}``),
``estimation_rate`` 100 Hz (so that cycles run back to back: ``ros::Rate`` does not sleep after a
cycle longer than its period) and ``merging_rate`` 0.01 Hz (no compositing or publishing competes
for the 2 cores). A cycle's estimate time runs from its ``computing features`` line (the grids
fed, inside ``estimateTransforms``) to the next cycle's ``Grid pose estimation started.`` line
(``estimateTransforms`` returned, its lock released); only cycles that started after every map's
``received full map update`` count.
"""
from __future__ import annotations

import os
import re
import signal
import statistics
import tempfile
import time

import peer
from peer import PACKAGE, Session, proc_figures

# m-explore 2.1.4's own DEBUG lines (map_merge.cpp, merging_pipeline.cpp) that time its estimation
CYCLE_START, FEATURES_START = 'Grid pose estimation started.', 'computing features'
MAP_RECEIVED = 'received full map update'
MATCHED = 'calculating transforms in global reference frame'   # a cycle found two maps or more matched
# rosconsole's line: wall time (s.ns), severity, message
LOG_FORMAT = 'MMMT ${walltime} ${severity} ${message}'
# a line of it, whatever rosconsole wraps it in (colour codes on a terminal or not)
LOG_LINE = re.compile(r'MMMT (\d+\.\d+) +[A-Z]+ (.*?)(?:\x1b\[0m)?$')
# the node's rates for the estimation run (Hz): cycles back to back, no compositing in between
ESTIMATION_RATES = {'discovery_rate': 1.0, 'estimation_rate': 100.0, 'merging_rate': 0.01}
ESTIMATION_CYCLES = 9   # as many as ours' 3 processes x 3 cycles on the small rows
SERVER_SECONDS = 86400.0      # the maps' feeder of an EstimateServer: until it is closed
FIRST_CYCLE_SECONDS = 600.0   # the longest wait for a first cycle with every map (16 robots: about a minute)


def estimation_cycles(lines, robots):
    """The complete estimation cycles in m-explore's log ``lines`` (LOG_FORMAT, DEBUG on) that
    started after ``robots`` maps had arrived: [{'start', 'features', 'end' (wall s), 'estimate_ms'
    (its ``computing features`` line to the next cycle's start: ``estimateTransforms`` of every
    map), 'cycle_ms' (start to the next start: also taking the grids and feeding them), 'matched'
    (it found two maps or more matched and went on to place them)}], in order. Lines of other formats are ignored."""
    events = []
    for line in lines:
        m = LOG_LINE.search(line)
        if m:
            events.append((float(m.group(1)), m.group(2).strip()))
    received, cycles, current = 0, [], None
    for t, msg in events:
        if msg == MAP_RECEIVED:
            received += 1
        elif msg == CYCLE_START:
            if current is not None and current.get('features') is not None:
                cycles.append(dict(current, end=t, estimate_ms=(t - current['features']) * 1000.0,
                                   cycle_ms=(t - current['start']) * 1000.0))
            current = {'start': t, 'features': None, 'matched': False} if received >= robots else None
        elif msg == FEATURES_START and current is not None:
            current['features'] = t
        elif msg == MATCHED and current is not None:
            current['matched'] = True
    return cycles


def start(paths, max_seconds, work):
    """m-explore's node on ``paths`` as this module runs it (DEBUG lines with the wall time,
    ESTIMATION_RATES), its maps' feeder for at most ``max_seconds`` + 30 s: a peer.Session (its ``why`` set when it did
    not start)."""
    os.makedirs(work, exist_ok=True)
    config = os.path.join(work, 'rosconsole.config')
    with open(config, 'w') as f:
        f.write('log4j.logger.ros=INFO\nlog4j.logger.ros.%s=DEBUG\n' % PACKAGE)
    args = ['_known_init_poses:=false'] + ['_%s:=%s' % kv for kv in ESTIMATION_RATES.items()]
    node_env = {'ROSCONSOLE_CONFIG_FILE': config, 'ROSCONSOLE_FORMAT': LOG_FORMAT,
                'ROSCONSOLE_STDOUT_LINE_BUFFERED': '1'}
    return Session(paths, None, max_seconds + 30.0, 0.0, work, False, args, node_env)


def _cycles(session, robots):
    with open(session.log.name) as f:
        return estimation_cycles(f, robots)


def run_estimation(paths, cycles=None, max_seconds=120.0, out_dir=None):
    """m-explore's cold estimation on the maps ``paths``, timed from its own log (see the
    module's docstring): its node started with ``known_init_poses`` false and ESTIMATION_RATES,
    stopped after ``cycles`` (ESTIMATION_CYCLES when None) complete cycles with every map (or
    after ``max_seconds`` with at least one; the first is waited for up to FIRST_CYCLE_SECONDS).
    Returns {'estimate_ms': median over the cycles, 'estimate_first_ms': the first cycle with
    every map, 'estimate_runs_ms', 'cycle_ms' (median, with taking and feeding the grids),
    'cycles', 'matched_cycles' (cycles that found maps matched), 'rss_mb', 'cpu_s' (the node's,
    at its end), 'log'} or {'invalid': why}; times in ms of the wall clock."""
    ok, why = peer.available()
    if not ok:
        return {'invalid': why}
    cycles = cycles or ESTIMATION_CYCLES
    s = start(paths, max(max_seconds, FIRST_CYCLE_SECONDS), out_dir or tempfile.mkdtemp(prefix='mmm_mexplore_est_'))
    try:
        if s.why:
            return {'invalid': s.why}
        got = []
        t_end, t_last = s.t0 + max_seconds, s.t0 + max(max_seconds, FIRST_CYCLE_SECONDS)
        while len(got) < cycles and time.time() < (t_end if got else t_last):
            if s.node.poll() is not None:
                return {'invalid': 'm-explore\'s node exited (%s, see %s)' % (s.node.returncode, s.log.name)}
            time.sleep(0.2)
            got = _cycles(s, len(paths))
        cpu, rss = proc_figures(s.node.pid)
    finally:
        s.close()
    if not got:
        return {'invalid': 'no complete estimation cycle of m-explore with all %d maps within %.0f s: '
                           'INVALID (%s)' % (len(paths), max(max_seconds, FIRST_CYCLE_SECONDS), s.log.name)}
    got = got[:cycles]
    est = [c['estimate_ms'] for c in got]
    return {'estimate_ms': float(statistics.median(est)), 'estimate_first_ms': est[0], 'estimate_runs_ms': est,
            'cycle_ms': float(statistics.median(c['cycle_ms'] for c in got)), 'cycles': len(got),
            'matched_cycles': sum(1 for c in got if c['matched']),
            'rss_mb': rss, 'cpu_s': cpu, 'log': s.log.name}


class EstimateServer:
    """m-explore's side of bench/duel.py: its node, held stopped (SIGSTOP) between bursts; a burst
    lets it run (SIGCONT) until one estimation cycle that started after it resumed has ended,
    then stops it again, and returns {'ms': that cycle's estimate_ms, 'matched': ...}. The cycle
    in progress when it was stopped, which spans the pause, never counts: a burst takes up to two
    cycles, and fails after 3 times the first cycle's length + 60 s. ``ready`` is False with
    ``why`` when the node gave no cycle with every map within ``max_seconds``."""

    def __init__(self, paths, work, max_seconds=FIRST_CYCLE_SECONDS):
        self.robots, self.burst_seconds = len(paths), 120.0
        self.s = start(paths, SERVER_SECONDS, work)
        self.ready, self.why = False, self.s.why
        if self.why:
            return
        t_end = self.s.t0 + max_seconds
        while time.time() < t_end and self.s.node.poll() is None:
            got = _cycles(self.s, self.robots)
            if got:
                self.s.node.send_signal(signal.SIGSTOP)
                self.ready = True
                self.burst_seconds = 3 * got[0]['cycle_ms'] / 1000.0 + 60.0
                return
            time.sleep(0.05)
        self.why = 'no estimation cycle of m-explore with all %d maps within %.0f s (%s)' % (
            self.robots, max_seconds, self.s.log.name)

    def burst(self):
        t_cont = time.time()
        self.s.node.send_signal(signal.SIGCONT)
        try:
            while time.time() < t_cont + self.burst_seconds:
                if self.s.node.poll() is not None:
                    raise RuntimeError('m-explore\'s node exited (%s)' % self.s.log.name)
                done = [c for c in _cycles(self.s, self.robots) if c['start'] >= t_cont]
                if done:
                    return {'ms': done[0]['estimate_ms'], 'matched': done[0]['matched']}
                time.sleep(0.01)
            raise RuntimeError('no m-explore estimation cycle within %.0f s (%s)' % (self.burst_seconds,
                                                                                     self.s.log.name))
        finally:
            self.s.node.send_signal(signal.SIGSTOP)

    def close(self):
        if self.s.node is not None and self.s.node.poll() is None:
            self.s.node.send_signal(signal.SIGCONT)    # so that it can take its SIGINT
        self.s.close()


def available():
    """bench/peer.py ``available``: (True, '') or (False, why)."""
    return peer.available()
