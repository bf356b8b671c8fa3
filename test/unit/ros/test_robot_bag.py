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


def test_lds02_driver_bags_stamp_their_scans_base_scan(tmp_path):
    """make_robot_bags --lds02-driver: scans as ld08_driver publishes them, also in its frame:
    "base_scan" for every robot (the driver ignores the frame it is given), lengths varying,
    range 0-100 m; the TF still puts the laser at <robot>/base_scan, as each robot's
    robot_state_publisher does (tf_prefix), which scan_frame_relay republishes the scans in."""
    from multi_map_merge.lab.robot_bags import main
    out = str(tmp_path / 'driver.bag')
    assert main(['-o', out, '--robots', '2', '--seed', '2', '--no-single', '--sensors-only', '--lds02-driver']) == 0
    frames, lengths, limits = set(), set(), set()
    with rosbag.Bag(out) as bag:
        for _, msg, _ in bag.read_messages(topics=['/tb3_0/scan', '/tb3_1/scan']):
            frames.add(msg.header.frame_id)
            lengths.add(len(msg.ranges))
            limits.add((msg.range_min, msg.range_max))
    assert frames == {'base_scan'}
    assert len(lengths) > 10 and limits == {(0.0, 100.0)}
    _, tf_pairs = _contents(out)
    assert {('tb3_0/base_footprint', 'tb3_0/base_scan'), ('tb3_1/base_footprint', 'tb3_1/base_scan')} <= tf_pairs
    # without the option: each robot's scans in its own <robot>/base_scan, as before
    out = str(tmp_path / 'fixed.bag')
    assert main(['-o', out, '--robots', '2', '--seed', '2', '--no-single', '--sensors-only']) == 0
    with rosbag.Bag(out) as bag:
        assert {m.header.frame_id for _, m, _ in bag.read_messages(topics=['/tb3_0/scan', '/tb3_1/scan'])} \
            == {'tb3_0/base_scan', 'tb3_1/base_scan'}
