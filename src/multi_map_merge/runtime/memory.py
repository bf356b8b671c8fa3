"""A worker process's heap: glibc keeps the memory a task freed, and a worker would hold its
largest task's working set for good. Each task is run through :func:`run_task`, which hands
the heap's free memory back after a task that left much of it free, and a worker's idle thread
(:func:`trim_when_idle`) hands back the rest once the worker has been idle a while."""
from __future__ import annotations

import time

_BUSY = False
_LAST = 0.0
IDLE_TRIM_S = 1.0
# free heap (bytes) a task may leave behind before the worker hands it back at once: a task's
# ordinary leftovers (a parent's wall field, a window's masks: a few MB) stay for the next task
# of the cycle, which would otherwise fault them in again; the idle trim returns them after it
TRIM_FREE_BYTES = 16 << 20


def run_task(fn, *args):
    """``fn(*args)`` in a worker, its end noted for :func:`trim_when_idle`; the heap trimmed
    after it when it left much of it free (:func:`trim_if_free`)."""
    global _BUSY, _LAST
    _BUSY = True
    try:
        return fn(*args)
    finally:
        trim_if_free(TRIM_FREE_BYTES)
        _BUSY, _LAST = False, time.monotonic()


def malloc_trim():
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
    """:func:`malloc_trim`'s pair, looked up once per process (False where there is none)."""
    global _TRIM
    if _TRIM is None:
        _TRIM = malloc_trim() or False
    return _TRIM


def trim_if_free(limit: int) -> None:
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


def trim_when_idle() -> None:
    """Hand the memory a worker freed back to the system once it has been idle a second. glibc
    keeps freed heap memory (and raises its mmap threshold after a big array is freed, so later
    big arrays come from the heap too): a worker would hold its largest task's working set for
    good (what a task left under :data:`TRIM_FREE_BYTES`, and what the heap's fragments hold).
    Runs for ever: a worker's daemon thread."""
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
