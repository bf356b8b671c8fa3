"""evaluate.py: the paper's Fitness / inlier RMSE (Open3D ICP) against ground truth, coverage,
wrongly occupied area, transform errors, the truth file and the transforms report, and evaluate_map."""
import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml
from conftest import REPO, pose_error
from scipy.spatial import cKDTree

from multi_map_merge.core.grid import FREE, OCCUPIED, Grid, GridError
from multi_map_merge.core.mapio import save_map
from multi_map_merge.core.transforms import inverse, se2, xyyaw
from multi_map_merge.lab.evaluate import (
    Open3DMissing,
    load_transforms,
    load_truth,
    occupied_points,
    score_map,
    transform_errors,
)
from multi_map_merge.lab.pieces import cut_piece, random_poses

OFF = se2(0.15, 0.10, math.radians(3.0))   # a coarse pose this far off (in the truth's frame)


def in_frame(g: Grid, T: np.ndarray, name: str = 'k') -> Grid:
    """The very same cells expressed in a frame k whose pose in g's frame is T (the origin
    gets T's yaw: the cells stay where they were in g's frame)."""
    return Grid(g.data.copy(), g.resolution, xyyaw(inverse(T) @ se2(*g.origin)), name)


def test_occupied_points_use_the_origin_with_its_yaw():
    d = np.zeros((4, 6), np.int8)
    d[1, 2] = 100                                  # centre at (2.5, 1.5) cells
    g = Grid(d, 0.1, (1.0, 2.0, math.pi / 2))
    p = occupied_points(g)
    assert p.shape == (1, 2)
    assert np.allclose(p[0], [1.0 - 0.15, 2.0 + 0.25])


def test_the_map_against_itself_at_a_known_offset(house, open3d):
    T = se2(3.0, -1.5, 0.6)
    s = score_map(in_frame(house, T), house, T)
    assert s.init_source == 'given'
    assert s.fitness > 0.9999 and s.inlier_rmse < 1e-6
    assert s.coverage > 0.9999 and s.wrong_occupied_m2 == 0.0
    d, a = pose_error(s.T, T)
    assert d < 1e-6 and a < 1e-6
    assert np.allclose(s.correction, 0.0, atol=1e-6)
    n = int((house.levels() == OCCUPIED).sum())
    assert s.occupied_points == n and s.truth_points == n
    # and the pose matters: the same frame taken for the truth's own is another map
    bad = score_map(in_frame(house, T), house, np.eye(3), stages=(1.0,))
    assert bad.fitness < 0.2


@pytest.mark.parametrize('name,pose', [('house', (1.234, -0.77, 0.5)), ('intel', (-2.0, 3.1, -2.4))])
@pytest.mark.parametrize('sign', [1, -1])
def test_icp_recovers_a_coarse_pose_off_by_15cm_10cm_3deg(name, pose, sign, house, intel, open3d):
    world = {'house': house, 'intel': intel}[name]
    # the whole map re-rasterised in a rotated frame: walls one cell off here and there
    piece, T = cut_piece(world, (0, world.height, 0, world.width), pose, 'k')
    off = OFF if sign > 0 else inverse(OFF)
    s = score_map(piece, world, off @ T)
    d, a = pose_error(s.T, T)
    assert d < 0.03 and a < 0.5, (d, a)
    assert s.fitness > 0.99 and s.inlier_rmse < 0.04
    assert s.coverage > 0.98 and s.wrong_occupied_m2 < 0.05
    # the correction is what undoes the offset, in the map's frame
    assert pose_error(se2(*s.correction), inverse(T) @ inverse(off) @ T)[0] < 0.03


def test_a_single_icp_at_0_1m_does_not_recover_intel_off_by_3deg(intel, open3d):
    # why score_map anneals: plain ICP at the scoring distance stays where it started
    piece, T = cut_piece(intel, (0, intel.height, 0, intel.width), (0.0, 0.0, 0.0), 'k')
    s = score_map(piece, intel, OFF @ T, stages=(1.0,))
    assert pose_error(s.T, T)[1] > 1.0 and s.fitness < 0.6


def moved_block(world: Grid, cells: int = 7) -> tuple:
    """A copy of ``world`` whose walls in the lower-left quarter of the building are moved
    ``cells`` along +x and +y (0.49 m diagonally at 0.05 m); returns (grid, moved walls, all
    walls)."""
    lv = world.levels()
    rows, cols = np.nonzero(lv == OCCUPIED)
    r0, r1 = rows.min(), (rows.min() + rows.max()) // 2
    c0, c1 = cols.min(), (cols.min() + cols.max()) // 2
    block = np.zeros(lv.shape, bool)
    block[r0:r1, c0:c1] = lv[r0:r1, c0:c1] == OCCUPIED
    d = world.data.copy()
    d[block] = 0
    br, bc = np.nonzero(block)
    d[br + cells, bc + cells] = 100
    return Grid(d, world.resolution, world.origin, 'distorted'), int(block.sum()), len(rows)


def test_a_block_of_walls_moved_half_a_metre_loses_fitness(house, open3d):
    bad, moved, total = moved_block(house)
    assert moved / total > 0.2
    s = score_map(bad, house, np.eye(3))
    # the rest of the building holds the alignment where it is
    d, a = pose_error(s.T, np.eye(3))
    assert d < 0.02 and a < 0.2
    # Fitness is the fraction of the map's walls with a truth wall within 0.1 m: count it
    # independently
    pts = occupied_points(bad)
    near = cKDTree(occupied_points(house)).query(pts, distance_upper_bound=0.1 + 1e-9)[0] <= 0.1 + 1e-9
    assert abs(s.fitness - near.mean()) < 0.01
    # and nearly every moved wall is lost (a few land beside another wall)
    assert 1.0 - moved / total - 0.02 < s.fitness < 1.0 - 0.7 * moved / total
    assert s.occupied_points == total
    # the moved walls that stand on open floor
    assert 0.5 < s.wrong_occupied_m2 <= moved * house.resolution ** 2
    assert s.inlier_rmse < 0.05     # what fits, fits well: RMSE alone does not see the damage
    good = score_map(house, house, np.eye(3))
    assert good.fitness > 0.9999 and good.wrong_occupied_m2 == 0.0


def test_without_a_coarse_pose_the_merger_places_a_cut_piece(house, open3d):
    pose = random_poses(1, seed=7)[0]
    r0, r1, c0, c1 = house.height // 4, 3 * house.height // 4, house.width // 4, 3 * house.width // 4
    piece, T = cut_piece(house, (r0, r1, c0, c1), pose, 'piece')
    s = score_map(piece, house)
    assert s.init_source == 'merger', s.note
    d, a = pose_error(s.T, T)
    assert d < 0.03 and a < 0.5, (pose, d, a)
    assert pose_error(s.T_init, T)[0] < 0.2       # the merger's own estimate was close already
    assert s.fitness > 0.98
    # coverage: the truth's free cells inside the cut rectangle, of all its free cells
    free = house.levels() == FREE
    part = free[r0:r1, c0:c1].sum() / free.sum()
    assert 0.2 < part < 0.9 and abs(s.coverage - part) < 0.01, (s.coverage, part)


def test_when_the_merger_cannot_place_the_map_icp_starts_from_the_identity(house, open3d):
    rng = np.random.default_rng(3)
    d = np.zeros((120, 120), np.int8)
    d[rng.random(d.shape) < 0.03] = 100           # dots that are nowhere in the house
    s = score_map(Grid(d, 0.05, (0.0, 0.0, 0.0), 'noise'), house)
    assert s.init_source == 'none'
    assert np.allclose(s.T_init, np.eye(3)) and 'identity' in s.note
    assert s.fitness < 0.5


def test_clear_errors(house):
    empty = Grid(np.zeros((20, 20), np.int8), 0.05)
    with pytest.raises(GridError, match='no occupied cell'):
        score_map(empty, house, np.eye(3))
    with pytest.raises(GridError, match='ground truth'):
        score_map(house, empty, np.eye(3))
    with pytest.raises(ValueError, match='max_distance'):
        score_map(house, house, np.eye(3), max_distance=0.0)
    with pytest.raises(ValueError, match='3x3'):
        score_map(house, house, np.eye(4))


def test_transform_errors_on_hand_made_poses():
    starts = {'r0': se2(1.0, 2.0, 0.5), 'r1': se2(3.0, 1.0, -0.2), 'r2': se2(-1.0, 0.0, 2.0)}
    true1 = np.linalg.inv(starts['r0']) @ starts['r1']
    est = {'r0': np.eye(3),
           'r1': true1 @ se2(0.03, -0.04, math.radians(1.5)),   # 0.05 m, 1.5 deg off
           'ghost': se2(9.0, 9.0, 0.0)}                        # not in the truth: left out
    e = transform_errors(est, starts, 'r0')
    assert set(e) == {'r0', 'r1', 'r2'}
    assert e['r0'] == pytest.approx((0.0, 0.0), abs=1e-9)
    assert e['r1'] == pytest.approx((0.05, 1.5), abs=1e-9)
    assert e['r2'] is None
    # the other convention (inv(start_k) @ start_ref) would be far off
    e = transform_errors({'r1': true1}, starts, 'r0')
    assert e['r1'] == pytest.approx((0.0, 0.0), abs=1e-9)
    e = transform_errors({'r1': np.linalg.inv(starts['r1']) @ starts['r0']}, starts, 'r0')
    assert e['r1'][0] > 1.0
    # reference r1: r0 seen from r1
    e = transform_errors({'r0': np.linalg.inv(true1)}, starts, 'r1')
    assert e['r0'] == pytest.approx((0.0, 0.0), abs=1e-9)
    with pytest.raises(ValueError, match='reference'):
        transform_errors(est, starts, 'nobody')


def test_load_truth_resolves_a_relative_world_path(tmp_path):
    (tmp_path / 'sub').mkdir()
    p = tmp_path / 'sub' / 'house.truth.yaml'
    p.write_text(yaml.safe_dump({'world': '../gt/world.yaml', 'reference': 'tb3_1',
                                 'robots': {'tb3_0': {'start': [1.0, 2.0, 0.5]},
                                            'tb3_1': {'start': [0.0, -1.0, 0.0]}},
                                 'single': {'start': [0, 0, 0], 'distance_m': 3.0}}))
    t = load_truth(str(p))
    assert t['world_path'] == str(tmp_path / 'gt' / 'world.yaml')
    assert t['reference'] == 'tb3_1' and t['single']['distance_m'] == 3.0
    assert np.allclose(t['starts']['tb3_0'], se2(1.0, 2.0, 0.5))
    p.write_text(yaml.safe_dump({'world': '/abs/w.yaml', 'robots': {'b': {'start': [0, 0, 0]},
                                                                     'a': {'start': [1, 0, 0]}}}))
    t = load_truth(str(p))
    assert t['world_path'] == '/abs/w.yaml' and t['reference'] == 'a'
    for bad in ({'world': 'w.yaml'}, {'world': 'w.yaml', 'robots': {'a': {'start': [0, 0]}}},
                {'world': 'w.yaml', 'reference': 'z', 'robots': {'a': {'start': [0, 0, 0]}}}):
        p.write_text(yaml.safe_dump(bad))
        with pytest.raises(ValueError, match='house.truth.yaml'):
            load_truth(str(p))
    with pytest.raises(ValueError, match='missing.yaml'):
        load_truth(str(tmp_path / 'missing.yaml'))


def test_load_transforms(tmp_path):
    p = tmp_path / 'T.yaml'
    p.write_text(yaml.safe_dump({'reference': 'A', 'maps': {
        'B': {'merged': True, 'x': 1.25, 'y': -0.4, 'yaw': 0.5236, 'reliability': 0.8, 'via': 'A'},
        'C': {'merged': False, 'reason': 'grids disagree'}}}, sort_keys=False))
    T = load_transforms(str(p))
    assert list(T) == ['A', 'B']
    assert np.allclose(T['A'], np.eye(3)) and np.allclose(T['B'], se2(1.25, -0.4, 0.5236))
    p.write_text('maps: {}\n')
    with pytest.raises(ValueError, match='T.yaml'):
        load_transforms(str(p))


def run_cli(*args):
    env = dict(os.environ, PYTHONPATH=os.path.join(REPO, 'src'))
    return subprocess.run([sys.executable, os.path.join(REPO, 'scripts', 'evaluate_map')] + list(args),
                          capture_output=True, text=True, env=env, timeout=120)


def test_without_open3d_scoring_says_what_to_install(house, monkeypatch, tmp_path, house_yaml):
    """Open3D is optional (Ubuntu 20.04 does not package it): without it scoring raises an
    ImportError naming what to install, and evaluate_map exits 2 with that one line."""
    monkeypatch.setitem(sys.modules, 'open3d', None)          # `import open3d` fails, as where absent
    for T in (np.eye(3), None):                               # None: before the merger's coarse pose
        with pytest.raises(Open3DMissing, match=r'pip3 install --user open3d .*python3-open3d-pip'):
            score_map(house, house, T)
    code = ("import sys; sys.modules['open3d'] = None; from multi_map_merge.lab.evaluate import main; "
            "sys.exit(main(sys.argv[1:]))")
    env = dict(os.environ, PYTHONPATH=os.path.join(REPO, 'src'))
    r = subprocess.run([sys.executable, '-c', code, house_yaml, house_yaml, '--json', str(tmp_path / 'o.json')],
                       capture_output=True, text=True, env=env, timeout=120)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, (r.returncode, r.stderr)
    assert lines[0].startswith('evaluate_map: Open3D is not installed') and 'pip3 install' in lines[0]
    assert not (tmp_path / 'o.json').exists() and r.stdout == ''


def test_cli_exits_2_naming_a_bad_file(tmp_path, house_yaml):
    r = run_cli(str(tmp_path / 'missing.yaml'), house_yaml)
    assert r.returncode == 2 and 'missing.yaml' in r.stderr
    (tmp_path / 'notamap.yaml').write_text('hello: 1\n')
    r = run_cli(house_yaml, str(tmp_path / 'notamap.yaml'))
    assert r.returncode == 2 and 'notamap.yaml' in r.stderr
    r = run_cli(house_yaml, house_yaml, '--truth', str(tmp_path / 'missing.truth.yaml'))
    assert r.returncode == 2 and 'missing.truth.yaml' in r.stderr


def test_cli_prints_the_figures_on_a_real_pair(tmp_path, house, open3d, house_yaml):
    # a "merged map" in tb3_0's map frame; the truth file gives tb3_0's start in the world
    start0, start1 = (2.0, -1.0, 0.4), (2.3, -0.8, 1.9)
    T = se2(*start0)
    save_map(in_frame(house, T, 'merged'), str(tmp_path / 'merged.yaml'))
    (tmp_path / 'run.truth.yaml').write_text(yaml.safe_dump({
        'world': os.path.relpath(house_yaml, str(tmp_path)), 'reference': 'tb3_0',
        'robots': {'tb3_0': {'start': list(start0)}, 'tb3_1': {'start': list(start1)},
                   'tb3_2': {'start': [0.0, 0.0, 0.0]}}}))
    t1 = np.linalg.inv(se2(*start0)) @ se2(*start1) @ se2(0.02, 0.0, math.radians(0.5))
    x, y, yaw = xyyaw(t1)
    (tmp_path / 'T.yaml').write_text(yaml.safe_dump({'reference': 'tb3_0', 'maps': {
        'tb3_1': {'merged': True, 'x': x, 'y': y, 'yaw': yaw},
        'tb3_2': {'merged': False, 'reason': 'too few inliers'}}}))
    r = run_cli(str(tmp_path / 'merged.yaml'), house_yaml, '--truth', str(tmp_path / 'run.truth.yaml'),
                '--transforms', str(tmp_path / 'T.yaml'), '--json', str(tmp_path / 'o.json'))
    assert r.returncode == 0, r.stderr
    out = json.loads((tmp_path / 'o.json').read_text())
    print(r.stdout)
    assert out['init_source'] == 'given' and out['fitness'] > 0.999 and out['coverage'] > 0.99
    assert out['wrong_occupied_m2'] == 0.0 and out['inlier_rmse'] < 0.01
    assert np.allclose(out['pose'], start0, atol=1e-3)
    for word in ('Fitness', 'inlier RMSE', 'coverage', 'wrongly occupied', 'start pose of tb3_0',
                 'ICP correction', 'NOT merged'):
        assert word in r.stdout, word
    assert 'error 0.020 m 0.50 deg' in r.stdout
    e = out['transform_errors']
    assert e['tb3_2'] is None and e['tb3_1']['translation_m'] == pytest.approx(0.02, abs=1e-4)
