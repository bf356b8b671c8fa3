"""/diagnostics as a function of the merger's status (needs diagnostic_msgs, no master), and one
placement written the same way by its three writers: the state file, merge_maps' transforms
file and /diagnostics."""
import math
import os

import pytest
from conftest import DATA, merged

pytest.importorskip('diagnostic_msgs')   # the ROS shell: not on a stack without ROS (make test-focal)

from multi_map_merge.core.grid import known_bbox  # noqa: E402
from multi_map_merge.core.mapio import load_map  # noqa: E402
from multi_map_merge.core.offline import transforms_report  # noqa: E402
from multi_map_merge.core.state import placement_dict  # noqa: E402
from multi_map_merge.lab.synth import cut_piece  # noqa: E402
from multi_map_merge.ros.diagnostics import diagnostics_by_robot, diagnostics_msg  # noqa: E402


@pytest.fixture(scope='module')
def merger():
    """Robots a, b (two overlapping halves of the Intel lab, b turned and moved) and c (a map of
    nowhere: not merged), after one cycle."""
    w = load_map(os.path.join(DATA, 'intel.yaml'))
    r0, r1, c0, c1 = known_bbox(w.levels())
    cut = c0 + int(0.6 * (c1 - c0))
    a = cut_piece(w, (r0, r1, c0, cut), (0, 0, 0))[0]
    b = cut_piece(w, (r0, r1, c0 + int(0.4 * (c1 - c0)), c1), (3, -2, 2.0))[0]
    c = cut_piece(w, (r0, r0 + 40, c0, c0 + 40), (1, 1, 1.0))[0]
    return merged({'a': a, 'b': b, 'c': c}, reference_robot='a')


def test_one_placement_reads_the_same_in_the_state_the_transforms_file_and_diagnostics(merger):
    pl = merger.placements()['b']
    d = placement_dict(pl)
    assert set(d) == {'x', 'y', 'yaw', 'inlier_ratio', 'agreement', 'inliers', 'via', 'chain'}
    assert d['via'] == 'a' and d['chain'] == ['a', 'b']
    assert merger.export_state()['placements']['b'] == d
    report = transforms_report(merger, 'a', ['a', 'b', 'c'])['maps']
    assert report['b'].pop('merged') is True and set(report['b']) == set(d)
    assert report['c'] == {'merged': False, 'reason': merger.status()['c'].last_attempt.reason}
    msg = diagnostics_msg(merger.status(), {}, 1.5, 3, 2, None, pl.stamp + 2.0)
    diag = {}
    diagnostics_by_robot(msg, diag)
    assert diag['b']['via'] == 'a' and diag['b']['chain'] == 'a -> b' and diag['b']['age_s'] == '2.0'
    assert int(diag['b']['inliers']) == report['b']['inliers'] == d['inliers']
    for k in ('x', 'y', 'yaw', 'inlier_ratio', 'agreement'):
        assert math.isclose(report['b'][k], d[k], abs_tol=1e-4), k
        assert math.isclose(float(diag['b'][k]), d[k], abs_tol=1e-3), k
    assert diag['a']['message'] == 'reference map' and diag['a']['via'] == '-'
    assert diag['c']['message'].startswith('not merged')
