"""Steps (1)-(4) (docs/design.md) of many pairs in worker processes, and what a merger derives once per map.

Processes, not threads: estimation is partly pure Python, and in threads it would hold the GIL
that the node's /map and TF timers need (and two threads ran no faster than one: the GIL).
One pool serves every merger of a process. Small problems are estimated inline (see
:data:`POOL_FROM_CELLS`): a pool's workers cost memory, and on a few small maps they save tens
of milliseconds.

The workers are forked from the process while it has no other thread (:func:`start_pool`, which
the node calls before ``rospy.init_node``): they share the process's memory, its imports (OpenCV,
numpy) above all, page by page until written. Workers started later, from a process running
threads, come from a 'forkserver' that imported the estimation's modules once for all of them
(forking a threaded process could copy a lock held by another thread). How workers are
started, and what they do with their memory, is :mod:`multi_map_merge.runtime`'s; this module
is the pool of pair jobs. With ``dask_scheduler`` set, the pool is a Dask cluster's
(:mod:`multi_map_merge.runtime.cluster`), the local pool taking over when it fails.
"""
from __future__ import annotations

import itertools
import math
import os
import time
import zlib
from concurrent.futures import FIRST_COMPLETED, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Dict, FrozenSet, List, Optional, Tuple

import numpy as np

from ..runtime import pool as local_pool
from ..runtime.memory import run_task
from .config import MergeConfig
from .features import Features
from .pair import PairInput, PairResult, align_pair, crop_known, describe_version, pin_later, track_pair
from .robot_map import RobotMap

_MERGERS = itertools.count()
# With ``workers: 0`` (one per core), maps whose known parts (their crops) hold fewer cells than
# this in all are estimated in this process: on a few small maps (a Turtlebot3 team in a house or
# a lab) the workers save a few tens of milliseconds per cold cycle, and the memory they take while
# they work is a large share of the node's then (docs/measurements.md, "Small problems inline").
# Larger problems, where the workers save up to seconds, use the pool; so does an explicit
# ``workers`` >= 2, always.
POOL_FROM_CELLS = 400_000

# the modules a forkserver's workers import before their first job: the pair estimation's
PRELOAD = [__name__.rsplit('.', 1)[0] + '.pair']
# what this module derives once per map version (RobotMap.memo)
CROP, FEATURES = 'crop', 'features'


class PairWorkers:
    """One merger's side of the pool: the crop (known part) and the features of each of its
    maps, derived once per map version (:attr:`RobotMap.key`), and the pairs' alignment."""

    def __init__(self, config: MergeConfig):
        self.config = config
        # names its maps in worker caches; unique across machines too (a Dask cluster's workers
        # serve the mergers of several machines, whose process ids may be the same)
        self.uid = '%d-%d-%s' % (os.getpid(), next(_MERGERS), os.urandom(4).hex())

    def crop(self, m: RobotMap) -> Tuple[np.ndarray, Tuple[int, int]]:
        """The known part of a map's levels and its (col, row) offset, once per map version:
        what features are computed on and what goes to the worker processes."""
        c = self.config
        return m.memo(CROP, lambda: crop_known(m.grid.levels(c.free_thresh, c.occupied_thresh),
                                               m.grid.known_box(c.free_thresh, c.occupied_thresh)))

    def features_of(self, m: RobotMap) -> Features:
        """(1) features of a map (in its crop's cells), computed once per map version."""
        return m.memo(FEATURES, lambda: describe_version(self.config, self.crop(m)[0], self.uid, m.name, m.version))

    def _stale(self, maps: Dict[str, RobotMap]) -> List[RobotMap]:
        """The maps whose features are not those of their current version."""
        return [m for m in maps.values() if not m.memo_ready(FEATURES)]

    def pool_for(self, maps: Dict[str, RobotMap]):
        """The worker pool that estimates these maps, or None to estimate them in this process:
        ``workers: 1``, or ``workers: 0`` and maps smaller than :data:`POOL_FROM_CELLS`."""
        c = self.config
        if c.workers == 0 and sum(self.crop(m)[0].size for m in maps.values()) < POOL_FROM_CELLS:
            return None
        return local_pool.shared(c.workers, PRELOAD)

    def runner(self, maps: Dict[str, RobotMap]) -> Optional[local_pool.PoolRunner]:
        """The local pool's workers for other work on these maps (:class:`PoolRunner`), or
        None to do it in this process (:meth:`pool_for`)."""
        local = self.pool_for(maps)
        return local_pool.PoolRunner(local) if local is not None else None

    def input(self, m: RobotMap, features: bool = True) -> PairInput:
        """A map as one side of a pair: its crop, and its features unless ``features`` is False
        (one side of a tracked pair, :func:`pair.track_pair`: a map only tracked is never
        described)."""
        levels, offset = self.crop(m)
        return PairInput(m.name, m.version, levels, m.grid.resolution, m.grid.origin,
                         self.features_of(m) if features else None, self.uid, offset)

    def align_pairs(self, maps: Dict[str, RobotMap], todo: List[Tuple[str, str]],
                    tracks: Optional[Dict[Tuple[str, str], Tuple[np.ndarray, bool]]] = None,
                    budget: float = 0.0, defer_pin: FrozenSet[Tuple[str, str]] = frozenset()
                    ) -> List[Optional[PairResult]]:
        """Every pair of ``todo`` (parent, child) worked on, the results in ``todo``'s order: a
        pair of ``tracks`` follows its kept link (``tracks[pair]``: cells of the child's grid ->
        cells of the parent's, and whether to compute its covariance: :func:`pair.track_pair`);
        the others are aligned from their
        features (:func:`pair.align_pair`, the features of the maps that changed computed first).

        ``defer_pin``: pairs whose accepted result leaves its covariance search for later
        (:func:`pair.pin_later`, :meth:`pin_results`).

        ``budget`` (seconds, 0 = none): no alignment but the first starts after it has passed
        since the call began; the pairs not started get None (the merger tries them in a later cycle). Tracked
        pairs always run, first: they take milliseconds. The alignments start in ``todo``'s order
        (the merger's priority).

        With a worker pool the stages overlap: waiting for every map's features before the first
        pair would leave a worker idle while the slowest map is described.

        A worker that died (killed, e.g. by the kernel's OOM killer) breaks the pool: this
        cycle raises ``BrokenProcessPool``, and the next one starts a new pool.

        With ``dask_scheduler`` set the pool is that Dask cluster's (:mod:`runtime.cluster`):
        the same jobs, the same results. A cluster that fails (unreachable, its scheduler or
        every worker lost) is left for the local pool, which does this cycle's pairs again:
        the merge completes, with one log line."""
        tracks = tracks or {}
        address = self.config.dask_scheduler
        if address and todo:
            # a Dask cluster (runtime/cluster.py); when it fails, the local pool does the cycle again
            from ..runtime import cluster
            try:
                pool = cluster.pool(address)
                if pool is not None:
                    return self._align_pairs(maps, todo, pool, tracks, budget, defer_pin)
            except cluster.failure_types() as e:
                cluster.lost(address, e)
        try:
            return self._align_pairs(maps, todo, self.pool_for(maps), tracks, budget, defer_pin)
        except BrokenProcessPool:
            local_pool.discard()
            raise

    def _align_pairs(self, maps: Dict[str, RobotMap], todo: List[Tuple[str, str]], pool,
                     tracks: Dict[Tuple[str, str], Tuple[np.ndarray, bool]],
                     budget: float, defer_pin: FrozenSet[Tuple[str, str]]) -> List[Optional[PairResult]]:
        c = self.config
        deadline = time.monotonic() + budget if budget > 0 else math.inf
        seeds = {ab: zlib.crc32(('%s|%s' % ab).encode()) for ab in todo}
        detect = [ab for ab in todo if ab not in tracks]
        results: Dict[Tuple[str, str], PairResult] = {}
        if pool is None:
            for ab in todo:
                if ab in tracks:
                    results[ab] = track_pair(c, self.input(maps[ab[0]], False), self.input(maps[ab[1]], False),
                                             *tracks[ab])
            for i, ab in enumerate(detect):
                if i and time.monotonic() > deadline:
                    break                     # (one alignment at least per cycle: progress)
                results[ab] = align_pair(c, self.input(maps[ab[0]]), self.input(maps[ab[1]]), seeds[ab],
                                         ab not in defer_pin)
            return [results.get(ab) for ab in todo]
        running: Dict[object, tuple] = {}    # future -> ('track' | 'pair', pair) or ('features', map)
        for ab in todo:
            if ab in tracks:
                running[pool.submit(run_task, track_pair, c, self.input(maps[ab[0]], False),
                                    self.input(maps[ab[1]], False), *tracks[ab])] = ('track', ab)
        needed = {n: maps[n] for ab in detect for n in ab}
        stale = self._stale(needed)
        # the biggest maps first: the last task to start should be a short one
        stale.sort(key=lambda m: -m.grid.width * m.grid.height)
        for m in stale:
            running[pool.submit(run_task, describe_version, c, self.crop(m)[0], self.uid, m.name, m.version)] = (
                'features', m)
        ready = set(needed) - {m.name for m in stale}
        waiting = list(detect)            # in priority order
        inputs: Dict[str, PairInput] = {}
        # alignments in flight at most: enough to keep every worker busy, few enough that the
        # budget can stop the rest
        in_flight = len(detect) if budget <= 0 else 2 * max(
            1, getattr(pool, '_max_workers', 0) or c.workers or os.cpu_count() or 1)

        def start_ready() -> None:
            busy = sum(1 for kind, _ in running.values() if kind == 'pair')
            for ab in list(waiting):
                if busy >= in_flight or (len(waiting) < len(detect) and time.monotonic() > deadline):
                    return                    # (one alignment at least per cycle: progress)
                if ab[0] in ready and ab[1] in ready:
                    for n in ab:
                        if n not in inputs:
                            inputs[n] = self.input(maps[n])
                    running[pool.submit(run_task, align_pair, c, inputs[ab[0]], inputs[ab[1]], seeds[ab],
                                        ab not in defer_pin)] = (
                        'pair', ab)
                    waiting.remove(ab)
                    busy += 1

        start_ready()
        while running:
            done, _ = wait(list(running), return_when=FIRST_COMPLETED)
            for fut in done:
                kind, what = running.pop(fut)
                if kind == 'features':
                    what.remember(FEATURES, fut.result())
                    ready.add(what.name)
                else:
                    results[what] = fut.result()
            start_ready()
        return [results.get(ab) for ab in todo]


    def pin_results(self, maps: Dict[str, RobotMap],
                    jobs: Dict[Tuple[str, str], PairResult]) -> Dict[Tuple[str, str], PairResult]:
        """The covariance searches left for later (:func:`pair.pin_later`) of the accepted
        results ``jobs`` (pair -> its result, on the current versions of ``maps``), in the
        worker processes when these maps' alignments would be: pair -> the result pinned."""
        if not jobs:
            return {}
        inputs = {n: self.input(maps[n], False) for ab in jobs for n in ab}
        calls = [(self.config, inputs[a], inputs[b], r) for (a, b), r in jobs.items()]
        run = self.runner(maps)
        pinned = run(pin_later, calls) if run is not None else [pin_later(*args) for args in calls]
        return dict(zip(jobs, pinned))


def start_pool(workers: int = 0) -> None:
    """Start the local worker pool now (:func:`runtime.pool.start_pool`), its forkserver, when
    there is one, having imported the pair estimation's module."""
    local_pool.start_pool(workers, PRELOAD)
