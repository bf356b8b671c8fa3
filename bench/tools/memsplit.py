#!/usr/bin/env python3
"""Where the estimation workers' memory comes from, page by page (root: reads /proc/PID/pagemap).

    bench/bench.py memsplit [--row 'house 4'] [--cycles 2] [--idle 0]

Runs what bench/ours.py --memory runs (the node's imports, the worker pool forked as the node
forks it, cold cycles of a merger on the row's maps) in this process, with the page frames of
this process read just before the fork. After the cycles, each page a worker maps that this
process does not is one of:
  worker-wrote  a page of this process's from before the fork that the worker wrote to: its copy
                (a reference count, an allocator's list, a freed block reused; one per worker)
  node-wrote    a page from before the fork that this process wrote to since: the worker still
                maps the original, this process its copy (one for all the workers)
  new           memory the worker mapped after the fork (its working memory; heap grown since)
  library       pages of a library file that only the workers touched (OpenCV code the node
                never runs: shared by the workers, counted once in the tree)
by the mapping it is in ([heap], [anon]: Python's and numpy's arenas, lib-rw: a library's
written data). Prints one line per worker and the tree's total. Needs ../shared/data (the maps of
every row).
"""
from __future__ import annotations

import argparse
import collections
import os
import subprocess
import sys
import time

import inputs  # noqa: E402
import memtree  # noqa: E402
import numpy as np

PAGE = memtree.PAGE


KINDS = ('[heap]', '[anon]', '[stack]', 'lib-rw', 'library')


def resident(pid: int):
    """``pid``'s resident pages as arrays (sorted virtual page numbers, their frames, their kind:
    an index into KINDS: [heap], [anon] (and other anonymous mappings), [stack], lib-rw (a
    library's writable data), library (a library's other pages)). Arrays, not a dict: reading
    must not move much of this process's own memory."""
    pages, frames, kinds = [], [], []
    with open('/proc/%d/pagemap' % pid, 'rb', buffering=0) as pm:
        for lo, hi, perms, name in memtree.mappings(pid):
            kind = (KINDS.index(name) if name in KINDS else 1) if name.startswith('[') else (
                3 if perms.startswith('rw') else 4)
            k, f = memtree.present(pm.fileno(), lo, hi)
            pages.append(lo + k.astype(np.uint64))
            frames.append(f)
            kinds.append(np.full(k.size, kind, np.uint8))
    pages, frames, kinds = (np.concatenate(x) for x in (pages, frames, kinds))
    order = np.argsort(pages)
    return pages[order], frames[order], kinds[order]


def split(before, node, worker) -> collections.Counter:
    """Pages of ``worker`` not shared with ``node`` (this process now), by origin and kind
    (each a :func:`resident`; ``before``: this process's, just before the fork)."""
    pages, frames, kinds = worker
    mine = ~np.isin(frames, node[1])
    at = np.minimum(np.searchsorted(before[0], pages), before[0].size - 1)
    existed = before[0][at] == pages
    original = existed & (before[1][at] == frames)
    out = collections.Counter()
    for origin, sel in (('node-wrote', original), ('worker-wrote', existed & ~original), ('new', ~existed)):
        for k, n in zip(*np.unique(kinds[mine & sel], return_counts=True)):
            out['library' if KINDS[k] == 'library' else '%s %s' % (origin, KINDS[k])] += int(n)
    return out


def measure(paths, cycles: int, idle: float) -> None:
    """The split, in this process, on the map files ``paths`` (read without cv2.imread, as
    bench/ours.py --memory reads them: imread maps GDAL's library, which the node never does)."""
    import ours

    import multi_map_merge.ros.node  # noqa: F401  (the node's imports, as bench/ours.py --memory)
    from multi_map_merge.core import workers
    from multi_map_merge.core.config import MergeConfig
    grids = ours.maps_as_the_node_reads_them(paths)
    me = os.getpid()
    before = resident(me)
    if not before[1].any():
        raise SystemExit('pagemap gives no page frames without CAP_SYS_ADMIN: run as root')
    workers.start_pool(0)
    for _ in range(cycles):
        ours.node_cycle(MergeConfig(), grids)
    time.sleep(idle)
    node = resident(me)
    mb = lambda n: n * PAGE / 2.0 ** 20  # noqa: E731
    print('%d cold cycles%s: this process %.1f MB (%.1f MB before the fork)' % (
        cycles, ', %.1f s idle' % idle if idle else '', mb(node[0].size), mb(before[0].size)))
    frames = [node[1]]
    for pid in memtree.children(me):
        w = resident(pid)
        c = split(before, node, w)
        frames.append(w[1])
        print('worker %d: %.1f MB not shared with this process: %s' % (
            pid, mb(sum(c.values())), ', '.join('%s %.1f' % (k, mb(v)) for k, v in c.most_common())))
    print('the tree, every page once: %.1f MB' % mb(np.unique(np.concatenate(frames)).size))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--row', default='house 4', help="a row of bench/inputs.py ('house 4', 'intel 4', ...)")
    ap.add_argument('--cycles', type=int, default=2, help='cold cycles before the pages are read')
    ap.add_argument('--idle', type=float, default=0.0,
                    help='seconds to wait after them (the workers trim their heap after 1 s idle)')
    ap.add_argument('--maps', nargs='+', help=argparse.SUPPRESS)   # (the measuring process)
    a = ap.parse_args()
    if a.maps:
        measure(a.maps, a.cycles, a.idle)
        return 0
    import tempfile
    with tempfile.TemporaryDirectory(prefix='memsplit_') as root:
        paths = inputs.row_paths(a.row, root)
        print(a.row, end=', ', flush=True)
        # a process of its own: building the rows took memory that the node never holds
        return subprocess.call([sys.executable, os.path.abspath(__file__), '--cycles', str(a.cycles),
                                '--idle', str(a.idle), '--maps'] + paths)


if __name__ == '__main__':
    sys.exit(main())
