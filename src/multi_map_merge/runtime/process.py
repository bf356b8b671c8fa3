"""Worker processes: how they are started (forked, or from a forkserver), what each sets up
first (:func:`worker_init`), and the library threads of the processes involved."""
from __future__ import annotations

import threading
from typing import Sequence

from . import memory


def worker_init() -> None:
    """One OpenCV thread and one BLAS thread per worker: the pool already keeps every core
    busy, and the libraries' own threads on top of it only contend (two workers running two
    threads each are slower than two workers with one each). A worker ignores SIGINT (Ctrl-C
    reaches the whole process group: the node, not its workers, decides when they stop) and
    dies with the process that started it, which a forked worker would otherwise outlive,
    blocked on a queue whose other end it holds itself. Its heap is trimmed when it is idle
    (:func:`memory.trim_when_idle`)."""
    import signal
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    die_with_parent()
    threading.Thread(target=memory.trim_when_idle, name='trim', daemon=True).start()
    import cv2
    if cv2.getNumThreads() != 1:   # (a forked worker is on one thread already: see fork_now)
        cv2.setNumThreads(1)
    one_blas_thread()


def die_with_parent() -> None:
    """SIGKILL this process when its parent exits (Linux's PR_SET_PDEATHSIG; elsewhere nothing)."""
    import ctypes
    import signal
    try:
        libc = ctypes.CDLL(None)
        libc.prctl(1, signal.SIGKILL)   # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def one_blas_thread() -> None:
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


def start_context(preload: Sequence[str]):
    """The multiprocessing context to start workers with: 'fork' while this process runs no
    other thread (the workers share its pages: its imports cost the machine once, not once per
    worker), else a 'forkserver' that imports the modules ``preload`` once for all of them
    (forking a threaded process could copy a lock held by another thread)."""
    import multiprocessing
    if threading.active_count() == 1 and 'fork' in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context('fork')
    ctx = multiprocessing.get_context('forkserver')
    ctx.set_forkserver_preload(list(preload))
    return ctx


def fork_now(pool) -> None:
    """Every worker of a 'fork' pool forked now, before this process starts a thread (the
    pool's own thread starts with its first task: Python forks all of a 'fork' pool's workers
    then), and with OpenCV on one thread meanwhile: OpenCV's own thread pool, once started (a
    warp before), would be copied without its threads, and a worker changing its thread count
    would wait for them for ever (seen with OpenCV 4.2's pthreads pool)."""
    import gc

    import cv2
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    # Every object alive now (the imports', above all) out of the collector's reach for good:
    # a collection writes to each object it visits, and each page it writes in this process
    # afterwards is one page more for the machine, the workers keeping the page as it was
    gc.freeze()
    try:
        pool.submit(int).result()
    finally:
        cv2.setNumThreads(threads)
