"""bench/peer.py: m-explore is measured only where its node is installed; where it is not, every
figure says so, never a number. The measuring path (master, feeder, node, /map; its estimation
cycles read from its own log) runs only where m-explore's node is installed (Ubuntu:
ros-noetic-multirobot-map-merge) or built by hand and named by MMM_MEXPLORE_SETUP: no stand-in for
it here, and nothing of its output is kept in the repository."""
import glob
import os
import subprocess
import sys

import pytest

REPO = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..'))
sys.path.insert(0, os.path.join(REPO, 'bench'))

import peer  # noqa: E402
import peer_estimate  # noqa: E402


def test_without_the_package_it_says_not_installed(monkeypatch):
    monkeypatch.setattr(peer, 'PACKAGE', 'multirobot_map_merge_surely_absent')
    monkeypatch.setattr(peer, 'SETUP_WHY', '')
    assert peer.available() == (False, peer.NOT_INSTALLED)
    assert peer.live_node() is None
    res = peer.run_node(['a.yaml', 'b.yaml'])
    assert res == {'invalid': peer.NOT_INSTALLED}
    assert peer.column(res, 'first_map_s') == 'm-explore not installed (ros-noetic-multirobot-map-merge): not measured'
    assert peer.column(None, 'rss_mb') == peer.NOT_INSTALLED


def test_without_the_package_its_estimation_says_not_installed(monkeypatch):
    monkeypatch.setattr(peer, 'PACKAGE', 'multirobot_map_merge_surely_absent')
    monkeypatch.setattr(peer, 'SETUP_WHY', '')
    res = peer_estimate.run_estimation(['a.yaml', 'b.yaml'])
    assert res == {'invalid': peer.NOT_INSTALLED}
    assert peer.column(res, 'estimate_ms') == peer.NOT_INSTALLED


def test_a_setup_file_that_is_not_there_says_why(tmp_path, monkeypatch):
    missing = str(tmp_path / 'no_ws' / 'devel' / 'setup.bash')
    env, why = peer.mexplore_env(missing, {'PATH': '/bin'})
    assert why == 'MMM_MEXPLORE_SETUP=%s: no such file: m-explore not measured' % missing
    assert env['PATH'].startswith('/usr/bin:/bin:')
    monkeypatch.setattr(peer, 'SETUP_WHY', why)
    assert peer.available() == (False, why) and peer_estimate.available() == (False, why)
    assert peer_estimate.run_estimation(['a.yaml', 'b.yaml']) == {'invalid': why}


def test_a_setup_file_extends_the_environment(tmp_path):
    setup = tmp_path / 'setup.bash'
    setup.write_text('[ "$1" = --extend ] && export ROS_PACKAGE_PATH=/ws/src:$ROS_PACKAGE_PATH\n')
    env, why = peer.mexplore_env(str(setup), {'PATH': '/bin', 'ROS_PACKAGE_PATH': '/ours/src', 'KEEP': 'x'})
    assert why == ''
    assert env['ROS_PACKAGE_PATH'] == '/ws/src:/ours/src' and env['KEEP'] == 'x'
    setup.write_text('exit 4\n')
    env, why = peer.mexplore_env(str(setup), {'PATH': '/bin', 'KEEP': 'x'})
    assert 'sourcing it failed' in why and env['KEEP'] == 'x'


def two_house_maps_and_the_node():
    """Two Turtlebot3 house maps (../shared/data), or skip; skip too where m-explore's node is not there."""
    ok, why = peer.available()
    if not ok:
        pytest.skip(why)
    import inputs
    paths = sorted(glob.glob(os.path.join(inputs.DATA, 'tb3_house', 'tb3_*_map.yaml')))[:2]
    if len(paths) < 2:
        pytest.skip('../shared/data/tb3_house is absent')
    return paths


def test_its_estimation_cycles_read_from_its_real_node():
    """Where m-explore's node is there: its cycles on two Turtlebot3 house maps (../shared/data)
    read from its own log, as run_bench.py reads them."""
    paths = two_house_maps_and_the_node()
    res = peer_estimate.run_estimation(paths, cycles=3, max_seconds=60.0)
    assert 'invalid' not in res, res
    assert res['cycles'] == 3 and len(res['estimate_runs_ms']) == 3
    assert res['estimate_first_ms'] == res['estimate_runs_ms'][0]
    assert all(0.0 < ms < 60000.0 for ms in res['estimate_runs_ms'])
    assert res['estimate_ms'] <= res['cycle_ms'] + 1e-6 and res['rss_mb'] > 0
    with open(res['log']) as f:
        lines = f.readlines()
    cycles = peer_estimate.estimation_cycles(lines, len(paths))
    assert [c['estimate_ms'] for c in cycles[:3]] == res['estimate_runs_ms']
    times = [float(m.group(1)) for m in map(peer_estimate.LOG_LINE.search, lines)
             if m and m.group(2) == peer_estimate.MAP_RECEIVED]
    assert len(times) >= len(paths)
    # only cycles that started with every map in count; each one's features before its end
    assert cycles[0]['start'] > times[len(paths) - 1]
    assert all(c['start'] <= c['features'] < c['end'] for c in cycles)
    assert all(a['end'] == b['start'] for a, b in zip(cycles, cycles[1:]))
    # with fewer maps than arrived, earlier cycles count too
    assert len(peer_estimate.estimation_cycles(lines, 1)) >= len(cycles)


def test_on_this_machine_the_answer_matches_rospack():
    installed = subprocess.run(['rospack', 'find', 'multirobot_map_merge'], capture_output=True,
                               env=peer.ENV).returncode == 0
    assert peer.available()[0] == installed


def test_the_bench_tables_say_not_installed_in_every_mexplore_cell():
    import report
    ours = {'map_cells': 400000, 'features_ms': 40.0, 'pair_ms': 45.0, 'cold_ms': 900.0, 'warm_ms': 1.1,
            'compose_ms': 8.0, 'publish_ms': 1.0, 'live_ms': 2.0, 'rss_mb': 230.0, 'rss_self_mb': 190.0,
            'placed': 3, 'errors': {'r01': (0.02, 0.1)}, 'max_err_m': 0.02, 'max_err_deg': 0.1}
    mrpt = {'align_s': 0.9, 'wall_s': 2.0, 'rss_mb': 150.0, 'placed': 3, 'errors': {'r01': (0.1, 0.5)},
            'max_err_m': 0.1, 'max_err_deg': 0.5}
    rows = [{'name': 'intel 4', 'kind': 'size', 'robots': 4, 'ours': ours, 'mrpt': mrpt,
             'mexplore': {'invalid': peer.NOT_INSTALLED}}]
    text = report.rows_table(rows, peer.NOT_INSTALLED)
    lines = [ln for ln in text.splitlines() if ln.startswith('intel 4')]
    assert len(lines) == 2 and all(ln.endswith(peer.NOT_INSTALLED) for ln in lines)
    assert '0.90 (2.00)' in lines[0] and '3 (1) / 3 (1)' in lines[1]
    assert peer.NOT_INSTALLED[:22] in lines[0]       # the m-explore est column, cut to its width
    rows[0]['mexplore_est'] = {'estimate_ms': 450.0, 'estimate_first_ms': 500.0}
    time_line = [ln for ln in report.rows_table(rows, '').splitlines() if ln.startswith('intel 4')][0]
    assert '| 450 (500)              | 2.00x unpaired      |' in time_line
    rows[0]['mexplore_paired'] = {'ratio': 1.5, 'ours_ms': 600.0, 'mexplore_ms': 400.0}
    time_line = [ln for ln in report.rows_table(rows, '').splitlines() if ln.startswith('intel 4')][0]
    assert '| 450 (500)              | 1.50x (600/400)     |' in time_line


def test_its_estimation_paired_with_ours_round_after_round(tmp_path):
    """Where m-explore's node is there: ours' cold cycle and its cycle alternated (run_bench.py
    pair_mexplore), its node stopped between its cycles."""
    import run_bench
    paths = two_house_maps_and_the_node()
    res = run_bench.pair_mexplore(paths, str(tmp_path), 3)
    assert 'invalid' not in res, res
    assert len(res['ours_rounds_ms']) == len(res['mexplore_rounds_ms']) == len(res['ratios']) == 3
    assert all(ms > 0 for ms in res['ours_rounds_ms'] + res['mexplore_rounds_ms'])
    assert res['ratio'] == sorted(res['ratios'])[1]
    assert abs(res['ratios'][0] - res['ours_rounds_ms'][0] / res['mexplore_rounds_ms'][0]) < 1e-9


def test_scale_says_what_the_node_gave():
    import scale
    line = scale.peer_line(8, {'run': True, 'first_map_s': 3.2, 'cpu_s': 2.5, 'rss_mb': 120.0})
    assert line.startswith('  m-explore: 8 robots: first merged /map 3.20 s after its node started')
    assert scale.peer_line(8, {'run': False, 'why': peer.NOT_INSTALLED}) == \
        '  m-explore: not run (%s)' % peer.NOT_INSTALLED
