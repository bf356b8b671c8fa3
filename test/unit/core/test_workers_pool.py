"""The worker pool after one of its processes died (killed, e.g. by the kernel's OOM killer):
the estimation cycle that needs it raises BrokenProcessPool, and the next cycle starts a new
pool and estimates."""
import os
import signal
import time
from concurrent.futures.process import BrokenProcessPool

import numpy as np
import pytest
from conftest import pose_error, truth

from multi_map_merge.core import workers
from multi_map_merge.core.config import MergeConfig
from multi_map_merge.core.grid import Grid
from multi_map_merge.core.merger import MapMerger
from multi_map_merge.lab.pieces import cut_piece, split_rects


def test_a_killed_worker_fails_one_cycle_then_a_new_pool_estimates(intel):
    rects = split_rects(intel, 2, 0.35)
    pieces = [cut_piece(intel, r, p) for r, p in zip(rects, [(0.0, 0.0, 0.0), (-2.0, 3.0, 2.6)])]
    m = MapMerger(MergeConfig(workers=2, reference_robot='a'))
    m.update_map('a', pieces[0][0])
    m.update_map('b', pieces[1][0])
    m.estimate()
    assert 'b' in m.placements()
    pool = workers._POOL
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
    assert workers._POOL is None           # the broken pool was let go
    m.estimate()                           # a new pool
    assert workers._POOL is not None and workers._POOL is not pool
    d, a = pose_error(m.placements()['b'].T, truth(pieces[0][1], pieces[1][1]))
    assert d < 0.1 and a < 1.0
