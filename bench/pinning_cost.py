#!/usr/bin/env python3
"""What the links' covariance (core/covariance.py) costs in a cold estimation cycle: CPU time
of ``MapMerger.estimate()`` inline (workers=1) with and without it, alternating in one process
(a loaded machine hits both alike), median of 5, on profile_core.py's inputs; and the CPU
time spent in the covariance (and the search's pose, ``pair._pin``) over the rest of the same
cycles, which a loaded machine disturbs far less than two separate runs.

    bench/bench.py pinning-cost house4 intel4 intel8 edmonton4
"""
import os
import statistics
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
import profile_core  # noqa: E402

from multi_map_merge.core import pair  # noqa: E402
from multi_map_merge.core.config import MergeConfig  # noqa: E402
from multi_map_merge.core.merger import MapMerger  # noqa: E402

# issue 22: the covariance may make a cold estimation at most this much slower (percent)
LIMIT_PERCENT = 20.0


def main(names):
    real = pair._pin
    spent = [0.0]

    def timed(*a):
        t0 = time.process_time()
        real(*a)
        spent[0] += time.process_time() - t0

    for name in names or ['house4', 'intel4', 'intel8', 'edmonton4']:
        grids = [g for g, _ in profile_core.CONFIGS[name]()]
        t = {True: [], False: []}
        share = []
        for _ in range(5):
            for on in (False, True):
                pair._pin = timed if on else (lambda *a: None)
                m = MapMerger(MergeConfig(workers=1))
                for k, g in enumerate(grids):
                    m.update_map('r%02d' % k, g)
                spent[0] = 0.0
                t0 = time.process_time()
                m.estimate()
                t[on].append(time.process_time() - t0)
                if on:
                    share.append(spent[0] / (t[on][-1] - spent[0]))
        pair._pin = real
        b, a = statistics.median(t[False]), statistics.median(t[True])
        over = 100 * statistics.median(share)
        print('%-10s CPU without %.3f s  with %.3f s  %+.1f%% (median of 5, in-process A/B); '
              'time in the covariance over the rest of the cycle: %+.1f%% (median): %s'
              % (name, b, a, 100 * (a / b - 1), over,
                 'within the 20% limit' if over <= LIMIT_PERCENT else 'OVER the 20% limit'), flush=True)


if __name__ == '__main__':
    main(sys.argv[1:])
