"""bench/peer.py: m-explore is measured only where its node is installed; where it is not, every
figure says so, never a number. The measuring path (master, feeder, node, /map) runs only where
m-explore's node is installed (Ubuntu: ros-noetic-multirobot-map-merge): no stand-in for it here."""
import os
import subprocess
import sys

REPO = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..'))
sys.path.insert(0, os.path.join(REPO, 'bench'))

import peer  # noqa: E402


def test_without_the_package_it_says_not_installed(monkeypatch):
    monkeypatch.setattr(peer, 'PACKAGE', 'multirobot_map_merge_surely_absent')
    assert peer.available() == (False, peer.NOT_INSTALLED)
    assert peer.live_node() is None
    res = peer.run_node(['a.yaml', 'b.yaml'])
    assert res == {'invalid': peer.NOT_INSTALLED}
    assert peer.column(res, 'first_map_s') == 'm-explore not installed (ros-noetic-multirobot-map-merge): not measured'
    assert peer.column(None, 'rss_mb') == peer.NOT_INSTALLED


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


def test_scale_says_what_the_node_gave():
    import scale
    line = scale.peer_line(8, {'run': True, 'first_map_s': 3.2, 'cpu_s': 2.5, 'rss_mb': 120.0})
    assert line.startswith('  m-explore: 8 robots: first merged /map 3.20 s after its node started')
    assert scale.peer_line(8, {'run': False, 'why': peer.NOT_INSTALLED}) == \
        '  m-explore: not run (%s)' % peer.NOT_INSTALLED
