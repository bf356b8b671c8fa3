"""Memory of a process tree, each physical page counted once (what the tree costs the machine).

A process and its worker processes share pages: the libraries' code (file pages), and, for
workers forked from a process that had already imported them, the imports' own memory
(copy-on-write). Summing each process's RSS counts those pages once per process (an upper
bound); summing PSS divides pages shared with processes outside the tree too (other Python
processes that load OpenCV make ours look smaller). Counted here instead: the union of the
physical pages mapped by the tree's processes, read from ``/proc/PID/pagemap`` (page frame
numbers; needs CAP_SYS_ADMIN, i.e. root). For a single process this is its RSS, so it compares
with m-explore's ``ru_maxrss``. Without root the union is unknown: ``unique_mb`` is None and
the sum of PSS is given instead (``pss_mb``), with ``rss_sum_mb`` as the upper bound.

    python3 bench/memtree.py PID [PID...]     -> one JSON line: the tree of each PID, now

:func:`watch` runs a command and samples its tree from this process (the measuring is no part of
what is measured: reading pagemap costs the reader a few MB of buffers).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time

import numpy as np

PAGE = os.sysconf('SC_PAGE_SIZE')
_PFN_MASK = np.uint64((1 << 55) - 1)
_PRESENT = np.uint64(1 << 63)


def children(pid: int) -> list:
    """Every descendant of ``pid`` (from /proc/*/stat's parent ids)."""
    parent = {}
    for d in os.listdir('/proc'):
        if d.isdigit():
            try:
                with open('/proc/%s/stat' % d) as f:
                    s = f.read()
                parent[int(d)] = int(s[s.rindex(')') + 2:].split()[1])
            except (OSError, ValueError, IndexError):
                pass
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        out += kids
        todo += kids
    return out


def tree(pids) -> list:
    """The given processes and all their descendants."""
    out = []
    for p in pids:
        out += [p] + children(p)
    return sorted(set(out))


def _status(pid: int, key: str) -> int:
    """A figure of /proc/PID/status (kB for the memory ones)."""
    with open('/proc/%d/status' % pid) as f:
        for line in f:
            if line.startswith(key + ':'):
                return int(line.split()[1])
    return 0


def _rollup(pid: int, key: str) -> float:
    with open('/proc/%d/smaps_rollup' % pid) as f:
        for line in f:
            if line.startswith(key + ':'):
                return int(line.split()[1]) / 1024.0
    return 0.0


GAP_PAGES = 4096   # mappings closer than this (16 MB) are read from pagemap in one span


def mappings(pid: int):
    """``pid``'s mappings that can hold pages, as (lo, hi) page numbers, permissions and the
    mapped file or [heap], [stack], [anon]... Mappings without access (guard pages,
    reservations) are never resident and are left out."""
    with open('/proc/%d/maps' % pid) as m:
        for line in m:
            f = line.split()
            if f[1].startswith('---') or 'vsyscall' in line:
                continue
            a, b = f[0].split('-')
            yield int(a, 16) // PAGE, int(b, 16) // PAGE, f[1], f[5] if len(f) > 5 else '[anon]'


def present(fd: int, lo: int, hi: int):
    """(offsets from ``lo``, frames) of the resident pages among pages [lo, hi), from the
    pagemap open as ``fd``; nothing where the range cannot be read."""
    try:
        v = np.frombuffer(os.pread(fd, (hi - lo) * 8, lo * 8), np.uint64)
    except OSError:
        v = np.zeros(0, np.uint64)
    k = np.flatnonzero((v & _PRESENT) != 0)
    return k, v[k] & _PFN_MASK


def spans(pid: int) -> list:
    """``pid``'s mappings (:func:`mappings`) as [lo, hi) page ranges, neighbours merged: a
    process that has loaded OpenCV has some 2000 mappings, and reading each one's pagemap on its
    own made a sample of a node tree take 100 ms (a house's cold cycle lasts 60: most went
    unseen). A gap between mappings reads as pages not present."""
    out = []
    for lo, hi, _, _ in mappings(pid):
        if out and lo - out[-1][1] < GAP_PAGES:
            out[-1][1] = max(out[-1][1], hi)
        else:
            out.append([lo, hi])
    return out


def frames(pid: int):
    """The page frame numbers of ``pid``'s resident pages (None without permission)."""
    with open('/proc/%d/pagemap' % pid, 'rb', buffering=0) as pm:
        out = [present(pm.fileno(), lo, hi)[1] for lo, hi in spans(pid)]
    f = np.concatenate(out) if out else np.zeros(0, np.uint64)
    if f.size and not f.any():
        return None       # no CAP_SYS_ADMIN: the kernel reports frame 0 for every page
    return f


def measure(pids, pss: bool = True) -> dict:
    """Now: the tree of ``pids``: unique MB (pages counted once; None without root), the sums of
    RSS and PSS (PSS None when not ``pss``: smaps_rollup walks every page, a third of a sample's
    time), each process's RSS and peak RSS (VmHWM), and its threads."""
    procs = {}
    union = []
    unique_ok = True
    for p in tree(pids):
        try:
            procs[p] = {'rss_mb': _status(p, 'VmRSS') / 1024.0, 'hwm_mb': _status(p, 'VmHWM') / 1024.0,
                        'pss_mb': _rollup(p, 'Pss') if pss else None, 'threads': _status(p, 'Threads')}
            f = frames(p) if unique_ok else None
        except (OSError, ValueError):
            procs.pop(p, None)
            continue
        if f is None:
            unique_ok = False
        else:
            union.append(f)
    unique = (np.unique(np.concatenate(union)).size * PAGE / 2.0 ** 20) if unique_ok and union else None
    return {'unique_mb': unique, 'rss_sum_mb': sum(v['rss_mb'] for v in procs.values()),
            'pss_mb': sum(v['pss_mb'] for v in procs.values()) if pss else None,
            'hwm_sum_mb': sum(v['hwm_mb'] for v in procs.values()),
            'processes': len(procs), 'threads': sum(v['threads'] for v in procs.values()), 'procs': procs}


class Sampler:
    """Samples :func:`measure` of a tree in a thread, every ``period`` seconds, keeping the
    largest figures seen (a sampled peak: a spike between two samples is missed; the sum of the
    processes' VmHWM bounds it from above). Where pages are counted once (root), PSS is read
    only every :attr:`PSS_EVERY` samples: a sample of a node and two workers then takes about
    40 ms instead of 55 (100 before the pagemap was read in merged spans)."""

    PSS_EVERY = 10

    def __init__(self, pids, period: float = 0.05):
        self.pids, self.period = list(pids), period
        self.peak = {}
        self.samples = 0
        self.busy = 0.0   # seconds spent sampling
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.is_set():
            t = time.monotonic()
            self.sample()
            self._stop.wait(max(0.0, self.period - (time.monotonic() - t)))   # a sample every period, or back to back

    def sample(self) -> dict:
        pss = self.samples % self.PSS_EVERY == 0 or self.peak.get('unique_mb') is None
        t = time.perf_counter()
        m = measure(self.pids, pss)
        self.busy += time.perf_counter() - t
        self.samples += 1
        for k in ('unique_mb', 'rss_sum_mb', 'pss_mb', 'hwm_sum_mb', 'processes'):
            if m[k] is not None:
                self.peak[k] = max(self.peak.get(k, 0), m[k])
        return m

    def __enter__(self):
        self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self.sample()


def watch(cmd, period: float = 0.02, env=None) -> dict:
    """Run ``cmd`` (a process that prints one JSON line when its work is done, then waits for
    its stdin to close) and sample its tree meanwhile. Returns that line's figures plus the
    peaks: ``unique_mb`` (sampled; None without root), ``hwm_sum_mb`` (every process's peak RSS,
    summed: an upper bound), ``rss_sum_mb``, ``pss_mb``, ``processes``, ``self_hwm_mb`` (the
    command's own process), ``samples`` and ``sample_ms`` (the mean time a sample took)."""
    p = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True, env=env)
    s = Sampler([p.pid], period)
    try:
        with s:
            line = p.stdout.readline()
        out = json.loads(line) if line.strip() else {}
        end = measure([p.pid])
    finally:
        p.stdin.close()
        err = p.stderr.read()
        p.wait()
    if not line.strip():
        raise RuntimeError('%s stopped: %s' % (' '.join(cmd[:3]), err[-1000:]))
    out.update({k: s.peak.get(k) for k in ('unique_mb', 'hwm_sum_mb', 'rss_sum_mb', 'pss_mb', 'processes')})
    out.update({'self_hwm_mb': end['procs'][p.pid]['hwm_mb'], 'samples': s.samples, 'threads': end['threads'],
                'end_unique_mb': end['unique_mb'], 'sample_ms': 1000.0 * s.busy / max(1, s.samples)})
    if out['unique_mb'] is None:
        out['unique_note'] = 'pages could not be counted once (pagemap needs root): pss_mb instead'
    return out


if __name__ == '__main__':
    m = measure([int(p) for p in sys.argv[1:]] or [os.getpid()])
    t = time.perf_counter()
    measure([int(p) for p in sys.argv[1:]] or [os.getpid()])
    m['measure_s'] = time.perf_counter() - t
    print(json.dumps(m))
