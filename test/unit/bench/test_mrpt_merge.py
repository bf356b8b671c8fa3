"""bench/mrpt_merge.py (MRPT's CGridMapAligner through bench/mrpt_grid_align.cpp, built here on
first use) on a case of known truth: two overlapping crops of the Intel lab's ground-truth map,
the second rotated by a known angle; the recovered pose within 0.1 m and 1 degree. Skips when
../shared/data or libmrpt-dev is absent."""
import math
import os
import sys

import numpy as np
import pytest

REPO = os.path.abspath(os.path.join(os.path.dirname(__file__), '..', '..', '..'))
sys.path.insert(0, os.path.join(REPO, 'bench'))
sys.path.insert(0, os.path.join(REPO, 'src'))

import mrpt_merge  # noqa: E402

INTEL = os.path.join(REPO, '..', 'shared', 'data', 'ground_truth', 'intel_gt.yaml')


def _needs():
    if not os.path.exists(INTEL):
        pytest.skip('../shared/data is absent: no intel_gt.yaml for the known case')
    ok, why = mrpt_merge.available()
    if not ok:
        pytest.skip(why)


def write_case(tmp, angle_deg):
    """A.yaml (left 65 % of the map, in the map's own frame) and B.yaml (right 65 %, rotated by
    ``angle_deg`` about its centre, origin 0): returns the paths and B's true pose in A's frame."""
    import cv2

    from multi_map_merge.core.grid import Grid
    from multi_map_merge.core.mapio import load_map, save_map
    g = load_map(INTEL)
    res, (ox, oy, _) = g.resolution, g.origin
    w = g.width
    cut = int(w * 0.65)
    a = Grid(np.ascontiguousarray(g.data[:, :cut]), res, (ox, oy, 0.0), frame_id='A')
    c0 = w - cut                                 # B's first column in the whole map
    crop = np.ascontiguousarray(g.data[:, c0:])
    h, wc = crop.shape
    side = int(math.ceil(math.hypot(h, wc))) + 2
    th = math.radians(angle_deg)
    c, s = math.cos(th), math.sin(th)
    ci, ci2 = np.array([(wc - 1) / 2.0, (h - 1) / 2.0]), np.array([(side - 1) / 2.0] * 2)
    # index space (column, row; rows upwards, as the metric y): dst = R (src - ci) + ci2
    R = np.array([[c, -s], [s, c]])
    M = np.hstack([R, (ci2 - R @ ci)[:, None]])
    codes = np.where(crop < 0, 1, np.where(crop >= 50, 2, 0)).astype(np.uint8)   # free 0, unknown 1, occupied 2
    rot = cv2.warpAffine(codes, M, (side, side), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=1)
    data = np.where(rot == 2, 100, np.where(rot == 0, 0, -1)).astype(np.int8)
    b = Grid(data, res, (0.0, 0.0, 0.0), frame_id='B')
    pa, pb = os.path.join(tmp, 'A.yaml'), os.path.join(tmp, 'B.yaml')
    save_map(a, pa)
    save_map(b, pb)
    # metric: p_B = R (p_crop - res (ci + 0.5)) + res (ci2 + 0.5), p_map = p_crop + corner of the crop
    corner = np.array([ox + c0 * res, oy])
    t = corner + res * (ci + 0.5) - R.T @ (res * (ci2 + 0.5))
    T = np.eye(3)
    T[:2, :2], T[:2, 2] = R.T, t
    return pa, pb, T


@pytest.mark.parametrize('angle', [40.0, -125.0])
def test_mrpt_recovers_a_known_rotation_and_shift(tmp_path, angle):
    _needs()
    pa, pb, truth = write_case(str(tmp_path), angle)
    rep, poses, grids = mrpt_merge.merge([pa, pb], reference='A', seed=1)
    got = rep['maps']['B']
    assert got['merged'], rep['pairs']
    d = math.hypot(got['x'] - truth[0, 2], got['y'] - truth[1, 2])
    yaw_t = math.atan2(truth[1, 0], truth[0, 0])
    dyaw = abs(math.degrees(math.atan2(math.sin(got['yaw'] - yaw_t), math.cos(got['yaw'] - yaw_t))))
    assert d < 0.1 and dyaw < 1.0, (got, truth)


def test_the_command_line_writes_the_merged_map_and_the_transforms(tmp_path):
    _needs()
    import yaml
    pa, pb, _ = write_case(str(tmp_path), 40.0)
    out, tf = str(tmp_path / 'm.yaml'), str(tmp_path / 'T.yaml')
    assert mrpt_merge.main([pa, pb, '-o', out, '--transforms', tf, '--reference', 'A']) == 0
    rep = yaml.safe_load(open(tf))
    assert rep['reference'] == 'A' and rep['maps']['B']['merged'] and rep['maps']['B']['parent'] == 'A'
    assert os.path.exists(out) and os.path.exists(str(tmp_path / 'm.pgm'))


def test_the_spanning_tree_keeps_the_best_links_and_leaves_unlinked_maps_out():
    T = np.eye(3)
    pairs = [{'i': 0, 'j': 1, 'kept': True, 'quality': 0.4, 'T': T},
             {'i': 0, 'j': 2, 'kept': True, 'quality': 0.3, 'T': T},
             {'i': 1, 'j': 2, 'kept': True, 'quality': 0.9, 'T': T},
             {'i': 0, 'j': 3, 'kept': False}]
    tree = mrpt_merge.spanning_tree(4, pairs, 0)
    assert sorted(tree) == [0, 1, 2] and tree[1][0] == 0 and tree[2][0] == 1


def test_without_mrpt_it_says_so(monkeypatch):
    monkeypatch.setattr(mrpt_merge, 'HEADER', '/nonexistent/CGridMapAligner.h')
    assert mrpt_merge.available() == (False, 'MRPT not installed (libmrpt-dev): not measured')
    assert mrpt_merge.main(['a.yaml', 'b.yaml', '-o', 'm.yaml']) == 3
