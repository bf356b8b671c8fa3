"""A Dask cluster on the loopback, for the rostest and the benchmark that merge through one
(``test/ros/test_dask_cluster.py``, ``bench/cluster_overhead.py``): a scheduler and workers
started as users start them (``python3 -m distributed.cli.dask_scheduler`` and ``dask_worker``),
each a process of its own group with its output in a log file, and a client of the caller's own
to ask the scheduler which tasks ran where. Needs ``distributed`` (Debian/Ubuntu
``python3-distributed``), imported when the cluster starts."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from typing import Dict, List, Optional, Tuple

from . import processes


class LoopbackCluster:
    """A scheduler and ``n_workers`` workers of one thread each on 127.0.0.1, without nannies
    (a killed worker stays dead), their logs and working directories in ``tmp``; ``env``: the
    processes' environment (default: this one's)."""

    def __init__(self, tmp: str, env: Optional[Dict[str, str]] = None):
        self.tmp = tmp
        self.env = env
        self.scheduler: Optional[subprocess.Popen] = None
        self.workers: List[subprocess.Popen] = []     # in start order: worker0, worker1, ...
        self.address: Optional[str] = None
        self.client = None

    def _start(self, name: str, *args: str) -> subprocess.Popen:
        return processes.start_group([sys.executable, '-m'] + list(args), os.path.join(self.tmp, name + '.log'),
                                     self.env, cwd=self.tmp, append=False)

    def log(self, name: str, lines: int = 20) -> str:
        """The last ``lines`` of a process's output ('scheduler', 'worker0', ...), for messages."""
        try:
            with open(os.path.join(self.tmp, name + '.log')) as f:
                return ''.join(f.readlines()[-lines:])
        except OSError as e:
            return str(e)

    def start(self, n_workers: int = 2, timeout: float = 90.0) -> str:
        """Start them; returns the scheduler's address once every worker has joined (it takes a
        free port of the loopback and writes its address to a file). Raises RuntimeError, with
        the processes' last lines, when they do not come up within ``timeout`` seconds; what
        started is left to :meth:`stop`; RuntimeError too without ``distributed``."""
        try:
            import distributed
        except ImportError as e:   # optional: only a Dask cluster needs it
            raise RuntimeError('python3-distributed is not installed (import distributed: %s)' % e) from None
        info = os.path.join(self.tmp, 'scheduler.json')
        self.scheduler = self._start('scheduler', 'distributed.cli.dask_scheduler', '--host', '127.0.0.1',
                                     '--port', '0', '--scheduler-file', info, '--no-dashboard',
                                     '--dashboard-address', '127.0.0.1:0')
        end = time.monotonic() + timeout
        while self.address is None:
            try:
                with open(info) as f:
                    self.address = json.load(f)['address']
            except (OSError, ValueError, KeyError):       # not written yet, or not whole yet
                if self.scheduler.poll() is not None:
                    raise RuntimeError('the Dask scheduler ended (%s): %s'
                                       % (self.scheduler.returncode, self.log('scheduler'))) from None
                if time.monotonic() > end:
                    raise RuntimeError('the Dask scheduler did not start within %.0f s: %s'
                                       % (timeout, self.log('scheduler'))) from None
                time.sleep(0.1)
        for i in range(n_workers):
            self.workers.append(self._start('worker%d' % i, 'distributed.cli.dask_worker', self.address,
                                            '--nthreads', '1', '--no-nanny', '--memory-limit', '0',
                                            '--no-dashboard', '--name', 'worker%d' % i,
                                            '--local-directory', os.path.join(self.tmp, 'worker%d' % i),
                                            '--death-timeout', '10'))
        self.client = distributed.Client(self.address, timeout=30, set_as_default=False)
        while len(self.client.scheduler_info()['workers']) < n_workers:
            if time.monotonic() > end:
                raise RuntimeError('the Dask workers did not join within %.0f s: %s' % (
                    timeout, '\n'.join(self.log('worker%d' % i) for i in range(n_workers))))
            time.sleep(0.2)
        self.client.get_task_stream()   # the scheduler records every task from now on (its task stream)
        return self.address

    def tasks(self, prefix: str) -> List[Tuple[str, str]]:
        """The finished tasks whose key starts with ``prefix``: [(key, worker address)]."""
        return [(str(t['key']), t['worker']) for t in self.client.get_task_stream()
                if str(t['key']).startswith(prefix) and t.get('status', 'OK') == 'OK']

    def close_client(self) -> None:
        if self.client is not None:
            try:
                self.client.close(timeout=10)
            except Exception:   # a scheduler already gone: nothing to close
                pass
            self.client = None

    @staticmethod
    def kill(p: Optional[subprocess.Popen]) -> None:
        """SIGKILL to a process's group; waits for it (``processes.stop_group``)."""
        processes.stop_group(p, 0.0, first=signal.SIGKILL)

    def stop(self) -> None:
        """The client closed, every process killed (workers first)."""
        self.close_client()
        for p in self.workers + [self.scheduler]:
            self.kill(p)
