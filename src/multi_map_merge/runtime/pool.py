"""The local worker pool's lifecycle: one process pool shared by every merger of a process,
started early (before the process runs another thread, so that its workers are forked and share
the process's pages), resized when configured otherwise, and dropped when one of its workers died
(the next call starts a new one). How a worker is started and set up is :mod:`.process`'s."""
from __future__ import annotations

import os
from concurrent.futures.process import BrokenProcessPool
from typing import List, Sequence

from . import process
from .memory import run_task

_POOL = None
_POOL_SIZE = 0


def workers_count(workers: int) -> int:
    """Processes of the local pool for ``workers`` (``MergeConfig.workers``: 0 = one per core)."""
    return workers or os.cpu_count() or 1


def shared(workers: int, preload: Sequence[str] = ()):
    """The process pool shared by every merger in this process (None: work inline); started
    as :func:`start_pool` says when there is none of that size."""
    n = workers_count(workers)
    if (n <= 1 and _POOL is not None) or (n > 1 and (_POOL is None or _POOL_SIZE != n)):
        start_pool(n, preload)   # (started early with the default size, then configured otherwise)
    return _POOL


def discard() -> None:
    """Drop a broken pool: the next :func:`shared` starts a new one."""
    global _POOL, _POOL_SIZE
    if _POOL is not None:
        _POOL.shutdown(wait=False)
    _POOL, _POOL_SIZE = None, 0


def start_pool(workers: int = 0, preload: Sequence[str] = ()) -> None:
    """Start the worker pool now (``workers`` as ``MergeConfig.workers``: 0 = one per core).

    Called while the process runs no other thread (the node: before ``rospy.init_node``), the
    workers are forked from it and share its pages: its imports cost the machine once, not once
    per worker. Otherwise they come from a 'forkserver' that has imported the modules of
    ``preload`` (the estimation's), so that at least the workers share those."""
    global _POOL, _POOL_SIZE
    from concurrent.futures import ProcessPoolExecutor
    # This process places the robots (the pose graph's and the covariances' small solves, a
    # few 3N x 3N systems per cycle): OpenBLAS's LAPACK runs even a 9 x 9 solve on its threads,
    # which take milliseconds to wake while the workers keep the cores busy, microseconds on one
    process.one_blas_thread()
    n = workers_count(workers)
    if _POOL is not None:
        # waiting for the old workers (idle: a pool is replaced only when the configured size
        # differs from the one started early); Python 3.8's executor left behind with wait=False
        # can hang the interpreter's exit
        _POOL.shutdown(wait=True)
        _POOL, _POOL_SIZE = None, 0
    if n <= 1:
        return
    ctx = process.start_context(list(preload))
    pool = ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=process.worker_init)
    if ctx.get_start_method() == 'fork':
        process.fork_now(pool)
    _POOL, _POOL_SIZE = pool, n


class PoolRunner:
    """Calls run in the local pool's worker processes (``joint.Runner``): a merger's serial
    steps that split into independent pieces (``joint.refine_placements``). A worker that died
    breaks the pool: the call raises ``BrokenProcessPool``, and the next starts a new pool."""

    def __init__(self, pool):
        self.pool = pool
        self.workers = int(getattr(pool, '_max_workers', 0) or 1)

    def __call__(self, fn, calls: List[tuple]) -> list:
        try:
            futures = [self.pool.submit(run_task, fn, *args) for args in calls]
            return [f.result() for f in futures]
        except BrokenProcessPool:
            discard()
            raise
