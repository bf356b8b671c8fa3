import math

import numpy as np
import pytest


from multi_map_merge.mapio import load_map
from multi_map_merge.synth import cut_piece
from multi_map_merge.transforms import (apply, cell_to_metric, image_to_pose, pose_to_image,
                                        rigid_from_points, se2, xyyaw)
from conftest import DATA


def test_cell_to_metric_by_hand():
    W = cell_to_metric(0.05, (1.0, -2.0, 0.0))
    # centre of cell (col 0, row 0) is half a cell inside the origin corner
    assert apply(W, np.array([[0.0, 0.0]]))[0] == pytest.approx([1.025, -1.975])
    assert apply(W, np.array([[10.0, 4.0]]))[0] == pytest.approx([1.525, -1.775])
    Wr = cell_to_metric(0.1, (0.0, 0.0, math.pi / 2))   # grid turned 90 deg in its frame
    assert apply(Wr, np.array([[9.5, -0.5]]))[0] == pytest.approx([0.0, 1.0])


def test_image_pose_round_trip():
    T = se2(3.2, -1.1, 2.5)
    A = pose_to_image(T, 0.05, (-10, -10, 0), 0.05, (-4.3, 2.0, 0))
    assert np.linalg.det(A[:2, :2]) == pytest.approx(1.0)
    assert image_to_pose(A, 0.05, (-10, -10, 0), 0.05, (-4.3, 2.0, 0)) == pytest.approx(T)


def test_hand_made_shift_gives_pose():
    """A grid whose frame is the reference frame moved by 2 m in x, 1 m in y: the same wall
    cell is 40 columns and 20 rows further in the reference grid."""
    A = np.array([[1, 0, 40.0], [0, 1, 20.0], [0, 0, 1]])
    T = image_to_pose(A, 0.05, (0, 0, 0), 0.05, (0, 0, 0))
    assert xyyaw(T) == pytest.approx((2.0, 1.0, 0.0))
    # a 90 deg turn of the image about cell (0, 0) with identical origins at 0 is the frame turn
    R = np.array([[0, -1, 0.0], [1, 0, 0.0], [0, 0, 1]])
    T = image_to_pose(R, 0.05, (0, 0, 0), 0.05, (0, 0, 0))
    x, y, yaw = xyyaw(T)
    assert yaw == pytest.approx(math.pi / 2)
    # the cell-centre offset (half a cell) turns with it
    assert (x, y) == pytest.approx((0.05, 0.0))


def test_cut_piece_pose_matches_image_transform():
    w = load_map(DATA + '/intel.yaml')
    g, T = cut_piece(w, (200, 400, 300, 500), (2.0, -3.0, 2.0))
    A = pose_to_image(T, w.resolution, w.origin, g.resolution, g.origin)   # cells of g -> cells of w
    rr, cc = np.nonzero(g.data == 100)
    p = apply(A, np.stack([cc, rr], 1).astype(float))
    hit = w.data[np.clip(np.rint(p[:, 1]).astype(int), 0, w.height - 1),
                 np.clip(np.rint(p[:, 0]).astype(int), 0, w.width - 1)]
    assert (hit == 100).mean() > 0.9


def test_rigid_from_points_never_mirrors():
    rng = np.random.default_rng(1)
    src = rng.uniform(-5, 5, (30, 2))
    T = se2(1.0, 2.0, 0.7)
    assert rigid_from_points(src, apply(T, src)) == pytest.approx(T)
    mirrored = src * np.array([1, -1])
    M = rigid_from_points(src, mirrored)
    assert np.linalg.det(M[:2, :2]) == pytest.approx(1.0)
