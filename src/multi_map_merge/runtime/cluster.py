"""A Dask cluster as the pool of pair jobs (``~dask_scheduler``): what one machine cannot hold.

:func:`pool` connects a ``distributed.Client`` to the scheduler once per process, lazily (the
first cycle that asks for it), and returns a :class:`ClusterPool`: the client's own executor
(``Client.get_executor``), whose ``submit`` gives ``concurrent.futures`` futures, as the local
process pool's does, so the pair jobs are sent to either the same way. ``distributed`` is
imported only here, only then: it is an optional dependency.

A cluster fails fast rather than hang. The scheduler reschedules a dead worker's tasks on the
others (invisible here), but with every worker gone it would wait for ever, and with the
scheduler gone the client cancels every task: a watchdog thread fails the pending futures
(:class:`ClusterLost`) when the client no longer runs, or the scheduler cannot be asked, or it
has had no worker for :data:`NO_WORKERS_S`. The caller then does the cycle's pairs in the local
pool and calls :func:`lost`, which logs one line, closes the client and leaves the cluster alone
for :data:`RETRY_S`.

Workers run the same functions on the same plain data (numpy arrays, dataclasses), pickled by
reference: the package, OpenCV and numpy must be importable there, in the same versions, for
the same results. Each worker process runs with one OpenCV and one BLAS thread, as a local
worker does (:func:`run_on_worker`)."""
from __future__ import annotations

import concurrent.futures as cf
import logging
import threading
import time
import warnings
from typing import Optional

log = logging.getLogger(__name__)

#: seconds to wait for the scheduler when connecting (and for its answers afterwards)
CONNECT_TIMEOUT_S = 5.0
#: seconds a cluster may have no worker while tasks wait before it counts as lost
NO_WORKERS_S = 3.0
#: seconds after a failure before the cluster is tried again
RETRY_S = 60.0
#: seconds between the watchdog's looks at the cluster while tasks are pending
WATCH_S = 0.5

_LOCK = threading.Lock()
_POOL: Optional['ClusterPool'] = None
_RETRY_AT = {}   # address -> time.monotonic() before which it is not tried again
_ABANDONED: list = []   # clients left reconnecting (:meth:`ClusterPool.close`)


class ClusterLost(RuntimeError):
    """The cluster cannot finish the work: unreachable, its scheduler or workers lost, or a
    worker that cannot import the package."""


def pool(address: str) -> Optional['ClusterPool']:
    """The pool of the cluster at ``address``, connected on first use; None while it is left
    alone after a failure (:data:`RETRY_S`). Raises :class:`ClusterLost` when it cannot connect
    (``distributed`` missing, or the scheduler unreachable within :data:`CONNECT_TIMEOUT_S`)."""
    global _POOL
    with _LOCK:
        _close_abandoned()
        if _POOL is not None and _POOL.address == address and _POOL.running():
            return _POOL
        if time.monotonic() < _RETRY_AT.get(address, 0.0):
            return None
        if _POOL is not None:
            _POOL.close()
            _POOL = None
        _POOL = ClusterPool(address)
        return _POOL


def lost(address: str, reason: BaseException) -> None:
    """After a failure: one log line, the client closed, the cluster left alone for
    :data:`RETRY_S`."""
    global _POOL
    with _LOCK:
        _RETRY_AT[address] = time.monotonic() + RETRY_S
        p, _POOL = _POOL, None
    if p is not None:
        p.close()
    log.warning('multi_map_merge: the Dask cluster at %s failed (%s): this cycle\'s pairs are done by the '
                'local workers, and the cluster is tried again in %.0f s', address, _reason(reason), RETRY_S)


def _reason(e: BaseException) -> str:
    """An exception in a few words: its type and its message's first line (only the message
    of :class:`ClusterLost`, which says it all)."""
    text = str(e).strip().splitlines()[0] if str(e).strip() else ''
    if isinstance(e, ClusterLost):
        return text
    return '%s: %s' % (type(e).__name__, text) if text else type(e).__name__


def failure_types() -> tuple:
    """The exceptions that mean the cluster, not the work, failed (a task's own exception is
    raised as it would be locally)."""
    return (ClusterLost, cf.CancelledError, cf.TimeoutError, OSError, ImportError)


def run_on_worker(fn, *args):
    """``fn(*args)`` on a cluster's worker (``fn`` is :func:`memory.run_task`, as in a local
    worker), which first sets itself up as a local worker's threads are
    (:func:`process.worker_init`'s one OpenCV thread, one BLAS thread)."""
    global _WORKER_READY
    if not _WORKER_READY:
        import cv2

        from . import process
        cv2.setNumThreads(1)
        process.one_blas_thread()
        _WORKER_READY = True
    return fn(*args)


_WORKER_READY = False


def _quiet_distributed() -> None:
    """``distributed``'s own log lines off in this process (reconnecting, closing, a lost
    connection's traceback): the one line of :func:`lost` says what happened. Its loggers with a
    level of their own (``distributed.client``) are set one by one."""
    names = [n for n in list(logging.root.manager.loggerDict) if n == 'distributed' or n.startswith('distributed.')]
    for n in set(names) | {'distributed', 'distributed.client'}:
        logging.getLogger(n).setLevel(logging.CRITICAL)


class ClusterPool:
    """A ``distributed.Client``'s own ``concurrent.futures`` executor (``Client.get_executor``)
    whose futures fail with :class:`ClusterLost` when the cluster does (see the module)."""

    def __init__(self, address: str):
        self.address = address
        try:
            import dask
            import distributed
        except ImportError as e:
            raise ClusterLost('python3-distributed is not installed (%s)' % e) from None
        _quiet_distributed()
        # a big map's crop is sent with each of its pairs (not scattered ahead): distributed
        # advises scattering once, on stderr; the maps change between cycles anyway
        warnings.filterwarnings('ignore', message='Large object of size', category=UserWarning)
        # the scheduler's answers (the watchdog's questions) within the same time as connecting
        dask.config.set({'distributed.comm.timeouts.connect': '%gs' % CONNECT_TIMEOUT_S})
        try:
            self.client = distributed.Client(address, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except Exception as e:   # OSError, asyncio's or tornado's TimeoutError, a bad address
            raise ClusterLost('cannot connect: %s' % _reason(e)) from None
        self._executor = self.client.get_executor(pure=False)
        self._lock = threading.Lock()
        # the futures handed out and not settled: each relays its executor future's outcome,
        # unless the watchdog failed it first (an executor future waits for ever with no worker)
        self._pending = set()
        self._watch = None
        self._failed: Optional[ClusterLost] = None
        self.finished = 0       # tasks the cluster finished

    def running(self) -> bool:
        return self._failed is None and self.client.status == 'running'

    def submit(self, fn, *args) -> cf.Future:
        out = cf.Future()
        out.set_running_or_notify_cancel()
        if self._failed is not None:
            out.set_exception(self._failed)
            return out
        try:
            task = self._executor.submit(run_on_worker, fn, *args)
        except Exception as e:
            out.set_exception(ClusterLost('cannot submit: %s' % _reason(e)))
            return out
        with self._lock:
            self._pending.add(out)
            if self._watch is None:
                self._watch = threading.Thread(target=self._watchdog, name='dask-watch', daemon=True)
                self._watch.start()
        task.add_done_callback(lambda task: self._relay(task, out))
        return out

    def _relay(self, task: cf.Future, out: cf.Future) -> None:
        """An executor future's outcome onto the future handed out for it: a cancelled task (the
        scheduler lost), a killed worker's or a missing import's as :class:`ClusterLost`."""
        if task.cancelled():
            result, error = None, ClusterLost('tasks cancelled: the scheduler is lost')
        else:
            result, error = None, task.exception()
            if error is None:
                result = task.result()
            elif type(error).__name__ == 'KilledWorker' or isinstance(error, ImportError):
                error = ClusterLost(_reason(error))
        with self._lock:
            if out not in self._pending:
                return               # failed by the watchdog already
            self._pending.discard(out)
            if error is None:
                out.set_result(result)
                self.finished += 1
            else:
                out.set_exception(error)

    def _fail_all(self, why: str) -> None:
        with self._lock:
            if self._failed is None:
                self._failed = ClusterLost(why)
            entries = list(self._pending)
            self._pending.clear()
            for out in entries:
                if not out.done():
                    out.set_exception(self._failed)

    def _watchdog(self) -> None:
        """While tasks are pending: fail them when the client stops running, the scheduler
        does not answer, or it has had no worker for :data:`NO_WORKERS_S`."""
        no_workers_since = None
        while True:
            time.sleep(WATCH_S)
            with self._lock:
                if not self._pending:
                    self._watch = None
                    return
            if self.client.status != 'running':
                self._fail_all('the client lost its scheduler (%s)' % self.client.status)
                continue
            try:
                try:
                    n = self.client.nthreads(callback_timeout=CONNECT_TIMEOUT_S)
                except TypeError:   # (a version whose sync methods take no callback_timeout)
                    n = self.client.nthreads()
            except Exception as e:
                self._fail_all('the scheduler does not answer: %s' % _reason(e))
                continue
            if n:
                no_workers_since = None
            elif no_workers_since is None:
                no_workers_since = time.monotonic()
            elif time.monotonic() - no_workers_since > NO_WORKERS_S:
                self._fail_all('no worker for %.0f s' % NO_WORKERS_S)

    def close(self) -> None:
        """Cancel what is pending and close the client (quietly: its scheduler may be gone).
        A client still trying to reconnect to a lost scheduler is left to give up by itself
        (within :data:`CONNECT_TIMEOUT_S`; closed at the next :func:`pool` if it reconnected):
        closing it meanwhile cancels its reconnection, which ``distributed`` reports as an
        error with a traceback on asyncio's logger."""
        self._fail_all('closed')
        if self.client.status == 'connecting':
            _ABANDONED.append(self.client)
            return
        try:
            self.client.close(timeout=CONNECT_TIMEOUT_S)
        except Exception:
            pass


def _close_abandoned() -> None:
    """Close the clients :meth:`ClusterPool.close` left reconnecting that are done with it."""
    for c in [c for c in _ABANDONED if c.status != 'connecting']:
        _ABANDONED.remove(c)
        if c.status != 'closed':
            try:
                c.close(timeout=CONNECT_TIMEOUT_S)
            except Exception:
                pass
