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
    bend_decision,
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
                  r'team at true starts mean (\S+), rigid bound mean (\S+); worst merged minus true starts (\S+); '
                  r'time to 90%: team (.+), single (.+)$')


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
    # merged minus true starts (0.5 each): 0.1, -0.1, 0.0, 0.2: the smallest is -0.1; no timelines
    assert m.groups() == ('2', '2', '0.5500', '0.6500', '0.5000', '0.7875', '-0.1000', 'INVALID', 'INVALID')


def test_summary_line_with_invalid_rows():
    conds = [cond('house', 1, merged=Invalid('tb3_2: gmapping processed no scan'), mexplore=Invalid('absent')),
             cond('house', 2)]
    agg = aggregate(conds, ['house'])
    line = summary_line(agg['overall'])
    m = LINE.match(line)
    assert m, line
    assert m.group(3) == 'INVALID' and m.group(7) == 'INVALID'     # merged mean, worst against the starts
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


def timeline(team_t90, single_t90, team_fit=0.8, single_fit=0.9):
    score = {'fitness': 0.0, 'inlier_rmse': 0.04, 'free': 0.9, 'walls': 0.8}
    return {'team_t90': team_t90, 'single_t90': single_t90, 'team_t99': None, 'single_t99': 400.0,
            'end': {'team': dict(score, fitness=team_fit), 'single': dict(score, fitness=single_fit)},
            'equal_time': {'team': dict(score, fitness=team_fit), 'single': dict(score, fitness=0.95, free=0.5)}}


def test_the_merged_row_is_the_default_merge_and_times_go_into_the_line():
    conds = [cond('home', 1, merged=0.70, merged_rigid=0.80, starts=0.75),
             cond('home', 2, merged=0.79, merged_rigid=0.78, starts=0.80)]
    conds[0]['timeline'] = timeline(100.0, 390.0)
    conds[1]['timeline'] = timeline(110.0, 410.0, team_fit=0.6)
    agg = aggregate(conds, ['home'], merged_row='merged_rigid')
    o = agg['overall']
    assert abs(o['merged_default'] - 0.79) < 1e-12
    assert abs(o['worst_vs_starts'] - (-0.02)) < 1e-12              # seed 2: 0.78 - 0.80
    m = LINE.match(summary_line(o))
    assert m, summary_line(o)
    assert m.group(3) == '0.7900' and m.group(7) == '-0.0200'
    assert m.group(8) == '105 s' and m.group(9) == '400 s'
    t = agg['worlds']['home']['time']
    assert t['team_t90']['worst'] == '110' and t['team_t99']['mean'] == 'not reached'
    assert abs(t['end_team_fitness']['worst'] - 0.6) < 1e-12
    # bent minus unbent: -0.10 and +0.01: off (a seed loses more than 0.005)
    assert bend_decision(agg['worlds']['home']['bend_gain']['per_seed']) == 'off'


def test_a_time_not_reached_in_some_seeds_says_so():
    conds = [cond('intel', 1), cond('intel', 2)]
    conds[0]['timeline'] = timeline(None, 900.0)
    conds[1]['timeline'] = timeline(300.0, 1100.0)
    o = aggregate(conds, ['intel'])['overall']
    m = LINE.match(summary_line(o))
    assert m and m.group(8) == '300 s (not reached in 1 of 2)' and m.group(9) == '1000 s'
    conds[1]['timeline'] = {'invalid': 'timeline.py failed'}
    m = LINE.match(summary_line(aggregate(conds, ['intel'])['overall']))
    assert m and m.group(8) == 'INVALID' and m.group(9) == 'INVALID'


def test_bend_rule():
    assert bend_decision([0.01, -0.004, 0.002]) == 'on'
    assert bend_decision([0.01, -0.006, 0.02]) == 'off'          # one seed below unbent - 0.005
    assert bend_decision([0.0, -0.001]) == 'off'                 # not above on the mean
    assert bend_decision([0.01, Invalid('x')]).startswith('undecided')
