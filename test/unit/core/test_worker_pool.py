"""The worker pool of pair jobs: how its workers are started (forked from a process that runs no
other thread, sharing its memory; from a forkserver otherwise; the same estimates either way),
what they do with their memory and their caches, when a problem is estimated inline, and the
pool after one of its workers died."""
from __future__ import annotations

import os
import subprocess
import sys

SRC = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', '..', 'src')

SCRIPT = r'''
import threading, time
import numpy as np
from multi_map_merge.core import workers
from multi_map_merge.core.config import MergeConfig
from multi_map_merge.core.pair import compute_features
from multi_map_merge.runtime import pool
from multi_map_merge.runtime.memory import run_task

def main():
    rng = np.random.default_rng(1)
    levels = np.where(rng.random((120, 160)) < 0.1, 2, 1).astype(np.uint8)
    inline = compute_features(MergeConfig(), levels)
    methods = []
    workers.start_pool(2)
    methods.append(pool._POOL._mp_context.get_start_method())
    a = pool._POOL.submit(run_task, compute_features, MergeConfig(), levels).result()
    t = threading.Thread(target=time.sleep, args=(5,), daemon=True)
    t.start()
    workers.start_pool(3)      # a thread runs now: no fork
    methods.append(pool._POOL._mp_context.get_start_method())
    b = pool._POOL.submit(run_task, compute_features, MergeConfig(), levels).result()
    workers.start_pool(1)      # inline: no pool
    same = all(np.array_equal(x.points, inline.points) for x in (a, b))
    print(methods, pool._POOL is None, same)

if __name__ == '__main__':
    main()
'''


def run_script(tmp_path, text):
    """``text`` run as a script in a fresh interpreter (a process of its own: what a pool does
    at its start depends on the threads the process has); the last line it printed."""
    script = tmp_path / 'pool.py'
    script.write_text(text)
    env = dict(os.environ, PYTHONPATH=os.path.abspath(SRC) + os.pathsep + os.environ.get('PYTHONPATH', ''))
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip().splitlines()[-1]


def test_workers_forked_when_single_threaded_else_forkserver(tmp_path):
    assert run_script(tmp_path, SCRIPT) == "['fork', 'forkserver'] True True"


SCRIPT_AFTER_WARPS = r'''
import cv2
import numpy as np
from multi_map_merge.core import workers
from multi_map_merge.core.config import MergeConfig
from multi_map_merge.core.pair import compute_features
from multi_map_merge.runtime import pool
from multi_map_merge.runtime.memory import run_task

def main():
    cv2.setNumThreads(2)
    img = np.zeros((600, 600), np.uint8)
    for _ in range(5):      # OpenCV's thread pool started in this process
        cv2.warpAffine(img, np.eye(2, 3), (600, 600))
    workers.start_pool(2)
    levels = np.where(np.random.default_rng(2).random((120, 160)) < 0.1, 2, 1).astype(np.uint8)
    fs = [f.result(timeout=60) for f in [pool._POOL.submit(run_task, compute_features, MergeConfig(), levels)
                                         for _ in range(4)]]
    print(pool._POOL._mp_context.get_start_method(), len(fs), cv2.getNumThreads())

if __name__ == '__main__':
    main()
'''


def test_workers_forked_after_opencv_started_its_threads(tmp_path):
    """A pool forked after OpenCV's own thread pool ran: the workers must not wait for threads
    that were not copied (OpenCV 4.2's pthreads pool hung a worker in setNumThreads)."""
    assert run_script(tmp_path, SCRIPT_AFTER_WARPS) == 'fork 4 2'


TRIM_SCRIPT = r'''
import ctypes
from multi_map_merge.runtime.memory import run_task

libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.free.argtypes = [ctypes.c_void_p]

def rss_mb():
    return int(open('/proc/self/statm').read().split()[1]) * 4096 / 1e6

def leave_free_heap():
    """40 MB in 1 kB blocks, written, then freed but the last (at the heap's top): glibc keeps
    the memory below a block in use."""
    blocks = [libc.malloc(1000) for _ in range(40000)]
    for b in blocks:
        ctypes.memset(b, 1, 1000)
    for b in blocks[:-1]:
        libc.free(b)

before = rss_mb()
leave_free_heap()
kept = rss_mb() - before          # without a trim
run_task(leave_free_heap)          # the same in a task: trimmed after it
after_task = rss_mb() - before
print('%.1f %.1f' % (kept, after_task))
'''


def test_a_task_that_leaves_megabytes_free_hands_them_back(tmp_path):
    """glibc keeps a task's freed heap; a worker trims it after a task that left more than
    TRIM_FREE_BYTES free (its footprint would otherwise be its largest task's)."""
    import ctypes

    import pytest
    if not hasattr(ctypes.CDLL(None), 'malloc_trim'):
        pytest.skip('not glibc: no malloc_trim')
    kept, after_task = map(float, run_script(tmp_path, TRIM_SCRIPT).split())
    from multi_map_merge.runtime.memory import TRIM_FREE_BYTES
    assert kept > 35 and kept > TRIM_FREE_BYTES / 1e6 + 10   # the premise: freed, not handed back
    assert after_task < kept - 30


def test_derived_data_of_a_former_merger_is_dropped(house):
    """A process keeps the derived data (wall fields, masks) of one merger: a new merger's
    maps replace an old merger's, whose data would otherwise stay until the cache's bound."""
    from multi_map_merge.core import cache
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.merger import MapMerger
    first = MapMerger(MergeConfig(workers=1))
    for k in range(3):
        first.update_map('r%d' % k, house)
    first.estimate()
    n_first = len(cache._DERIVED)
    assert n_first > 0 and cache._DERIVED_OWNER == first._workers.uid
    second = MapMerger(MergeConfig(workers=1))
    second.update_map('r0', house)
    second.update_map('r1', house)
    second.estimate()
    assert 0 < len(cache._DERIVED) < n_first
    assert cache._DERIVED_OWNER == second._workers.uid


def test_describing_a_new_version_drops_what_was_derived_from_the_former(house):
    """A map's new version is described with its former version's wall fields and masks
    already dropped (stale; a description is a worker's largest working set); the other
    maps' are kept."""
    import numpy as np

    from multi_map_merge.core import cache, pair
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.merger import MapMerger
    m = MapMerger(MergeConfig(workers=1))
    for k in range(3):
        m.update_map('r%d' % k, house)
    m.estimate()
    names = {key[1] for key in cache._DERIVED}
    assert {'r0', 'r1'} <= names
    version = {key[1]: v[0] for key, v in cache._DERIVED.items()}
    pair.describe_version(MergeConfig(), np.zeros((50, 50), np.uint8), m._workers.uid, 'r0', version['r0'] + 1)
    assert not any(key[1] == 'r0' for key in cache._DERIVED)
    assert {key[1] for key in cache._DERIVED} == names - {'r0'}


def _worked_here(config, maps):
    """Whether a cold estimation of ``maps`` (name -> Grid) under ``config`` ran in this process:
    a process that aligns a merger's pairs keeps what it derived for that merger
    (``cache._DERIVED_OWNER``); the cells of the maps' known parts in all."""
    from multi_map_merge.core import cache
    from multi_map_merge.core.merger import MapMerger
    m = MapMerger(config)
    for name, g in maps.items():
        m.update_map(name, g)
    m.estimate()
    cells = sum(m._workers.crop(r)[0].size for r in m._team.maps.values())
    return cache._DERIVED_OWNER == m._workers.uid, cells


def test_small_problems_are_estimated_inline_and_large_ones_in_the_pool(house, intel):
    """``workers: 0``: maps under POOL_FROM_CELLS in all are estimated in this process, larger
    ones in the worker pool; an explicit pool size uses the pool for small maps too."""
    from multi_map_merge.core import workers
    from multi_map_merge.core.config import MergeConfig
    small = {'a': house, 'b': house}
    big = {'a': intel, 'b': intel}
    here, cells = _worked_here(MergeConfig(workers=0), small)
    assert cells < workers.POOL_FROM_CELLS and here
    here, cells = _worked_here(MergeConfig(workers=0), big)
    assert cells >= workers.POOL_FROM_CELLS and here == ((os.cpu_count() or 1) < 2)   # (one core: no pool)
    here, _ = _worked_here(MergeConfig(workers=2), small)
    assert not here


def test_a_killed_worker_fails_one_cycle_then_a_new_pool_estimates(intel):
    """After one of the pool's processes died (killed, e.g. by the kernel's OOM killer) the
    estimation cycle that needs it raises BrokenProcessPool, and the next cycle starts a new
    pool and estimates."""
    import signal
    import time
    from concurrent.futures.process import BrokenProcessPool

    import numpy as np
    import pytest
    from conftest import pose_error, truth

    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.grid import Grid
    from multi_map_merge.core.merger import MapMerger
    from multi_map_merge.lab.pieces import cut_piece, split_rects
    from multi_map_merge.runtime import pool as local_pool
    rects = split_rects(intel, 2, 0.35)
    pieces = [cut_piece(intel, r, p) for r, p in zip(rects, [(0.0, 0.0, 0.0), (-2.0, 3.0, 2.6)])]
    m = MapMerger(MergeConfig(workers=2, reference_robot='a'))
    m.update_map('a', pieces[0][0])
    m.update_map('b', pieces[1][0])
    m.estimate()
    assert 'b' in m.placements()
    pool = local_pool._POOL
    pids = list(pool._processes)
    assert pids, 'no worker process'
    os.kill(pids[0], signal.SIGKILL)
    end = time.time() + 10
    while time.time() < end and not pool._broken:   # the pool's own thread notices the death
        time.sleep(0.05)
    # b's map changes: the next cycle needs the pool
    g = pieces[1][0]
    data = g.data.copy()
    rows, cols = np.nonzero(data == -1)
    data[rows[len(rows) // 2], cols[len(cols) // 2]] = 100
    m.update_map('b', Grid(data, g.resolution, g.origin))
    with pytest.raises(BrokenProcessPool):
        m.estimate()
    assert local_pool._POOL is None           # the broken pool was let go
    m.estimate()                           # a new pool
    assert local_pool._POOL is not None and local_pool._POOL is not pool
    d, a = pose_error(m.placements()['b'].T, truth(pieces[0][1], pieces[1][1]))
    assert d < 0.1 and a < 1.0
