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


def aggregate(conditions: Sequence[Dict[str, Any]], worlds: Sequence[str]) -> Dict[str, Any]:
    """Mean and worst per world and row, and over everything.

    ``conditions``: one per (world, seed): ``{'world': name, 'seed': n, 'rows': {row: Figure}}``.
    Returns ``{'worlds': {world: {row: {'mean', 'worst'}, 'loss': {'mean', 'worst'}, 'seeds': [..]}},
    'overall': {row: mean over every condition, 'worst_loss': ..., 'seeds': n, 'worlds': w}}``
    (figures, not yet JSON)."""
    out: Dict[str, Any] = {'worlds': {}}
    all_rows: Dict[str, List[Figure]] = {r: [] for r in ROWS}
    all_losses: List[Figure] = []
    seeds_seen = set()
    for w in worlds:
        cs = [c for c in conditions if c['world'] == w]
        d: Dict[str, Any] = {'seeds': [c['seed'] for c in cs]}
        for r in ROWS:
            vals = [c['rows'].get(r, Invalid('not run')) for c in cs]
            d[r] = {'mean': mean(vals), 'worst': worst(vals)}
            all_rows[r].extend(vals)
        ls = [loss(c['rows'].get('rigid', Invalid('not run')), c['rows'].get('merged', Invalid('not run')))
              for c in cs]
        all_losses.extend(ls)
        d['loss'] = {'mean': mean(ls), 'worst': worst_loss(ls)}
        out['worlds'][w] = d
        seeds_seen.update(c['seed'] for c in cs)
    overall: Dict[str, Any] = {r: mean(all_rows[r]) for r in ROWS}
    overall['worst_loss'] = worst_loss(all_losses)
    overall['seeds'] = len(seeds_seen)
    overall['worlds'] = len(worlds)
    out['overall'] = overall
    return out


def summary_line(overall: Dict[str, Any]) -> str:
    """The last line bench/accuracy.py prints (its form is fixed: scripts parse it)."""
    return ('accuracy: %d seeds x %d worlds; merged mean %s, single mean %s, own maps mean %s, '
            'rigid bound mean %s; worst loss to the rigid bound %s'
            % (overall['seeds'], overall['worlds'], fmt(overall['merged']), fmt(overall['single']),
               fmt(overall['own']), fmt(overall['rigid']), fmt(overall['worst_loss'])))


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
        cells = ['loss to the rigid bound (ours)']
        for c in cs:
            rows = c['rows']
            cells.append(fmt(loss(rows.get('rigid', Invalid('not run')), rows.get('merged', Invalid('not run')))))
        cells += [fmt(d['loss']['mean']), fmt(d['loss']['worst']) + ' (largest)']
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
