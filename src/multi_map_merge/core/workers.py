"""Steps (1)-(4) of many pairs in worker processes, and what a merger derives once per map.

Processes, not threads: estimation is partly pure Python, and in threads it would hold the GIL
that the node's /map and TF timers need (and two threads ran no faster than one: the GIL).
One pool serves every merger of a process. Small problems are estimated inline (see
:data:`POOL_FROM_CELLS`): a pool's workers cost memory, and on a few small maps they save tens
of milliseconds.

The workers are forked from the process while it has no other thread (:func:`start_pool`, which
the node calls before ``rospy.init_node``): they share the process's memory, its imports (OpenCV,
numpy) above all, page by page until written. Workers started later, from a process running
threads, come from a 'forkserver' that imported the estimation's modules once for all of them
(forking a threaded process could copy a lock held by another thread).
"""
from __future__ import annotations

import itertools
import os
import time
import zlib
from concurrent.futures.process import BrokenProcessPool
from typing import TYPE_CHECKING, Dict, List, Tuple

import numpy as np

from .config import MergeConfig
from .features import Features
from .pair import PairInput, PairResult, align_pair, crop_known, describe_version

if TYPE_CHECKING:   # (the merger imports this module)
    from .merger import RobotMap

_MERGERS = itertools.count()
_POOL = None
_POOL_SIZE = 0
# With ``workers: 0`` (one per core), maps whose known parts (their crops) hold fewer cells than
# this in all are estimated in this process: on a few small maps (a Turtlebot3 team in a house or
# a lab) the workers save a few tens of milliseconds per cold cycle, and the memory they take while
# they work is a large share of the node's then (docs/measurements.md, "Small problems inline").
# Larger problems, where the workers save up to seconds, use the pool; so does an explicit
# ``workers`` >= 2, always.
POOL_FROM_CELLS = 400_000


class PairWorkers:
    """One merger's side of the pool: the crop (known part) and the features of each of its
    maps, derived once per map version (:attr:`RobotMap.key`), and the pairs' alignment."""

    def __init__(self, config: MergeConfig):
        self.config = config
        self.uid = '%d-%d' % (os.getpid(), next(_MERGERS))   # names its maps in worker caches
        self._features: Dict[str, Tuple[tuple, Features]] = {}   # in the crops' cells
        self._crops: Dict[str, Tuple[tuple, np.ndarray, Tuple[int, int]]] = {}

    def forget(self, name: str) -> None:
        """Drop what was derived from a robot's maps."""
        self._features.pop(name, None)
        self._crops.pop(name, None)

    def crop(self, m: RobotMap) -> Tuple[np.ndarray, Tuple[int, int]]:
        """The known part of a map's levels and its (col, row) offset, once per map version:
        what features are computed on and what goes to the worker processes."""
        cached = self._crops.get(m.name)
        if cached is None or cached[0] != m.key:
            c = self.config
            lv = m.grid.levels(c.free_thresh, c.occupied_thresh)
            cached = self._crops[m.name] = (m.key,) + crop_known(
                lv, m.grid.known_box(c.free_thresh, c.occupied_thresh))
        return cached[1], cached[2]

    def features_of(self, m: RobotMap) -> Features:
        """(1) features of a map (in its crop's cells), computed once per map version."""
        cached = self._features.get(m.name)
        if cached is None or cached[0] != m.key:
            self._features[m.name] = (m.key, describe_version(self.config, self.crop(m)[0], self.uid,
                                                              m.name, m.version))
        return self._features[m.name][1]

    def _stale(self, maps: Dict[str, RobotMap]) -> List[RobotMap]:
        """The maps whose features are not those of their current version."""
        return [m for m in maps.values() if self._features.get(m.name, (None,))[0] != m.key]

    def _features_all(self, maps: Dict[str, RobotMap], pool) -> None:
        """Features of every map that changed, in ``pool``'s worker processes (None: here)."""
        todo = self._stale(maps)
        if not todo:
            return
        c = self.config
        levels = [self.crop(m)[0] for m in todo]
        for m, f in zip(todo, _map(pool, describe_version, [c] * len(todo), levels, [self.uid] * len(todo),
                                   [m.name for m in todo], [m.version for m in todo])):
            self._features[m.name] = (m.key, f)

    def pool_for(self, maps: Dict[str, RobotMap]):
        """The worker pool that estimates these maps, or None to estimate them in this process:
        ``workers: 1``, or ``workers: 0`` and maps smaller than :data:`POOL_FROM_CELLS`."""
        c = self.config
        if c.workers == 0 and sum(self.crop(m)[0].size for m in maps.values()) < POOL_FROM_CELLS:
            return None
        return _pool(c.workers)

    def input(self, m: RobotMap) -> PairInput:
        """A map as one side of a pair (its crop and features)."""
        levels, offset = self.crop(m)
        return PairInput(m.name, m.version, levels, m.grid.resolution, m.grid.origin,
                         self.features_of(m), self.uid, offset)

    def align_pairs(self, maps: Dict[str, RobotMap], todo: List[Tuple[str, str]]) -> List[PairResult]:
        """Features of the maps that changed, then every pair of ``todo`` aligned
        (:func:`pair.align_pair`), the results in ``todo``'s order.

        With a worker pool the two stages overlap: waiting for every map's features before
        the first pair would leave a worker idle while the slowest map is described.

        A worker that died (killed, e.g. by the kernel's OOM killer) breaks the pool: this
        cycle raises ``BrokenProcessPool``, and the next one starts a new pool."""
        try:
            return self._align_pairs(maps, todo)
        except BrokenProcessPool:
            _discard_pool()
            raise

    def _align_pairs(self, maps: Dict[str, RobotMap], todo: List[Tuple[str, str]]) -> List[PairResult]:
        c = self.config
        seeds = {ab: zlib.crc32(('%s|%s' % ab).encode()) for ab in todo}
        stale = self._stale(maps)
        # the biggest maps first: the last task to start should be a short one
        stale.sort(key=lambda m: -m.grid.width * m.grid.height)
        pool = self.pool_for(maps)
        if pool is None or not stale:
            self._features_all(maps, pool)
            inputs = {n: self.input(maps[n]) for n in {x for ab in todo for x in ab}}
            return _map(pool, align_pair, [c] * len(todo), [inputs[a] for a, _ in todo],
                        [inputs[b] for _, b in todo], [seeds[ab] for ab in todo])
        from concurrent.futures import as_completed
        waiting = {pool.submit(_task, describe_version, c, self.crop(m)[0], self.uid, m.name, m.version): m
                   for m in stale}
        ready = set(maps) - {m.name for m in stale}
        queued: Dict[Tuple[str, str], object] = {}
        inputs: Dict[str, PairInput] = {}

        def submit_ready() -> None:
            for ab in todo:
                if ab not in queued and ab[0] in ready and ab[1] in ready:
                    for n in ab:
                        if n not in inputs:
                            inputs[n] = self.input(maps[n])
                    queued[ab] = pool.submit(_task, align_pair, c, inputs[ab[0]], inputs[ab[1]], seeds[ab])

        submit_ready()
        for fut in as_completed(waiting):
            m = waiting[fut]
            self._features[m.name] = (m.key, fut.result())
            ready.add(m.name)
            submit_ready()
        return [queued[ab].result() for ab in todo]


def _map(pool, fn, *iterables) -> list:
    """fn over the arguments in ``pool``'s workers (in this process when it is None)."""
    if pool is None:
        return list(map(fn, *iterables))
    return list(pool.map(_task, itertools.repeat(fn), *iterables))


def _task(fn, *args):
    """``fn(*args)`` in a worker, its end noted for :func:`_trim_when_idle`; the heap trimmed
    after it when it left much of it free (:func:`_trim_if_free`)."""
    global _BUSY, _LAST
    _BUSY = True
    try:
        return fn(*args)
    finally:
        _trim_if_free(TRIM_FREE_BYTES)
        _BUSY, _LAST = False, time.monotonic()


_BUSY = False
_LAST = 0.0
IDLE_TRIM_S = 1.0
# free heap (bytes) a task may leave behind before the worker hands it back at once: a task's
# ordinary leftovers (a parent's wall field, a window's masks: a few MB) stay for the next task
# of the cycle, which would otherwise fault them in again; the idle trim returns them after it
TRIM_FREE_BYTES = 16 << 20


def _malloc_trim():
    """glibc's ``malloc_trim`` and a function giving the heap's free bytes (``mallinfo2``, or
    ``mallinfo`` before glibc 2.33: Ubuntu 20.04), or None elsewhere."""
    import ctypes
    try:
        libc = ctypes.CDLL(None)
        trim = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    wide = hasattr(libc, 'mallinfo2')
    field = ctypes.c_size_t if wide else ctypes.c_int

    class MallInfo(ctypes.Structure):
        _fields_ = [(n, field) for n in ('arena', 'ordblks', 'smblks', 'hblks', 'hblkhd', 'usmblks',
                                         'fsmblks', 'uordblks', 'fordblks', 'keepcost')]
    info = libc.mallinfo2 if wide else libc.mallinfo
    info.restype = MallInfo
    return trim, lambda: info().fordblks


_TRIM = None


def _trim_functions():
    """:func:`_malloc_trim`'s pair, looked up once per process (False where there is none)."""
    global _TRIM
    if _TRIM is None:
        _TRIM = _malloc_trim() or False
    return _TRIM


def _trim_if_free(limit: int) -> None:
    """Hand the heap's free memory back to the system when more than ``limit`` bytes of it are
    free: a task that described a big map (AKAZE's scale space: about 170 bytes per pixel) or
    searched a big pair leaves tens of megabytes free that glibc keeps; the next task would
    reuse only part of them, and the worker's footprint would be its largest task's until the
    cycle ends. Only then: trimming after every task would fault the next task's memory in
    again, page by page (a fault costs microseconds; a task's fresh memory is thousands of
    pages).
    Asking is cheap (``mallinfo`` walks the arena's bins, microseconds against a task's
    milliseconds), so it is asked after every task."""
    found = _trim_functions()
    if found and found[1]() > limit:
        found[0](0)


def _trim_when_idle() -> None:
    """Hand the memory a worker freed back to the system once it has been idle a second. glibc
    keeps freed heap memory (and raises its mmap threshold after a big array is freed, so later
    big arrays come from the heap too): a worker would hold its largest task's working set for
    good (what a task left under :data:`TRIM_FREE_BYTES`, and what the heap's fragments hold)."""
    found = _trim_functions()
    if not found:
        return
    trim = found[0]
    done = _LAST
    while True:
        time.sleep(IDLE_TRIM_S / 2)
        last = _LAST
        if not _BUSY and last != done and time.monotonic() - last >= IDLE_TRIM_S:
            trim(0)
            done = last


def _worker_init() -> None:
    """One OpenCV thread and one BLAS thread per worker: the pool already keeps every core
    busy, and the libraries' own threads on top of it only contend (two workers running two
    threads each are slower than two workers with one each). A worker ignores SIGINT (Ctrl-C
    reaches the whole process group: the node, not its workers, decides when they stop) and
    dies with the process that started it, which a forked worker would otherwise outlive,
    blocked on a queue whose other end it holds itself."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent()
    import threading
    threading.Thread(target=_trim_when_idle, name='trim', daemon=True).start()
    import cv2
    if cv2.getNumThreads() != 1:   # (a forked worker is on one thread already: see start_pool)
        cv2.setNumThreads(1)
    _one_blas_thread()


def _die_with_parent() -> None:
    """SIGKILL this process when its parent exits (Linux's PR_SET_PDEATHSIG; elsewhere nothing)."""
    import ctypes
    import signal
    try:
        libc = ctypes.CDLL(None)
        libc.prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def _one_blas_thread() -> None:
    """numpy's BLAS to one thread in this process where it is OpenBLAS (Debian's libblas.so.3
    once libopenblas is installed). RANSAC scores hypotheses by matrix products, and
    OpenBLAS's threads spin after each one, costing CPU the other worker could use. Other BLAS
    builds are left as they are."""
    import ctypes
    for name in ('libblas.so.3', 'libopenblas.so.0'):
        try:
            lib = ctypes.CDLL(name)
        except OSError:
            continue
        set_threads = getattr(lib, 'openblas_set_num_threads', None)
        if set_threads is not None:
            set_threads(1)
            return


def _discard_pool() -> None:
    """Drop a broken pool: the next :func:`_pool` starts a new one."""
    global _POOL, _POOL_SIZE
    if _POOL is not None:
        _POOL.shutdown(wait=False)
    _POOL, _POOL_SIZE = None, 0


def _pool(workers: int):
    """The process pool shared by every merger in this process (None: work inline)."""
    global _POOL, _POOL_SIZE
    n = workers or os.cpu_count() or 1
    if (n <= 1 and _POOL is not None) or (n > 1 and (_POOL is None or _POOL_SIZE != n)):
        start_pool(n)   # (started early with the default size, then configured otherwise)
    return _POOL


def start_pool(workers: int = 0) -> None:
    """Start the worker pool now (``workers`` as :attr:`MergeConfig.workers`: 0 = one per core).

    Called while the process runs no other thread (the node: before ``rospy.init_node``), the
    workers are forked from it and share its pages: its imports cost the machine once, not once
    per worker. Otherwise they come from a 'forkserver' that has imported the estimation's
    modules, so that at least the workers share those."""
    global _POOL, _POOL_SIZE
    import multiprocessing
    import threading
    from concurrent.futures import ProcessPoolExecutor
    # This process places the robots (the pose graph's and the covariances' small solves, a
    # few 3N x 3N systems per cycle): OpenBLAS's LAPACK runs even a 9 x 9 solve on its threads,
    # which take milliseconds to wake while the workers keep the cores busy, microseconds on one
    _one_blas_thread()
    n = workers or os.cpu_count() or 1
    if _POOL is not None:
        # waiting for the old workers (idle: a pool is replaced only when the configured size
        # differs from the one started early); Python 3.8's executor left behind with wait=False
        # can hang the interpreter's exit
        _POOL.shutdown(wait=True)
        _POOL, _POOL_SIZE = None, 0
    if n <= 1:
        return
    if threading.active_count() == 1 and 'fork' in multiprocessing.get_all_start_methods():
        ctx = multiprocessing.get_context('fork')
    else:
        ctx = multiprocessing.get_context('forkserver')
        ctx.set_forkserver_preload([__name__.rsplit('.', 1)[0] + '.pair'])
    pool = ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_worker_init)
    if ctx.get_start_method() == 'fork':
        # Every worker forked now, before this process starts a thread (the pool's own thread
        # starts with its first task: Python forks all of a 'fork' pool's workers then), and
        # with OpenCV on one thread meanwhile: OpenCV's own thread pool, once started (a warp
        # before), would be copied without its threads, and a worker changing its thread count
        # would wait for them for ever (seen with OpenCV 4.2's pthreads pool).
        import cv2
        threads = cv2.getNumThreads()
        cv2.setNumThreads(1)
        try:
            pool.submit(int).result()
        finally:
            cv2.setNumThreads(threads)
    _POOL, _POOL_SIZE = pool, n
