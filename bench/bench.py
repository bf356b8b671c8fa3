#!/usr/bin/env python3
"""The one way into the benchmarks and the measuring tools: ``bench/bench.py NAME [ARGS]``.

    bench/bench.py list                      # every name, what it measures, where its results go
    bench/bench.py accuracy [--quick]        # make accuracy
    bench/bench.py all                       # make bench: speed, live-gap, pinning-cost, scale, cluster-overhead
    bench/bench.py versus --commit a260f5a   # a tool (bench/tools/), not a benchmark

It sets up what every script needs once, here, and nowhere else: the import path (the
package's ``src``, ``bench/`` and ``bench/tools/``, also for the processes they start, through
PYTHONPATH) and one OpenCV/BLAS thread per process unless told otherwise; then it runs the script
as its own ``__main__`` with ARGS. Run it with Debian's /usr/bin/python3 and the workspace sourced
(the make targets do both). Benchmarks write ``bench/results/NAME.{json,txt}`` (or ``.md``) through
``results.py``: each file names the commit and the configuration that made it.
"""
from __future__ import annotations

import os
import runpy
import sys
from typing import Dict, List, Optional, Tuple

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
TOOLS = os.path.join(HERE, 'tools')
PATHS = [HERE, TOOLS, os.path.join(REPO, 'src')]

# name -> (script, what it measures and where its results go); the maintained benchmarks
BENCHMARKS: Dict[str, Tuple[str, str]] = {
    'accuracy': ('accuracy.py', "the paper's Table 1 and the time a team saves: 5 seeds x home, Intel lab, every "
                                'map by rbpf_slam (results/accuracy.{json,md,txt}; --quick: accuracy_quick.*)'),
    'bend-sweep': ('bend_sweep.py', 'placement covariances against the real error on CARMEN logs '
                                    '(results/bend_sweep.{json,txt})'),
    'speed': ('run_bench.py', 'estimation, compositing and memory against MRPT and m-explore over map sizes '
                              'and robot counts (results/bench.{json,png})'),
    'live-gap': ('live_gap.py', 'does estimation block /map and /tf in the live node (results/live.json)'),
    'soak': ('soak.py', 'the live node over 30 robot minutes: memory, CPU, threads (results/soak.json)'),
    'pinning-cost': ('pinning_cost.py', "what the links' covariance costs a cold estimation "
                                        '(results/pinning_cost.txt)'),
    'scale': ('scale.py', 'teams of 8-64 robots whose maps grow live (results/scale.{json,txt})'),
    'cluster-overhead': ('cluster_overhead.py', 'ms per pair: local pool against a Dask cluster on the loopback '
                                                '(results/cluster_overhead.txt)'),
}
# what `make bench` runs, in order: (name, its arguments, a results file its printed output is
# copied into, or None)
ALL = [('speed', [], None), ('live-gap', [], None),
       ('pinning-cost', [], os.path.join(HERE, 'results', 'pinning_cost.txt')), ('scale', [], None),
       ('cluster-overhead', ['-o', os.path.join(HERE, 'results', 'cluster_overhead.txt')], None)]
# tools: measure one question on demand (bench/tools/), results where they say
TOOL_SCRIPTS: Dict[str, Tuple[str, str]] = {
    'pair-digest': ('pair_digest.py', 'a change keeps behaviour: every pair result over the buildings, digested'),
    'profile-core': ('profile_core.py', 'where estimation time goes: cProfile of one cold estimation'),
    'versus': ('versus.py', "this tree's cold estimation against an earlier commit's, round after round"),
    'memsplit': ('memsplit.py', "where the estimation workers' memory comes from, page by page (root)"),
    'bend-check': ('bend_check.py', 'why a merge misses the world: rigid, bent, and bent onto the truth'),
    'pinning-sweep': ('pinning_sweep.py', "links' and placements' covariances on cut buildings"),
    'relay-rss': ('relay_rss.py', "the relays' memory on a robot"),
    'own-map-turn': ('own_map_turn.py', "how far each robot's own rbpf_slam map sits turned and shifted from its "
                                        'start, over seeds'),
    'mrpt-merge': ('mrpt_merge.py', "MRPT's grid map aligner behind merge_maps' interface (a peer)"),
    'peer': ('peer.py', "m-explore's map_merge node where installed (a peer)"),
    'timeline': ('timeline.py', 'coverage over time of one accuracy condition (accuracy runs it)'),
    'accuracy-figure': ('accuracy_figure.py', "the README's first figure from results/accuracy.json: time to "
                                              '90 % and final Fitness, team against lone robot (docs/time_to_map.png)'),
}


def script_path(name: str) -> Optional[str]:
    """The script of ``name`` (a benchmark or a tool; its file name works too), None if unknown."""
    for table in (BENCHMARKS, TOOL_SCRIPTS):
        if name in table:
            name = table[name][0]
            break
    for d in (HERE, TOOLS):
        p = os.path.join(d, name if name.endswith('.py') else name + '.py')
        if os.path.exists(p) and os.path.basename(p) != 'bench.py':
            return p
    return None


def setup_environment() -> None:
    """The import path for this process and every process it starts, and one library thread."""
    for p in reversed(PATHS):
        if p not in sys.path:
            sys.path.insert(0, p)
    old = os.environ.get('PYTHONPATH', '')
    os.environ['PYTHONPATH'] = ':'.join(PATHS + ([old] if old else []))
    os.environ.setdefault('OMP_NUM_THREADS', '1')


def listing() -> List[str]:
    lines = ['benchmarks (make bench, make accuracy, make bend-sweep):']
    lines += ['  %-17s %s' % (n, d) for n, (_, d) in BENCHMARKS.items()]
    lines += ['  %-17s %s' % ('all', 'what make bench runs: ' + ', '.join(n for n, _, _ in ALL)), '',
              'tools (bench/tools/ and the peers; results where each says):']
    lines += ['  %-17s %s' % (n, d) for n, (_, d) in TOOL_SCRIPTS.items()]
    return lines


def run_script(path: str, args: List[str]) -> int:
    """``path`` as ``__main__`` with ``args``: its exit code."""
    sys.argv = [path] + list(args)
    try:
        runpy.run_path(path, run_name='__main__')
    except SystemExit as e:
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    return 0


def main(argv: Optional[List[str]] = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ('-h', '--help', 'list'):
        print(__doc__.split('\n\n')[0] + '\n')
        print('\n'.join(listing()))
        return 0 if argv else 2
    name, args = argv[0], argv[1:]
    setup_environment()
    if name == 'all':
        import subprocess
        for n, a, tee in ALL:        # each in a fresh interpreter: one benchmark's state never leaks
            print('bench: %s %s' % (n, ' '.join(a)), flush=True)
            cmd = [sys.executable, os.path.abspath(__file__), n] + a + args
            if tee is None:
                rc = subprocess.call(cmd)
            else:                    # its printed table is its results file
                import results
                with open(tee, 'w') as f:
                    f.write('\n'.join(results.header(results.provenance({'benchmark': n, 'args': a + args})))
                            + '\n\n')
                    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, universal_newlines=True)
                    for line in p.stdout:
                        sys.stdout.write(line)
                        f.write(line)
                    rc = p.wait()
            if rc != 0:
                print('bench: %s exited %d' % (n, rc), file=sys.stderr)
                return rc
        return 0
    path = script_path(name)
    if path is None:
        print('bench: unknown name %r\n%s' % (name, '\n'.join(listing())), file=sys.stderr)
        return 2
    return run_script(path, args)


if __name__ == '__main__':
    sys.exit(main())
