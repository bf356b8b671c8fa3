"""Machine description, the printed tables and the plot."""
from __future__ import annotations

import os
import platform
import time

TOL_M, TOL_DEG = 0.5, 3.0   # a placement within these of the truth counts as correct


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


def mexplore_cell(r, key, fmt):
    """A row's m-explore figure, or why there is none (bench/peer.py: never a number when its
    node is not installed)."""
    mx = r.get('mexplore') or {}
    if 'invalid' in mx or mx.get(key) is None:
        return mx.get('invalid', '-')
    return fmt % mx[key]


def rows_table(rows, peer_note):
    """The two printed tables (time; memory and correctness) as one string."""
    out = []
    if peer_note:
        out.append('NOTE: %s' % peer_note)
    cols = ('input', 'cells', 'N', 'feat/map ms', 'pair ms', 'est cold ms', 'est warm ms', 'compose+publ ms',
            'one map chg ms', 'MRPT align s (run s)', 'ours/MRPT', 'm-explore est ms (1st)', 'ours/m-explore (ms)',
            'm-explore: first merged /map')
    row = '%-16s %5s %3s | %-11s | %-8s | %-11s | %-11s | %-15s | %-14s | %-20s | %-9s | %-22s | %-19s | %s'
    h = row % cols
    out += ['', 'TIME  (ours: bench/ours.py, medians of fresh processes; est cold: a whole estimation '
            'cycle of a new merger; one map chg: compose + publish when one robot\'s map changed. MRPT: '
            'CGridMapAligner on every pair (bench/mrpt_merge.py, seed 1): its aligner process (maps read, '
            'features, every pair) in s, the whole run (Python start, map I/O, compositing) in brackets; '
            'ours/MRPT = est cold / MRPT align (< 1: we are faster). m-explore: its node, from its start '
            'to its first merged /map (discovery and estimation at 1 Hz), CPU s in brackets; m-explore est: '
            'its node\'s estimation cycle (estimateTransforms: features, every pair, placement; from scratch '
            'every cycle), timed by its own DEBUG lines, median of its cycles, the first in brackets; '
            'ours/m-explore: ours\' cold cycle over m-explore\'s, alternated round after round in the same '
            'minutes (bench/duel.py; < 1: we are faster), the two medians of those rounds in ms in brackets)',
            h, '-' * len(h)]
    for r in rows:
        o, m = r['ours'], r.get('mrpt') or {}
        if m.get('align_s') is not None:
            mcell = '%.2f (%.2f)' % (m['align_s'], m['wall_s'])
            ratio = _f(_r(o['cold_ms'] / 1000.0, m['align_s']), '%.2fx')
        else:
            mcell, ratio = (m.get('skipped') or '-')[:20], '-'
        mx = mexplore_cell(r, 'first_map_s', '%.1f s')
        if 'invalid' not in (r.get('mexplore') or {'invalid': 1}):
            mx += ' (%.1f CPU s)' % r['mexplore']['cpu_s']
        est = r.get('mexplore_est') or r.get('mexplore') or {'invalid': '-'}
        paired = r.get('mexplore_paired') or {}
        if est.get('estimate_ms') is not None:
            ecell = '%.0f (%.0f)' % (est['estimate_ms'], est['estimate_first_ms'])
            if paired.get('ratio') is not None:
                eratio = '%.2fx (%.0f/%.0f)' % (paired['ratio'], paired['ours_ms'], paired['mexplore_ms'])
            else:       # not paired: the two medians, taken minutes apart
                eratio = _f(_r(o['cold_ms'], est['estimate_ms']), '%.2fx') + ' unpaired'
        else:
            ecell, eratio = (est.get('invalid') or '-')[:22], '-'
        out.append(row % (
            r['name'], '%dk' % (o['map_cells'] // 1000), r['robots'], _f(o['features_ms'], '%.1f'),
            _f(o['pair_ms']), _f(o['cold_ms']), _f(o['warm_ms'], '%.2f'),
            _f(o['compose_ms'] + o['publish_ms'], '%.1f'), _f(o.get('live_ms'), '%.1f'), mcell, ratio,
            ecell, eratio, mx))
    h = '%-16s %3s | %-24s | %-8s | %-17s | %-30s | %-30s | %s' % (
        'input', 'N', 'ours MB (node alone)', 'MRPT MB', 'placed (ok)', 'max error: ours', 'MRPT', 'm-explore MB')
    out += ['', 'MEMORY AND CORRECTNESS  (placed: robots put in the merged frame besides the reference, ours / '
            'MRPT; ok: within %.1f m and %.0f deg of the truth; peak memory: ours = the node\'s process tree '
            '(bench/ours.py --memory: the node\'s imports, its workers forked as the node forks them, '
            'its work on the maps: cold cycles repeated for 3 s), every physical page counted once, sampled '
            'about every 40 ms (the node\'s process alone in brackets); MRPT: its aligner process\'s peak '
            'RSS; m-explore: its node\'s peak RSS; m-explore publishes a merged map, not placements)'
            % (TOL_M, TOL_DEG), h, '-' * len(h)]
    for r in rows:
        o, m = r['ours'], r.get('mrpt') or {}

        def pl(s):
            if s.get('placed') is None:
                return '-'
            c = correct(s)
            return '%d%s' % (s['placed'], '' if c is None else ' (%d)' % c)

        def er(s):
            if s.get('placed') is None:
                return (s.get('skipped') or '-')[:30]
            return '%s m %s deg' % (_f(s.get('max_err_m'), '%.3f'), _f(s.get('max_err_deg'), '%.2f'))
        out.append('%-16s %3d | %-24s | %-8s | %-17s | %-30s | %-30s | %s' % (
            r['name'], r['robots'], '%.0f (%s)' % (o['rss_mb'], _f(o.get('rss_self_mb'))),
            _f(m.get('rss_mb')), '%s / %s' % (pl(o), pl(m)), er(o), er(m),
            mexplore_cell(r, 'rss_mb', '%.0f')))
    return '\n'.join(out)


def plot(rows, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 3, figsize=(17, 4.8))
    sweep = [r for r in rows if r['kind'] == 'count']
    sizes = [r for r in rows if r['kind'] == 'size']

    def series(a, rs, x, side, key, style, label, scale=1.0):
        pts = [(x(r), r[side][key] * scale) for r in rs if (r.get(side) or {}).get(key) is not None]
        if pts:
            a.plot(*zip(*pts), style, label=label)

    n = lambda r: r['robots']  # noqa: E731
    series(ax[0], sweep, n, 'ours', 'cold_ms', 'o-', 'ours: estimation, cold')
    series(ax[0], sweep, n, 'ours', 'warm_ms', 'd-', 'ours: estimation, warm')
    series(ax[0], sweep, n, 'mrpt', 'align_s', 'o--', 'MRPT: every pair aligned', 1000.0)
    series(ax[0], sweep, n, 'mexplore', 'first_map_s', 'o:', 'm-explore: to its first merged /map', 1000.0)
    series(ax[0], sweep, n, 'mexplore_est', 'estimate_ms', 's:', 'm-explore: estimation cycle')
    ax[0].set_xscale('log', base=2)
    ax[0].set_xlabel('robots (intel-sized maps, all overlapping)')
    ax[0].set_title('time against robot count')

    cells = lambda r: r['ours']['map_cells']  # noqa: E731
    series(ax[1], sizes, cells, 'ours', 'cold_ms', 'o-', 'ours: estimation (4 robots), cold')
    series(ax[1], sizes, cells, 'mrpt', 'align_s', 'o--', 'MRPT: every pair aligned (4 robots)', 1000.0)
    series(ax[1], sizes, cells, 'ours', 'pair_ms', '^-', 'ours: one pair')
    series(ax[1], sizes, cells, 'ours', 'features_ms', 'v-', 'ours: features of one map')
    for r in sizes:
        ax[1].annotate(r['name'].split()[0], (cells(r), r['ours']['cold_ms']), fontsize=8)
    ax[1].set_xscale('log')
    ax[1].set_xlabel('cells per robot map (median)')
    ax[1].set_title('time against map size')
    for a in ax[:2]:
        a.set_yscale('log')
        a.set_ylabel('ms')

    series(ax[2], sweep, n, 'ours', 'rss_mb', 'o-', 'ours (node + workers, pages once)')
    series(ax[2], sweep, n, 'ours', 'rss_self_mb', 'd-', 'ours (node process alone)')
    series(ax[2], sweep, n, 'mrpt', 'rss_mb', 'o--', 'MRPT (aligner process)')
    series(ax[2], sweep, n, 'mexplore', 'rss_mb', 'o:', 'm-explore (node)')
    ax[2].set_xscale('log', base=2)
    ax[2].set_xlabel('robots (intel-sized maps)')
    ax[2].set_ylabel('peak RSS, MB')
    ax[2].set_title('peak memory against robot count')
    for a in ax:
        a.grid(True, which='both', alpha=.3)
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
