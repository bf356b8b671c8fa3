"""How far each robot's own SLAM map sits from its start: its best fit to the ground truth.

Runs ``rbpf_slam_replay`` (every scan; the node's update rules, ``config/rbpf_lds02.yaml`` or
``--config``, ``--set KEY=VALUE`` over it) on each robot of a ``make_robot_bags`` bag for each
seed of the filter, fits each final map alone to the ground truth from its true start
(``lab.evaluate.score_map``, as the demo report's "fit") and prints, per robot and seed, the best
fit's offset (m) and turn (deg) from the start pose, and the map's Fitness (and, with
``--set gyro_scale_learning=true``, the odometry heading's scale factor the filter learned); then
per robot the mean and worst over seeds. At most two replays at once (``--jobs``), each in a roscore of its own.

    bench/bench.py own-map-turn --bag demo_output/bags/aws_house.bag \\
        --world ../shared/data/aws/small_house/map.yaml --seeds 1 2 3 4 5 --set stt=0.03

The truth is BAG with ``.truth.yaml`` for ``.bag``. Source the workspace first (``make build``).
Results: printed only (docs/measurements.md keeps what was measured with it).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import threading
from typing import Dict, List, Tuple

import accuracy_common as C
import numpy as np
import yaml
from accuracy_common import REPO
from accuracy_slam import replay_binary, run_gmapping

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import inverse, se2, xyyaw
from multi_map_merge.lab.evaluate import load_truth, score_map


def value(text: str) -> object:
    """A --set value as YAML reads it (0.03 a float, true a bool)."""
    return yaml.safe_load(text)


def learned_scale(meta: Dict[str, object]) -> str:
    """The factor the replay learned (``meta['gyro_scale']``, from its last gyro scale line) as
    '; gyro scale E (applied K, N steps)', or '' when it learned none."""
    g = meta.get('gyro_scale')
    if not g:
        return ''
    return '; gyro scale %s (applied %s, %d steps)' % (g['estimate'], g['applied'], g['steps'])


def main(argv: List[str] = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--bag', required=True)
    ap.add_argument('--world', help='the ground-truth map (default: the truth file\'s world)')
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3, 4, 5])
    ap.add_argument('--config', default=os.path.join(REPO, 'config', 'rbpf_lds02.yaml'))
    ap.add_argument('--set', action='append', default=[], metavar='KEY=VALUE', help='a parameter over --config')
    ap.add_argument('--work', default='/tmp/own_map_turn')
    ap.add_argument('--port', type=int, default=11620, help='first port of the roscores (each job its own 20)')
    ap.add_argument('--jobs', type=int, default=2)
    ap.add_argument('--single', action='store_true', help="the lone robot's bag instead (the truth file's single)")
    a = ap.parse_args(argv)
    extra = {k: value(v) for k, v in (s.split('=', 1) for s in a.set)}
    truth_path = a.bag[:-len('.bag')] + '.truth.yaml'
    truth = load_truth(truth_path)
    gt = load_map(a.world or truth['world_path'])
    exe = replay_binary('rbpf')
    if exe is None:
        print('rbpf_slam_replay not found: make build, then source the workspace', file=sys.stderr)
        return 2
    tag = '_'.join('%s%s' % kv for kv in sorted(extra.items())) or 'config'
    work = os.path.join(a.work, os.path.basename(a.bag)[:-4] + ('_single' if a.single else ''), tag)
    os.makedirs(work, exist_ok=True)
    bag = a.bag
    starts = {r: v['start'] for r, v in truth['robots'].items()}
    if a.single:         # the lone robot: its own bag beside the truth file, under its robot's name
        lone = truth['single']
        bag = os.path.join(os.path.dirname(truth_path), lone['bag'])
        starts = {lone['name']: lone['start']}
    robots = sorted(starts)
    todo = [(r, s) for s in a.seeds for r in robots]
    results: Dict[Tuple[str, int], Tuple[float, float, float]] = {}
    lock = threading.Lock()

    def worker(k: int) -> None:
        while True:
            with lock:
                if not todo:
                    return
                r, s = todo.pop(0)
            prefix = os.path.join(work, '%s_s%d' % (r, s))
            meta = run_gmapping(exe, bag, '/%s/scan' % r, r, s, a.config, prefix, {}, 1800,
                                a.port + 20 * k, os.path.join(work, 'ros_home'), extra_params=extra, slam='rbpf')
            if meta.get('invalid'):
                print('%s seed %d: %s' % (r, s, meta['invalid']), flush=True)
                continue
            start = se2(*starts[r])
            sc = score_map(load_map(prefix + '.yaml'), gt, start, 0.1)
            x, y, yaw = xyyaw(inverse(start) @ sc.T)       # the best fit in the start's frame
            res = (math.hypot(x, y), math.degrees(yaw), sc.fitness)
            with lock:
                results[(r, s)] = res
            print('%s seed %d: offset %.3f m turn %+.2f deg fitness %.3f (%d of %d scans processed, %.1f s CPU)%s'
                  % (r, s, res[0], res[1], res[2], meta['processed'], meta['scans'], meta['cpu_s'],
                     learned_scale(meta)), flush=True)

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(a.jobs)]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        C.stop_all()
    print('%s, %s %s, seeds %s' % (os.path.basename(bag), os.path.basename(a.config), extra or '', a.seeds))
    worst_all = 0.0
    for r in robots:
        rs = [results[(r, s)] for s in a.seeds if (r, s) in results]
        if not rs:
            continue
        off = np.array([x[0] for x in rs])
        turn = np.abs([x[1] for x in rs])
        fit = np.array([x[2] for x in rs])
        worst_all = max(worst_all, float(turn.max()))
        print('  %s |turn| mean %.2f worst %.2f deg; offset mean %.3f worst %.3f m; '
              'fitness mean %.3f worst %.3f (%d seeds)'
              % (r, turn.mean(), turn.max(), off.mean(), off.max(), fit.mean(), fit.min(), len(rs)))
    print('  worst |turn| over robots and seeds: %.2f deg' % worst_all)
    return 0


if __name__ == '__main__':
    sys.exit(main())
