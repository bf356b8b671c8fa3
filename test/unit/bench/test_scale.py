"""bench/scale.py's pure part: the schedule (stagger, the joiner's slot), the maps' growth, when
a cycle absorbed a version, staleness, the cost of a round of updates, the rounds, the verdicts
(INVALID with why) and the fixed form of the line."""
import math
import os
import re
import sys

import numpy as np

BENCH = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'bench')
sys.path.insert(0, os.path.abspath(BENCH))

import scale  # noqa: E402

LINE = re.compile(r'^scale: (\d+) robots: round of updates (\S+) s, staleness p50 (\S+) s p95 (\S+) s '
                  r'\((\S+) merge periods\), late joiner placed in (\S+) s, worst placement error (\S+) m$')


def cycle(start, end, taken, est_s=None):
    """An estimation cycle's record."""
    return {'start': start, 'end': end, 'est_s': end - start if est_s is None else est_s, 'taken': taken}


def publication(end, shown):
    """A publication's record: the versions its merged map holds."""
    return {'start': end - 0.01, 'end': end, 'shown': shown}


def test_robots_are_staggered_over_one_period():
    assert scale.stagger(4, 5.0) == [0.0, 1.25, 2.5, 3.75]
    assert scale.stagger(0) == []


def test_the_joiner_comes_at_its_own_slot_of_the_next_period():
    assert scale.next_slot(4.0, 2.0, 5.0) == 4.0          # not yet past its first slot
    assert scale.next_slot(4.0, 4.0, 5.0) == 4.0
    assert scale.next_slot(4.0, 4.1, 5.0) == 9.0
    assert scale.next_slot(4.0, 23.9, 5.0) == 24.0
    assert scale.next_slot(4.0, 24.0, 5.0) == 24.0


def test_a_map_grows_from_its_first_fraction_to_all_of_it_then_stays():
    assert scale.reveal_fraction(0.0, 0.35, 90.0) == 0.35
    assert abs(scale.reveal_fraction(45.0, 0.35, 90.0) - 0.675) < 1e-12
    assert scale.reveal_fraction(90.0, 0.35, 90.0) == 1.0
    assert scale.reveal_fraction(500.0, 0.35, 90.0) == 1.0
    assert scale.reveal_fraction(-1.0, 0.35, 90.0) == 0.35


def test_the_canvas_is_the_known_box_with_a_margin_clipped_to_the_window():
    known = np.zeros((50, 60), bool)
    assert scale.known_crop(known, 5) is None
    known[10:20, 30:40] = True
    assert scale.known_crop(known, 5) == (5, 25, 25, 45)
    known[0, 59] = True
    assert scale.known_crop(known, 5) == (0, 25, 25, 60)


def test_a_growing_disc_never_shrinks_the_canvas():
    """The merger takes a grid that shrank for a restarted map: a robot's canvas must only grow."""
    rng = np.random.default_rng(3)
    known = rng.random((80, 90)) < 0.7
    dist = np.hypot(np.arange(80)[:, None] - 30.0, np.arange(90)[None, :] - 50.0)
    before = None
    for t in range(0, 100, 5):
        box = scale.known_crop(known & (dist <= scale.reveal_fraction(t, 0.35, 90.0) * dist.max()), 3)
        if before is not None:
            assert box[0] <= before[0] and box[1] >= before[1] and box[2] <= before[2] and box[3] >= before[3]
        before = box


def test_percentile():
    assert scale.percentile([], 50) is None
    assert scale.percentile([1.0, 2.0, 3.0], 50) == 2.0
    assert abs(scale.percentile(list(range(101)), 95) - 95.0) < 1e-9


def test_a_version_is_absorbed_by_the_first_cycle_that_took_it_or_a_later_one():
    cycles = [cycle(0.0, 1.0, {'a': 0}), cycle(1.0, 3.0, {'a': 0, 'b': 0}), cycle(3.0, 6.0, {'a': 2, 'b': 1})]
    assert scale.absorbed_end(cycles, 'a', 0) == 1.0
    assert scale.absorbed_end(cycles, 'a', 1) == 6.0    # version 1 skipped: the cycle took 2
    assert scale.absorbed_end(cycles, 'b', 2) is None
    ups = [{'robot': 'a', 'version': 1, 'arrival': 2.5}, {'robot': 'b', 'version': 2, 'arrival': 5.0}]
    assert scale.staleness(ups, cycles) == [3.5, None]


def test_staleness_counts_publications_apart_from_estimation_cycles():
    cycles = [cycle(0.0, 2.0, {'a': 0}), cycle(2.0, 4.0, {'a': 1})]
    pubs = [publication(1.0, {'a': 0}), publication(1.5, {'a': 1})]
    ups = [{'robot': 'a', 'version': 1, 'arrival': 0.5}]
    assert scale.staleness(ups, pubs, 'shown') == [1.0]
    assert scale.staleness(ups, cycles) == [3.5]


def test_new_robots_per_cycle():
    cycles = [cycle(0, 1, {'a': 0}), cycle(1, 2, {'a': 0, 'b': 0}), cycle(2, 3, {'a': 1, 'b': 0}),
              cycle(3, 4, {'a': 3, 'b': 2})]
    assert scale.new_robots(cycles) == [['a'], ['b'], ['a'], ['a', 'b']]


def test_round_cost_is_estimation_seconds_per_new_version_of_every_robot():
    # a merger that keeps up: each cycle takes one of four robots anew, 0.5 s each
    taken = {'a': 0, 'b': 0, 'c': 0, 'd': 0}
    cycles = [cycle(0, 9, dict(taken), est_s=9.0)]
    for k, r in enumerate('abcd'):
        taken[r] = 1
        cycles.append(cycle(10 + k, 10.6 + k, dict(taken), est_s=0.5))
    assert abs(scale.round_cost(cycles, 1) - 2.0) < 1e-12
    # a merger behind: one cycle took every robot anew: its estimation is the round's cost
    cycles.append(cycle(20, 29, {r: 3 for r in 'abcd'}, est_s=8.5))
    assert abs(scale.round_cost(cycles, 5) - 8.5) < 1e-12
    assert abs(scale.round_cost(cycles, 1) - 10.5 / 2.0) < 1e-12
    assert scale.round_cost(cycles, 6) is None


def test_rounds_are_the_periods_after_the_cold_start():
    ups = [{'robot': 'a', 'version': v, 'arrival': 1.0 + 5.0 * v} for v in range(6)]
    r = scale.rounds_of(ups, 9.0, 2, 5.0)
    assert [[u['version'] for u in us] for us in r] == [[2], [3]]


def run_record(**over):
    """A run of 3 robots (a reference r00, r01, the joiner r02): cold start to 2 s, two rounds;
    publications every 0.5 s holding what the last estimation cycle took, 0.3 s after it."""
    cycles = [cycle(0.0, 2.0, {'r00': 0, 'r01': 0}), cycle(5.0, 6.0, {'r00': 1, 'r01': 1}),
              cycle(6.0, 7.5, {'r00': 1, 'r01': 1, 'r02': 0}), cycle(10.0, 11.0, {'r00': 2, 'r01': 2, 'r02': 0}),
              cycle(12.0, 13.0, {'r00': 2, 'r01': 2, 'r02': 1})]
    pubs = []
    for k in range(1, 28):
        t = 0.5 * k
        took = [c for c in cycles if c['end'] + 0.3 <= t]
        if took:
            pubs.append(publication(t, dict(took[-1]['taken'])))
    updates = [{'robot': 'r00', 'version': 1, 'arrival': 5.0, 'placed': True, 'known': 120},
               {'robot': 'r01', 'version': 1, 'arrival': 4.9, 'placed': True, 'known': 130},
               {'robot': 'r02', 'version': 0, 'arrival': 6.0, 'placed': False, 'known': 100},
               {'robot': 'r00', 'version': 2, 'arrival': 10.0, 'placed': True, 'known': 140},
               {'robot': 'r01', 'version': 2, 'arrival': 9.9, 'placed': True, 'known': 150},
               {'robot': 'r02', 'version': 1, 'arrival': 11.0, 'placed': True, 'known': 110}]
    rec = {'robots': 3, 'rounds': 2, 'cycles': cycles, 'updates': updates, 'cold_end': 2.0, 'cold_placed': 1,
           'joiner': {'name': 'r02', 'arrival': 6.0, 'placed_end': 7.5}, 'reference': 'r00',
           'placed_end': ['r00', 'r01', 'r02'], 'errors': {'r01': (0.02, 0.1), 'r02': (0.05, 0.3)},
           'wall_s': 13.0, 'grew_cells': [100, 200], 'feed_late_max_s': 0.0, 'breakdown_after': {},
           'publishes': pubs, 'merge_period_s': 0.5, 'serialised': True, 'composes': 27, 'compose_p50_s': 0.01,
           'compose_max_s': 0.02}
    rec.update(over)
    return rec


def test_a_run_that_created_every_condition_has_every_figure():
    s = scale.summarise(run_record())
    assert s['invalid'] == {}
    assert s['rounds_complete'] == 2
    # until estimation took it: round 1 [2, 7): r00 v1 5.0 -> 6.0, r01 v1 4.9 -> 6.0 (the joiner's
    # first map: not placed then); round 2 [7, 12): r00 v2 10 -> 11, r01 v2 9.9 -> 11, r02 v1 11 -> 13
    assert np.allclose(s['lag_by_round'], [1.05, 1.1])
    assert abs(s['placed_p50_s'] - 1.1) < 1e-9
    # published at the first half second 0.3 s past those ends: 6.5, 6.5, 11.5, 11.5, 13.5
    assert np.allclose(sorted([s['stale_p50_s']]), [1.6]) and s['stale_n'] == 5
    assert abs(s['stale_p50_periods'] - 3.2) < 1e-9
    assert s['joiner_s'] == 1.5
    assert s['worst_err_m'] == 0.05
    line = scale.scale_line(3, s)
    m = LINE.match(line)
    assert m, line
    assert m.group(1) == '3' and m.group(3) == '1.60' and m.group(6) == '1.50' and m.group(7) == '0.050'
    assert float(m.group(5)) == round(s['stale_p95_s'] / 0.5, 1)
    assert all(line.startswith('  ') for line in scale.detail_lines(run_record(), s))


def test_no_robot_placed_is_invalid():
    s = scale.summarise(run_record(placed_end=['r00'], errors={}))
    line = scale.scale_line(3, s)
    assert line.startswith('scale: 3 robots: INVALID: no robot placed') and not LINE.match(line)


def test_maps_that_did_not_grow_are_invalid():
    line = scale.scale_line(3, scale.summarise(run_record(grew_cells=[200, 200])))
    assert 'INVALID: the maps did not grow' in line


def test_a_run_that_ended_before_a_round_was_absorbed_is_invalid():
    rec = run_record()
    rec['cycles'] = rec['cycles'][:1]
    s = scale.summarise(rec)
    assert s['rounds_complete'] == 0
    line = scale.scale_line(3, s)
    assert 'round of updates INVALID (the run ended' in line and 'staleness INVALID' in line
    assert 'worst placement error 0.050 m' in line


def test_a_joiner_that_never_came_or_was_never_placed_is_said_so():
    s = scale.summarise(run_record(joiner={'name': 'r02', 'scheduled': 14.0, 'arrival': None, 'placed_end': None}))
    assert 'late joiner placed in INVALID (the run ended (13 s) before its first map, due at 14 s)' in \
        scale.scale_line(3, s)
    s = scale.summarise(run_record(joiner={'name': 'r02', 'arrival': 6.0, 'placed_end': None}))
    assert 'late joiner placed in INVALID (not placed within 7 s' in scale.scale_line(3, s)


def test_mexplore_is_not_run_where_its_cycle_would_pass_the_limit():
    assert scale.peer_plan(8, None) is None
    assert scale.peer_plan(32, (16, {'run': True, 'wall_s': 60.0}), 300.0) is None       # 240 s
    why = scale.peer_plan(64, (32, {'run': True, 'wall_s': 100.0}), 300.0)                # 400 s
    assert why and 'would not end within 300 s' in why
    why = scale.peer_plan(64, (32, {'run': False, 'timed_out': True, 'why': 'x'}), 300.0)
    assert why and 'did not end within 300 s' in why
    assert scale.peer_plan(64, (32, {'run': False, 'why': '--no-peer'})) is None
    assert scale.peer_line(64, {'run': False, 'why': 'because'}) == '  m-explore: not run (because)'


def test_seconds_are_printed_with_three_figures_at_most():
    assert [scale.fmt_s(v) for v in (None, 0.004, 1.234, 12.34, 123.4)] == ['-', '0.00', '1.23', '12.3', '123']
    assert math.isclose(float(scale.fmt_s(4.999)), 5.0)


def test_the_json_keeps_each_update_with_its_two_stalenesses():
    rec = run_record(paths=['x.yaml'])
    rec['updates'] = [dict(u, known=10) for u in rec['updates']]
    out = scale.compact(rec)
    assert 'paths' not in out and out['update_fields'][0] == 'robot'
    row = dict(zip(out['update_fields'], out['updates'][0]))
    assert row['robot'] == 'r00' and row['version'] == 1 and row['shown_s'] == 1.5 and row['taken_s'] == 1.0
    assert out['publishes'][0] == [2.49, 2.5]


def test_growth_is_measured_and_for_maps_of_equal_size():
    # 8 robots whose maps average 40,000 known cells, 64 whose maps average 60,000: a round
    # x9 as measured is x6 for maps of equal size
    line = scale.growth_line({8: {'round_s': 0.4, 'round_known': 40000.0},
                              16: {'round_s': 1.0, 'round_known': 50000.0},
                              64: {'round_s': 3.6, 'round_known': 60000.0}})
    assert line == ('scale: from 8 to 64 robots a round of updates grew x9.0 (linear: x8); for maps of '
                    'equal size x6.0 (their maps had 40000 and 60000 known cells on average)')
    # a size whose round is INVALID does not count; fewer than two sizes: no line
    assert scale.growth_line({8: {'round_s': 0.4, 'round_known': 4.0}, 64: {'invalid': {'round': 'x'}}}) is None
    assert 'from 8 to 16 robots' in scale.growth_line({8: {'round_s': 0.4, 'round_known': 4.0},
                                                       16: {'round_s': 0.8, 'round_known': 4.0},
                                                       64: {'invalid': {'round': 'x'}}})


def test_a_run_reports_the_mean_known_cells_of_the_maps_its_rounds_took():
    # the versions placed when they came, in rounds 1 and 2 (r02's first map was not placed yet)
    s = scale.summarise(run_record())
    assert abs(s['round_known'] - (120 + 130 + 140 + 150 + 110) / 5.0) < 1e-9


def test_a_negative_estimation_rate_is_refused(capsys):
    for bad in ('-1', 'nan'):
        try:
            scale.main(['--estimation-rate', bad, '--no-peer', '--sizes', '8'])
        except SystemExit as e:
            assert e.code == 2
        else:
            raise AssertionError('--estimation-rate %s was taken' % bad)
        assert '--estimation-rate must be >= 0 Hz' in capsys.readouterr().err
