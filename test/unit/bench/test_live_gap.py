"""bench/live_gap.py's verdict: a long estimation cycle counts for the part of it surely inside
the measured span, also when it is reported after the window ended (it was still running then)."""
import os
import sys

BENCH = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'bench')
sys.path.insert(0, os.path.abspath(BENCH))

import live_gap  # noqa: E402

PERIOD = 0.5   # s, the merge period


def recording(cycle_s, reported_at):
    """A 40 s window from t=0: /map changed every period from 2 s on, except a 0.6 s gap at 20 s;
    short cycles reported until 14 s, then one of ``cycle_s`` reported at ``reported_at``."""
    maps = [(2.0 + k * PERIOD, k) for k in range(76) if not 20.0 < 2.0 + k * PERIOD < 20.6]
    est = [(t, 0.1 + 0.01 * (t % 3)) for t in range(2, 15)]
    est += [(reported_at + k, cycle_s) for k in range(3)]
    return maps, [], est


def test_a_cycle_reported_after_the_window_counts_for_its_part_inside():
    maps, tfs, est = recording(30.0, 45.0)          # ran 15-44 s: 15-40 in the window
    out = live_gap.analyse(maps, tfs, est, 0.0, 40.0, PERIOD)
    assert out['valid'], out
    assert out['long_cycles_in_span'][0][:2] == [15.0, 40.0]
    assert abs(out['max_gap_across_long_s'] - 1.0) < 1e-9    # the gap at 20 s (two periods' messages)


def test_no_long_cycle_inside_the_window_is_invalid():
    maps, tfs, est = recording(30.0, 75.0)          # ran 45-74 s: after the window
    out = live_gap.analyse(maps, tfs, est, 0.0, 40.0, PERIOD)
    assert not out['valid'] and 'no estimation cycle' in out['invalid_because']


def test_a_cycle_ended_since_a_report():
    est = [(1.0, 0.2), (2.0, 0.2), (3.0, 0.2)]
    assert not live_gap.cycle_ended_since(est, 3)
    assert not live_gap.cycle_ended_since(est + [(4.0, 0.2)], 3)
    assert live_gap.cycle_ended_since(est + [(4.0, 16.0)], 3)
    assert live_gap.cycle_ended_since([(1.0, 0.2)], 0) and not live_gap.cycle_ended_since([], 0)
