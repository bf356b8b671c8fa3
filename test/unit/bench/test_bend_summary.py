"""bench/bend_summary.py, the pure part of `make bend-sweep`: the error of a placement against
the truth, its Mahalanobis distance, coverage at 95%, the "off" thresholds, the summary and the
fixed form of its last line."""
import math
import os
import re
import sys

import numpy as np

BENCH = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'bench')
sys.path.insert(0, os.path.abspath(BENCH))

from bend_summary import (  # noqa: E402
    CHI2_2,
    CHI2_3,
    OFF,
    compose,
    error_vector,
    invert,
    is_off,
    mahalanobis2,
    own_maps,
    own_maps_lines,
    placement_record,
    relative,
    summarize,
    summary_line,
    summary_lines,
)

LINE = re.compile(r'^bend sweep: (\d+) placements in (\d+) cases; within 95% ellipse (\S+)%; '
                  r'off (\d+), flagged weak (\d+) of them; worst (\S+) m \(2-sigma (\S+) m\)$')


def test_relative_pose_is_the_reference_inverse_times_the_robot():
    ref, k = [2.0, 1.0, math.pi / 2], [2.0, 3.0, math.pi - 0.5]
    r = relative(ref, k)
    assert np.allclose(r, [2.0, 0.0, math.pi / 2 - 0.5])
    assert np.allclose(compose(ref, r), k)
    assert np.allclose(compose(invert(ref), ref), [0, 0, 0])


def test_error_vector_wraps_yaw():
    ev = error_vector([1.0, 0.0, math.pi - 0.01], [0.5, 0.2, -math.pi + 0.01])
    assert np.allclose(ev, [0.5, -0.2, -0.02])


def test_mahalanobis_full_and_position():
    cov = np.diag([0.01, 0.04, 1e-4])
    ev = [0.1, 0.2, 0.01]
    assert abs(mahalanobis2(ev, cov) - 3.0) < 1e-9           # 1 + 1 + 1
    assert abs(mahalanobis2(ev[:2], cov) - 2.0) < 1e-9       # the x, y block only
    assert mahalanobis2(ev, None) is None
    assert mahalanobis2(ev, np.zeros((3, 3))) is None        # singular
    assert mahalanobis2(ev, np.full((3, 3), np.nan)) is None


def test_mahalanobis_uses_the_correlation():
    # a corridor along x, turned 45 degrees: error along the corridor is cheap, across it is not
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    R = np.array([[c, -s], [s, c]])
    C2 = R @ np.diag([1.0, 0.0001]) @ R.T
    cov = np.eye(3) * 1e-4
    cov[:2, :2] = C2
    along, across = [0.5 * c, 0.5 * s, 0.0], [-0.05 * s, 0.05 * c, 0.0]
    assert mahalanobis2(along, cov) < CHI2_3
    assert mahalanobis2(across, cov) > CHI2_3


def test_off_thresholds():
    assert not is_off(OFF[0], OFF[1])
    assert is_off(OFF[0] + 1e-6, 0.0)
    assert is_off(0.0, OFF[1] + 1e-6)


def test_record_covered_and_not():
    cov = np.diag([0.05 ** 2, 0.05 ** 2, math.radians(0.5) ** 2])
    ok = placement_record('tb3_1', [1.05, 0.0, 0.0], [1.0, 0.0, 0.0], cov, 0.05, False, 'tb3_0')
    assert ok['in95'] and ok['in95_pos'] and not ok['off'] and abs(ok['sigma2_m'] - 0.10) < 1e-12
    bad = placement_record('tb3_2', [1.3, 0.0, 0.0], [1.0, 0.0, 0.0], cov, 0.05, False,
                           fit_true=[1.28, 0.0, 0.0])
    assert bad['off'] and bad['off_wide'] and not bad['in95'] and not bad['in95_pos']
    assert abs(bad['err_m'] - 0.3) < 1e-9 and abs(bad['fit']['err_m'] - 0.02) < 1e-9
    assert bad['fit']['d2_pos'] < CHI2_2
    none = placement_record('tb3_3', [0, 0, 0], [0, 0, 0.1], None, None, True)
    assert none['in95'] is None and none['d2'] is None and none['weak'] and none['off']


def _case(name, recs, robots=3, **kw):
    for r in recs:
        r['case'] = name
    return dict({'name': name, 'robots': robots, 'placements': recs}, **kw)


def test_summary_counts_and_line():
    cov = np.diag([0.05 ** 2, 0.05 ** 2, math.radians(0.5) ** 2])
    c1 = _case('a-3r-s1', [
        placement_record('tb3_1', [1.02, 0, 0], [1, 0, 0], cov, 0.05, False),             # in, right
        placement_record('tb3_2', [1.40, 0, 0], [1, 0, 0], cov, 0.05, True)])             # out, off, weak
    c2 = _case('b-4r-s1', [
        placement_record('tb3_1', [1.15, 0, 0], [1, 0, 0], cov, 0.05, False),             # out, off, not weak
        placement_record('tb3_3', [1.0, 0, 0], [1, 0, 0], None, None, True)], robots=4)   # no covariance
    bad = {'name': 'c-3r-s1', 'robots': 3, 'invalid': 'gmapping dropped 98 of 99 scans'}
    s = summarize([c1, c2, bad])
    assert s['cases'] == 2 and s['placements'] == 4 and s['robots'] == 5 and s['with_cov'] == 3
    assert abs(s['in95'] - 1 / 3) < 1e-12
    assert s['off'] == 2 and s['off_weak'] == 1 and s['off_wide'] == 1 and s['off_wide_weak'] == 1
    assert s['weak'] == 2 and s['weak_not_off'] == 1
    assert abs(s['worst_m'] - 0.4) < 1e-9 and abs(s['worst_sigma2_m'] - 0.1) < 1e-12
    assert s['invalid'] == [{'name': 'c-3r-s1', 'invalid': 'gmapping dropped 98 of 99 scans'}]
    lines = summary_lines(s)
    assert lines[-1] == summary_line(s)
    assert any(ln.startswith('INVALID cases: 1 (c-3r-s1)') for ln in lines)
    m = LINE.match(lines[-1])
    assert m, lines[-1]
    assert m.groups() == ('4', '2', '33.3', '2', '1', '0.400', '0.100')
    assert s['links'] == 0 and s['links_in95'] is None


def test_summary_counts_links_against_starts_and_fits():
    cov = np.diag([0.05 ** 2, 0.05 ** 2, math.radians(0.5) ** 2])
    links = [placement_record('tb3_0-tb3_1', [1.02, 0, 0], [1, 0, 0], cov, 0.05, False, fit_true=[1.3, 0, 0]),
             placement_record('tb3_1-tb3_2', [1.40, 0, 0], [1, 0, 0], cov, 0.05, False, fit_true=[1.4, 0, 0])]
    s = summarize([_case('a-3r-s1', [], links=links)])
    assert s['links'] == 2 and s['links_in95'] == 0.5 and s['links_fit_in95'] == 0.5
    assert any(ln.startswith('links (every kept link') and '50.0% against the starts' in ln
               for ln in summary_lines(s))


def test_summary_of_nothing_has_no_numbers_made_up():
    s = summarize([{'name': 'x', 'robots': 3, 'invalid': 'bags not made'}])
    assert s['cases'] == 0 and s['placements'] == 0 and s['in95'] is None
    m = LINE.match(summary_line(s))
    assert m and m.group(3) == '-' and m.group(6) == '-' and m.group(7) == '-'


def test_own_maps_per_log_mean_worst_cost_and_unscored():
    cases = [
        {'name': 'a-3r-s1', 'log': 'a', 'robots': 3,
         'gmapping': {'tb3_0': {'cpu_s': 4.0, 'processed': 50, 'scans': 100},
                      'tb3_1': {'cpu_s': 6.0, 'processed': 60, 'scans': 120},
                      'tb3_2': {'invalid': 'rbpf_slam processed no scan of 100'}},
         'own_fit': {'tb3_0': {'fitness': 0.9, 'from_start_pose': 0.8},
                     'tb3_1': {'fitness': 0.7, 'from_start_pose': 0.7}}},
        {'name': 'a-4r-s1', 'log': 'a', 'robots': 4, 'invalid': 'tb3_3: no map saved',   # merge failed: still scored
         'gmapping': {'tb3_0': {'cpu_s': 2.0, 'processed': 30, 'scans': 40}},
         'own_fit': {'tb3_0': {'fitness': 0.8, 'from_start_pose': None}}},
        {'name': 'b-3r-s1', 'log': 'b', 'robots': 3,
         'gmapping': {'tb3_0': {'cpu_s': 1.0, 'processed': 10, 'scans': 20},
                      'tb3_1': {'cpu_s': 1.0, 'processed': 10, 'scans': 20}},
         'own_fit': {'tb3_0': {'fitness': None, 'invalid': 'cannot be scored: empty'}}},
    ]
    o = own_maps(cases)
    a = o['logs']['a']
    assert a['maps'] == 3 and a['cases'] == 2
    assert math.isclose(a['mean'], 0.8) and a['worst'] == 0.7
    assert math.isclose(a['from_start_mean'], 0.75)                 # over the maps scored from their start
    assert a['cpu_s_mean'] == 4.0 and a['cpu_s_max'] == 6.0 and (a['processed'], a['scans']) == (140, 260)
    b = o['logs']['b']                                               # nothing scored there: no figure made up
    assert b['maps'] == 0 and b['mean'] is None and b['worst'] is None
    assert o['overall']['maps'] == 3 and o['overall']['worst'] == 0.7
    assert sorted(u[:2] for u in o['unscored']) == [['a-3r-s1', 'tb3_2'], ['b-3r-s1', 'tb3_0'], ['b-3r-s1', 'tb3_1']]
    lines = own_maps_lines(o, 'rbpf_slam')
    assert 'rbpf_slam' in lines[0] and any(ln.split()[0] == 'all' for ln in lines[2:])
    assert any('not scored' in ln and 'processed no scan' in ln for ln in lines)


def test_bend_sweep_slam_option():
    import pytest
    pytest.importorskip('yaml')
    import bend_sweep
    if not os.path.exists(bend_sweep.log_path('seattle')):
        pytest.skip('no CARMEN logs (../shared/data/carmen)')
    a = bend_sweep.parse_args(['--logs', 'seattle'])
    assert a.slam == 'rbpf' and a.stem == 'bend_sweep' and a.gmapping_params == {'maxUrange': 20.0}
    a = bend_sweep.parse_args(['--logs', 'seattle', '--slam', 'gmapping', '--slam-param', 'particles=10'])
    assert a.slam == 'gmapping' and a.stem == 'bend_sweep_gmapping'
    assert a.gmapping_params == {'maxUrange': 20.0, 'particles': 10}
