"""What both nodes do with a robot's map as it arrives (ros/map_input.py) and which placements
they send again (ros/pose_changes.py): real messages, a real merger, the lines each would log."""
import numpy as np
import pytest

rospy = pytest.importorskip('rospy')   # the ROS shell's messages: not on a stack without ROS (make test-focal)

from multi_map_merge.core.config import MergeConfig  # noqa: E402
from multi_map_merge.core.grid import Grid  # noqa: E402
from multi_map_merge.core.merger import MapMerger  # noqa: E402
from multi_map_merge.core.placement import Placement  # noqa: E402
from multi_map_merge.core.transforms import se2  # noqa: E402
from multi_map_merge.ros.convert import NumpyGridUpdate, grid_from_msg, grid_to_msg  # noqa: E402
from multi_map_merge.ros.map_input import Log, MapInput  # noqa: E402
from multi_map_merge.ros.pose_changes import PoseChanges, tf_children  # noqa: E402


@pytest.fixture
def node():
    """A MapInput over a fresh merger, its log lines gathered as (level, line)."""
    lines = []
    merger = MapMerger(MergeConfig(workers=1))
    intake = MapInput(merger, 'map', 10 ** 6, Log(lambda s: lines.append(('error', s)),
                                                  lambda s: lines.append(('warning', s)),
                                                  lambda s: lines.append(('info', s))))
    return intake, merger, lines


def map_msg(frame='tb3_1/map', cells=None, resolution=0.05):
    cells = np.zeros((20, 30), np.int8) if cells is None else cells
    return grid_to_msg(Grid(cells, resolution, (1.0, -2.0, 0.0)), rospy.Time(3), frame)


def take(intake, robot, msg):
    intake.on_map(robot, lambda: grid_from_msg(msg, intake.max_cells))


def test_a_refused_map_is_logged_once_per_reason_and_shown_until_a_valid_one(node):
    intake, merger, lines = node
    bad = map_msg()
    bad.info.resolution = 0.0
    for _ in range(3):
        take(intake, 'tb3_1', bad)
    errors = [s for level, s in lines if level == 'error']
    assert len(errors) == 1 and errors[0].startswith('ignoring map of tb3_1: ') and 'resolution' in errors[0]
    assert 'resolution' in merger.status()['tb3_1'].error
    assert 'tb3_1' not in intake.latest   # nothing of it reached the merge
    take(intake, 'tb3_1', map_msg())
    assert ('info', 'map of tb3_1 is valid again') in lines
    assert intake.latest['tb3_1'].resolution == 0.05 and merger.status()['tb3_1'].map_received is not None


def test_a_map_in_the_merged_frame_gets_a_frame_of_its_own_with_one_warning(node):
    intake, merger, lines = node
    for _ in range(2):
        take(intake, 'tb3_2', map_msg(frame='map'))
    warnings = [s for level, s in lines if level == 'warning']
    assert warnings == ['map of tb3_2 is in frame "map", not one of its own: publishing its TF as tb3_2/map']
    assert intake.latest['tb3_2'].frame_id == 'tb3_2/map' and merger.frames()['tb3_2'] == 'tb3_2/map'
    take(intake, 'tb3_3', map_msg(frame='tb3_3/map'))   # its own frame: kept, no warning
    assert merger.frames()['tb3_3'] == 'tb3_3/map'
    assert [s for level, s in lines if level == 'warning'] == warnings


def test_an_update_applies_to_the_last_full_map_and_a_bad_one_is_refused(node):
    intake, merger, lines = node
    update = NumpyGridUpdate()
    update.x, update.y, update.width, update.height = 2, 3, 4, 2
    update.data = np.full(8, 100, np.int8)
    intake.on_update('tb3_1', update.x, update.y, update.width, update.height, update.data)
    assert 'tb3_1' not in intake.latest and not lines   # nothing to apply it to yet
    take(intake, 'tb3_1', map_msg())
    intake.on_update('tb3_1', update.x, update.y, update.width, update.height, update.data)
    cells = intake.latest['tb3_1'].data
    assert (cells[3:5, 2:6] == 100).all() and np.count_nonzero(cells) == 8
    update.x = 28   # 4 cells wide from column 28 of a 30-cell map: out of it
    intake.on_update('tb3_1', update.x, update.y, update.width, update.height, update.data)
    errors = [s for level, s in lines if level == 'error']
    assert len(errors) == 1 and errors[0].startswith('ignoring map of tb3_1: map_updates: ')
    assert np.count_nonzero(intake.latest['tb3_1'].data) == 8   # the last good map kept


def test_the_reference_is_logged_once_when_chosen(node):
    intake, merger, lines = node
    take(intake, 'tb3_0', map_msg(frame='tb3_0/map'))
    take(intake, 'tb3_0', map_msg(frame='tb3_0/map'))
    chosen = [s for level, s in lines if level == 'info' and s.startswith('reference robot')]
    assert len(chosen) == 1 and 'tb3_0' in chosen[0] and merger.reference == 'tb3_0'


def placed(T, via='tb3_0', cov=None):
    return Placement(T, 0.5, 0.95, 40, via, ('tb3_0', 'tb3_1'), 0.0, cov=cov)


def test_a_placement_is_sent_again_only_when_it_changed():
    changes = PoseChanges()
    a = placed(se2(1.0, 2.0, 0.3))
    placements = {'tb3_1': a}
    assert [r for r, _, _ in changes.due(placements)] == ['tb3_1']
    assert changes.due(placements) == []
    a.cov = np.diag([0.01, 0.01, 0.001])   # its covariance came: sent again
    assert [r for r, _, _ in changes.due(placements)] == ['tb3_1']
    placements['tb3_1'] = placed(se2(1.0, 2.05, 0.3), cov=a.cov)
    assert [r for r, _, _ in changes.due(placements)] == ['tb3_1']


def test_tf_is_sent_for_placed_robots_with_a_frame_of_their_own():
    placements = {'tb3_0': placed(np.eye(3), via=''), 'tb3_1': placed(se2(1.0, 0.0, 0.0)),
                  'tb3_2': placed(se2(2.0, 0.0, 0.0))}
    frames = {'tb3_0': 'map', 'tb3_1': 'tb3_1/map'}   # tb3_0's map is the merged frame; tb3_2's unknown
    out = tf_children(placements, frames, 'map')
    assert [child for _, child in out] == ['tb3_1/map'] and out[0][0][0, 2] == 1.0
