#!/usr/bin/env python3
"""Soak: the live node's memory, CPU and threads over a long run of robots' maps that grow.

    bench/bench.py soak [--robots 8] [--minutes 30] [--speed 10] [--grow-minutes 20]
                          [--map-interval 5] [--sample 2] [--port 11800] [--no-peer] [--no-build]

Runs `make build` first (unless --no-build), its own roscore, a map publisher (this script,
--publish) and map_merge_node (merge_rate 2 Hz, every other parameter its default). The
publisher replays ``--minutes`` of robot time at ``--speed`` times real time (30 min at 10x:
3 min): each robot's map is a window of 60% of the intel map (``inputs.pieces_windows``: every
pair overlaps) revealed from its known centre, the radius widening from 30% to all of it over
``--grow-minutes`` of robot time, on a canvas cropped to what is known (gmapping grows its canvas
the same way), published every ``--map-interval`` robot seconds (0.5 s wall at 10x, robots
staggered), with 200 of its known cells flipped at random each time (gmapping's maps keep changing
when nothing new is seen): every message is a new map, every estimation cycle has work. After
``--grow-minutes`` the maps keep their size but still change every message: that steady phase is
where a node that does not leak must be flat.

The node's process tree (the node and its estimation workers, bench/memtree.py: physical pages
counted once) is sampled every ``--sample`` wall seconds: memory, CPU (user + system of every
process of the tree, % of one core over the interval) and threads. Reported: start (the first
10 wall seconds after the first merge), middle, end of the growth phase and end of the run
(medians of the samples within 5 wall seconds), the slope of memory over the steady phase
(least squares, MB per robot minute), and the verdict:

    flat  when over the steady phase the fitted memory change is within max(5 MB, 2% of its
          mean) and the thread count ends within 2 of where it started.

INVALID instead of a verdict when the node had not merged all robots but one by the end of the
growth phase (then it did not do the work the soak is about), or when the steady phase has
fewer than 10 samples. Where m-explore's node is installed (bench/peer.py), it is soaked the same way, and the two
memory figures are compared.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
import memtree  # noqa: E402
import results as results_io  # noqa: E402
from inputs import world_map  # noqa: E402
from live_gap import bench_processes, growing_map, mexplore_node  # noqa: E402
from report import machine  # noqa: E402

from multi_map_merge.core.mapio import save_map  # noqa: E402
from multi_map_merge.lab.pieces import pieces_windows  # noqa: E402

FLIPS = 200          # known cells flipped free <-> occupied in every message
GROW_FROM = 0.3      # of the largest radius, at robot time 0
MARGIN = 20          # unknown cells kept around the known box (as gmapping's canvas)


def publisher(spec):
    """The robots' maps (--publish SPEC): see the module docstring."""
    import numpy as np
    import rospy

    from multi_map_merge.core.grid import Grid
    from multi_map_merge.core.transforms import cell_to_metric
    from multi_map_merge.ros.convert import NumpyGrid, grid_to_msg
    rospy.init_node('soak_maps', anonymous=True)
    rng = np.random.default_rng(0)
    robots = []
    for r in spec['robots']:
        robots.append(dict(growing_map(r['path']), name=r['name'],
                           pub=rospy.Publisher('/%s/map' % r['name'], NumpyGrid, queue_size=1, latch=True)))
    wall_interval = spec['map_interval'] / spec['speed']
    t0 = time.monotonic()
    j = 0   # message slots: robot j % R sends its (j // R + 1)-th map at t0 + (j / R) * interval
    while not rospy.is_shutdown():
        behind = int((time.monotonic() - t0) / wall_interval * len(robots)) - j
        if behind > len(robots):   # a late message is not replayed: on to the current slot
            j += behind
        time.sleep(max(0.0, t0 + j / float(len(robots)) * wall_interval - time.monotonic()))
        r, k = robots[j % len(robots)], j // len(robots) + 1
        j += 1
        robot_s = k * spec['map_interval']
        f = GROW_FROM + (1.0 - GROW_FROM) * min(1.0, robot_s / spec['grow_s'])
        g = r['grid']
        data = np.where(r['dist'] <= f * r['dmax'], g.data, np.int8(-1))
        known = np.flatnonzero(data >= 0)
        if known.size:
            flip = rng.choice(known, min(FLIPS, known.size), replace=False)
            flat = data.reshape(-1)
            flat[flip] = np.where(flat[flip] == 100, 0, 100).astype(np.int8)
        rows = np.flatnonzero((data >= 0).any(axis=1))
        cols = np.flatnonzero((data >= 0).any(axis=0))
        if rows.size:
            r0, r1 = max(0, rows[0] - MARGIN), min(g.height, rows[-1] + 1 + MARGIN)
            c0, c1 = max(0, cols[0] - MARGIN), min(g.width, cols[-1] + 1 + MARGIN)
            o = cell_to_metric(g.resolution, g.origin) @ np.array([c0 - 0.5, r0 - 0.5, 1.0])
            part = Grid(np.ascontiguousarray(data[r0:r1, c0:c1]), g.resolution, (float(o[0]), float(o[1]),
                                                                                  g.origin[2]), g.frame_id)
            r['pub'].publish(grid_to_msg(part, rospy.Time.now(), '%s/map' % r['name']))


def cpu_seconds(pids):
    """User + system CPU seconds of the processes ``pids`` so far."""
    tick = os.sysconf('SC_CLK_TCK')
    total = 0.0
    for p in pids:
        try:
            with open('/proc/%d/stat' % p) as f:
                s = f.read()
            v = s[s.rindex(')') + 2:].split()
            total += (int(v[11]) + int(v[12])) / float(tick)
        except (OSError, ValueError, IndexError):
            pass
    return total


def soak(pid, seconds, period, merged_of):
    """Sample the tree of ``pid`` every ``period`` s for ``seconds``: [{t, unique_mb, rss_sum_mb,
    pss_mb, threads, processes, cpu_pct, merged}]. CPU: the tree's CPU seconds over the interval,
    summed over the processes alive at both ends (a worker restarted in between is missed)."""
    out = []
    t0 = time.monotonic()
    last_t, last_cpu, last_pids = t0, None, None
    while time.monotonic() - t0 < seconds:
        m = memtree.measure([pid])
        now = time.monotonic()
        pids = set(m['procs'])
        cpu_now = {p: cpu_seconds([p]) for p in pids}
        pct = None
        if last_cpu is not None:
            both = pids & last_pids
            pct = 100.0 * sum(cpu_now[p] - last_cpu[p] for p in both) / max(1e-6, now - last_t)
        out.append({'t': now - t0, 'unique_mb': m['unique_mb'], 'rss_sum_mb': m['rss_sum_mb'],
                    'pss_mb': m['pss_mb'], 'threads': m['threads'], 'processes': m['processes'],
                    'cpu_pct': pct, 'merged': merged_of()})
        last_t, last_cpu, last_pids = now, cpu_now, pids
        time.sleep(max(0.0, period - (time.monotonic() - now)))
    return out


def summarise(samples, grow_wall_s, speed, key='unique_mb'):
    """start / middle / end of growth / end figures, the steady phase's slope and the verdict."""
    import numpy as np
    merged_at = next((s['t'] for s in samples if (s['merged'] or 0) > 0), None)
    t_first = merged_at if merged_at is not None else samples[0]['t']

    def around(t, k):
        v = [s[k] for s in samples if abs(s['t'] - t) <= 5.0 and s[k] is not None]
        return float(np.median(v)) if v else None
    t_end = samples[-1]['t']
    at = {'start': t_first + 5.0, 'middle': (t_first + t_end) / 2.0, 'end_growth': grow_wall_s, 'end': t_end - 2.5}
    figures = {name: {k: around(t, k) for k in (key, 'rss_sum_mb', 'cpu_pct', 'threads', 'merged')}
               for name, t in at.items()}
    for name, t in at.items():
        figures[name]['t_wall_s'] = t
    steady = [s for s in samples if s['t'] >= grow_wall_s and s[key] is not None]
    out = {'figures': figures, 'merged_at_wall_s': merged_at, 'samples': len(samples), 'steady_samples': len(steady)}
    robots = max((s['merged'] or 0) for s in samples) if samples else 0
    out['merged_max'] = robots
    if len(steady) < 10:
        out.update(valid=False, invalid_because='%d samples in the steady phase (< 10)' % len(steady))
        return out
    t = np.array([s['t'] for s in steady])
    y = np.array([s[key] for s in steady])
    slope, _ = np.polyfit(t, y, 1)           # MB per wall second
    change = slope * (t[-1] - t[0])
    bound = max(5.0, 0.02 * float(y.mean()))
    th = [s['threads'] for s in steady]
    out.update({'slope_mb_per_robot_min': slope * 60.0 / speed, 'slope_mb_per_wall_min': slope * 60.0,
                'steady_change_mb': change, 'steady_bound_mb': bound, 'steady_mean_mb': float(y.mean()),
                'steady_threads': [min(th), max(th), th[0], th[-1]],
                'cpu_pct_growth': float(np.mean([s['cpu_pct'] for s in samples
                                                 if s['cpu_pct'] is not None and s['t'] < grow_wall_s] or [0])),
                'cpu_pct_steady': float(np.mean([s['cpu_pct'] for s in steady if s['cpu_pct'] is not None] or [0]))})
    out['flat'] = bool(abs(change) <= bound and abs(th[-1] - th[0]) <= 2)
    out['valid'] = True
    return out


def lines(name, r, speed):
    """Printed summary of one node's soak."""
    s = r['summary']
    f = lambda v, fmt='%.0f': '-' if v is None else fmt % v  # noqa: E731
    out = []
    for k in ('start', 'middle', 'end_growth', 'end'):
        x = s['figures'][k]
        out.append('  %-10s %5.0f s wall (%4.1f robot min): %s MB (RSS sum %s), CPU %s%%, %s threads, %s merged' % (
            k, x['t_wall_s'], x['t_wall_s'] * speed / 60.0, f(x['unique_mb']), f(x['rss_sum_mb']), f(x['cpu_pct']),
            f(x['threads']), f(x['merged'])))
    if not s.get('valid', True) and 'invalid_because' in s:
        head = '%s: INVALID: %s' % (name, s['invalid_because'])
    else:
        head = ('%s: %s. Steady phase: memory %+.1f MB fitted (bound %.1f MB: max(5 MB, 2%% of %.0f MB)), slope '
                '%+.2f MB per robot minute; threads %d..%d (start %d, end %d); CPU %.0f%% growing, %.0f%% steady'
                % (name, 'FLAT' if s['flat'] else 'NOT FLAT', s['steady_change_mb'], s['steady_bound_mb'],
                   s['steady_mean_mb'], s['slope_mb_per_robot_min'], *s['steady_threads'], s['cpu_pct_growth'],
                   s['cpu_pct_steady']))
    return [head] + out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--robots', type=int, default=8)
    ap.add_argument('--minutes', type=float, default=30.0, help='robot time replayed')
    ap.add_argument('--speed', type=float, default=10.0, help='robot seconds per wall second')
    ap.add_argument('--grow-minutes', type=float, default=20.0, help='robot minutes of growth, then steady size')
    ap.add_argument('--map-interval', type=float, default=5.0, help='robot seconds between a robot\'s maps')
    ap.add_argument('--sample', type=float, default=2.0, help='wall seconds between samples')
    ap.add_argument('--no-build', action='store_true')
    ap.add_argument('--port', type=int, default=11800)
    ap.add_argument('--no-peer', action='store_true', help='do not soak m-explore\'s node')
    ap.add_argument('--publish', help=argparse.SUPPRESS)
    ap.add_argument('--out', default=os.path.join(HERE, 'results'))
    a = ap.parse_args()
    if a.publish:
        return publisher(json.load(open(a.publish)))
    os.makedirs(a.out, exist_ok=True)
    world = world_map('intel', required=True)
    tmp = tempfile.mkdtemp(prefix='mmm_soak_')
    robots = ['tb3_%d' % k for k in range(a.robots)]
    spec = {'speed': a.speed, 'map_interval': a.map_interval, 'grow_s': a.grow_minutes * 60.0, 'robots': []}
    for r, (g, _) in zip(robots, pieces_windows(world, a.robots, 0.6, seed=5)):
        p = os.path.join(tmp, r + '.yaml')
        save_map(g, p)
        spec['robots'].append({'name': r, 'path': p})
    procs, port = bench_processes(spec, tmp, a.port, not a.no_build)
    start, stop = procs.start, procs.stop

    seconds = a.minutes * 60.0 / a.speed
    grow_wall = a.grow_minutes * 60.0 / a.speed
    results = {'machine': machine(), 'robots': a.robots, 'robot_minutes': a.minutes, 'speed': a.speed,
               'grow_robot_minutes': a.grow_minutes, 'map_interval_robot_s': a.map_interval,
               'wall_s': seconds, 'sample_s': a.sample, 'flips_per_message': FLIPS,
               'criterion': 'flat: fitted memory change over the steady phase within max(5 MB, 2% of its mean), '
                            'threads end within 2 of their start'}

    def run(cmd, log, merged_of):
        pub = start([sys.executable, os.path.abspath(__file__), '--publish', os.path.join(tmp, 'publish.json')],
                    'publish_' + log)
        node = start(cmd, log)
        try:
            samples = soak(node.pid, seconds, a.sample, merged_of)
        finally:
            stop([node, pub])
        return {'samples': samples, 'summary': summarise(samples, grow_wall, a.speed)}

    try:
        start(['roscore', '-p', str(port)], 'roscore.log')
        import rosgraph
        import rospy
        from diagnostic_msgs.msg import DiagnosticArray
        for _ in range(100):
            if rosgraph.is_master_online():
                break
            time.sleep(0.2)
        rospy.init_node('soak', anonymous=True)
        merged = {'n': None}

        def on_diag(m):   # the node's own status: 'merged', robots placed (the reference included)
            for st in m.status:
                for kv in st.values:
                    if kv.key == 'merged' and kv.value.isdigit():
                        merged['n'] = int(kv.value)
        rospy.Subscriber('/diagnostics', DiagnosticArray, on_diag, queue_size=20)
        results['ours'] = run(['rosrun', 'multi_map_merge', 'map_merge_node', '_merge_rate:=2.0'], 'ours.log',
                              lambda: merged['n'])
        s = results['ours']['summary']
        if s.get('valid') and (s['figures']['end_growth']['merged'] or 0) < a.robots - 1:
            s['valid'] = False
            s['invalid_because'] = ('%s of %d robots merged at the end of the growth phase (< %d): the node did '
                                    'not do the work the soak is about' % (s['figures']['end_growth']['merged'],
                                                                           a.robots, a.robots - 1))
        peer, why_not = mexplore_node(a.no_peer)
        if peer:
            results['mexplore'] = run(peer, 'mexplore.log', lambda: None)
            results['mexplore']['summary']['note'] = 'm-explore reports no merged count: not checked'
        else:
            results['mexplore'] = why_not
    finally:
        stop(list(reversed(procs)))
    results_io.write_json(os.path.join(a.out, 'soak.json'), results, vars(a))
    out = ['SOAK: %d robots, %.0f robot minutes at %.0fx (%.0f s wall): maps growing for %.0f robot minutes, then '
           'steady in size but changing every message (%d cells flipped); a map per robot every %.0f robot s; '
           'the node\'s process tree sampled every %.0f s (memory: pages counted once). Criterion: %s' % (
               a.robots, a.minutes, a.speed, seconds, a.grow_minutes, FLIPS, a.map_interval, a.sample,
               results['criterion'])]
    out += lines('ours', results['ours'], a.speed)
    if isinstance(results['mexplore'], dict):
        out += lines('m-explore', results['mexplore'], a.speed)
        o, p = results['ours']['summary']['figures']['end'], results['mexplore']['summary']['figures']['end']
        if o['unique_mb'] and p['unique_mb']:
            out.append('memory at the end, ours / m-explore: %.0f / %.0f MB = %.2fx' % (
                o['unique_mb'], p['unique_mb'], o['unique_mb'] / p['unique_mb']))
    else:
        out.append('m-explore: %s' % results['mexplore'])
    print('\n'.join(out))
    results_io.write_text(os.path.join(a.out, 'soak.txt'), out, vars(a))


if __name__ == '__main__':
    main()
