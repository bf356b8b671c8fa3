#!/usr/bin/env python3
"""Cold estimation of this tree against an earlier commit's, in one run, with m-explore beside.

    bench/bench.py versus [--commit a260f5a] [--rows 'house 4' 'intel 4' ...] [--rounds 11]

Did a change cost speed? A ratio taken in another run cannot say: a machine's speed drifts
between runs. Here the two trees run side by side, round after round (as bench/duel.py pairs
run_bench.py's figures): this tree's cold cycle (bench/ours.py --serve-estimate) and the other
commit's (the same script of that commit, checked out into a temporary git worktree: commits from
a260f5a on have it). Each round asks each side for one cycle, in an order that rotates.

m-explore beside them, where its node is installed (ros-noetic-multirobot-map-merge,
bench/peer.py): the time from its node's start to its first merged /map on the row's maps, once a
row, after the rounds (not paired: its node cannot be asked for one cycle at a time); elsewhere
its column says it is not installed.

Prints per row each tree's median, this tree over the other commit (the median of the rounds'
ratios: below 1, this tree is faster) and m-explore's figure. Writes results/versus_<commit>.txt.
Needs ../shared (the maps) and git; not part of `make bench` (about 3 min a row).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

BENCH = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))    # (bench/tools/ -> bench/)
REPO = os.path.dirname(BENCH)

import duel  # noqa: E402
import inputs  # noqa: E402
import peer  # noqa: E402

ROWS = ['house 4', 'intel 4', 'aces 4', 'intel-sized x2', 'intel-sized x4', 'intel-sized x8']


def rounds_of(sides, rounds):
    """{label: [ms per round]} (:func:`duel.bursts`), after two uncounted cycles of each side
    (its pool warming)."""
    for _, srv in sides:
        srv.burst()
        srv.burst()
    return {label: [b['ms'] if 'ms' in b else b['estimate_ms'] for b in got]
            for label, got in duel.bursts(sides, rounds).items()}


def row_line(name, got, mexplore):
    """One row of the table from the rounds' figures (:func:`rounds_of`) and m-explore's cell."""
    change = np.median([x / y for x, y in zip(got['this'], got['other'])])
    return '%-16s | %-10.1f | %-10.1f | %-9s | %s' % (name, np.median(got['this']), np.median(got['other']),
                                                      '%.2fx' % change, mexplore)


def mexplore_cell(paths, root):
    """m-explore's time to its first merged /map on ``paths`` (bench/peer.py), or why none."""
    res = peer.run_node(paths, out_dir=tempfile.mkdtemp(prefix='mexplore_', dir=root))
    return peer.column(res, 'first_map_s', '%.2f s to its first merged /map')


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--commit', default='a260f5a',
                    help='the commit to compare with (default: where issue 21 was filed)')
    ap.add_argument('--rows', nargs='*', default=ROWS)
    ap.add_argument('--rounds', type=int, default=duel.ROUNDS)
    ap.add_argument('--out', default=os.path.join(BENCH, 'results'))
    a = ap.parse_args()
    head = subprocess.run(['git', '-C', REPO, 'rev-parse', '--short', 'HEAD'], capture_output=True,
                          text=True, check=True).stdout.strip()
    # (changes to the code measured, not to bench/results)
    dirty = subprocess.run(['git', '-C', REPO, 'status', '--porcelain', '--', 'src', 'bench/*.py'],
                           capture_output=True, text=True, check=True).stdout.strip()
    this = head + (' + changes' if dirty else '')
    root = tempfile.mkdtemp(prefix='mmm_versus_')
    other = os.path.join(root, 'other')
    subprocess.run(['git', '-C', REPO, 'worktree', 'add', '--detach', other, a.commit],
                   capture_output=True, text=True, check=True)
    lines = ['COLD ESTIMATION, side by side in one run (%d rounds a row; medians): this tree (%s) and %s; '
             'this / %s = the median of the rounds\' ratios (< 1: this tree is faster); m-explore: its node, '
             'not paired' % (a.rounds, this, a.commit, a.commit),
             '%-16s | %-10s | %-10s | %-9s | %s' % ('input', 'this ms', '%s ms' % a.commit, 'this / %s' % a.commit,
                                                  'm-explore')]
    print('\n'.join(lines), flush=True)
    try:
        for name in a.rows:
            paths = inputs.row_paths(name, root)
            spec = os.path.join(root, 'spec_%s.json' % name.replace(' ', '_'))
            with open(spec, 'w') as f:
                json.dump({'paths': paths}, f)
            sides = [('this', duel.Server([sys.executable, os.path.join(BENCH, 'ours.py'), '--serve-estimate', spec])),
                     ('other', duel.Server([sys.executable, os.path.join(other, 'bench', 'ours.py'),
                                            '--serve-estimate', spec]))]
            try:
                got = rounds_of(sides, a.rounds)
            finally:
                for _, srv in sides:
                    srv.close()
            lines.append(row_line(name, got, mexplore_cell(paths, root)))
            print(lines[-1], flush=True)
    finally:
        subprocess.run(['git', '-C', REPO, 'worktree', 'remove', '--force', other], capture_output=True)
    os.makedirs(a.out, exist_ok=True)
    path = os.path.join(a.out, 'versus_%s.txt' % a.commit)
    with open(path, 'w') as f:
        f.write('\n'.join(lines) + '\n')
    print('-> %s' % path)


if __name__ == '__main__':
    main()
