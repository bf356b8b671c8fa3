"""/diagnostics as a function of the merger's status (needs diagnostic_msgs, no master): a
placement there reads as core.state.placement_dict says, as in the state and transforms files."""
import math

import pytest

pytest.importorskip('diagnostic_msgs')   # the ROS shell: not on a stack without ROS (make test-focal)

from multi_map_merge.core.state import placement_dict  # noqa: E402
from multi_map_merge.ros.diagnostics import diagnostics_by_robot, diagnostics_msg  # noqa: E402


def test_a_placement_on_diagnostics_reads_as_placement_dict(halves_merged):
    m = halves_merged
    pl = m.placements()['b']
    d = placement_dict(pl)
    diag = {}
    diagnostics_by_robot(diagnostics_msg(m.status(), {}, 1.5, 3, 2, None, pl.stamp + 2.0), diag)
    b = diag['b']
    assert b['via'] == 'a' and b['chain'] == 'a -> b' and b['age_s'] == '2.0' and b['message'] == 'merged via a'
    assert int(b['inliers']) == d['inliers']
    for k in ('x', 'y', 'yaw', 'inlier_ratio', 'agreement'):
        assert math.isclose(float(b[k]), d[k], abs_tol=1e-3), k
    assert diag['a']['message'] == 'reference map' and diag['a']['via'] == '-'
    assert diag['c']['message'].startswith('not merged') and 'via' not in diag['c']
