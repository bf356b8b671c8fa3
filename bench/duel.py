"""Figures measured in pairs: two or more long-lived processes, burst after burst, in the same
minutes (bench/tools/versus.py: this tree's cold estimation against another commit's).

This VM's speed drifts by up to a factor of two over minutes (other guests share its cores), so
two figures taken minutes apart can put a ratio near 1 on either side of it. Here each side is
a long-lived process that has already loaded its maps; each round asks every side for one burst,
in an order that rotates from round to round. Each round gives a ratio of ours over each other
side's burst; the figure is the median over the rounds, of the times and of the ratios.

The processes speak JSON lines: a first line {"ready": true, ...}, then one line per line they
read on stdin (bench/ours.py --serve / --serve-estimate).
"""
from __future__ import annotations

import json
import subprocess

import numpy as np

ROUNDS = 11


class Server:
    """One side: a process serving bursts."""

    def __init__(self, cmd, env=None):
        self.p = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, env=env)
        self.ready = self._line()

    def _line(self):
        line = self.p.stdout.readline()
        if not line:
            err = self.p.stderr.read()
            raise RuntimeError('%s stopped: %s' % (self.p.args[0], err[-500:]))
        return json.loads(line)

    def burst(self):
        self.p.stdin.write('\n')
        self.p.stdin.flush()
        return self._line()

    def close(self):
        if self.p.poll() is None:
            self.p.stdin.close()
            try:
                self.p.wait(timeout=60)
            except subprocess.TimeoutExpired:
                self.p.kill()


def bursts(sides, rounds=ROUNDS):
    """{label: [burst per round]} of ``sides`` ([(label, Server)]): each round asks every side
    for one burst, in an order that rotates from round to round."""
    got = {label: [] for label, _ in sides}
    for r in range(rounds):
        k = r % len(sides)
        for label, srv in sides[k:] + sides[:k]:
            got[label].append(srv.burst())
    return got


def duel(ours, peers, rounds=ROUNDS, key='compose_ms'):
    """``ours``: a Server whose bursts carry 'ms' (compose + publish, or one cold estimation)
    and, for compositing, 'live_ms' (compose + publish with one robot's map changed: its
    ratio to the peer's full compositing of the same round is 'live_ratio');
    ``peers``: {label: Server} whose bursts carry ``key``. Returns {'ours_ms', 'ours_rounds',
    label: {key, 'ratio', 'rounds', 'ratios', 'cells', 'known'}}: medians over the rounds."""
    got = bursts([('ours', ours)] + sorted(peers.items()), rounds)
    mine = [b['ms'] for b in got['ours']]
    live = [b.get('live_ms') for b in got['ours']]
    live = live if None not in live else None
    out = {'ours_ms': float(np.median(mine)), 'ours_rounds': mine, 'rounds': rounds,
           'ours_live_ms': float(np.median(live)) if live else None}
    for name in sorted(peers):
        theirs = [b[key] for b in got[name]]
        ratios = [a / b for a, b in zip(mine, theirs) if b > 0]
        live_ratios = [a / b for a, b in zip(live, theirs) if b > 0] if live else []
        out[name] = {key: float(np.median(theirs)), 'rounds': theirs,
                     'ratio': float(np.median(ratios)) if ratios else None, 'ratios': ratios,
                     'live_ratio': float(np.median(live_ratios)) if live_ratios else None,
                     'cells': got[name][-1].get('cells'), 'known': got[name][-1].get('known')}
    return out
