#!/usr/bin/env python3
"""Scale: teams of 8, 16, 32 and 64 robots whose maps grow live, merged in real time.

    bench/bench.py scale [--sizes 8,16,32,64] [--rounds 3] [--world intel] [--seed 0]
                           [--estimation-rate 0] [--max-minutes 12] [--no-peer]
                           [--results bench/results]

Each team size runs in a fresh process (``--one``, so that its worker pool, caches and memory
are its own) that holds one :class:`MapMerger` with the project's defaults (``NodeConfig()``),
its worker pool started before any thread as the node starts it, and no ROS master.

The robots. Robot k's whole map is a random window of 60% of a ground-truth building
(``../shared/data/ground_truth/<world>_gt.yaml``, by default the Intel lab, through
``pieces.pieces_windows``: every pair of robots overlaps, the worst case for estimation), in a
map frame of its own at a random pose (``random_poses``: the truth, ``T_world_k``, is known).
The robot starts at a random free cell near its window's known centre and its map grows as
gmapping's does: a disc around that cell, its radius from ``GROW_FROM`` of the farthest known
cell's distance at its first map to all of it after ``GROW_S`` seconds of robot time, on a
canvas cropped to the known cells plus ``MARGIN`` unknown ones (the canvas and its origin grow
outwards, never shrink: the merger must not take a version for a restart). Every version also
has ``FLIPS`` of its known cells flipped between free and occupied (gmapping's maps keep
changing when nothing new is seen), so that every version is new work for the merger.

The schedule (robot time is wall time: the merger runs in real time against it). Robot k of
the R - 1 robots present from the start publishes its first map at ``5 k / (R - 1)`` s and a new
version every ``PERIOD`` (5) s after that: the robots are staggered over the period. The last
robot, the late joiner, publishes its first map at its own slot of the first period after every
other robot is placed, then a new version every period. The maps are fed, from a thread of
their own, through ``MapMerger.update_map`` as the node's subscribers feed them.

The merger runs as the node runs it, in three threads of this process: estimation cycles
(``estimate()``), each taking the newest maps: by default back to back (the node's estimation
thread with no rate limit: the most cycles a round, the worst case for a round's cost; a cycle
starts as soon as a map arrived since the previous one started: a cycle with nothing new
computes nothing, and waiting for news instead of spinning keeps the CPU for the work
measured), or with ``--estimation-rate`` at the node's ``~estimation_rate`` (0.5 Hz by default:
a cycle starts a period after the one before started, or when it ends if it took longer, and
once a map is new); while no cycle is due, the spare time refreshes the stalest links
(``refresh()``, as the node spends its time between cycles: ``~refresh_links``; back to back a
slice of ``REFRESH_SLICE`` at a time, at a rate until the period ends less the node's margin;
not counted in a round's cost, but a map that arrives during a refresh waits for it, which the
staleness holds); compositing (``compose()``, the node's compositing thread: again after half a merge
period); publishing every merge period (``1 / merge_rate``, 0.5 s: the node's /map timer) the
newest composited grid when it is a new one (``ros.convert.grid_to_msg`` and the message
serialised, as the node sends it; timed without it when rospy is not importable).

Phases. Cold start: from the first map until the end of the first cycle in which every robot
but the joiner is placed (or ``COLD_CAP`` of the size's time without it). Then R update rounds
(``--rounds``): round k is every map version that arrives in the k-th period after the cold
start ended (one new version of every robot). The run stops at the end of the first cycle
after which every round's versions are absorbed and the joiner is placed (or given up on: its
whole window known, ``GROW_S`` after its first map, and three more cycles of the median length
run), once every version of the rounds was published; or at ``--max-minutes`` (checked at the
end of each cycle: a cycle is never cut).

Reported per team size (seconds are wall seconds, errors metres):

  round of updates  the estimation time needed to absorb one new version of every robot's map:
                    over the estimation cycles after the cold start, the sum of their ``estimate()``
                    seconds over the sum, per cycle, of the share of the robots whose map it
                    took anew (a cycle that took a new version of every robot counts 1).
                    Above ``PERIOD`` the merger cannot keep up with the robots.
  staleness         per new version of a robot placed when it arrived (rounds 1..R): from its
                    arrival to the end of the first publication of a merged map that holds it
                    (or a later version of that robot's map), at the robot's kept placement;
                    p50 and p95, and p95 in merge periods (``1 / merge_rate``). Beside it
                    (``placed_*``): until the end of the first estimation cycle that took it,
                    the robot's placement estimated against it (how far estimation lags).
  late joiner       from the joiner's first map's arrival to the end of the first cycle that
                    placed it.
  worst error       at the end of the run, the largest distance between a placed robot's map
                    frame (reference excluded) and the truth, in the reference's frame.
  m-explore         its ``map_merge`` node (``bench/peer.py``), where it is installed
                    (ros-noetic-multirobot-map-merge), on the maps the merger held at the end,
                    ``known_init_poses`` false: the time from its start to its first merged /map
                    (it matches every pair each cycle, so a round of updates costs it at least
                    one such cycle), its CPU and peak RSS; stopped after ``PEER_TIMEOUT`` s and
                    not run at a size whose predicted time (its previous size's, times the
                    square of the ratio of robots: it matches every pair) is longer. Where it is
                    not installed its line says so.

One line per size, in this form (a figure whose condition the run did not create is INVALID
with why):

    scale: R robots: round of updates X s, staleness p50 A s p95 B s (C merge periods),
    late joiner placed in D s, worst placement error E m

and a last line with how a round's cost grew from the smallest size to the largest, as
measured and for maps of equal size (:func:`growth_line`: the teams draw their windows at
random, so the smaller team's maps are not the larger's size on average).

Writes ``<results>/scale.json`` (every estimation cycle and every update, per size) and
``<results>/scale.txt`` (the lines). Needs ``export PATH=/usr/bin:$PATH`` (Debian's python3: cv2,
numpy); no ROS master.
"""
from __future__ import annotations

import argparse
import heapq
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
import results  # noqa: E402
from inputs import REPO, world_map  # noqa: E402

SIZES = (8, 16, 32, 64)
PERIOD = 5.0          # s of robot time between two versions of a robot's map (gmapping's map_update_interval)
GROW_FROM = 0.35      # of the robot's reach (farthest known cell of its window), at its first map
GROW_S = 90.0         # s of robot time until the robot's whole window is known
START_WITHIN = 0.3    # of the window's reach: where a robot may start, from the window's known centre
FLIPS = 200           # known cells flipped free <-> occupied in every version (as bench/soak.py)
REFRESH_SLICE = 0.25  # s: spare time spent refreshing links at a time (a new map waits at most this)
REFRESH_MARGIN = 0.1  # s: the node's refresh ends this long before its next cycle is due (ros/node.py)
MARGIN = 20           # cells of unknown kept around the known box (gmapping's canvas has some)
WINDOW = 0.6          # of the building's known box, per robot (as run_bench.py's intel-sized rows)
COLD_CAP = 0.5        # of --max-minutes: the cold start ends then even if a robot is still unplaced
PEER_TIMEOUT = 300.0  # s: m-explore's run is stopped after this (the 5 minutes)


# ---------------------------------------------------------------- pure helpers (tested)

def stagger(n: int, period: float = PERIOD) -> List[float]:
    """Offsets (s) of ``n`` robots' first maps within one period, evenly staggered."""
    return [period * k / n for k in range(n)] if n else []


def next_slot(offset: float, after: float, period: float = PERIOD) -> float:
    """The first time ``offset + j * period`` (s, j >= 0 an integer) not before ``after``."""
    if after <= offset:
        return offset
    return offset + math.ceil((after - offset) / period - 1e-9) * period


def reveal_fraction(robot_s: float, grow_from: float = GROW_FROM, grow_s: float = GROW_S) -> float:
    """Radius of a robot's known disc, as a fraction of its reach, ``robot_s`` seconds after its
    first map: from ``grow_from`` to 1 over ``grow_s`` seconds, then 1."""
    if grow_s <= 0:
        return 1.0
    return grow_from + (1.0 - grow_from) * min(1.0, max(0.0, robot_s) / grow_s)


def known_crop(known: np.ndarray, margin: int = MARGIN) -> Optional[Tuple[int, int, int, int]]:
    """(row0, row1, col0, col1), half-open, of the known cells plus ``margin`` cells, clipped to
    the array; None when nothing is known."""
    rows = np.flatnonzero(known.any(axis=1))
    if not rows.size:
        return None
    cols = np.flatnonzero(known.any(axis=0))
    h, w = known.shape
    return (max(0, int(rows[0]) - margin), min(h, int(rows[-1]) + 1 + margin),
            max(0, int(cols[0]) - margin), min(w, int(cols[-1]) + 1 + margin))


def percentile(values: Sequence[float], q: float) -> Optional[float]:
    """The ``q``-th percentile (0-100, linear interpolation) of ``values``; None when empty."""
    return float(np.percentile(np.asarray(values, float), q)) if len(values) else None


def absorbed_end(cycles: Sequence[dict], robot: str, version: int, key: str = 'taken') -> Optional[float]:
    """End (s) of the first of ``cycles`` (records in the order they ended: estimation cycles,
    whose 'taken' are the versions ``estimate()`` took, or publications, whose 'shown' are the
    versions the merged map they sent holds) whose ``key`` holds ``robot``'s version
    ``version`` or a later one; None when none does."""
    for c in cycles:
        if c[key].get(robot, -1) >= version:
            return c['end']
    return None


def staleness(updates: Sequence[dict], cycles: Sequence[dict], key: str = 'taken') -> List[Optional[float]]:
    """Per update (a dict with 'robot', 'version', 'arrival'), seconds from its arrival to the
    end of the first of ``cycles`` that holds it (:func:`absorbed_end`); None when none does."""
    out = []
    for u in updates:
        end = absorbed_end(cycles, u['robot'], u['version'], key)
        out.append(None if end is None else end - u['arrival'])
    return out


def new_robots(cycles: Sequence[dict]) -> List[List[str]]:
    """Per cycle, the robots whose map version it took is newer than the one the cycle before
    took (all it took, for the first)."""
    out, before = [], {}
    for c in cycles:
        out.append(sorted(r for r, v in c['taken'].items() if v > before.get(r, -1)))
        before = c['taken']
    return out


def round_cost(cycles: Sequence[dict], start: int = 0) -> Optional[float]:
    """Estimation seconds per round of updates (one new version of every robot): over the
    cycles from index ``start`` on, the sum of their ``estimate()`` seconds ('est_s') over the
    sum of their shares (the robots whose map the cycle took anew, over the robots it held).
    None when no cycle from ``start`` on took anything new."""
    new = new_robots(cycles)
    secs = share = 0.0
    for c, n in list(zip(cycles, new))[start:]:
        if c['taken'] and n:
            secs += c['est_s']
            share += len(n) / float(len(c['taken']))
    return secs / share if share > 0 else None


def rounds_of(updates: Sequence[dict], cold_end: float, rounds: int, period: float = PERIOD) -> List[List[dict]]:
    """The updates of each round 1..``rounds``: round k holds those arriving in
    [cold_end + (k - 1) period, cold_end + k period)."""
    out = [[] for _ in range(rounds)]
    for u in updates:
        k = int(math.floor((u['arrival'] - cold_end) / period))
        if 0 <= k < rounds:
            out[k].append(u)
    return out


def fmt_s(v: Optional[float]) -> str:
    """Seconds for the line: 3 significant figures at most, at least 0.01 s."""
    if v is None:
        return '-'
    if v >= 100:
        return '%.0f' % v
    if v >= 10:
        return '%.1f' % v
    return '%.2f' % v


def summarise(run: dict) -> dict:
    """The figures of one team size's run (``run``: what :func:`run_team` returns) and why any
    of them is INVALID: {'round_s', 'stale_p50_s', 'stale_p95_s', 'stale_p95_periods',
    'stale_p50_periods', 'period_s', 'joiner_s', 'worst_err_m', 'lag_by_round', 'invalid': {figure:
    why}, 'rounds_complete'}."""
    cycles, updates = run['cycles'], run['updates']
    inv = {}
    out = {'invalid': inv}
    placed_end = [r for r in run['placed_end'] if r != run['reference']]
    if not placed_end:
        inv['all'] = 'no robot placed besides the reference (%d robots)' % run['robots']
        return out
    if run['grew_cells'][1] <= run['grew_cells'][0]:
        inv['all'] = ('the maps did not grow: %d known cells per map at the first maps, %d in the last '
                      'taken' % tuple(run['grew_cells']))
        return out
    cold_end = run['cold_end']
    if cold_end is None:
        inv['all'] = 'the run ended (%.0f s) before its cold start did: no cycle placed anyone' % run['wall_s']
        return out
    first = next(i for i, c in enumerate(cycles) if c['start'] >= cold_end) if any(
        c['start'] >= cold_end for c in cycles) else len(cycles)
    after = cycles[first:]
    out['cycle_s'] = float(np.median([c['end'] - c['start'] for c in after])) if after else None
    placed_at = [u for u in updates if u['placed']]
    by_round = rounds_of(placed_at, cold_end, run['rounds'])
    # a round is complete when estimation took every version of it (or a later one)
    complete, samples, lag = 0, [], []
    for k, us in enumerate(by_round):
        est = staleness(us, cycles)
        shown = staleness(us, run['publishes'], 'shown')
        if not us or any(v is None for v in est + shown):
            break
        complete = k + 1
        samples += shown
        lag.append(float(np.median(est)))
    out['rounds_complete'] = complete
    out['lag_by_round'] = lag
    period = run['merge_period_s']
    out['merge_period_s'] = period
    if complete == 0:
        inv['round'] = inv['staleness'] = (
            'the run ended (%.0f s) before round 1 of updates was absorbed' % run['wall_s'])
    else:
        last = max(absorbed_end(cycles, u['robot'], u['version']) for u in by_round[complete - 1])
        used = [c for c in after if c['end'] <= last]
        out['round_s'] = round_cost(cycles[:first + len(used)], first)
        if out['round_s'] is None:
            inv['round'] = 'no cycle after the cold start took a new map'
        # the maps that round cost was spent on: their mean known cells (cost goes with map size)
        out['round_known'] = float(np.mean([u['known'] for us in by_round[:complete] for u in us]))
        out['stale_p50_s'] = percentile(samples, 50)
        out['stale_p95_s'] = percentile(samples, 95)
        out['stale_n'] = len(samples)
        out['stale_p50_periods'] = out['stale_p50_s'] / period
        out['stale_p95_periods'] = out['stale_p95_s'] / period
        est = [v for v in staleness([u for us in by_round[:complete] for u in us], cycles)]
        out['placed_p50_s'], out['placed_p95_s'] = percentile(est, 50), percentile(est, 95)
    j = run['joiner']
    if j['arrival'] is None and j.get('scheduled') is not None:
        inv['joiner'] = 'the run ended (%.0f s) before its first map, due at %.0f s' % (run['wall_s'], j['scheduled'])
    elif j['arrival'] is None:
        inv['joiner'] = 'it never joined: the run ended (%.0f s) before the cold start did' % run['wall_s']
    elif j['placed_end'] is None:
        inv['joiner'] = 'not placed within %.0f s of its first map' % (run['wall_s'] - j['arrival'])
    else:
        out['joiner_s'] = j['placed_end'] - j['arrival']
    errs = [e[0] for r, e in run['errors'].items()]
    out['worst_err_m'] = max(errs) if errs else None
    if not errs:
        inv['error'] = 'no placed robot has a known truth'
    return out


def scale_line(robots: int, s: dict) -> str:
    """The one line of a team size (module docstring), INVALID with why where a figure's
    condition was not created."""
    inv = s.get('invalid', {})
    if 'all' in inv:
        return 'scale: %d robots: INVALID: %s' % (robots, inv['all'])
    rnd = 'INVALID (%s)' % inv['round'] if 'round' in inv else '%s s' % fmt_s(s.get('round_s'))
    if 'staleness' in inv:
        stale = 'staleness INVALID (%s)' % inv['staleness']
    else:
        stale = 'staleness p50 %s s p95 %s s (%s merge periods)' % (
            fmt_s(s['stale_p50_s']), fmt_s(s['stale_p95_s']),
            '%.1f' % s['stale_p95_periods'] if s.get('stale_p95_periods') is not None else '-')
    joiner = 'INVALID (%s)' % inv['joiner'] if 'joiner' in inv else '%s s' % fmt_s(s.get('joiner_s'))
    err = 'INVALID (%s)' % inv['error'] if 'error' in inv else '%.3f m' % s['worst_err_m']
    return ('scale: %d robots: round of updates %s, %s, late joiner placed in %s, worst placement error %s'
            % (robots, rnd, stale, joiner, err))


def growth_line(summaries: Dict[int, dict]) -> Optional[str]:
    """How a round's cost grew from the smallest team size to the largest (None without two
    sizes whose round is valid): as measured, and for maps of equal size (the measured ratio
    times the smaller team's mean known cells a map over the larger's: a map's tracking and
    refinement cost goes with its known cells, and teams draw their windows at random)."""
    ok = sorted(n for n, s in summaries.items() if s.get('round_s') and s.get('round_known'))
    if len(ok) < 2:
        return None
    a, b = summaries[ok[0]], summaries[ok[-1]]
    x = b['round_s'] / a['round_s']
    return ('scale: from %d to %d robots a round of updates grew x%.1f (linear: x%.0f); for maps of '
            'equal size x%.1f (their maps had %.0f and %.0f known cells on average)'
            % (ok[0], ok[-1], x, ok[-1] / float(ok[0]), x * a['round_known'] / b['round_known'],
               a['round_known'], b['round_known']))


def detail_lines(run: dict, s: dict) -> List[str]:
    """Indented lines under a size's line: what the figures rest on."""
    out = []
    if 'all' in s.get('invalid', {}):
        return out
    after = [c for c in run['cycles'] if run['cold_end'] is not None and c['start'] >= run['cold_end']]
    out.append('  cold start: %d of %d robots placed in %s s (%d estimation cycles); then %d cycles of %s s '
               '(median); %d of %d rounds of updates absorbed' % (
                   run['cold_placed'], run['robots'] - 1, fmt_s(run['cold_end']),
                   len(run['cycles']) - len(after), len(after), fmt_s(s.get('cycle_s')),
                   s.get('rounds_complete', 0), run['rounds']))
    if s.get('stale_p50_periods') is not None:
        out.append('  staleness: p50 %.1f, p95 %.1f merge periods of %s s (%d updates); until estimation took it: '
                   'p50 %s s, p95 %s s; by round (p50): %s s' % (
                       s['stale_p50_periods'], s['stale_p95_periods'], fmt_s(s['merge_period_s']), s['stale_n'],
                       fmt_s(s.get('placed_p50_s')), fmt_s(s.get('placed_p95_s')),
                       ', '.join(fmt_s(v) for v in s.get('lag_by_round', []))))
    pubs = run['publishes']
    if pubs:
        out.append('  compositing: %d new merged maps, compose() %.1f ms (median, max %.1f ms); %d published%s' % (
            run['composes'], 1000.0 * (run['compose_p50_s'] or 0.0), 1000.0 * (run['compose_max_s'] or 0.0),
            len(pubs),
            '' if run['serialised'] else ' (not serialised: rospy not importable)'))
    br = run.get('breakdown_after')
    if br:
        out.append('  estimate() after the cold start: %s s in all: %s' % (
            fmt_s(br['estimate']), ', '.join('%s %s s' % (k, fmt_s(v)) for k, v in sorted(br.items())
                                             if k != 'estimate')))
    fresh = [r for r in run.get('refreshes', []) if run['cold_end'] is not None and r['start'] >= run['cold_end']]
    if fresh:
        out.append('  refresh (spare time, after the cold start): %d slices, %s s in all, %d links tracked again' % (
            len(fresh), fmt_s(sum(r['end'] - r['start'] for r in fresh)), sum(r['pairs'] for r in fresh)))
    errs = run['errors']
    if errs:
        worst = max(errs, key=lambda r: errs[r][0])
        out.append('  placed at the end: %d of %d (reference %s); worst %s: %.3f m, %.2f deg; known cells per map '
                   '%d at the first maps, %d at the last taken; wall %s s; feeder late by up to %s s' % (
                       len(run['placed_end']) - 1, run['robots'] - 1, run['reference'], worst, errs[worst][0],
                       errs[worst][1], run['grew_cells'][0], run['grew_cells'][1], fmt_s(run['wall_s']),
                       fmt_s(run['feed_late_max_s'])))
    return out


def peer_line(robots: int, p: dict) -> str:
    """The m-explore line of a team size."""
    if not p.get('run'):
        return '  m-explore: not run (%s)' % p['why']
    return ('  m-explore: %d robots: first merged /map %s s after its node started (known_init_poses false: '
            'every pair matched), CPU %s s, peak RSS %.0f MB' % (
                robots, fmt_s(p['first_map_s']), fmt_s(p['cpu_s']), p['rss_mb']))


def peer_plan(robots: int, before: Optional[Tuple[int, dict]], limit: float = PEER_TIMEOUT) -> Optional[str]:
    """Why m-explore is not run at ``robots`` given its result at the previous size ``before``
    ((robots, its result) or None); None to run it. It matches every pair of maps: its cycle
    grows at least as the square of the robots."""
    if before is None:
        return None
    n, p = before
    if not p.get('run'):
        if p.get('timed_out'):
            return 'at %d robots its cycle did not end within %.0f s' % (n, limit)
        return None
    guess = p['wall_s'] * (robots / float(n)) ** 2
    if guess > limit:
        return ('its cycle would not end within %.0f s: %.0f s at %d robots, and it matches every pair'
                % (limit, p['wall_s'], n))
    return None


# ---------------------------------------------------------------- the robots

class Robot:
    """One simulated robot: its whole window (``whole``, a Grid in its own map frame), the truth
    ``T`` (3x3, its map frame in the world's, metres), and the versions of its growing map."""

    def __init__(self, name: str, whole, T: np.ndarray, rng: np.random.Generator):
        self.name, self.whole, self.T, self.rng = name, whole, T, rng
        known = whole.data >= 0
        rr, cc = np.nonzero(known)
        rows, cols = np.arange(whole.height)[:, None], np.arange(whole.width)[None, :]
        centre = np.hypot(rows - rr.mean(), cols - cc.mean())
        reach = float(centre[known].max())
        # a free cell near the known centre: where the robot started exploring its window
        free = np.flatnonzero(((whole.data == 0) & (centre <= START_WITHIN * reach)).ravel())
        if not free.size:
            free = np.flatnonzero((whole.data == 0).ravel())
        r0, c0 = np.unravel_index(int(rng.choice(free)), known.shape)
        self.dist = np.hypot(rows - r0, cols - c0).astype(np.float32)   # cells from the start
        self.reach = float(self.dist[known].max())

    def version(self, robot_s: float):
        """Its map ``robot_s`` seconds after its first one (a Grid in its map frame, cropped to
        the known cells plus MARGIN, its origin moved accordingly) and its known cells."""
        from multi_map_merge.core.grid import Grid
        from multi_map_merge.core.transforms import cell_to_metric
        g = self.whole
        data = np.where(self.dist <= reveal_fraction(robot_s) * self.reach, g.data, np.int8(-1))
        known = np.flatnonzero(data >= 0)
        flat = data.reshape(-1)
        if known.size:
            flip = self.rng.choice(known, min(FLIPS, known.size), replace=False)
            flat[flip] = np.where(flat[flip] == 100, 0, 100).astype(np.int8)
        r0, r1, c0, c1 = known_crop(data >= 0)
        o = cell_to_metric(g.resolution, g.origin) @ np.array([c0 - 0.5, r0 - 0.5, 1.0])
        part = Grid(np.ascontiguousarray(data[r0:r1, c0:c1]), g.resolution,
                    (round(float(o[0]), 6), round(float(o[1]), 6), g.origin[2]), '%s/map' % self.name)
        return part, int(known.size)


class Feeder(threading.Thread):
    """Feeds every robot's versions to the merger on schedule, as the node's subscribers do
    (``update_map`` from a thread of their own), and records each arrival."""

    def __init__(self, merger, robots: List[Robot], t0: float, joiner: str):
        super().__init__(name='feeder', daemon=True)
        self.merger, self.robots, self.t0, self.joiner = merger, {r.name: r for r in robots}, t0, joiner
        self.cond = threading.Condition()
        self.fed: Dict[str, int] = {}        # robot -> newest version fed
        self.seq = 0                         # versions fed so far
        self.updates: List[dict] = []        # every arrival
        self.placed: set = set()             # robots placed at the end of the last cycle
        self.grids: Dict[str, object] = {}   # robot -> newest grid fed
        self.first_cells: Dict[str, int] = {}
        self.cells: Dict[str, List[int]] = {}
        self.stop = threading.Event()
        self.late_max = 0.0
        offsets = stagger(len(robots) - 1)
        # (due s, version, robot, when its first map was due: robot time 0)
        self._queue = [(offsets[k], 0, r.name, offsets[k]) for k, r in enumerate(robots) if r.name != joiner]
        heapq.heapify(self._queue)
        self._joiner_offset = PERIOD * (len(robots) - 1) / len(robots)

    def now(self) -> float:
        return time.monotonic() - self.t0

    def join_now(self) -> float:
        """Schedule the joiner's first map at its slot of the next period; returns when (s)."""
        at = next_slot(self._joiner_offset, self.now())
        with self.cond:
            heapq.heappush(self._queue, (at, 0, self.joiner, at))
            self.cond.notify_all()
        return at

    def run(self) -> None:
        while not self.stop.is_set():
            with self.cond:
                if not self._queue:
                    self.cond.wait(0.2)
                    continue
                due, v, name, first = self._queue[0]
                wait = due - self.now()
                if wait > 0:
                    self.cond.wait(min(wait, 0.2))
                    continue
                heapq.heappop(self._queue)
                heapq.heappush(self._queue, (due + PERIOD, v + 1, name, first))
            grid, known = self.robots[name].version(due - first)
            arrival = self.now()
            self.merger.update_map(name, grid)
            with self.cond:
                self.late_max = max(self.late_max, arrival - due)
                self.fed[name] = v
                self.grids[name] = grid
                self.cells.setdefault(name, []).append(known)
                self.updates.append({'robot': name, 'version': v, 'arrival': arrival, 'due': due,
                                     'placed': name in self.placed, 'known': known})
                self.seq += 1
                self.cond.notify_all()

    def taken(self) -> Dict[str, int]:
        with self.cond:
            return dict(self.fed)


class Outputs:
    """The node's compositing thread and /map timer (``ros/node.py``): ``compose()`` again
    after half a merge period, and every merge period the newest composited grid published
    when it is a new one; records each publication ({'start', 'end', 'shown': the versions of
    the robots placed when the grid was composited})."""

    def __init__(self, merger, feeder: Feeder, period: float, frame: str):
        self.merger, self.feeder, self.period, self.frame = merger, feeder, period, frame
        self.stop = threading.Event()
        self.publishes: List[dict] = []
        self.compose_s: List[float] = []    # s, of each compose() that made a new merged grid
        self._ready = None     # (grid, versions it holds)
        try:
            import rospy

            from multi_map_merge.ros.convert import grid_to_msg
            self.serialise = (rospy, grid_to_msg)
        except ImportError:
            self.serialise = None
        self._threads = [threading.Thread(target=self._compositing, name='compositing', daemon=True),
                         threading.Thread(target=self._publishing, name='publishing', daemon=True)]

    def start(self) -> None:
        for t in self._threads:
            t.start()

    def join(self, timeout: float) -> None:
        for t in self._threads:
            t.join(timeout)

    def _compositing(self) -> None:
        last = None
        while not self.stop.is_set():
            t = time.monotonic()
            # the versions before compose() takes its own: a map fed in between is credited to a later grid
            fed = self.feeder.taken()
            placed = set(self.merger.placements())
            grid = self.merger.compose()
            if grid is not None and grid is not last:
                # (an unchanged merge returns the very same grid at once: not counted)
                self.compose_s.append(time.monotonic() - t)
                last = grid
                self._ready = (grid, {r: v for r, v in fed.items() if r in placed})
            self.stop.wait(max(0.01, self.period / 2.0 - (time.monotonic() - t)))

    def _publishing(self) -> None:
        import io
        sent = None
        tick = time.monotonic()
        while not self.stop.is_set():
            tick += self.period
            self.stop.wait(max(0.0, tick - time.monotonic()))
            tick = max(tick, time.monotonic() - self.period)   # a late tick is not made up for
            ready = self._ready
            if ready is None or ready[0] is sent:
                continue
            start = self.feeder.now()
            if self.serialise is not None:
                rospy, grid_to_msg = self.serialise
                grid_to_msg(ready[0], rospy.Time(0), self.frame).serialize(io.BytesIO())
            sent = ready[0]
            self.publishes.append({'start': start, 'end': self.feeder.now(), 'shown': ready[1]})


class Timers:
    """Seconds spent in some steps of ``estimate()`` (the pairs in the worker pool, the pose
    graph, the joint refinement, the bending), by wrapping the core's functions in this
    process only; a step the core no longer has is left out."""

    STEPS = (('multi_map_merge.core.workers', 'PairWorkers', 'align_pairs', 'pairs'),
             ('multi_map_merge.core.placement', None, 'graph_poses', 'pose graph'),
             ('multi_map_merge.core.joint', None, 'refine_placements', 'joint refinement'),
             ('multi_map_merge.core.deform', None, 'fit_fields', 'bending'))

    def __init__(self):
        import importlib
        self.spent: Dict[str, float] = {}
        self.pairs = 0
        for mod, cls, fn, label in self.STEPS:
            owner = importlib.import_module(mod)
            owner = getattr(owner, cls, None) if cls else owner
            if owner is not None and hasattr(owner, fn):
                setattr(owner, fn, self._wrap(getattr(owner, fn), label))

    def _wrap(self, f, label):
        def timed(*a, **k):
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                self.spent[label] = self.spent.get(label, 0.0) + time.perf_counter() - t
                if label == 'pairs' and len(a) >= 3:
                    self.pairs += len(a[2])
        return timed

    def take(self) -> Tuple[Dict[str, float], int]:
        out, n = dict(self.spent), self.pairs
        self.spent.clear()
        self.pairs = 0
        return out, n


def team(world, robots: int, seed: int) -> List[Robot]:
    """``robots`` robots on windows of ``world`` (names r00, r01, ...: the last is the joiner)."""
    from multi_map_merge.lab.pieces import pieces_windows
    rng = np.random.default_rng(seed + 1000)
    return [Robot('r%02d' % k, g, T, np.random.default_rng(int(rng.integers(1 << 31))))
            for k, (g, T) in enumerate(pieces_windows(world, robots, WINDOW, seed))]


def run_team(robots: int, rounds: int, world_name: str, seed: int, max_s: float, maps_dir: str,
             rate: float = 0.0) -> dict:
    """One team size's run in this process (module docstring); returns its record. ``rate``:
    estimation cycles per second (Hz; 0: back to back)."""
    from multi_map_merge.core.mapio import save_map
    from multi_map_merge.core.merger import MapMerger
    from multi_map_merge.core.transforms import pose_distance
    from multi_map_merge.core.workers import start_pool
    from multi_map_merge.node_config import NodeConfig
    cfg = NodeConfig()
    # the worker pool forked before any thread, as the node does before rospy starts
    start_pool(cfg.workers)
    world = world_map(world_name)
    if world is None:
        raise SystemExit('no ground-truth map %r in ../shared/data' % world_name)
    bots = team(world, robots, seed)
    joiner = bots[-1].name
    merger = MapMerger(cfg)
    timers = Timers()
    t0 = time.monotonic()
    feeder = Feeder(merger, bots, t0, joiner)
    outputs = Outputs(merger, feeder, 1.0 / cfg.merge_rate, cfg.merged_map_frame)
    feeder.start()
    outputs.start()
    cycles: List[dict] = []
    refreshes: List[dict] = []
    seen = 0
    cold_end, cold_placed = None, 0
    joiner_at = joiner_placed = None
    stop_why = ''
    period = 1.0 / rate if rate > 0 else 0.0
    next_start = 0.0      # the node's next cycle starts a period after the last one started
    try:
        while True:
            while True:
                with feeder.cond:
                    now = feeder.now()
                    if (feeder.seq != seen and now >= next_start) or now >= max_s:
                        seen = feeder.seq
                        break
                # spare time refreshes the stalest links: until the period ends (less the node's
                # margin) as the node does, or a slice at a time while no map is new
                start = feeder.now()
                budget = next_start - REFRESH_MARGIN - start if period else 0.0
                merger.refresh(budget if budget > 0 else REFRESH_SLICE)
                spent, pairs = timers.take()
                if pairs:
                    refreshes.append({'start': start, 'end': feeder.now(), 'pairs': pairs, 'steps': spent})
                    continue
                with feeder.cond:
                    wait = next_start - feeder.now()
                    if feeder.seq == seen or wait > 0:
                        feeder.cond.wait(min(0.2, wait) if wait > 0 else 0.2)
            if feeder.now() >= max_s:
                stop_why = 'time limit (%.0f s)' % max_s
                break
            taken = feeder.taken()
            start = feeder.now()
            events = merger.estimate()
            end = feeder.now()
            next_start = start + period
            placed = sorted(merger.placements())
            spent, pairs = timers.take()
            with feeder.cond:
                feeder.placed = set(placed)
            cycles.append({'start': start, 'est_s': end - start, 'end': end, 'taken': taken,
                           'placed': len(placed), 'pairs': pairs, 'steps': spent, 'events': len(events)})
            others = [b.name for b in bots if b.name != joiner]
            if cold_end is None:
                cold_placed = sum(1 for n in others if n in placed)
                if cold_placed == len(others) or end >= COLD_CAP * max_s:
                    cold_end = end
                    joiner_at = feeder.join_now()
                    print('  %d robots: cold start over at %.1f s: %d of %d placed; the joiner comes at %.1f s'
                          % (robots, end, cold_placed, len(others), joiner_at), file=sys.stderr, flush=True)
            if joiner_placed is None and joiner in placed:
                joiner_placed = end
            if cold_end is not None and _done(feeder.updates, cycles, cold_end, rounds, joiner_placed,
                                              joiner_deadline(feeder.updates, cycles, joiner), end):
                stop_why = 'rounds absorbed, joiner %s' % ('placed' if joiner_placed is not None else 'given up')
                break
            if end >= max_s:
                stop_why = 'time limit (%.0f s)' % max_s
                break
        if stop_why.startswith('rounds'):
            # the last cycle's placements reach /map at the next compositing and timer tick: wait for
            # the publication of every version of the rounds (at most 10 merge periods)
            ups = [u for us in rounds_of([u for u in feeder.updates if u['placed']], cold_end, rounds) for u in us]
            until = feeder.now() + 10.0 * outputs.period
            while feeder.now() < until and None in staleness(ups, list(outputs.publishes), 'shown'):
                time.sleep(0.1)
    finally:
        feeder.stop.set()
        outputs.stop.set()
        feeder.join(5.0)
        outputs.join(30.0)
    wall = feeder.now()
    ref = merger.reference
    P = merger.placements()
    truth = {b.name: b.T for b in bots}
    errors = {}
    for n, p in P.items():
        if n != ref:
            d, a = pose_distance(p.T, np.linalg.inv(truth[ref]) @ truth[n])
            errors[n] = (float(d), math.degrees(float(a)))
    # the maps as the merger held them at the end, for m-explore
    paths = []
    os.makedirs(maps_dir, exist_ok=True)
    for b in bots:
        g = feeder.grids.get(b.name)
        if g is not None:
            p = os.path.join(maps_dir, '%s.yaml' % b.name)
            save_map(g, p)
            paths.append(p)
    first = [c[0] for c in feeder.cells.values() if c]
    last_taken = cycles[-1]['taken'] if cycles else {}
    last = [feeder.cells[r][v] for r, v in last_taken.items() if r in feeder.cells and v < len(feeder.cells[r])]
    after = [c for c in cycles if cold_end is not None and c['start'] >= cold_end]
    breakdown = {}
    for c in after:
        breakdown['estimate'] = breakdown.get('estimate', 0.0) + c['est_s']
        for k, v in c['steps'].items():
            breakdown[k] = breakdown.get(k, 0.0) + v
    return {'robots': robots, 'rounds': rounds, 'world': world_name, 'seed': seed, 'estimation_rate': rate,
            'cycles': cycles,
            'updates': feeder.updates, 'cold_end': cold_end, 'cold_placed': cold_placed,
            'joiner': {'name': joiner, 'scheduled': joiner_at,
                       'arrival': next((u['arrival'] for u in feeder.updates if u['robot'] == joiner), None),
                       'placed_end': joiner_placed},
            'reference': ref, 'placed_end': sorted(P), 'errors': errors, 'wall_s': wall, 'stop': stop_why,
            'grew_cells': [int(np.median(first)) if first else 0, int(np.median(last)) if last else 0],
            'feed_late_max_s': feeder.late_max, 'breakdown_after': breakdown,
            'publishes': outputs.publishes, 'merge_period_s': outputs.period,
            'serialised': outputs.serialise is not None,
            'composes': len(outputs.compose_s), 'compose_p50_s': percentile(outputs.compose_s, 50),
            'compose_max_s': max(outputs.compose_s) if outputs.compose_s else None,
            'pairs_after': sum(c['pairs'] for c in after), 'paths': paths, 'refreshes': refreshes,
            'truth': {b.name: b.T.tolist() for b in bots}, 'loadavg_end': list(os.getloadavg())}


def _done(updates, cycles, cold_end, rounds, joiner_placed, give_up, now) -> bool:
    """Every version of rounds 1..``rounds`` absorbed (all of them arrived by ``now``), and the
    joiner placed or given up on (``give_up``: when, s; None while it has not come)."""
    if now < cold_end + rounds * PERIOD:
        return False   # the last round has not all arrived yet
    for us in rounds_of([u for u in updates if u['placed']], cold_end, rounds):
        if any(absorbed_end(cycles, u['robot'], u['version']) is None for u in us):
            return False
    return joiner_placed is not None or (give_up is not None and now >= give_up)


def joiner_deadline(updates, cycles, joiner) -> Optional[float]:
    """When (s) the run stops waiting for the joiner to be placed: once its whole window is
    known (GROW_S after its first map) and three more cycles of the median duration ran; None
    before its first map."""
    arrival = next((u['arrival'] for u in updates if u['robot'] == joiner), None)
    if arrival is None:
        return None
    return arrival + GROW_S + 3.0 * float(np.median([c['end'] - c['start'] for c in cycles]))


# ---------------------------------------------------------------- m-explore

def run_peer(paths: List[str], truth: Dict[str, list], timeout: float = PEER_TIMEOUT) -> dict:
    """m-explore's node once on ``paths`` (robot map files), stopped after ``timeout`` s
    (bench/peer.py ``run_node``): {'run', 'why', 'first_map_s', 'wall_s' (the same: what
    :func:`peer_plan` predicts from), 'cpu_s', 'rss_mb', 'timed_out'}. (``truth`` unused: the
    node publishes a merged map, not placements.)"""
    from peer import available, run_node
    ok, why = available()
    if not ok:
        return {'run': False, 'why': why}
    res = run_node(paths, timeout=timeout)
    if 'invalid' in res:
        return {'run': False, 'timed_out': res['invalid'].startswith('no merged /map'), 'why': res['invalid']}
    return {'run': True, 'first_map_s': res['first_map_s'], 'wall_s': res['first_map_s'],
            'cpu_s': res['cpu_s'], 'rss_mb': res['rss_mb']}


# ---------------------------------------------------------------- driver

UPDATE_FIELDS = ('robot', 'version', 'arrival', 'placed', 'known', 'shown_s', 'taken_s')


def compact(run: dict) -> dict:
    """``run`` for the JSON file: the updates as rows of ``UPDATE_FIELDS`` (arrival s; placed
    when it arrived; its known cells; its staleness: 'shown_s' until a published merged map held
    it, 'taken_s' until an estimation cycle took it, None: never; seconds to the millisecond),
    the publications as their times only (their versions are what those figures are made of)."""
    def ms(v):
        return None if v is None else round(v, 3)
    out = dict(run)
    out.pop('paths', None)
    out['update_fields'] = list(UPDATE_FIELDS)
    out['updates'] = [[u['robot'], u['version'], ms(u['arrival']), u['placed'], u['known'], ms(shown), ms(taken)]
                      for u, shown, taken in zip(run['updates'],
                                                 staleness(run['updates'], run['publishes'], 'shown'),
                                                 staleness(run['updates'], run['cycles']))]
    out['publishes'] = [[ms(p['start']), ms(p['end'])] for p in run['publishes']]
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--sizes', default=','.join(str(s) for s in SIZES), help='team sizes, e.g. 8,16')
    ap.add_argument('--rounds', type=int, default=3, help='rounds of updates measured after the cold start')
    ap.add_argument('--world', default='intel', help='ground-truth building (../shared/data/ground_truth)')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--max-minutes', type=float, default=12.0,
                    help='per team size: the run stops at the end of the first cycle past this')
    ap.add_argument('--estimation-rate', type=float, default=0.0,
                    help="estimation cycles per second (Hz), as the node's ~estimation_rate; 0 (default): back to back")
    ap.add_argument('--no-peer', action='store_true', help='do not run m-explore')
    ap.add_argument('--results', default=os.path.join(HERE, 'results'))
    ap.add_argument('--one', type=int, help=argparse.SUPPRESS)       # one team size, in this process
    ap.add_argument('--maps-dir', help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        rec = run_team(a.one, a.rounds, a.world, a.seed, a.max_minutes * 60.0, a.maps_dir, a.estimation_rate)
        print(json.dumps(rec))
        return 0
    from report import machine
    sizes = [int(s) for s in a.sizes.split(',') if s.strip()]
    if any(s < 3 for s in sizes) or a.rounds < 1:
        ap.error('every team size needs at least 3 robots (a reference, another, the joiner), --rounds >= 1')
    if not a.estimation_rate >= 0:
        ap.error('--estimation-rate must be >= 0 Hz (0: cycles back to back), not %r' % a.estimation_rate)
    os.makedirs(a.results, exist_ok=True)
    tmp = tempfile.mkdtemp(prefix='scale_')
    out = {'machine': machine(), 'loadavg_start': list(os.getloadavg()), 'options': vars(a),
           'constants': {'period_s': PERIOD, 'grow_from': GROW_FROM, 'grow_s': GROW_S, 'flips': FLIPS,
                         'window': WINDOW, 'peer_timeout_s': PEER_TIMEOUT}, 'sizes': {}}
    lines = []
    peer_before = None
    t_all = time.monotonic()
    for n in sizes:
        print('scale: %d robots ...' % n, file=sys.stderr, flush=True)
        cmd = [sys.executable, os.path.abspath(__file__), '--one', str(n), '--rounds', str(a.rounds),
               '--world', a.world, '--seed', str(a.seed), '--max-minutes', str(a.max_minutes),
               '--maps-dir', os.path.join(tmp, 'r%d' % n)]
        cmd += ['--estimation-rate', str(a.estimation_rate)]
        r = subprocess.run(cmd, stdout=subprocess.PIPE, text=True, cwd=REPO)
        if r.returncode != 0:
            line = 'scale: %d robots: INVALID: its process failed (exit %d)' % (n, r.returncode)
            lines.append(line)
            print(line, flush=True)
            out['sizes'][str(n)] = {'failed': r.returncode}
            continue
        run = json.loads(r.stdout.strip().splitlines()[-1])
        s = summarise(run)
        block = [scale_line(n, s)] + detail_lines(run, s)
        if a.no_peer:
            p = {'run': False, 'why': '--no-peer'}
        else:
            why = peer_plan(n, peer_before)
            p = {'run': False, 'why': why} if why else run_peer(run['paths'], run['truth'])
            if p.get('run') or p.get('timed_out'):
                peer_before = (n, p)   # a size skipped by the prediction predicts nothing
        block.append(peer_line(n, p))
        for line in block:
            print(line, flush=True)
        lines += block
        out['sizes'][str(n)] = {'summary': s, 'run': compact(run), 'mexplore': p}
    growth = growth_line({int(n): v['summary'] for n, v in out['sizes'].items() if 'summary' in v})
    if growth:
        print(growth, flush=True)
        lines.append(growth)
    out['wall_s'] = time.monotonic() - t_all
    out['loadavg_end'] = list(os.getloadavg())
    lines.append('(%s; %d cores, load %.1f at the start, %.1f at the end; %.0f s in all)' % (
        out['machine'].get('date', ''), out['machine'].get('nproc', 0), out['loadavg_start'][0],
        out['loadavg_end'][0], out['wall_s']))
    print(lines[-1])
    results.write_json(os.path.join(a.results, 'scale.json'), out, vars(a),
                       separators=(',', ':'))   # (one line: thousands of update rows)
    results.write_text(os.path.join(a.results, 'scale.txt'), lines, vars(a))
    return 0


if __name__ == '__main__':
    sys.exit(main())
