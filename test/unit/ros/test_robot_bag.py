"""The robots' bags as `make_robot_bags` writes them: with the SLAM model's maps, or only what
the robots' sensors record (--sensors-only, what the live-gmapping demo replays)."""
import pytest

rosbag = pytest.importorskip('rosbag')
# Debian's generated sensor_msgs serialise numpy arrays with tostring(): one warning per scan
pytestmark = pytest.mark.filterwarnings('ignore:tostring.. is deprecated:DeprecationWarning')

from multi_map_merge.lab import simulate as sim  # noqa: E402
from multi_map_merge.ros.replay import write_robot_bag  # noqa: E402


@pytest.fixture(scope='module')
def runs(house):
    team, _ = sim.simulate_world(house, sim.SimConfig(robots=2, seed=3))
    return team


def _contents(path):
    topics, tf_pairs = set(), set()
    with rosbag.Bag(path) as bag:
        for topic, msg, _ in bag.read_messages():
            topics.add(topic)
            if topic == '/tf':
                tf_pairs.update((t.header.frame_id, t.child_frame_id) for t in msg.transforms)
    return topics, tf_pairs


@pytest.mark.parametrize('slam', [True, False])
def test_sensors_only_bags_carry_no_slam_output(runs, tmp_path, slam):
    path = str(tmp_path / 'team.bag')
    counts = write_robot_bag(path, runs, slam=slam)
    topics, tf_pairs = _contents(path)
    for r in runs:
        n = r.name
        # what a robot's own sensors record is always there
        assert {'/%s/scan' % n, '/%s/odom' % n} <= topics
        assert ('%s/odom' % n, '%s/base_footprint' % n) in tf_pairs
        assert ('%s/base_footprint' % n, '%s/base_scan' % n) in tf_pairs
        # the SLAM model's maps and map -> odom only when asked for
        assert ('/%s/map' % n in topics) == slam
        assert (('%s/map' % n, '%s/odom' % n) in tf_pairs) == slam
        assert counts.get('/%s/map' % n, 0) == (len(r.maps) if slam else 0)
    assert '/clock' in topics
