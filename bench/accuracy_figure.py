"""The README's first figure from ``make accuracy``'s results: the time a team saves.

    bench/bench.py accuracy-figure [--json bench/results/accuracy.json] [-o docs/time_to_map.png]

Per world, the fraction of the ground truth's free area known in the map against the run's bag
time (s): the team's merged map (our merger, its default configuration) and the lone robot's, one
line per seed, the 90 % level dashed and each one's mean time to it marked. Beside the curves, per
world, the mean and worst over the seeds of the time to 90 % and of the final Fitness of both.
Prints the same as a markdown table (the README's) and draws the png with matplotlib.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any, Dict, List, Optional

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
TITLES = {'home': "the project's home (119 m2)", 'intel': 'Intel lab (28 x 28 m)', 'house': 'AWS small house'}


def _stats(values: List[Optional[float]], worst_is_max: bool) -> str:
    """'mean (worst)' of the values; a run that never reached it (None) makes the worst 'not
    reached' and is left out of the mean, said so."""
    got = [v for v in values if v is not None]
    if not values:
        return 'no runs'
    if not got:
        return 'not reached'
    mean = sum(got) / len(got)
    worst = (max(got) if worst_is_max else min(got))
    fmt = '%.0f s' if worst_is_max else '%.3f'
    out = fmt % mean
    if len(got) < len(values):
        return '%s (not reached in %d of %d)' % (out, len(values) - len(got), len(values))
    return '%s (%s)' % (out, fmt % worst)


def rows(doc: Dict[str, Any]) -> List[Dict[str, Any]]:
    """Per world: its timelines and the figures of the table."""
    out = []
    for w in doc['args']['worlds']:
        tls = [c['timeline'] for c in doc['conditions'] if c['world'] == w and not
               (c.get('timeline') or {'invalid': 1}).get('invalid')]
        if not tls:
            continue
        fit = {who: [t['end'][who].get('fitness') for t in tls] for who in ('team', 'single')}
        out.append({'world': w, 'seeds': len(tls), 'timelines': tls,
                    'team_t90': _stats([t['team_t90'] for t in tls], True),
                    'single_t90': _stats([t['single_t90'] for t in tls], True),
                    'team_fit': _stats(fit['team'], False), 'single_fit': _stats(fit['single'], False),
                    'team_end': sum(t['team_end_s'] for t in tls) / len(tls),
                    'single_end': sum(t['single_end_s'] for t in tls) / len(tls)})
    return out


def markdown(table: List[Dict[str, Any]]) -> List[str]:
    lines = ['| mean (worst) over the seeds | team: time to 90 % | lone robot: time to 90 % | '
             'team: final Fitness | lone robot: final Fitness |', '| --- | --- | --- | --- | --- |']
    for r in table:
        lines.append('| %s, %d seeds (drives of %.0f s team, %.0f s alone) | %s | %s | %s | %s |'
                     % (TITLES.get(r['world'], r['world']), r['seeds'], r['team_end'], r['single_end'],
                        r['team_t90'], r['single_t90'], r['team_fit'], r['single_fit']))
    return lines


def plot(table: List[Dict[str, Any]], path: str, line: str) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(table), figsize=(6.2 * len(table), 4.6), squeeze=False)
    for ax, r in zip(axes[0], table):
        for who, colour, name in (('team', 'tab:blue', 'team of 4, merged'), ('single', 'tab:orange', 'lone robot')):
            for k, t in enumerate(r['timelines']):
                pts = t[who]
                ax.plot([p['t'] for p in pts], [p['free'] for p in pts], color=colour, lw=1.0, alpha=0.7,
                        label=name if k == 0 else None)
            t90 = [t['%s_t90' % who] for t in r['timelines'] if t['%s_t90' % who] is not None]
            if t90:
                m = sum(t90) / len(t90)
                ax.axvline(m, color=colour, ls=':', lw=1.2)
                ax.annotate('90%% at %.0f s' % m, (m, 0.02), color=colour, rotation=90, ha='right', va='bottom',
                            fontsize=8)
        ax.axhline(0.9, color='grey', ls='--', lw=0.8)
        ax.set_ylim(0, 1.02)
        ax.set_xlabel('bag time (s): the robots drive at once')
        ax.set_ylabel("fraction of the truth's free area known")
        ax.set_title('%s, %d seeds' % (TITLES.get(r['world'], r['world']), r['seeds']), fontsize=10)
        ax.text(0.98, 0.30, 'time to 90%%, mean (worst)\nteam %s\nlone %s\n'
                'final Fitness, mean (worst)\nteam %s\nlone %s'
                % (r['team_t90'], r['single_t90'], r['team_fit'], r['single_fit']),
                transform=ax.transAxes, ha='right', va='bottom', fontsize=8,
                bbox={'facecolor': 'white', 'alpha': 0.85, 'edgecolor': 'lightgrey'})
        ax.legend(loc='lower right', fontsize=8, bbox_to_anchor=(1.0, 0.12))
    head, _, tail = line.partition('; worst')
    fig.suptitle(head + ('\nworst' + tail if tail else ''), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog='accuracy_figure.py', description=__doc__.split('\n\n')[0])
    ap.add_argument('--json', default=os.path.join(HERE, 'results', 'accuracy.json'))
    ap.add_argument('-o', '--output', default=os.path.join(REPO, 'docs', 'time_to_map.png'))
    a = ap.parse_args(argv)
    with open(a.json) as f:
        doc = json.load(f)
    table = rows(doc)
    if not table:
        print('accuracy_figure: no coverage over time in %s' % a.json, file=sys.stderr)
        return 1
    print('\n'.join(markdown(table)))
    print()
    print(doc.get('line', ''))
    plot(table, a.output, doc.get('line', ''))
    print('wrote %s' % a.output)
    return 0


if __name__ == '__main__':
    sys.exit(main())
