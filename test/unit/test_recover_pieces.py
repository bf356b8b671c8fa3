"""Pieces cut out of real maps, moved by known poses, recovered within 2 cells and 1 degree."""
import os
import subprocess

import numpy as np
import pytest
import yaml

from multi_map_merge import cli
from multi_map_merge.mapio import load_map, save_map
from multi_map_merge.merger import MapMerger
from multi_map_merge.synth import cut_piece, random_poses, split_rects
from multi_map_merge.transforms import se2
from conftest import DATA, REPO, pose_error, truth

CASES = [(world, n, seed) for world in ('intel', 'aws_small_house') for n in (2, 3, 4) for seed in (0, 1)]


def pieces(world, n, seed):
    w = load_map(os.path.join(DATA, world + '.yaml'))
    return w, [cut_piece(w, r, p, 'p%d' % i)
               for i, (r, p) in enumerate(zip(split_rects(w, n, 0.3), random_poses(n, seed, 5.0)))]


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


def check_report(report, ps, stems):
    assert set(report) >= {'reference', 'maps'} and report['reference'] == stems[0]
    assert set(report['maps']) == set(stems[1:])
    for i, s in enumerate(stems[1:], 1):
        r = report['maps'][s]
        assert r['merged'] is True
        assert {'x', 'y', 'yaw', 'reliability', 'inliers'} <= set(r)
        assert 0 < r['reliability'] <= 1 and r['inliers'] >= 10
        d, a = pose_error(se2(r['x'], r['y'], r['yaw']), truth(ps[0][1], ps[i][1]))
        assert d <= 0.10 and a <= 1.0


def write_pieces(tmp_path, ps):
    paths = []
    for i, (g, _) in enumerate(ps):
        p = str(tmp_path / ('robot%d.yaml' % i))
        save_map(g, p)
        paths.append(p)
    return paths


@pytest.mark.parametrize('world, n', [('intel', 4), ('aws_small_house', 3)])
def test_merge_maps_cli(tmp_path, world, n):
    w, ps = pieces(world, n, 2)
    paths = write_pieces(tmp_path, ps)
    out, tf = str(tmp_path / 'merged.yaml'), str(tmp_path / 'T.yaml')
    assert cli.main(paths + ['-o', out, '--transforms', tf]) == 0
    check_report(yaml.safe_load(open(tf)), ps, ['robot%d' % i for i in range(n)])
    # the merged map, seen in the world frame, is the world's content
    merged = load_map(out)
    assert merged.resolution == pytest.approx(w.resolution)
    from multi_map_merge.transforms import apply, cell_to_metric, inverse
    rr, cc = np.nonzero(merged.data == 100)
    pts = apply(inverse(cell_to_metric(w.resolution, w.origin)) @ ps[0][1]
                @ cell_to_metric(merged.resolution, merged.origin), np.stack([cc, rr], 1).astype(float))
    ij = np.rint(pts).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < w.width) & (ij[:, 1] >= 0) & (ij[:, 1] < w.height)
    assert ok.mean() > 0.99
    near = np.zeros(ij.shape[0], bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            r = np.clip(ij[:, 1] + dr, 0, w.height - 1)
            c = np.clip(ij[:, 0] + dc, 0, w.width - 1)
            near |= w.data[r, c] == 100
    assert near.mean() > 0.97, 'merged walls off the world walls: %.3f' % near.mean()
    # and it covers the union of the pieces (nearly all of the world's known cells in them)
    known_world = sum(int((g.data >= 0).sum()) for g, _ in ps)
    assert (merged.data >= 0).sum() >= 0.5 * known_world


def test_merge_maps_script_subprocess(tmp_path):
    _, ps = pieces('intel', 2, 0)
    paths = write_pieces(tmp_path, ps)
    env = dict(os.environ, PYTHONPATH=os.path.join(REPO, 'src'))
    r = subprocess.run(['/usr/bin/python3', os.path.join(REPO, 'scripts', 'merge_maps')] + paths
                       + ['-o', str(tmp_path / 'm.yaml'), '--transforms', str(tmp_path / 'T.yaml'),
                          '--reference', 'robot1'], capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stderr
    rep = yaml.safe_load(open(tmp_path / 'T.yaml'))
    assert rep['reference'] == 'robot1' and rep['maps']['robot0']['merged']
    d, a = pose_error(se2(rep['maps']['robot0']['x'], rep['maps']['robot0']['y'], rep['maps']['robot0']['yaw']),
                      truth(ps[1][1], ps[0][1]))
    assert d <= 0.10 and a <= 1.0
    assert 'robot0' in r.stdout and 'merged' in r.stdout
