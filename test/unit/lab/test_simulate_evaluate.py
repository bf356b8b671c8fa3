"""The bag generator's core (robots in a real map), the evaluation against ground truth, and the
pose graph: real outputs checked against what they must be."""
import math
import os

import numpy as np
import pytest
from conftest import pose_error

from multi_map_merge.core.grid import FREE, OCCUPIED, Grid
from multi_map_merge.core.posegraph import optimise, worst_residual
from multi_map_merge.core.transforms import relative, se2, wrap_angle
from multi_map_merge.lab import simulate as sim
from multi_map_merge.lab.evaluate import score_map, transform_errors


@pytest.fixture(scope='module')
def team(house):
    """Four robots and a lone one in the AWS house (about 10 s)."""
    return sim.simulate_world(house, sim.SimConfig(robots=4, seed=1))


def test_raycast_hits_the_walls_of_the_map(house):
    w = sim.World(house)
    nav = w.navigable(0.3)
    r, c = np.argwhere(nav)[len(np.argwhere(nav)) // 2]
    x, y = w.to_metric(c, r)
    angles = np.arange(360) * math.pi / 180
    rng = w.raycast(np.array([[x, y, 0.0]]), angles, 8.0)[0]
    ok = np.isfinite(rng)
    assert ok.mean() > 0.9
    # every end point lies on (or within one cell of) an occupied cell of the map
    ex, ey = x + rng[ok] * np.cos(angles[ok]), y + rng[ok] * np.sin(angles[ok])
    cc, rr = w.to_cell(ex, ey)
    occ = w.occupied
    near = [occ[max(0, int(round(b)) - 1):int(round(b)) + 2, max(0, int(round(a)) - 1):int(round(a)) + 2].any()
            for a, b in zip(cc, rr)]
    assert np.mean(near) > 0.98
    # and nothing occupied lies between the robot and the end point
    for a, d in zip(angles[ok][::20], rng[ok][::20]):
        s = np.arange(0.0, d - 0.08, 0.02)
        c2, r2 = w.to_cell(x + s * np.cos(a), y + s * np.sin(a))
        assert not occ[np.rint(r2).astype(int), np.rint(c2).astype(int)].any()


@pytest.mark.slow
def test_team_starts_together_and_explores_apart(team):
    robots, lone = team
    starts = np.array([r.start[:2] for r in robots])
    assert np.max(np.linalg.norm(starts - starts.mean(0), axis=1)) < 0.5       # close together
    headings = sorted(r.start[2] % (2 * math.pi) for r in robots)
    assert min(np.diff(headings + [headings[0] + 2 * math.pi])) > 0.3          # headings differ
    ends = np.array([r.true[-1, :2] for r in robots])
    d = np.linalg.norm(ends[:, None] - ends[None], axis=2)
    assert d[np.triu_indices(4, 1)].min() > 1.5                                  # different regions
    assert lone.distance > 2.0 * max(r.distance for r in robots)                # one robot does it all


@pytest.mark.slow
def test_sensors_follow_the_datasheet_and_the_clock(team):
    r = team[0][0]
    sc = r.scans
    assert sc.ranges.shape[1] == 360 and abs(sc.angle_increment - math.pi / 180) < 1e-9
    fin = sc.ranges[np.isfinite(sc.ranges)]
    assert fin.min() >= 0.16 and fin.max() <= 8.0
    dt = np.diff(r.t[sc.steps])
    assert np.allclose(dt, 0.2)                                                  # 5 Hz
    assert abs((r.t[1] - r.t[0]) - 0.05) < 1e-9                                  # odometry 20 Hz
    # published maps grow, every 2 s or more, in the robot's own frame
    times = [t for t, _ in r.maps]
    assert min(np.diff(times)) >= 2.0 - 1e-9
    known = [int((g.data >= 0).sum()) for _, g in r.maps]
    assert known[-1] > 3 * known[0] and all(b >= a * 0.98 for a, b in zip(known, known[1:]))
    assert r.maps[-1][1].frame_id == 'tb3_0/map'


@pytest.mark.slow
def test_errors_grow_with_distance(team):
    robots, lone = team

    def slam_error(run):   # end pose of the SLAM estimate against the truth, in the map frame
        truth = relative(run.true[0], run.true[-1])
        return math.hypot(*(run.slam[-1, :2] - truth[:2])), abs(wrap_angle(run.slam[-1, 2] - truth[2]))

    def odom_error(run):
        truth = relative(run.true[0], run.true[-1])
        return math.hypot(*(run.odom[-1, :2] - truth[:2]))

    def odom_heading_error(run):
        truth = relative(run.true[0], run.true[-1])
        return abs(wrap_angle(run.odom[-1, 2] - truth[2]))

    for run in robots + [lone]:
        assert odom_heading_error(run) < math.radians(5.0)  # a Burger's heading is its gyro's
    # the lone robot drives 3-6x as far as any of the team: its wheels' distance, and its SLAM's
    # position and heading, end further off than any team robot's
    assert odom_error(lone) > max(odom_error(r) for r in robots)
    assert slam_error(lone)[0] > max(slam_error(r)[0] for r in robots)
    assert slam_error(lone)[1] > max(slam_error(r)[1] for r in robots)


@pytest.mark.slow
def test_deterministic_for_a_seed(house):
    cfg = sim.SimConfig(robots=2, seed=7, viewpoint_spacing=3.0)
    a, _ = sim.simulate_world(house, cfg)
    b, _ = sim.simulate_world(house, cfg)
    assert np.array_equal(a[1].scans.ranges, b[1].scans.ranges)
    assert np.array_equal(a[1].maps[-1][1].data, b[1].maps[-1][1].data)


def test_gmapping_counting_model():
    cfg = sim.SimConfig(max_urange=3.0)
    gm = sim.GmappingMap((-4.0, -4.0, 4.0, 4.0), cfg)
    # a wall 1 m ahead, seen 10 times; a beam longer than max_urange marks no wall
    gm.add(np.zeros((10, 3)), np.full((10, 2), [1.0, np.inf]), np.array([0.0, math.pi / 2]))
    g = gm.grid('r/map')
    lv = g.levels()
    col = lambda x: int((x - g.origin[0]) / g.resolution)    # noqa: E731
    row = lambda y: int((y - g.origin[1]) / g.resolution)    # noqa: E731
    assert lv[row(0.01), col(1.01)] == OCCUPIED
    assert lv[row(0.01), col(0.5)] == FREE
    assert lv[row(1.5), col(0.01)] == FREE and lv[row(2.9), col(0.01)] == FREE
    assert (lv == OCCUPIED).sum() == 1


@pytest.mark.slow
def test_team_maps_merge_and_score_against_the_truth(house, team, open3d):
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.merger import MapMerger
    robots, lone = team
    m = MapMerger(MergeConfig.from_dict({'reference_robot': 'tb3_0', 'workers': 1}))
    for r in robots:
        m.update_map(r.name, r.maps[-1][1])
    m.estimate()
    starts = {r.name: se2(*r.start) for r in robots}
    errs = transform_errors({k: p.T for k, p in m.placements().items()}, starts, 'tb3_0')
    assert all(e is not None and e[0] < 0.1 and e[1] < 1.5 for e in errs.values()), errs
    merged = score_map(m.compose(), house, starts['tb3_0'])
    single = score_map(lone.maps[-1][1], house, se2(*lone.start))
    assert merged.fitness >= 0.95 and merged.inlier_rmse <= 0.05, merged
    assert single.fitness < merged.fitness - 0.1                 # the lone robot drifted (paper)


def test_score_of_the_truth_itself_and_a_shifted_start(house, open3d):
    T = se2(1.0, -2.0, 0.3)
    s = score_map(house, house, np.eye(3))
    assert s.fitness > 0.999 and s.inlier_rmse < 1e-6 and s.coverage > 0.999 and s.wrong_occupied_m2 == 0
    # the same map in a frame of its own, coarse pose 0.12 m / 2 degrees off: ICP recovers it
    moved = Grid(house.data.copy(), house.resolution, house.origin, 'moved')
    # moved's frame sits at T in the truth frame: its cells are the house's, so the frame is the same
    s = score_map(moved, house, se2(0.08, -0.09, math.radians(2.0)))
    d, a = pose_error(s.T, np.eye(3))
    assert d < 0.02 and a < 0.3 and s.fitness > 0.99
    assert T is not None


def test_a_distorted_map_loses_fitness(house, open3d):
    bad = house.data.copy()
    h = bad.shape[0]
    bad[h // 2:] = np.roll(bad[h // 2:], 8, axis=1)            # half the building 0.4 m off
    s = score_map(Grid(bad, house.resolution, house.origin, 'bad'), house, np.eye(3))
    assert s.fitness < 0.8 and s.wrong_occupied_m2 > 1.0


def test_score_without_a_coarse_pose_uses_the_merger(house, open3d):
    from multi_map_merge.lab.pieces import cut_piece
    piece, T = cut_piece(house, (150, 330, 60, 260), (2.0, -1.0, 1.2), 'piece')
    s = score_map(piece, house)
    assert s.init_source == 'merger'
    d, a = pose_error(s.T, T)
    assert d < 0.05 and a < 0.5 and s.fitness > 0.97


def test_pose_graph_averages_a_cycle_and_keeps_the_reference():
    true = {'a': np.eye(3), 'b': se2(2.0, 0.0, 0.3), 'c': se2(1.0, 2.0, -0.5)}
    rng = np.random.default_rng(0)

    def meas(p, q, noise):
        Z = np.linalg.inv(true[p]) @ true[q]
        return Z @ se2(*(rng.normal(0, 1, 3) * noise))

    links = [('a', 'b', meas('a', 'b', [0.02, 0.02, 0.01]), 1.0),
             ('b', 'c', meas('b', 'c', [0.02, 0.02, 0.01]), 1.0),
             ('a', 'c', meas('a', 'c', [0.02, 0.02, 0.01]), 1.0)]
    chain = {'a': np.eye(3), 'b': links[0][2], 'c': links[0][2] @ links[1][2]}
    opt = optimise(chain, links, 'a')
    assert np.allclose(opt['a'], np.eye(3))
    err = lambda P: sum(pose_error(P[k], true[k])[1] for k in 'bc')  # noqa: E731
    assert err(opt) < err(chain)
    w = worst_residual(opt, links)
    assert w[0] < 0.1 and w[1] < 0.05
    # a tree has nothing to average: unchanged
    assert optimise(chain, links[:2], 'a') == chain


def test_carmen_reader(tmp_path):
    p = tmp_path / 'x.log'
    p.write_text('# comment\nODOM 0 0 0 0 0 0 1.0 h 1\n'
                 'FLASER 4 1 2 3 81.9 0.5 0.5 0.1 0.5 0.5 0.1 10.0 h 10.0\n'
                 'FLASER 4 1 2 3 4 1.5 0.5 0.2 1.5 0.5 0.2 9.5 h 11.0\n')
    log = sim.read_carmen(str(p))
    assert log.ranges.shape == (2, 4)
    assert list(log.t) == [10.0, 10.0]                    # a clock step back is held, not reversed
    assert np.allclose(log.poses[1], [1.5, 0.5, 0.2])
    assert abs(log.angles[0] + math.pi / 2) < 1e-9
    with pytest.raises(ValueError):
        (tmp_path / 'y.log').write_text('nothing here\n')
        sim.read_carmen(str(tmp_path / 'y.log'))


def test_evaluate_map_cli(tmp_path, open3d, house_yaml):
    import subprocess
    import sys

    from conftest import REPO
    env = dict(os.environ, PYTHONPATH=os.path.join(REPO, 'src'))
    exe = [sys.executable, os.path.join(REPO, 'scripts', 'evaluate_map')]
    r = subprocess.run(exe + [house_yaml, house_yaml, '--init', '0.05', '0', '0.01', '--json',
                              str(tmp_path / 'o.json')], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    import json
    out = json.load(open(tmp_path / 'o.json'))
    assert out['fitness'] > 0.99 and abs(out['pose'][0]) < 0.02 and 'Fitness' in r.stdout
    r = subprocess.run(exe + [str(tmp_path / 'missing.yaml'), house_yaml], capture_output=True, text=True, env=env)
    assert r.returncode == 2 and 'missing.yaml' in r.stderr
