#!/usr/bin/env python3
"""Where does our estimation time go? cProfile of one cold estimation cycle, run inline
(MergeConfig(workers=1): the worker pool would hide the work from the profiler).

    bench/bench.py profile-core [edmonton4|intel8|intel16|house4 ...] [--top 25]

Prints, per configuration, the functions with the most own time and the most cumulative time,
and writes results/profile_<config>.txt. Not part of `make bench` (the lead optimises the core
with it); the inputs are the same as run_bench.py's rows.
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import time

BENCH = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))    # (bench/tools/ -> bench/)

import inputs  # noqa: E402

CONFIGS = {
    'house4': lambda: [(inputs.load_map(p), None) for p in sorted(
        __import__('glob').glob(os.path.join(inputs.DATA, 'tb3_house', 'tb3_*_map.yaml')))],
    'intel4': lambda: inputs.pieces_split(inputs.world_map('intel', required=True), 4),
    'edmonton4': lambda: inputs.pieces_split(inputs.world_map('edmonton', required=True), 4),
    'intel8': lambda: inputs.pieces_windows(inputs.world_map('intel', required=True), 8),
    'intel16': lambda: inputs.pieces_windows(inputs.world_map('intel', required=True), 16),
}


def profiled(fn):
    """(cProfile of one call of ``fn``, its wall seconds)."""
    prof = cProfile.Profile()
    t = time.perf_counter()
    prof.enable()
    fn()
    prof.disable()
    return prof, time.perf_counter() - t


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('configs', nargs='*', default=['edmonton4', 'intel16'], choices=sorted(CONFIGS))
    ap.add_argument('--top', type=int, default=25)
    ap.add_argument('--out', default=os.path.join(BENCH, 'results'))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.merger import MapMerger
    for name in a.configs:
        grids = [g for g, _ in CONFIGS[name]()]
        m = MapMerger(MergeConfig(workers=1))
        for k, g in enumerate(grids):
            m.update_map('r%02d' % k, g)
        prof, wall = profiled(m.estimate)
        prof2, wall_c = profiled(m.compose)
        buf = io.StringIO()
        buf.write('%s: %d robots, cold estimate inline %.2f s (profiled), placed %d; compose %.3f s\n'
                  % (name, len(grids), wall, len(m.placements()) - 1, wall_c))
        for title, p, key in (('own time', prof, 'tottime'), ('cumulative', prof, 'cumulative'),
                              ('compose, cumulative', prof2, 'cumulative')):
            buf.write('\n--- estimate, %s ---\n' % title if p is prof else '\n--- %s ---\n' % title)
            st = pstats.Stats(p, stream=buf)
            st.strip_dirs().sort_stats(key).print_stats(a.top if p is prof else 12)
        text = buf.getvalue()
        print(text)
        with open(os.path.join(a.out, 'profile_%s.txt' % name), 'w') as f:
            f.write(text)


if __name__ == '__main__':
    main()
