"""Pieces cut out of real maps, moved by known poses, recovered within 2 cells and 1 degree."""
import os
import subprocess
import sys

import numpy as np
import pytest
import yaml
from conftest import HOUSE_MAP, INTEL_MAP, REPO, pose_error, shared_file, truth

from multi_map_merge.cli import merge_maps as cli
from multi_map_merge.core.mapio import load_map, save_map
from multi_map_merge.core.merger import MapMerger
from multi_map_merge.core.transforms import se2
from multi_map_merge.lab.pieces import cut_piece, random_poses, split_rects

WORLDS = {'intel': INTEL_MAP, 'house': HOUSE_MAP}   # in ../shared/data
CASES = [(world, n, seed) for world in WORLDS for n in (2, 3, 4) for seed in (0, 1, 2, 3)]


def pieces(world, n, seed):
    w = load_map(shared_file(WORLDS[world]))
    return w, [cut_piece(w, r, p, 'p%d' % i)
               for i, (r, p) in enumerate(zip(rects(w, n), random_poses(n, seed, 5.0)))]


@pytest.mark.parametrize('world, n, seed', CASES)
def test_core_api_recovers_every_pose(world, n, seed):
    _, ps = pieces(world, n, seed)
    m = MapMerger()
    for i, (g, _) in enumerate(ps):
        m.update_map('p%d' % i, g)
    m.estimate()
    pl = m.placements()
    assert m.reference == 'p0'
    for i in range(1, n):
        assert 'p%d' % i in pl, 'piece %d not merged: %s' % (i, m.status()['p%d' % i].last_attempt)
        d, a = pose_error(pl['p%d' % i].T, truth(ps[0][1], ps[i][1]))
        assert d <= 0.10 and a <= 1.0, 'piece %d off by %.3f m %.2f deg' % (i, d, a)
        assert np.linalg.det(pl['p%d' % i].T[:2, :2]) == pytest.approx(1.0)


MERGED_KEYS = {'merged', 'x', 'y', 'yaw', 'inlier_ratio', 'inliers', 'agreement', 'via', 'chain', 'weak',
               'sigma_position', 'cov'}


def check_report(report, ps, stems):
    """The transforms report's exact shape (README: reference, maps: {stem: {merged, x, y, yaw,
    inlier_ratio, agreement, inliers, via, chain, weak, sigma_position, cov}}, links) and every
    pose against the truth."""
    assert set(report) == {'reference', 'maps', 'links'} and report['reference'] == stems[0]
    check_links(report['links'], ps, stems)
    assert set(report['maps']) == set(stems[1:])
    for i, s in enumerate(stems[1:], 1):
        r = report['maps'][s]
        assert set(r) == MERGED_KEYS, sorted(r)
        assert r['merged'] is True and r['via'] in stems and r['via'] != s
        assert all(isinstance(r[k], float) for k in ('x', 'y', 'yaw', 'inlier_ratio', 'agreement'))
        assert isinstance(r['inliers'], int)
        assert 0 < r['inlier_ratio'] <= 1 and r['inliers'] >= 10 and 0.8 <= r['agreement'] <= 1
        d, a = pose_error(se2(r['x'], r['y'], r['yaw']), truth(ps[0][1], ps[i][1]))
        assert d <= 0.10 and a <= 1.0, '%s off by %.3f m %.2f deg' % (s, d, a)
        # pieces of a third of a building, rooms and corners: pinned well in every direction
        assert 0.005 < r['sigma_position'] < 0.05 and r['weak'] is False
        C = np.array(r['cov']).reshape(3, 3)
        assert r['sigma_position'] == pytest.approx(np.sqrt(np.linalg.eigvalsh(C[:2, :2])[-1]), rel=1e-3)


def check_links(links, ps, stems):
    """Every verified link: its pose against the truth, and a covariance (row-major 3x3,
    symmetric, positive definite) whose position sigma is its worst direction's."""
    assert links
    for lk in links:
        assert set(lk) == {'parent', 'child', 'x', 'y', 'yaw', 'cov', 'sigma_position'}, sorted(lk)
        i, j = stems.index(lk['parent']), stems.index(lk['child'])
        d, a = pose_error(se2(lk['x'], lk['y'], lk['yaw']), truth(ps[i][1], ps[j][1]))
        assert d <= 0.10 and a <= 1.0
        C = np.array(lk['cov']).reshape(3, 3)
        assert np.allclose(C, C.T, rtol=1e-4, atol=1e-12) and np.all(np.linalg.eigvalsh(C) > 0)
        assert lk['sigma_position'] == pytest.approx(np.sqrt(np.linalg.eigvalsh(C[:2, :2])[-1]), rel=1e-3)
        assert 0.005 < lk['sigma_position'] < 0.5


def write_pieces(tmp_path, ps):
    paths = []
    for i, (g, _) in enumerate(ps):
        p = str(tmp_path / ('robot%d.yaml' % i))
        save_map(g, p)
        paths.append(p)
    return paths


@pytest.mark.parametrize('world, n', [('intel', 4), ('house', 3)])
def test_merge_maps_cli(tmp_path, world, n):
    w, ps = pieces(world, n, 2)
    paths = write_pieces(tmp_path, ps)
    out, tf = str(tmp_path / 'merged.yaml'), str(tmp_path / 'T.yaml')
    # pieces of one ground truth do not drift from their frames' origins (core/drift.py)
    cfg = tmp_path / 'no_drift.yaml'
    cfg.write_text('map_drift: 0.0\nmap_drift_yaw: 0.0\n')
    assert cli.main(paths + ['-o', out, '--transforms', tf, '--config', str(cfg)]) == 0
    check_report(yaml.safe_load(open(tf)), ps, ['robot%d' % i for i in range(n)])
    check_merged_is_the_world(load_map(out), w, ps, rects(w, n))


def rects(w, n):
    return split_rects(w, n, 0.3)


def check_merged_is_the_world(merged, w, ps, rs):
    """The merged map (frame of piece 0) warped back into the world grid covers the union of
    the cut rectangles and says there what the world says; nothing lies outside it."""
    import cv2

    from multi_map_merge.core.grid import FREE, OCCUPIED
    from multi_map_merge.core.transforms import cell_to_metric, inverse
    assert merged.resolution == pytest.approx(w.resolution)
    # cells of the merged grid -> cells of the world grid
    A = inverse(cell_to_metric(w.resolution, w.origin)) @ ps[0][1] @ cell_to_metric(merged.resolution, merged.origin)
    back = cv2.warpAffine(merged.levels(), A[:2], (w.width, w.height), flags=cv2.INTER_NEAREST,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    union = np.zeros(w.data.shape, bool)
    for r0, r1, c0, c1 in rs:
        union[r0:r1, c0:c1] = True
    wl = w.levels()
    known = union & (wl > 0)
    covered = (back[known] > 0).mean()
    assert covered > 0.97, 'merged map covers %.3f of the pieces\' known cells' % covered
    assert np.count_nonzero((back > 0) & ~union) < 0.01 * np.count_nonzero(known)
    k = np.ones((3, 3), np.uint8)
    near_w = cv2.dilate((wl == OCCUPIED).astype(np.uint8), k) > 0
    near_b = cv2.dilate((back == OCCUPIED).astype(np.uint8), k) > 0
    both = known & (back > 0)
    walls_ok = ((back == OCCUPIED) & both & near_w).sum() / max(1, ((back == OCCUPIED) & both).sum())
    walls_kept = ((wl == OCCUPIED) & both & near_b).sum() / max(1, ((wl == OCCUPIED) & both).sum())
    free_ok = ((back == FREE) & (wl == FREE) & both).sum() / max(1, ((wl == FREE) & both).sum())
    assert walls_ok > 0.97 and walls_kept > 0.97 and free_ok > 0.95, (walls_ok, walls_kept, free_ok)


def test_merge_maps_script_subprocess(tmp_path):
    _, ps = pieces('intel', 2, 0)
    paths = write_pieces(tmp_path, ps)
    env = dict(os.environ, PYTHONPATH=os.path.join(REPO, 'src'))
    r = subprocess.run([sys.executable, os.path.join(REPO, 'scripts', 'merge_maps')] + paths
                       + ['-o', str(tmp_path / 'm.yaml'), '--transforms', str(tmp_path / 'T.yaml'),
                          '--reference', 'robot1'], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    rep = yaml.safe_load(open(tmp_path / 'T.yaml'))
    assert rep['reference'] == 'robot1' and rep['maps']['robot0']['merged']
    d, a = pose_error(se2(rep['maps']['robot0']['x'], rep['maps']['robot0']['y'], rep['maps']['robot0']['yaw']),
                      truth(ps[1][1], ps[0][1]))
    assert d <= 0.10 and a <= 1.0
    assert 'robot0' in r.stdout and 'merged' in r.stdout


def test_core_merged_map_is_the_world():
    w, ps = pieces('house', 4, 3)
    m = MapMerger()
    for i, (g, _) in enumerate(ps):
        m.update_map('p%d' % i, g)
    m.estimate()
    assert len(m.placements()) == 4
    check_merged_is_the_world(m.compose(), w, ps, rects(w, 4))


def test_merge_maps_cli_reports_a_map_it_cannot_place(tmp_path):
    """A map of another building is listed with merged: false and a reason, exit status 0."""
    _, ps = pieces('intel', 2, 1)
    paths = write_pieces(tmp_path, ps)
    other = load_map(shared_file(HOUSE_MAP))
    save_map(other, str(tmp_path / 'house.yaml'))
    tf = str(tmp_path / 'T.yaml')
    assert cli.main(paths + [str(tmp_path / 'house.yaml'), '-o', str(tmp_path / 'm.yaml'),
                             '--transforms', tf]) == 0
    rep = yaml.safe_load(open(tf))
    assert set(rep['maps']) == {'robot1', 'house'}
    assert set(rep['maps']['house']) == {'merged', 'reason'}
    assert rep['maps']['house']['merged'] is False and rep['maps']['house']['reason']
    assert set(rep['maps']['robot1']) == MERGED_KEYS
