#!/usr/bin/env python3
"""Cold estimation time of two checkouts side by side (a change's cost), inline (workers=1).

    git archive BEFORE | tar -x -C /tmp/before
    python3 bench/cold_time.py /tmp/before/src src [--rounds 5] [--configs house4 intel4 ...]

Each round runs every configuration (``profile_core.py``'s inputs) once per checkout, in a
fresh process each, alternating, so the machine's drift hits both alike; prints the median
and the minimum of the rounds.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))

# the inputs are made by this checkout's bench (the same maps for both), then the checkout
# under test is imported in their place
CHILD = r'''
import sys, time, json
sys.path.insert(0, sys.argv[2])
import profile_core
raw = [(g.data, g.resolution, g.origin, g.frame_id) for g, _ in profile_core.CONFIGS[sys.argv[3]]()]
for k in [k for k in sys.modules if k.startswith('multi_map_merge')]:
    del sys.modules[k]
sys.path.insert(0, sys.argv[1])
from multi_map_merge.core.config import MergeConfig
from multi_map_merge.core.grid import Grid
from multi_map_merge.core.merger import MapMerger
assert MapMerger.__module__ and sys.modules['multi_map_merge'].__file__.startswith(sys.argv[1])
grids = [Grid(*r) for r in raw]
m = MapMerger(MergeConfig(workers=1))
for k, g in enumerate(grids):
    m.update_map('r%02d' % k, g)
t = time.perf_counter()
m.estimate()
print(json.dumps([time.perf_counter() - t, len(m.placements()) - 1]))
'''


def run(src, config):
    out = subprocess.run([sys.executable, '-c', CHILD, os.path.abspath(src), HERE, config],
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('before')
    ap.add_argument('after')
    ap.add_argument('--rounds', type=int, default=5)
    ap.add_argument('--configs', nargs='*', default=['house4', 'intel4', 'intel8', 'edmonton4'])
    a = ap.parse_args()
    times = {(c, w): [] for c in a.configs for w in ('before', 'after')}
    placed = {}
    for _ in range(a.rounds):
        for c in a.configs:
            for w, src in (('before', a.before), ('after', a.after)):
                t, n = run(src, c)
                times[(c, w)].append(t)
                placed[(c, w)] = n
    import statistics
    for c in a.configs:
        b, f = times[(c, 'before')], times[(c, 'after')]
        print('%-10s before %.3f s (min %.3f)  after %.3f s (min %.3f)  %+.1f%% (median)  placed %d / %d'
              % (c, statistics.median(b), min(b), statistics.median(f), min(f),
                 100.0 * (statistics.median(f) / statistics.median(b) - 1.0),
                 placed[(c, 'before')], placed[(c, 'after')]))


if __name__ == '__main__':
    main()
