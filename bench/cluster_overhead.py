#!/usr/bin/env python3
"""What a Dask cluster (``~dask_scheduler``) costs per pair against the local process pool, on
the same pairs of real maps (not a timed test: measured and printed, never asserted).

    bench/bench.py cluster-overhead [--rows 'house 4' 'intel 4' 'intel-sized x4'] [--rounds 9] [-o FILE]

The rows are run_bench.py's (bench/inputs.py): ``house 4``, the four real Turtlebot3 gmapping
maps of ../shared/data/tb3_house; ``intel 4``, the Intel map cut into four robots' maps at known
poses; ``intel-sized x4``, four windows of 60% of it, every pair overlapping (a row whose maps
are missing is left out). Every pair of robots of a row is aligned cold (a new ``PairWorkers``:
no feature cached, here or in a worker), as a merger's first cycle does: the features of every
map, then every pair, through

* the local process pool: 2 worker processes (``workers: 2``, forked at the start, as the node's);
* a Dask cluster on the loopback that the script starts: a scheduler and 2 workers of one
  thread each (``python3 -m distributed.cli.dask_scheduler`` / ``dask_worker``, no nanny), the
  package on their PYTHONPATH, connected as the node connects (``dask_scheduler: tcp://...``).

A round aligns every row once through each pool, the pools alternating which goes first; a
first round, not timed, starts the pools and imports the package on the Dask workers. Printed:
the median over the rounds of the milliseconds per pair (the rows' wall time over their pairs,
the features included), the median of the rounds' differences (the cluster's overhead: each map
sent with each of its pairs, the scheduler, the results' way back), and whether every result
(transform, scores, covariance...) is identical, between the pools and from round to round.

The cluster's figure is INVALID when it did not do the work: fewer tasks finished on its
workers (the scheduler's task stream) than the rows' maps and pairs, or a fallback to the local
pool logged. Every line printed, the summary last, goes to ``--out``
(``bench/results/cluster_overhead.txt``); the exit status is 1 when the summary says INVALID or
the results differ.
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import logging
import math
import os
import shutil
import statistics
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
import inputs  # noqa: E402
import results as results_io  # noqa: E402

from multi_map_merge.core import workers  # noqa: E402
from multi_map_merge.core.config import MergeConfig  # noqa: E402
from multi_map_merge.core.robot_map import RobotMap  # noqa: E402
from multi_map_merge.lab.loopback_cluster import LoopbackCluster  # noqa: E402
from multi_map_merge.runtime import cluster  # noqa: E402

SRC = os.path.join(inputs.REPO, 'src')
RESULTS = os.path.join(HERE, 'results', 'cluster_overhead.txt')
ROWS = ['house 4', 'intel 4', 'intel-sized x4']
WORKERS = 2                    # processes of the local pool, and workers of the cluster
TASK = 'run_on_worker'         # the key prefix of the tasks runtime/cluster.py submits


SAID = []   # every line printed, for --out


def say(text: str) -> None:
    print(text, flush=True)
    SAID.append(text)


class Lines(logging.Handler):
    """The fallback lines of runtime/cluster.py (a failed cluster), kept."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.lines = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def rows(names):
    """[(name, {robot: RobotMap}, [(parent, child)])] of the rows found."""
    out = []
    confs = {n: pieces for n, _, pieces in inputs.configurations(quick=True) if n in names}
    for name in names:
        if name not in confs:
            say('(row %r: its maps are missing, left out)' % name)
            continue
        grids = [g for g, _ in confs[name]]
        res = grids[0].resolution
        maps = {'r%02d' % k: RobotMap('r%02d' % k, g, k + 1, 0.0).set_working_resolution(res)
                for k, g in enumerate(grids)}
        out.append((name, maps, list(itertools.combinations(sorted(maps), 2))))
    return out


def align(config, maps, todo):
    """One cold alignment of every pair of ``todo`` (a new PairWorkers: nothing cached):
    (seconds, results)."""
    pw = workers.PairWorkers(config)
    t0 = time.perf_counter()
    results = pw.align_pairs(maps, todo)
    return time.perf_counter() - t0, results


def same(a, b) -> bool:
    """Equal to the last bit: dataclasses field by field, arrays element by element (NaN equal
    to NaN), floats exactly."""
    if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
        return type(a) is type(b) and all(same(getattr(a, f.name), getattr(b, f.name))
                                          for f in dataclasses.fields(a))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return a.shape == b.shape and a.dtype == b.dtype and bool(np.array_equal(a, b) or (
            a.dtype.kind == 'f' and np.array_equal(np.isnan(a), np.isnan(b)) and np.array_equal(a[~np.isnan(a)],
                                                                                                b[~np.isnan(b)])))
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--rows', nargs='+', default=ROWS, help='rows of bench/inputs.py (default: %(default)s)')
    ap.add_argument('--rounds', type=int, default=9, help='timed rounds (default: %(default)s)')
    ap.add_argument('-o', '--out', default=RESULTS, help='where the last line goes (default: %(default)s)')
    a = ap.parse_args(argv)
    try:
        import distributed  # noqa: F401
    except ImportError as e:
        print('cluster overhead: skipped: python3-distributed is not installed (%s)' % e)
        return 0
    # the local pool first, forked while this process runs no other thread (as the node does)
    workers.start_pool(WORKERS)
    work = rows(a.rows)
    if not work:
        print('cluster overhead: skipped: none of the rows %s has its maps' % a.rows)
        return 0
    lines = Lines()
    logging.getLogger(cluster.__name__).addHandler(lines)
    tmp = tempfile.mkdtemp(prefix='mmm_cluster_overhead_')
    # the workers import the package from this source tree
    c = LoopbackCluster(tmp, env=dict(os.environ, PYTHONPATH=os.pathsep.join(
        [SRC] + [p for p in os.environ.get('PYTHONPATH', '').split(os.pathsep) if p])))
    try:
        c.start(WORKERS)
        local_cfg = MergeConfig(workers=WORKERS)
        dask_cfg = MergeConfig(workers=WORKERS, dask_scheduler=c.address)
        tasks_per_round = sum(len(maps) + len(todo) for _, maps, todo in work)
        n_pairs = sum(len(todo) for _, _, todo in work)
        per_pair = {'local': [], 'dask': []}
        identical, reference, short = True, {}, []
        for rnd in range(a.rounds + 1):      # round 0: warm-up, not timed
            order = ['local', 'dask'] if rnd % 2 else ['dask', 'local']
            took = {'local': 0.0, 'dask': 0.0}
            for side in order:
                before = len(c.tasks(TASK)) if side == 'dask' else 0
                for name, maps, todo in work:
                    s, results = align(local_cfg if side == 'local' else dask_cfg, maps, todo)
                    took[side] += s
                    if name not in reference:
                        reference[name] = results
                    elif not same(results, reference[name]):
                        identical = False
                        say('  %s: the %s pool\'s results differ from the first ones' % (name, side))
                if side == 'dask':
                    done = len(c.tasks(TASK)) - before
                    if done < tasks_per_round:
                        short.append('round %d: %d tasks on the cluster of %d' % (rnd, done, tasks_per_round))
            if rnd:
                for side in took:
                    per_pair[side].append(took[side] / n_pairs)
                say('  round %d: local pool %.1f ms/pair, Dask cluster %.1f ms/pair'
                    % (rnd, 1e3 * took['local'] / n_pairs, 1e3 * took['dask'] / n_pairs))
        invalid = []
        if short:
            invalid.append('the cluster did not do the work (%s)' % '; '.join(short))
        if lines.lines:
            invalid.append('the cluster failed: %s' % lines.lines[0])
        loc, dsk = statistics.median(per_pair['local']), statistics.median(per_pair['dask'])
        # the overhead: the median of the rounds' differences (a loaded machine slows both pools of a round)
        over = statistics.median(d - lo for d, lo in zip(per_pair['dask'], per_pair['local']))
        line = ('cluster overhead: local pool %.1f ms/pair, Dask cluster %.1f ms/pair (%+.1f ms/pair overhead), '
                '%d pairs, identical results: %s' % (1e3 * loc, 1e3 * dsk, 1e3 * over, n_pairs,
                                                      'yes' if identical else 'NO'))
        if invalid:
            line += ', INVALID: ' + '; '.join(invalid)
        details = ('(%s; %d local worker processes, %d Dask workers of one thread; median of %d rounds; '
                   'distributed %s)' % (', '.join('%s: %d pairs' % (name, len(todo)) for name, _, todo in work),
                                        WORKERS, WORKERS, a.rounds, distributed.__version__))
    finally:
        if cluster._POOL is not None:    # this process's client, before its scheduler goes
            cluster._POOL.close()
        c.stop()
        shutil.rmtree(tmp, ignore_errors=True)
    say(details)
    say(line)
    if a.out:
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        results_io.write_text(a.out, SAID, vars(a))
    return 0 if identical and not invalid else 1


if __name__ == '__main__':
    sys.exit(main())
