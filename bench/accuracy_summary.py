"""The pure part of bench/accuracy.py: figures that may be INVALID, their mean and worst over
the seeds, the loss to the rigid bound, the tables and the summary line. No ROS, no numpy:
unit-tested in test/unit/bench/test_accuracy_summary.py.

A figure is a float (a Fitness, 0..1) or an :class:`Invalid` naming why the condition behind it
was not created (the SLAM missing, a robot's SLAM processed nothing, a peer absent, a merge
that failed, ...). Anything computed from an INVALID figure is INVALID: a mean over the seeds
with one seed missing would be a mean over other seeds, not the figure asked for.
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Sequence, Union

# the rows of a condition (one world, one seed), in the order they are printed
ROWS = ('single', 'merged', 'merged_rigid', 'own', 'rigid', 'starts', 'mexplore', 'mrpt')
ROW_NAMES = {
    'single': 'single robot',
    'merged': 'merged team (ours)',
    'merged_rigid': 'ours, unbent',
    'own': "robots' own maps (mean)",
    'rigid': 'rigid bound',
    'starts': 'team at its true starts',
    'mexplore': 'm-explore merge',
    'mrpt': 'MRPT merge',
}


class Invalid:
    """A figure whose condition was not created; ``reason`` says why."""

    __slots__ = ('reason',)

    def __init__(self, reason: str):
        self.reason = str(reason)

    def __repr__(self) -> str:
        return 'Invalid(%r)' % self.reason

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Invalid) and other.reason == self.reason

    def __hash__(self) -> int:
        return hash(self.reason)


Figure = Union[float, Invalid]


def is_valid(v: Any) -> bool:
    return not isinstance(v, Invalid) and v is not None


def fmt(v: Any, digits: int = 4) -> str:
    """A figure as printed: ``%.4f`` or ``INVALID``."""
    return ('%.*f' % (digits, v)) if is_valid(v) else 'INVALID'


def to_json(v: Any) -> Dict[str, Any]:
    """A figure in the JSON file: ``{"fitness": x}`` or ``{"fitness": null, "invalid": why}``."""
    if is_valid(v):
        return {'fitness': float(v)}
    return {'fitness': None, 'invalid': v.reason if isinstance(v, Invalid) else 'not computed'}


def from_json(d: Optional[Dict[str, Any]]) -> Figure:
    if not d or d.get('fitness') is None:
        return Invalid((d or {}).get('invalid', 'not computed'))
    return float(d['fitness'])


def mean(values: Sequence[Figure]) -> Figure:
    """Mean of the figures; INVALID when there are none or any of them is INVALID."""
    bad = [v for v in values if not is_valid(v)]
    if not values:
        return Invalid('no runs')
    if bad:
        return Invalid('%d of %d INVALID (%s)' % (len(bad), len(values), _reasons(bad)))
    return sum(float(v) for v in values) / len(values)


def worst(values: Sequence[Figure]) -> Figure:
    """The lowest Fitness of the figures; INVALID as :func:`mean`."""
    m = mean(values)
    if not is_valid(m):
        return m
    return min(float(v) for v in values)


def loss(bound: Figure, merged: Figure) -> Figure:
    """What the merge lost against the rigid bound: bound - merged (negative: it did better)."""
    if not is_valid(bound):
        return Invalid('rigid bound INVALID: %s' % bound.reason) if isinstance(bound, Invalid) else Invalid('no bound')
    if not is_valid(merged):
        return Invalid('merged INVALID: %s' % merged.reason) if isinstance(merged, Invalid) else Invalid('no merge')
    return float(bound) - float(merged)


def worst_loss(losses: Sequence[Figure]) -> Figure:
    """The largest loss; INVALID when there are none or any is INVALID."""
    bad = [v for v in losses if not is_valid(v)]
    if not losses:
        return Invalid('no runs')
    if bad:
        return Invalid('%d of %d INVALID (%s)' % (len(bad), len(losses), _reasons(bad)))
    return max(float(v) for v in losses)


def group_reasons(pairs: Sequence[Any]) -> str:
    """``[(robot, why), ...]`` as one reason, robots with the same reason named together:
    ``tb3_0, tb3_2: rbpf_slam processed no scan; tb3_1: no map saved``."""
    order: List[str] = []
    who: Dict[str, List[str]] = {}
    for name, why in pairs:
        if why not in who:
            who[why] = []
            order.append(why)
        who[why].append(str(name))
    return '; '.join('%s: %s' % (', '.join(who[w]), w) for w in order)


def _reasons(bad: Sequence[Any]) -> str:
    seen: List[str] = []
    for v in bad:
        r = v.reason if isinstance(v, Invalid) else 'not computed'
        if r not in seen:
            seen.append(r)
    return '; '.join(seen)


def diff(a: Figure, b: Figure) -> Figure:
    """a - b, INVALID when either is."""
    if not is_valid(a) or not is_valid(b):
        return Invalid('; '.join(v.reason if isinstance(v, Invalid) else 'not computed'
                                 for v in (a, b) if not is_valid(v)))
    return float(a) - float(b)


def lowest(values: Sequence[Figure]) -> Figure:
    """The smallest figure; INVALID as :func:`mean`."""
    return worst(values)


def aggregate(conditions: Sequence[Dict[str, Any]], worlds: Sequence[str],
              merged_row: str = 'merged') -> Dict[str, Any]:
    """Mean and worst per world and row, and over everything.

    ``conditions``: one per (world, seed): ``{'world': name, 'seed': n, 'rows': {row: Figure}}``
    and, where measured, ``'timeline'`` (bench/timeline.py's document). ``merged_row``: the row
    that is the merger as it ships (its default configuration: ``merged`` bends the maps,
    ``merged_rigid`` does not), the one the loss, the targets and the summary line speak of.
    Returns ``{'worlds': {world: {row: {'mean', 'worst'}, 'loss': {'mean', 'worst'},
    'vs_starts': {'mean', 'worst'}, 'bend_gain': {...}, 'time': time_figures, 'seeds': [..]}},
    'overall': {row: mean over every condition, 'worst_loss', 'merged_default', 'worst_vs_starts',
    'bend_gain', 'time', 'seeds': n, 'worlds': w}}`` (figures, not yet JSON)."""
    out: Dict[str, Any] = {'worlds': {}, 'merged_row': merged_row}
    all_rows: Dict[str, List[Figure]] = {r: [] for r in ROWS}
    all_losses: List[Figure] = []
    all_vs: List[Figure] = []
    all_bend: List[Figure] = []
    seeds_seen = set()

    def row(c, r):
        return c['rows'].get(r, Invalid('not run'))
    for w in worlds:
        cs = [c for c in conditions if c['world'] == w]
        d: Dict[str, Any] = {'seeds': [c['seed'] for c in cs]}
        for r in ROWS:
            vals = [row(c, r) for c in cs]
            d[r] = {'mean': mean(vals), 'worst': worst(vals)}
            all_rows[r].extend(vals)
        ls = [loss(row(c, 'rigid'), row(c, merged_row)) for c in cs]
        all_losses.extend(ls)
        d['loss'] = {'mean': mean(ls), 'worst': worst_loss(ls)}
        vs = [diff(row(c, merged_row), row(c, 'starts')) for c in cs]
        all_vs.extend(vs)
        d['vs_starts'] = {'mean': mean(vs), 'worst': lowest(vs), 'per_seed': vs}
        bend = [diff(row(c, 'merged'), row(c, 'merged_rigid')) for c in cs]
        all_bend.extend(bend)
        d['bend_gain'] = {'mean': mean(bend), 'worst': lowest(bend), 'per_seed': bend}
        d['time'] = time_figures(cs)
        out['worlds'][w] = d
        seeds_seen.update(c['seed'] for c in cs)
    overall: Dict[str, Any] = {r: mean(all_rows[r]) for r in ROWS}
    overall['worst_loss'] = worst_loss(all_losses)
    overall['merged_default'] = overall[merged_row]
    overall['worst_vs_starts'] = lowest(all_vs)
    overall['bend_gain'] = {'mean': mean(all_bend), 'worst': lowest(all_bend)}
    overall['time'] = time_figures([c for c in conditions if c['world'] in worlds])
    overall['seeds'] = len(seeds_seen)
    overall['worlds'] = len(worlds)
    out['overall'] = overall
    return out


BEND_TOLERANCE = 0.005    # Fitness: bending may lose this much in a seed (issue 51's rule)
STARTS_TOLERANCE = 0.01   # Fitness: the merge may lose this much to the team at its true starts


def bend_decision(bend_gain: Sequence[Figure]) -> str:
    """Issue 51's rule for ``~bend_maps`` from the per-seed gains (bent - unbent Fitness): on by
    default only where it scores at least the rigid merge - 0.005 in every seed and above it on
    the mean."""
    if not bend_gain or not all(is_valid(v) for v in bend_gain):
        return 'undecided (a seed INVALID)'
    ok_each = all(float(v) >= -BEND_TOLERANCE for v in bend_gain)
    above = sum(float(v) for v in bend_gain) / len(bend_gain) > 0
    return 'on' if ok_each and above else 'off'


def _time_mean(values: Sequence[Any]) -> str:
    """Seconds over runs, each a float, None (not reached) or an Invalid: the mean when every
    run reached it, else INVALID or the mean over those that did and how many did not."""
    if not values or any(isinstance(v, Invalid) for v in values):
        return 'INVALID'
    got = [float(v) for v in values if v is not None]
    if not got:
        return 'not reached'
    m = '%.0f' % (sum(got) / len(got))
    return m if len(got) == len(values) else '%s (not reached in %d of %d)' % (m, len(values) - len(got), len(values))


def secs(v: str) -> str:
    """A printed time (``_time_mean``, ``_time_worst``) with its unit where it is a number."""
    if not v[:1].isdigit():
        return v
    num, _, rest = v.partition(' ')
    return num + ' s' + (' ' + rest if rest else '')


def _time_worst(values: Sequence[Any]) -> str:
    if not values or any(isinstance(v, Invalid) for v in values):
        return 'INVALID'
    if any(v is None for v in values):
        return 'not reached'
    return '%.0f' % max(float(v) for v in values)


TIME_KEYS = ('team_t90', 'single_t90', 'team_t99', 'single_t99')


def time_figures(conditions: Sequence[Dict[str, Any]]) -> Dict[str, Any]:
    """Over the conditions' timelines: per time key (TIME_KEYS) the mean and the worst (longest)
    as printed strings, and per figure of the final and equal-time scores ('end', 'equal_time'
    x 'team', 'single' x 'fitness', 'free') the mean and worst (lowest) Figures."""
    tls = [c.get('timeline') or {'invalid': 'not run'} for c in conditions]
    out: Dict[str, Any] = {}
    for k in TIME_KEYS:
        vals = [Invalid(t['invalid']) if t.get('invalid') else t.get(k) for t in tls]
        out[k] = {'mean': _time_mean(vals), 'worst': _time_worst(vals)}
    for when in ('end', 'equal_time'):
        for who in ('team', 'single'):
            for fig in ('fitness', 'free', 'inlier_rmse'):
                vals = []
                for t in tls:
                    d = (t.get(when) or {}).get(who) if not t.get('invalid') else None
                    vals.append(Invalid((d or t).get('invalid', 'not measured')) if not d or d.get('invalid')
                                else float(d[fig]))
                out['%s_%s_%s' % (when, who, fig)] = {'mean': mean(vals), 'worst': worst(vals)}
    return out


def summary_line(overall: Dict[str, Any]) -> str:
    """The last line bench/accuracy.py prints (its form is fixed: scripts parse it). ``merged``
    is the merger as it ships (``aggregate``'s ``merged_row``)."""
    t = overall.get('time') or {}
    return ('accuracy: %d seeds x %d worlds; merged mean %s, single mean %s, team at true starts mean %s, '
            'rigid bound mean %s; worst merged minus true starts %s; time to 90%%: team %s, single %s'
            % (overall['seeds'], overall['worlds'], fmt(overall.get('merged_default', overall['merged'])),
               fmt(overall['single']), fmt(overall['starts']), fmt(overall['rigid']),
               fmt(overall.get('worst_vs_starts', Invalid('not computed'))),
               secs(t.get('team_t90', {}).get('mean', 'INVALID')),
               secs(t.get('single_t90', {}).get('mean', 'INVALID'))))


def condition_cell(v: Figure, merged_count: Optional[str] = None) -> str:
    """A table cell: the Fitness (and how many robots were merged), or INVALID."""
    s = fmt(v)
    if merged_count and is_valid(v):
        s += ' (%s)' % merged_count
    return s


def markdown(conditions: Sequence[Dict[str, Any]], agg: Dict[str, Any], worlds: Sequence[str],
             titles: Dict[str, str]) -> str:
    """The markdown tables: per world, a row per figure, a column per seed, then mean and worst."""
    lines: List[str] = []
    for w in worlds:
        cs = sorted((c for c in conditions if c['world'] == w), key=lambda c: c['seed'])
        if not cs:
            continue
        lines.append('### %s' % titles.get(w, w))
        lines.append('')
        head = ['Fitness'] + ['seed %d' % c['seed'] for c in cs] + ['mean', 'worst']
        lines.append('| ' + ' | '.join(head) + ' |')
        lines.append('|' + ' --- |' * len(head))
        d = agg['worlds'][w]
        for r in ROWS:
            cells = [ROW_NAMES[r]]
            for c in cs:
                cells.append(condition_cell(c['rows'].get(r, Invalid('not run')), c.get('merged_counts', {}).get(r)))
            cells += [fmt(d[r]['mean']), fmt(d[r]['worst'])]
            lines.append('| ' + ' | '.join(cells) + ' |')
        mrow = agg.get('merged_row', 'merged')
        cells = ['loss to the rigid bound (%s)' % ROW_NAMES[mrow]]
        for c in cs:
            rows = c['rows']
            cells.append(fmt(loss(rows.get('rigid', Invalid('not run')), rows.get(mrow, Invalid('not run')))))
        cells += [fmt(d['loss']['mean']), fmt(d['loss']['worst']) + ' (largest)']
        lines.append('| ' + ' | '.join(cells) + ' |')
        if 'vs_starts' in d:
            for key, title in (('vs_starts', '%s minus true starts' % ROW_NAMES[mrow]),
                               ('bend_gain', 'bent minus unbent')):
                cells = [title] + [fmt(v) for v in d[key]['per_seed']]
                cells += [fmt(d[key]['mean']), fmt(d[key]['worst']) + ' (lowest)']
                lines.append('| ' + ' | '.join(cells) + ' |')
            for k in TIME_KEYS:
                cells = [k.replace('_t', ' time to ') + '% (s)']
                for c in cs:
                    tl = c.get('timeline') or {'invalid': 'not run'}
                    v = tl.get(k)
                    cells.append('INVALID' if tl.get('invalid') else ('not reached' if v is None else '%.0f' % v))
                cells += [d['time'][k]['mean'], d['time'][k]['worst'] + ' (longest)']
                lines.append('| ' + ' | '.join(cells) + ' |')
        lines.append('')
        notes = []
        for c in cs:
            for r in ROWS:
                v = c['rows'].get(r)
                if isinstance(v, Invalid):
                    notes.append('- seed %d, %s: INVALID: %s' % (c['seed'], ROW_NAMES[r], v.reason))
        if notes:
            lines += notes + ['']
    lines.append('`%s`' % summary_line(agg['overall']))
    lines.append('')
    return '\n'.join(lines)


# ------------------------------------------------------------------------------ coverage over time

def _secs(v: Any) -> str:
    return 'not reached' if v is None else '%.0f s' % v


def timeline_lines(tl: Dict[str, Any]) -> List[str]:
    """A condition's coverage over time (bench/timeline.py's document) as printed lines."""
    if tl.get('invalid'):
        return ['  coverage over time INVALID: %s' % tl['invalid']]
    lines = ['  coverage over time (free area, walls within %.2f m; a snapshot every %g s of bag time):'
             % (tl['tolerance_m'], tl['every_s'])]
    for who, name in (('team', 'team merged'), ('single', 'lone robot')):
        pts = tl[who]
        step = max(1, len(pts) // 8)
        shown = pts[::step] + ([pts[-1]] if (len(pts) - 1) % step else [])
        lines.append('    %-12s %s' % (name, '  '.join('%.0f s %.2f/%.2f' % (p['t'], p['free'], p['walls'])
                                                       for p in shown)))
        lines.append('    %-12s time to 90%% %s, to 99%% %s (end %.0f s)'
                     % ('', _secs(tl['%s_t90' % who]), _secs(tl['%s_t99' % who]), tl['%s_end_s' % who]))
    for when, title in (('equal_time', 'at the team\'s end (%.0f s)' % tl['team_end_s']), ('end', 'each at its end')):
        d = tl[when]
        lines.append('    %s: %s' % (title, '; '.join(
            '%s %s' % (who, 'INVALID: %s' % d[who]['invalid'] if d[who].get('invalid') else
                       'Fitness %.4f, inlier RMSE %.3f m, free %.3f, walls %.3f'
                       % (d[who]['fitness'], d[who]['inlier_rmse'], d[who]['free'], d[who]['walls']))
            for who in ('team', 'single'))))
    return lines
