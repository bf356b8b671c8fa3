"""A Burger's odometry (heading from the gyro, distance from the wheels) and the count of the
scans a gmapping processes: what the demo's robots and their gmappings must do."""
import math

import numpy as np

from multi_map_merge.core.transforms import compose, wrap_angle
from multi_map_merge.lab import simulate as sim
from multi_map_merge.lab.scans_processed import count_updates, gmapping_updates


def corridor_drive(legs: int = 24, length: float = 4.0, rate: float = 20.0) -> np.ndarray:
    """True poses of a robot driving ``legs`` times up and down a corridor at 0.22 m/s, turning
    half a turn on the spot at each end, left and right in turn (no net rotation)."""
    dt = 1.0 / rate
    pose = np.zeros(3)
    out = [pose.copy()]
    for k in range(legs):
        for _ in range(int(length / 0.22 / dt)):
            pose = compose(pose, np.array([0.22 * dt, 0.0, 0.0]))
            out.append(pose.copy())
        turn = 1.5 if k % 2 == 0 else -1.5
        for _ in range(int(math.pi / 1.5 / dt)):
            pose = compose(pose, np.array([0.0, 0.0, turn * dt]))
            out.append(pose.copy())
    return np.array(out)


def heading_error(true: np.ndarray, odom: np.ndarray) -> float:
    """Degrees: the odometry's heading error at the end of the drive."""
    return abs(math.degrees(wrap_angle(odom[-1, 2] - (true[-1, 2] - true[0, 2]))))


def test_gyro_heading_drifts_a_few_degrees_where_the_wheels_drift_tens():
    true = corridor_drive()                     # 96 m and 24 half turns (75 rad) in 487 s
    gyro, wheels = [], []
    for seed in range(12):
        odom, _ = sim.errors(true, sim.SimConfig(), np.random.default_rng(seed))
        gyro.append(heading_error(true, odom))
        odom, _ = sim.errors(true, sim.SimConfig(wheel_heading=True), np.random.default_rng(seed))
        wheels.append(heading_error(true, odom))
    # the gyro's bias (sigma 0.005 deg/s) over 487 s: 2.4 deg sigma; the wheels' model:
    # 2 deg/sqrt(m) over 96 m and 0.05 rad/sqrt(rad) over 75 rad turned: 28 deg sigma
    assert np.mean(gyro) < 4.0
    assert np.mean(wheels) > 4.0 * np.mean(gyro)


def test_no_gyro_error_no_heading_error():
    true = corridor_drive(legs=4)
    cfg = sim.SimConfig(gyro_scale_sigma=0.0, gyro_bias_sigma=0.0, gyro_noise_density=0.0)
    odom, _ = sim.errors(true, cfg, np.random.default_rng(3))
    assert heading_error(true, odom) < 1e-6
    # the wheels still err: the distance is theirs
    assert np.hypot(*(odom[-1, :2] - true[-1, :2])) > 1e-3


def test_the_bias_accrues_while_standing_still():
    true = np.zeros((20 * 100, 3))              # 100 s at rest
    cfg = sim.SimConfig(gyro_scale_sigma=0.0, gyro_noise_density=0.0, gyro_bias_sigma=math.radians(0.01))
    odom, _ = sim.errors(true, cfg, np.random.default_rng(5))
    assert heading_error(true, odom) > 0.01     # sigma 1 deg over 100 s
    assert np.allclose(odom[:, :2], 0.0)


def test_slam_poses_do_not_depend_on_where_the_odometry_heading_comes_from():
    true = corridor_drive(legs=4)
    _, slam_gyro = sim.errors(true, sim.SimConfig(), np.random.default_rng(11))
    _, slam_wheels = sim.errors(true, sim.SimConfig(wheel_heading=True), np.random.default_rng(11))
    assert np.array_equal(slam_gyro, slam_wheels)


def test_gmapping_update_rule():
    t = np.arange(50) * 0.2                     # 5 Hz, 10 s
    still = np.zeros((50, 3))
    # standing still: only the time rule, strictly more than 0.5 s: every third scan
    keep = gmapping_updates(t, still, 1.0, 0.2, 0.5)
    assert list(np.nonzero(keep)[0][:4]) == [0, 3, 6, 9]
    # no time rule (temporalUpdate -1, gmapping's default): only the first
    assert gmapping_updates(t, still, 1.0, 0.2, -1.0).sum() == 1
    # turning 0.3 rad a scan: every scan passes angularUpdate 0.2
    turning = np.zeros((50, 3))
    turning[:, 2] = wrap_angle(0.3 * np.arange(50))
    assert gmapping_updates(t, turning, 1.0, 0.2, -1.0).all()
    # driving 0.25 m a scan: every fourth scan (the distance is summed from scan to scan)
    driving = np.zeros((50, 3))
    driving[:, 0] = 0.25 * np.arange(50)
    assert list(np.nonzero(gmapping_updates(t, driving, 1.0, 0.2, -1.0))[0][:3]) == [0, 4, 8]
    assert gmapping_updates(t[:0], still[:0], 1.0, 0.2, 0.5).sum() == 0


def test_count_updates_reads_gmapping_stdout_logs(tmp_path):
    run = tmp_path / 'run_id'
    run.mkdir()
    (run / 'tb3_1-slam_gmapping-3-stdout.log').write_text(
        'update frame 0\nupdate ld=0 ad=0\nLaser Pose= 0 0 0\nupdate frame 4\nupdate ld=1 ad=0\n')
    (run / 'tb3_0-slam_gmapping-2-stdout.log').write_text('update frame 0\n')
    (tmp_path / 'latest').symlink_to(run)       # roslaunch's link to the last run: not twice
    assert count_updates(str(tmp_path), 'tb3_1') == (2, 5)
    assert count_updates(str(tmp_path), 'tb3_0') == (1, 1)
    assert count_updates(str(tmp_path), 'tb3_2') is None
    # slam:=rbpf: rbpf_slam's log, the same lines (not another robot's, not another node's)
    (run / 'tb3_2-rbpf_slam-4-stdout.log').write_text('update frame 0\nupdate frame 3\nupdate frame 7\n')
    (run / 'tb3_2-scan_frame_relay-5-stdout.log').write_text('update frame 9\n')
    assert count_updates(str(tmp_path), 'tb3_2') == (3, 8)
    assert count_updates(str(tmp_path), 'tb3_1') == (2, 5)
