"""bench/accuracy_summary.py, the pure part of `make accuracy`: INVALID figures, the mean and the
worst over seeds, the loss to the rigid bound and the fixed form of the summary line."""
import os
import re
import sys

BENCH = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'bench')
sys.path.insert(0, os.path.abspath(BENCH))

from accuracy_summary import (  # noqa: E402
    ROWS,
    Invalid,
    aggregate,
    fmt,
    from_json,
    group_reasons,
    is_valid,
    loss,
    markdown,
    mean,
    summary_line,
    to_json,
    worst,
    worst_loss,
)

LINE = re.compile(r'^accuracy: (\d+) seeds x (\d+) worlds; merged mean (\S+), single mean (\S+), '
                  r'own maps mean (\S+), rigid bound mean (\S+); worst loss to the rigid bound (\S+)$')


def cond(world, seed, **rows):
    full = {r: 0.5 for r in ROWS}
    full.update(rows)
    return {'world': world, 'seed': seed, 'rows': full}


def test_mean_and_worst():
    assert abs(mean([0.2, 0.4, 0.9]) - 0.5) < 1e-12
    assert worst([0.2, 0.4, 0.9]) == 0.2
    assert worst([0.7]) == 0.7


def test_invalid_propagates():
    m = mean([0.5, Invalid('gmapping processed no scan of 760'), 0.7])
    assert isinstance(m, Invalid)
    assert '1 of 3 INVALID' in m.reason and 'gmapping processed no scan' in m.reason
    assert isinstance(worst([0.5, Invalid('x')]), Invalid)
    assert isinstance(mean([]), Invalid)
    # the same reason is named once
    assert mean([Invalid('a'), Invalid('a'), Invalid('b')]).reason == '3 of 3 INVALID (a; b)'


def test_loss_to_the_rigid_bound():
    assert abs(loss(0.9, 0.6) - 0.3) < 1e-12
    assert loss(0.6, 0.7) < 0              # the merge beat the bound: a negative loss, kept
    assert isinstance(loss(Invalid('no maps'), 0.6), Invalid)
    assert isinstance(loss(0.9, Invalid('merge_maps failed')), Invalid)
    assert isinstance(loss(None, 0.6), Invalid)
    assert worst_loss([0.1, -0.05, 0.3]) == 0.3
    assert isinstance(worst_loss([0.1, Invalid('x')]), Invalid)
    assert isinstance(worst_loss([]), Invalid)


def test_format_and_json():
    assert fmt(0.12345) == '0.1235'
    assert fmt(Invalid('x')) == 'INVALID'
    assert fmt(None) == 'INVALID'
    assert not is_valid(None) and not is_valid(Invalid('x')) and is_valid(0.0)
    assert to_json(0.25) == {'fitness': 0.25}
    assert to_json(Invalid('peer absent')) == {'fitness': None, 'invalid': 'peer absent'}
    assert from_json(to_json(0.25)) == 0.25
    assert from_json(to_json(Invalid('peer absent'))) == Invalid('peer absent')


def test_aggregate_per_world_and_overall():
    conds = [cond('house', 1, merged=0.6, single=0.8, own=0.75, rigid=0.9),
             cond('house', 2, merged=0.4, single=0.7, own=0.65, rigid=0.8),
             cond('intel', 1, merged=0.5, single=0.6, own=0.7, rigid=0.7),
             cond('intel', 2, merged=0.7, single=0.5, own=0.7, rigid=0.75)]
    agg = aggregate(conds, ['house', 'intel'])
    h = agg['worlds']['house']
    assert abs(h['merged']['mean'] - 0.5) < 1e-12 and h['merged']['worst'] == 0.4
    assert abs(h['loss']['worst'] - 0.4) < 1e-12          # seed 2: 0.8 - 0.4
    o = agg['overall']
    assert o['seeds'] == 2 and o['worlds'] == 2
    assert abs(o['merged'] - 0.55) < 1e-12
    assert abs(o['single'] - 0.65) < 1e-12
    assert abs(o['worst_loss'] - 0.4) < 1e-12             # the largest over every seed and world
    line = summary_line(o)
    m = LINE.match(line)
    assert m, line
    assert m.groups() == ('2', '2', '0.5500', '0.6500', '0.7000', '0.7875', '0.4000')


def test_summary_line_with_invalid_rows():
    conds = [cond('house', 1, merged=Invalid('tb3_2: gmapping processed no scan'), mexplore=Invalid('absent')),
             cond('house', 2)]
    agg = aggregate(conds, ['house'])
    line = summary_line(agg['overall'])
    m = LINE.match(line)
    assert m, line
    assert m.group(3) == 'INVALID' and m.group(7) == 'INVALID'     # merged mean, worst loss
    assert m.group(4) == '0.5000'                                    # single unaffected
    assert isinstance(agg['worlds']['house']['mexplore']['mean'], Invalid)


def test_a_world_without_runs_is_invalid():
    agg = aggregate([cond('house', 1)], ['house', 'intel'])
    assert isinstance(agg['worlds']['intel']['merged']['mean'], Invalid)
    assert agg['overall']['worlds'] == 2


def test_markdown_names_invalid_rows():
    conds = [cond('house', 1, mrpt=Invalid('mrpt_merge.py failed')), cond('house', 2)]
    conds[1]['merged_counts'] = {'merged': '3/4'}
    agg = aggregate(conds, ['house'])
    md = markdown(conds, agg, ['house'], {'house': 'AWS small house'})
    assert '### AWS small house' in md
    assert '| seed 1 | seed 2 | mean | worst |' in md
    assert '0.5000 (3/4)' in md
    assert 'seed 1, MRPT merge: INVALID: mrpt_merge.py failed' in md
    assert md.rstrip().endswith('`' + summary_line(agg['overall']) + '`')


def test_group_reasons_names_robots_once_per_reason():
    s = group_reasons([('tb3_0', 'gmapping missing'), ('tb3_1', 'no map saved'), ('tb3_2', 'gmapping missing')])
    assert s == 'tb3_0, tb3_2: gmapping missing; tb3_1: no map saved'
