"""Machine description, the printed tables and the plot."""
from __future__ import annotations

import os
import platform
import time

TOL_M, TOL_DEG = 0.5, 3.0   # a placement within these of the truth counts as correct
PAIR_ESTIMATE_S = 5.0       # cold estimation is also measured in pairs (bench/duel.py, 11 rounds of
# one cycle each side) where m-explore's cycle is shorter than this; the longer rows (edmonton,
# 16 robots: 20-50 s a cycle) are far from the 0.5x line (0.04-0.11x)


def machine():
    info = {'nproc': len(os.sched_getaffinity(0)), 'cpu_count': os.cpu_count(), 'cpu_model': '',
            'mem_total_mb': None, 'python': platform.python_version(), 'kernel': platform.release(),
            'date': time.strftime('%Y-%m-%d %H:%M:%S')}
    try:
        with open('/proc/cpuinfo') as f:
            for line in f:
                if line.startswith('model name'):
                    info['cpu_model'] = line.split(':', 1)[1].strip()
                    break
        with open('/proc/meminfo') as f:
            kb = [line for line in f if line.startswith('MemTotal')][0].split()[1]
        info['mem_total_mb'] = int(kb) // 1024
    except (OSError, IndexError):
        pass
    try:
        import cv2
        info['opencv'] = cv2.__version__
        info['opencv_threads'] = cv2.getNumThreads()
    except ImportError:
        pass
    return info


def correct(side):
    """Robots placed within TOL_M / TOL_DEG of the truth (None when the truth is unknown)."""
    errs = side.get('errors')
    if not errs and side.get('max_err_m') is None:
        return None
    return sum(1 for d, a in errs.values() if d <= TOL_M and a <= TOL_DEG)


def _r(a, b):
    return None if a is None or b is None or not b else a / b


def _f(v, fmt='%.0f'):
    if v is None:
        return '-'
    if fmt == '%.2fx' and 0 < v < 0.01:
        return '%.1ex' % v      # warm cycles are thousands of times shorter
    return fmt % v


def compose_cells(r):
    """(ours: compose + publish ms, (m-explore on its own merge: ms, ratio), (on our poses: ms,
    ratio), (ours with one robot's map changed: ms, ratio to m-explore on its own merge)) of a
    row: the paired figures of bench/duel.py (each ratio the median of the rounds' ratios);
    without m-explore, ours from bench/ours.py and no peer figures."""
    d = r.get('compose') or {}
    if not d:
        o = r['ours']
        return o['compose_ms'] + o['publish_ms'], (None, None), (None, None), (o.get('live_ms'), None)
    pick = lambda k: (d[k]['compose_ms'], d[k]['ratio']) if d.get(k) else (None, None)  # noqa: E731
    live = (d.get('ours_live_ms'), (d.get('own') or {}).get('live_ratio'))
    return d['ours_ms'], pick('own'), pick('same_output'), live


def cold_cells(r):
    """(ours, m-explore, ratio, paired) of a row's cold estimation: the paired figures of
    bench/duel.py (medians of the rounds, the ratio the median of the rounds' ratios) when the
    row was paired, else each side's own runs."""
    d = r.get('estimate') or {}
    if d.get('mexplore'):
        return d['ours_ms'], d['mexplore']['estimate_ms'], d['mexplore']['ratio'], True
    a, b = r['ours']['cold_ms'], r['peer'].get('estimate_ms')
    return a, b, _r(a, b), False


def rows_table(rows, peer_note):
    """The two printed tables (time; memory and correctness) as one string."""
    out = []
    if peer_note:
        out.append('NOTE: %s' % peer_note)
    cols = ('input', 'cells', 'N', 'feat/map ms', 'pair ms', 'est cold ms', 'est warm ms',
            'compose+publ ms', 'same output', 'one map changed')
    h = '%-16s %5s %3s | %-21s | %-21s | %-24s | %-18s | %-26s | %-14s | %-15s' % cols
    out += ['', 'TIME  (each cell: ours / m-explore = ratio; ratio < 1: we are faster. compose: '
            'ours + publishing against m-explore\'s compositing of its own merge; same output: its '
            'compositing of the maps at our poses, ms = ratio; one map changed: ours when one robot\'s map '
            'changed (the others\' warps kept, as live), ms = ratio to m-explore\'s own, which warps every map '
            'each cycle. Compositing and, where m-explore\'s '
            'cycle is under %.0f s, cold estimation are measured in pairs, burst after burst '
            '(bench/duel.py): medians of the rounds and of their ratios; * = cold estimation not '
            'paired, one set of runs each)' % (PAIR_ESTIMATE_S,),
            h, '-' * len(h)]
    for r in rows:
        o, p = r['ours'], r['peer']

        def trip(a, b, fa='%.1f', fb='%.1f'):
            return '%s / %s = %s' % (_f(a, fa), _f(b, fb), _f(_r(a, b), '%.2fx'))
        cp, own, same, live = compose_cells(r)
        ca, cb, cr, paired = cold_cells(r)
        out.append('%-16s %5s %3d | %-21s | %-21s | %-24s | %-18s | %-26s | %-14s | %-15s' % (
            r['name'], '%dk' % (o['map_cells'] // 1000), r['robots'],
            trip(o['features_ms'], p.get('features_ms')), trip(o['pair_ms'], p.get('pair_ms'), '%.0f', '%.0f'),
            '%s / %s = %s%s' % (_f(ca), _f(cb), _f(cr, '%.2fx'), '' if paired or cb is None else '*'),
            trip(o['warm_ms'], p.get('estimate_ms'), '%.2f', '%.0f'),
            '%s / %s = %s' % (_f(cp, '%.1f'), _f(own[0], '%.1f'), _f(own[1], '%.2fx')),
            '%s = %s' % (_f(same[0], '%.1f'), _f(same[1], '%.2fx')),
            '%s = %s' % (_f(live[0], '%.1f'), _f(live[1], '%.2fx'))))
    h = '%-16s %3s | %-30s | %-16s | %-38s' % ('input', 'N', 'peak MB (ours: node + workers)', 'placed (ok)',
                                                'max error: ours | m-explore')
    out += ['', 'MEMORY AND CORRECTNESS  (placed: robots put in the merged frame besides the reference; '
            'ok: within %.1f m and %.0f deg of the truth; peak memory: ours = the node\'s process tree '
            '(bench/ours.py --memory: the node\'s imports, its workers forked as the node forks them, '
            'its work on the maps: cold cycles repeated for 3 s), every physical page counted once, sampled '
            'about every 40 ms (the node\'s '
            'process alone in brackets); m-explore: its process\'s peak RSS)' % (TOL_M, TOL_DEG),
            h, '-' * len(h)]
    for r in rows:
        o, p = r['ours'], r['peer']

        def pl(s):
            if s.get('placed') is None:
                return '-'
            c = correct(s)
            return '%d%s' % (s['placed'], '' if c is None else ' (%d)' % c)

        def er(s):
            return '%s m %s deg' % (_f(s.get('max_err_m'), '%.3f'), _f(s.get('max_err_deg'), '%.2f'))
        out.append('%-16s %3d | %-30s | %-16s | %-38s' % (
            r['name'], r['robots'],
            '%.0f (%s) / %s = %s' % (o['rss_mb'], _f(o.get('rss_self_mb')), _f(p.get('rss_mb')),
                                     _f(_r(o['rss_mb'], p.get('rss_mb')), '%.2fx')),
            '%s / %s' % (pl(o), pl(p)), '%s | %s' % (er(o), er(p) if p.get('placed') is not None
                                                      else p.get('skipped', '-'))))
    return '\n'.join(out)


def plot(rows, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(17, 4.8))
    sweep = [r for r in rows if r['kind'] == 'count']
    sizes = [r for r in rows if r['kind'] == 'size']

    def series(a, rs, x, side, key, style, label):
        pts = [(x(r), r[side][key]) for r in rs if r[side].get(key) is not None]
        if pts:
            a.plot(*zip(*pts), style, label=label)

    n = lambda r: r['robots']  # noqa: E731
    for k, style, label in ((0, 'o-', 'ours: estimation, cold'), (1, 'o--', 'm-explore: estimation')):
        pts = [(n(r), cold_cells(r)[k]) for r in sweep if cold_cells(r)[k] is not None]
        if pts:
            ax[0].plot(*zip(*pts), style, label=label)
    series(ax[0], sweep, n, 'ours', 'warm_ms', 'd-', 'ours: estimation, warm')
    for k, style, label in ((0, 's-', 'ours: compositing + publishing'),
                            (1, 's--', 'm-explore: compositing'),
                            (2, 's:', 'm-explore: compositing at our poses')):
        pts = [(n(r), compose_cells(r)[k] if k == 0 else compose_cells(r)[k][0]) for r in sweep]
        pts = [q for q in pts if q[1] is not None]
        if pts:
            ax[0].plot(*zip(*pts), style, label=label)
    ax[0].set_xscale('log', base=2)
    ax[0].set_xlabel('robots (intel-sized maps, all overlapping)')
    ax[0].set_title('time against robot count')

    cells = lambda r: r['ours']['map_cells']  # noqa: E731
    for k, style, label in ((0, 'o-', 'ours: estimation (4 robots), cold'),
                            (1, 'o--', 'm-explore: estimation (4 robots)')):
        pts = [(cells(r), cold_cells(r)[k]) for r in sizes if cold_cells(r)[k] is not None]
        if pts:
            ax[1].plot(*zip(*pts), style, label=label)
    series(ax[1], sizes, cells, 'ours', 'pair_ms', '^-', 'ours: one pair')
    series(ax[1], sizes, cells, 'peer', 'pair_ms', '^--', 'm-explore: one pair')
    series(ax[1], sizes, cells, 'ours', 'features_ms', 'v-', 'ours: features of one map')
    series(ax[1], sizes, cells, 'peer', 'features_ms', 'v--', 'm-explore: features of one map')
    for r in sizes:
        ax[1].annotate(r['name'].split()[0], (cells(r), cold_cells(r)[0]), fontsize=8)
    ax[1].set_xscale('log')
    ax[1].set_xlabel('cells per robot map (median)')
    ax[1].set_title('time against map size')
    for a in ax[:2]:
        a.set_yscale('log')
        a.set_ylabel('ms')

    series(ax[2], sweep, n, 'ours', 'rss_mb', 'o-', 'ours (node + workers, pages once)')
    series(ax[2], sweep, n, 'ours', 'rss_self_mb', 'd-', 'ours (node process alone)')
    series(ax[2], sweep, n, 'peer', 'rss_mb', 'o--', 'm-explore')
    ax[2].set_xscale('log', base=2)
    ax[2].set_xlabel('robots (intel-sized maps)')
    ax[2].set_ylabel('peak RSS, MB')
    ax[2].set_title('peak memory against robot count')
    for a in ax:
        a.grid(True, which='both', alpha=.3)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
