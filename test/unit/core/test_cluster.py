"""The pair work on a Dask cluster (``dask_scheduler``, :mod:`multi_map_merge.runtime.cluster`):
a real scheduler and two real workers started here on 127.0.0.1, the merge the same as the local
pool's, and a lost worker, a lost scheduler or an unreachable one leaving the work to the local
pool with one log line.

The tests of a cluster need ``distributed`` (python3-distributed) and skip without it; the tests of
a machine without it run everywhere, in an interpreter where ``import distributed`` fails."""
from __future__ import annotations

import hashlib
import json
import logging
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import INTEL_MAP, merged, shared_file

from multi_map_merge.runtime import cluster

NO_DISTRIBUTED = ('dask.distributed is not installed (optional: only for ~dask_scheduler; '
                  'Debian/Ubuntu python3-distributed)')

SRC = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', '..', 'src'))
CONFIG = dict(reference_robot='a', map_drift=0.0, map_drift_yaw=0.0)
LOGGER = cluster.__name__


def cut_pieces(intel):
    """Two overlapping parts of the Intel lab (b turned and moved) and a corner too small to
    place: the maps of ``halves_merged``."""
    from multi_map_merge.core.grid import known_bbox
    from multi_map_merge.lab.pieces import cut_piece
    r0, r1, c0, c1 = known_bbox(intel.levels())
    return {'a': cut_piece(intel, (r0, r1, c0, c0 + int(0.6 * (c1 - c0))), (0, 0, 0))[0],
            'b': cut_piece(intel, (r0, r1, c0 + int(0.4 * (c1 - c0)), c1), (3, -2, 2.0))[0],
            'c': cut_piece(intel, (r0, r0 + 40, c0, c0 + 40), (1, 1, 1.0))[0]}


@pytest.fixture(scope='module')
def pieces(intel):
    return cut_pieces(intel)


@pytest.fixture(scope='module')
def local(pieces):
    """The merge in this process (``workers: 1``): what the cluster must give."""
    return merged(pieces, workers=1, **CONFIG)


class Cluster:
    """A scheduler and workers, each a process of its own (its own process group)."""

    def __init__(self, tmp):
        self.tmp = tmp
        self.pids = {}
        self.env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get('PYTHONPATH', ''))
        self.scheduler = None
        self.workers = []
        self.address = None

    def _start(self, *args):
        return subprocess.Popen([sys.executable, '-m'] + list(args), env=self.env, cwd=str(self.tmp),
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)

    def start(self, n_workers=2, deadline_s=60.0):
        distributed = pytest.importorskip('distributed', reason=NO_DISTRIBUTED)
        f = self.tmp / 'scheduler.json'
        self.scheduler = self._start('distributed.cli.dask_scheduler', '--host', '127.0.0.1', '--port', '0',
                                     '--scheduler-file', str(f), '--no-dashboard',
                                     '--dashboard-address', '127.0.0.1:0')
        end = time.monotonic() + deadline_s
        while not (f.exists() and f.stat().st_size):
            assert self.scheduler.poll() is None and time.monotonic() < end, 'the scheduler did not start'
            time.sleep(0.1)
        self.address = json.loads(f.read_text())['address']
        for i in range(n_workers):
            self.workers.append(self._start('distributed.cli.dask_worker', self.address, '--nthreads', '1',
                                            '--no-nanny', '--memory-limit', '0', '--no-dashboard',
                                            '--local-directory', str(self.tmp / ('w%d' % i)),
                                            '--death-timeout', '10'))
        with distributed.Client(self.address, timeout=10, set_as_default=False) as c:
            while len(c.nthreads()) < n_workers:
                assert time.monotonic() < end, 'the workers did not start'
                time.sleep(0.1)
            self.pids = c.run(os.getpid)    # worker address -> its process id
        return self

    def worker_running_a_task(self, deadline_s=30.0):
        """The process of a worker that is running a task now (its thread in the
        task's code, as the workers themselves report it: ``Client.call_stack``), and that task's
        key. Assigned to a worker is not enough: a worker may hold a task it has not begun."""
        import distributed
        end = time.monotonic() + deadline_s
        with distributed.Client(self.address, timeout=10, set_as_default=False) as c:
            while True:
                for address, stacks in c.call_stack().items():
                    keys = list(stacks)   # (only the pool's tasks run on this test's cluster)
                    if keys:
                        pid = self.pids[address]
                        return next(p for p in self.workers if p.pid == pid), str(keys[0])
                assert time.monotonic() < end, 'no worker began a task within %.0f s' % deadline_s
                time.sleep(0.05)

    @staticmethod
    def kill(p):
        if p is not None and p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
        if p is not None:
            p.wait(timeout=10)

    def stop(self):
        for p in self.workers + [self.scheduler]:
            self.kill(p)


def _forget_cluster():
    """This process's client closed and no retry time left over from another test."""
    if cluster._POOL is not None:
        cluster._POOL.close()
    cluster._POOL = None
    cluster._RETRY_AT.clear()


@pytest.fixture
def dask_cluster(tmp_path):
    c = Cluster(tmp_path)
    _forget_cluster()
    try:
        yield c.start()
    finally:
        _forget_cluster()
        c.stop()


def assert_same(m, ref):
    """The same placements (every T) and the same merged grid."""
    a, b = m.placements(), ref.placements()
    assert sorted(a) == sorted(b)
    for n in a:
        assert np.array_equal(a[n].T, b[n].T), n
    ga, gb = m.compose(), ref.compose()
    assert np.array_equal(ga.data, gb.data) and ga.resolution == gb.resolution
    assert np.array_equal(np.asarray(ga.origin), np.asarray(gb.origin))


def fallback_lines(caplog):
    """Our lines; and no other line of warning or above (``distributed``'s own are silenced)."""
    others = [r.getMessage() for r in caplog.records if r.name != LOGGER and r.levelno >= logging.WARNING]
    assert not others, others
    return [r for r in caplog.records if r.name == LOGGER]


def test_the_cluster_merges_as_the_local_pool_does(dask_cluster, pieces, local, caplog):
    caplog.set_level(logging.WARNING)
    m = merged(pieces, dask_scheduler=dask_cluster.address, **CONFIG)
    assert cluster._POOL is not None and cluster._POOL.running() and cluster._POOL.finished >= 3
    assert not fallback_lines(caplog)
    assert sorted(m.placements()) == ['a', 'b']
    assert_same(m, local)


def test_a_worker_lost_before_the_cycle_leaves_the_work_to_the_other(dask_cluster, pieces, local, caplog):
    caplog.set_level(logging.WARNING)
    Cluster.kill(dask_cluster.workers[0])
    m = merged(pieces, dask_scheduler=dask_cluster.address, **CONFIG)
    assert not fallback_lines(caplog)
    assert cluster._POOL is not None and cluster._POOL.running() and cluster._POOL.finished >= 3
    assert_same(m, local)


def test_a_lost_scheduler_leaves_the_cycle_to_the_local_pool_with_one_line(dask_cluster, pieces, local, caplog):
    caplog.set_level(logging.WARNING)
    assert cluster.pool(dask_cluster.address).running()   # connected
    Cluster.kill(dask_cluster.scheduler)
    t0 = time.monotonic()
    m = merged(pieces, dask_scheduler=dask_cluster.address, **CONFIG)
    assert time.monotonic() - t0 < 30
    lines = fallback_lines(caplog)
    assert len(lines) == 1 and 'tried again in 60 s' in lines[0].getMessage(), [r.getMessage() for r in lines]
    assert_same(m, local)
    # the next cycle does not try the cluster again (for 60 s): no second line, no delay
    t0 = time.monotonic()
    merged(pieces, dask_scheduler=dask_cluster.address, **CONFIG)
    assert len(fallback_lines(caplog)) == 1 and time.monotonic() - t0 < 10


def test_no_worker_left_leaves_the_cycle_to_the_local_pool_within_seconds(dask_cluster, pieces, local, caplog):
    """(dask itself would wait for a worker for ever)"""
    caplog.set_level(logging.WARNING)
    assert cluster.pool(dask_cluster.address).running()   # connected
    for w in dask_cluster.workers:
        Cluster.kill(w)
    t0 = time.monotonic()
    m = merged(pieces, dask_scheduler=dask_cluster.address, **CONFIG)
    assert time.monotonic() - t0 < cluster.NO_WORKERS_S + 10
    lines = fallback_lines(caplog)
    assert len(lines) == 1 and 'no worker' in lines[0].getMessage(), [r.getMessage() for r in lines]
    assert_same(m, local)


def merged_locally_with_one_line(pieces, local, caplog, address):
    """Merge with ``dask_scheduler`` at ``address`` where no cluster can serve: the merge is the
    local pool's, with one fallback line (returned)."""
    try:
        m = merged(pieces, dask_scheduler=address, **CONFIG)
        lines = fallback_lines(caplog)
        assert len(lines) == 1, [r.getMessage() for r in lines]
        assert_same(m, local)
        return lines[0].getMessage()
    finally:
        _forget_cluster()


# A merge with a scheduler named, in an interpreter where ``import distributed`` fails (as on a
# machine without python3-distributed, whether or not this one has it): its placements, its
# composite's cells and the cluster's log lines, as JSON on the last line.
WITHOUT_DISTRIBUTED = """
import hashlib, json, logging, sys
sys.modules['distributed'] = None    # import distributed: ImportError, as where it is not installed
sys.path[:0] = sys.argv[3:]
from conftest import INTEL_MAP, merged, shared_file
from multi_map_merge.core.mapio import load_map
from test_cluster import CONFIG, cut_pieces
lines = []
handler = logging.Handler()
handler.emit = lambda r: lines.append(r.getMessage())
logging.getLogger('multi_map_merge.runtime.cluster').addHandler(handler)
m = merged(cut_pieces(load_map(sys.argv[1])), dask_scheduler=sys.argv[2], **CONFIG)
g = m.compose()
print(json.dumps(dict(lines=lines, placements={n: p.T.tolist() for n, p in m.placements().items()},
                      cells=hashlib.sha1(g.data.tobytes()).hexdigest(),
                      distributed=sorted(k for k in sys.modules if k.split('.')[0] == 'distributed'
                                         and sys.modules[k] is not None))))
"""


def test_without_distributed_the_local_pool_merges_with_one_line(pieces, local):
    here = os.path.dirname(os.path.abspath(__file__))
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get('PYTHONPATH', ''))
    out = subprocess.run([sys.executable, '-c', WITHOUT_DISTRIBUTED, shared_file(INTEL_MAP), 'tcp://127.0.0.1:8786',
                          here, os.path.dirname(here)], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got['distributed'] == [], got['distributed']     # not imported: it could not be
    assert len(got['lines']) == 1 and 'python3-distributed is not installed' in got['lines'][0], got['lines']
    ref = local.placements()
    assert sorted(got['placements']) == sorted(ref)
    for n, T in got['placements'].items():
        assert np.array_equal(np.array(T), ref[n].T), n
    assert got['cells'] == hashlib.sha1(local.compose().data.tobytes()).hexdigest()


def test_distributed_is_imported_only_when_a_scheduler_is_given(pieces, house_yaml):
    """Robots and users without a cluster do not need it (a fresh interpreter: this one has it)."""
    script = ('import sys\n'
              'from multi_map_merge.core.config import MergeConfig\n'
              'from multi_map_merge.core.merger import MapMerger\n'
              'from multi_map_merge.core.mapio import load_map\n'
              'm = MapMerger(MergeConfig(workers=1))\n'
              'for n in "ab":\n'
              '    m.update_map(n, load_map(sys.argv[1]))\n'
              'm.estimate()\n'
              'print(sorted(k for k in sys.modules if k.split(".")[0] in ("dask", "distributed")))\n')
    env = dict(os.environ, PYTHONPATH=SRC + os.pathsep + os.environ.get('PYTHONPATH', ''))
    out = subprocess.run([sys.executable, '-c', script, house_yaml], capture_output=True, text=True, env=env,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == '[]'


def test_an_unreachable_scheduler_falls_back_within_seconds_with_one_line(pieces, local, caplog):
    pytest.importorskip('distributed', reason=NO_DISTRIBUTED)
    caplog.set_level(logging.WARNING)
    _forget_cluster()
    t0 = time.monotonic()
    line = merged_locally_with_one_line(pieces, local, caplog, 'tcp://127.0.0.1:1')
    assert time.monotonic() - t0 < cluster.CONNECT_TIMEOUT_S + 10
    assert 'tcp://127.0.0.1:1' in line


# -- the pool itself, mid-cycle: tasks that wait (time.sleep: importable on the workers), and a
#    process killed meanwhile


TASK_S = 3.0   # how long a task of the tests below runs (s): time enough to kill its worker meanwhile


def test_a_worker_killed_mid_task_its_task_is_done_by_the_other(dask_cluster):
    p = cluster.pool(dask_cluster.address)
    future = p.submit(time.sleep, TASK_S)
    worker, key = dask_cluster.worker_running_a_task()
    time.sleep(TASK_S / 2)    # half done: its end, had it gone on, would come TASK_S / 2 after the kill
    t_kill = time.monotonic()
    Cluster.kill(worker)
    assert future.result(timeout=30) is None, key
    # begun again from its start on the other worker, not finished by the one killed
    assert time.monotonic() - t_kill >= TASK_S - 0.1, key
    assert worker.returncode == -signal.SIGKILL
    assert p.running() and p.finished == 1


def test_the_scheduler_killed_mid_task_fails_the_tasks_at_once(dask_cluster):
    p = cluster.pool(dask_cluster.address)
    futures = [p.submit(time.sleep, 30) for _ in range(2)]
    dask_cluster.worker_running_a_task()
    t0 = time.monotonic()
    Cluster.kill(dask_cluster.scheduler)
    for f in futures:
        with pytest.raises(cluster.ClusterLost):
            f.result(timeout=30)
    assert time.monotonic() - t0 < 10 and not p.running()


def test_every_worker_killed_mid_task_fails_the_tasks_within_seconds(dask_cluster):
    """(dask itself would wait for a worker for ever)"""
    p = cluster.pool(dask_cluster.address)
    futures = [p.submit(time.sleep, 30) for _ in range(2)]
    dask_cluster.worker_running_a_task()
    t0 = time.monotonic()
    for w in dask_cluster.workers:
        Cluster.kill(w)
    for f in futures:
        with pytest.raises(cluster.ClusterLost, match='no worker'):
            f.result(timeout=30)
    assert time.monotonic() - t0 < cluster.NO_WORKERS_S + 10
