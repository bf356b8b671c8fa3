import math

import numpy as np
import pytest
from conftest import INTEL_MAP, shared_file

from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import (
    apply,
    cell_to_metric,
    image_to_pose,
    pose_to_image,
    rigid_from_points,
    se2,
    xyyaw,
)
from multi_map_merge.lab.pieces import cut_piece


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
    w = load_map(shared_file(INTEL_MAP))
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


def _centroid(levels, value):
    rr, cc = np.nonzero(levels == value)
    assert rr.size, 'marker %d lost' % value
    return np.array([cc.mean(), rr.mean()])


@pytest.mark.parametrize('pose', [(2.0, -1.5, math.pi / 2), (-3.25, 0.7, -2.6), (0.4, 4.0, 0.3),
                                  (1.0, 1.0, math.pi)])
def test_image_to_pose_of_true_image_transform_is_the_pose(pose):
    """Grid B = grid A moved by a known pose (pieces.cut_piece). Two 3x3 markers (an occupied
    one and a free one, far apart, everything else unknown) give the true cell correspondence
    B -> A independently of pose_to_image; image_to_pose of it must be that pose."""
    from multi_map_merge.core.grid import FREE, OCCUPIED, Grid
    data = np.full((120, 150), -1, np.int8)
    data[19:22, 29:32] = 100          # occupied marker centred on (col 30, row 20)
    data[99:102, 119:122] = 0         # free marker centred on (col 120, row 100)
    world = Grid(data, 0.05, (-1.3, 2.1, 0.0))
    piece, T = cut_piece(world, (0, 120, 0, 150), pose)
    assert T == pytest.approx(se2(*pose))
    lv = piece.levels()
    assert np.count_nonzero(lv) in range(16, 21)          # both markers survive the warp
    src = np.array([_centroid(lv, OCCUPIED), _centroid(lv, FREE)])
    dst = np.array([[30.0, 20.0], [120.0, 100.0]])
    A_true = rigid_from_points(src, dst)                  # cells of B -> cells of A
    assert np.abs(apply(A_true, src) - dst).max() < 0.5  # a rigid fit exists: no mirror, no scale
    T_est = image_to_pose(A_true, world.resolution, world.origin, piece.resolution, piece.origin)
    x, y, yaw = xyyaw(T_est)
    assert math.hypot(x - pose[0], y - pose[1]) < 0.05              # within one cell
    assert abs((yaw - pose[2] + math.pi) % (2 * math.pi) - math.pi) < math.radians(0.6)


def test_pose_to_image_agrees_with_cut_piece_cells():
    """pose_to_image of the known pose maps the piece's marker onto the world's marker."""
    from multi_map_merge.core.grid import OCCUPIED, Grid
    data = np.full((60, 80), -1, np.int8)
    data[9:12, 59:62] = 100
    world = Grid(data, 0.1, (3.0, -4.0, 0.0))
    piece, T = cut_piece(world, (0, 60, 0, 80), (5.0, 5.0, 2.0))
    A = pose_to_image(T, world.resolution, world.origin, piece.resolution, piece.origin)
    assert apply(A, _centroid(piece.levels(), OCCUPIED)[None])[0] == pytest.approx([60.0, 10.0], abs=0.5)
