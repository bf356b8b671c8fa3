"""bench/memtree.py's page counting: the merged pagemap spans read the same frames as reading
each mapping on its own (which is far slower for a node tree)."""
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

BENCH = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'bench')
sys.path.insert(0, os.path.abspath(BENCH))

import memtree  # noqa: E402


def frames_per_mapping(pid):
    """Resident frames of ``pid``, one pagemap read per mapping of /proc/PID/maps."""
    out = []
    with open('/proc/%d/maps' % pid) as m, open('/proc/%d/pagemap' % pid, 'rb', buffering=0) as pm:
        for line in m:
            if 'vsyscall' in line:
                continue
            a, b = (int(x, 16) // memtree.PAGE for x in line.split()[0].split('-'))
            v = np.frombuffer(os.pread(pm.fileno(), (b - a) * 8, a * 8), np.uint64)
            out.append(v[(v & memtree._PRESENT) != 0] & memtree._PFN_MASK)
    return np.sort(np.concatenate(out))


@pytest.fixture
def stopped_child():
    """A Python process with numpy and a few hundred mappings, stopped (its pages hold still)."""
    p = subprocess.Popen([sys.executable, '-c', 'import numpy, sys; a = numpy.ones(1 << 20); '
                          'print(1, flush=True); sys.stdin.read()'],
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert p.stdout.readline().strip() == b'1'
        os.kill(p.pid, signal.SIGSTOP)
        time.sleep(0.1)
        yield p.pid
    finally:
        p.kill()
        p.wait()


def test_merged_spans_read_the_same_frames(stopped_child):
    merged = memtree.frames(stopped_child)
    if merged is None:
        pytest.skip('pagemap gives no page frames without CAP_SYS_ADMIN (not root)')
    one_by_one = frames_per_mapping(stopped_child)
    assert one_by_one.size > 2000             # numpy's pages and the 8 MB array, at least
    assert np.array_equal(np.sort(merged), one_by_one)
    spans = memtree.spans(stopped_child)
    maps = sum(1 for _ in open('/proc/%d/maps' % stopped_child))
    assert len(spans) < maps / 5
    assert all(lo < hi for lo, hi in spans)
    assert all(a[1] <= b[0] for a, b in zip(spans, spans[1:]))   # sorted, disjoint
