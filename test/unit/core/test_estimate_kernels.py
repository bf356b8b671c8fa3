"""The estimation kernels against plain reference computations (no ROS, no data files):
RANSAC's matrix-product residuals and its all-at-once refits, verification with a parent's
walls derived once, and the workers' single BLAS thread."""
import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import REPO

from multi_map_merge.core import matching, verify
from multi_map_merge.core.grid import FREE, OCCUPIED, known_bbox
from multi_map_merge.core.transforms import apply, rigid_from_points, se2

SRC = os.path.join(REPO, 'src')


def _matches(seed, n=300, inlier_share=0.4, noise=1.0):
    """(src, dst, true 3x3): ``inlier_share`` of the matches follow the true transform within
    ``noise`` cells, the rest land anywhere."""
    rng = np.random.default_rng(seed)
    T = se2(rng.uniform(-200, 200), rng.uniform(-200, 200), rng.uniform(-np.pi, np.pi))
    src = rng.uniform(0, 600, (n, 2))
    dst = apply(T, src) + rng.normal(0, noise, (n, 2))
    k = int(n * (1 - inlier_share))
    dst[:k] = rng.uniform(-300, 900, (k, 2))
    return src, dst, T


@pytest.mark.parametrize('seed', range(5))
def test_residuals_as_matrix_product_equal_direct_ones(seed):
    src, dst, _ = _matches(seed)
    rng = np.random.default_rng(100 + seed)
    a = rng.uniform(-np.pi, np.pi, 50)
    c, s, tx, ty = np.cos(a), np.sin(a), rng.uniform(-500, 500, 50), rng.uniform(-500, 500, 50)
    got = matching._hypothesis_terms(c, s, tx, ty) @ matching._match_terms(src, dst)
    ex = np.multiply.outer(c, src[:, 0]) - np.multiply.outer(s, src[:, 1]) + tx[:, None] - dst[:, 0]
    ey = np.multiply.outer(s, src[:, 0]) + np.multiply.outer(c, src[:, 1]) + ty[:, None] - dst[:, 1]
    assert np.abs(got - (ex * ex + ey * ey)).max() < 1e-6


def _refit_one(A, src, dst, th2):
    """The refit as it is specified, one hypothesis at a time: least squares on the inliers
    until the inlier set settles, never taking a fit that loses inliers (at most 5 fits)."""
    def inl(A):
        e = apply(A, src) - dst
        return (e * e).sum(axis=1) < th2
    mask = inl(A)
    for _ in range(5):
        if mask.sum() < 2:
            break
        A2 = rigid_from_points(src[mask], dst[mask])
        m2 = inl(A2)
        if m2.sum() < mask.sum():
            break
        A, same, mask = A2, np.array_equal(m2, mask), m2
        if same:
            break
    return A, mask


@pytest.mark.parametrize('seed', range(5))
def test_refits_all_at_once_equal_one_at_a_time(seed):
    src, dst, T = _matches(seed)
    rng = np.random.default_rng(200 + seed)
    # hypotheses near the truth (they gain inliers as they refit) and far from it
    a = np.arctan2(T[1, 0], T[0, 0]) + np.append(rng.normal(0, 0.002, 8), rng.uniform(-3, 3, 8))
    tx = T[0, 2] + np.append(rng.normal(0, 1, 8), rng.uniform(-300, 300, 8))
    ty = T[1, 2] + np.append(rng.normal(0, 1, 8), rng.uniform(-300, 300, 8))
    th2 = 9.0
    got = matching._refit_all(np.cos(a), np.sin(a), tx, ty, src, dst, matching._match_terms(src, dst), th2)
    assert len(got) == a.size
    for k, (A, mask) in enumerate(got):
        A0 = np.array([[np.cos(a[k]), -np.sin(a[k]), tx[k]], [np.sin(a[k]), np.cos(a[k]), ty[k]], [0, 0, 1.0]])
        B, ref_mask = _refit_one(A0, src, dst, th2)
        assert np.array_equal(mask, ref_mask)
        assert np.abs(A - B).max() < 1e-9
    # the near ones found the truth's inliers
    assert min(int(m.sum()) for _, m in got[:8]) >= 0.9 * 0.4 * len(src)


def test_ransac_finds_the_transform_among_outliers():
    src, dst, T = _matches(7, n=600, inlier_share=0.25)
    hyps = matching.ransac_rigid(src, dst, 3.0, 15000, seed=1, hypotheses=4)
    A, mask = hyps[0]
    assert mask.sum() >= 0.9 * 150
    centre = src.mean(axis=0, keepdims=True)
    assert np.hypot(*(apply(A, centre) - apply(T, centre))[0]) < 1.0


def _room_grids(seed):
    """Two overlapping grids of one room with a wall inside, the second turned and shifted:
    (levels of the parent, levels of the child, child cells -> parent cells)."""
    world = np.zeros((160, 200), np.uint8)
    world[20:140, 20:180] = FREE
    world[20, 20:180] = world[139, 20:180] = OCCUPIED
    world[20:140, 20] = world[20:140, 179] = OCCUPIED
    world[60:140, 90] = OCCUPIED
    rng = np.random.default_rng(seed)
    A = se2(rng.uniform(5, 15), rng.uniform(5, 15), rng.uniform(-0.3, 0.3))
    import cv2
    child = cv2.warpAffine(world, np.linalg.inv(A)[:2], (220, 200), flags=cv2.INTER_NEAREST,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    parent = world.copy()
    parent[:, 150:] = 0       # the parent has not seen the right end
    return parent, child, A


def _agreement_reference(parent, child, B, tol):
    """The verification score as specified, on the parent's whole grid: an occupied cell of
    either grid that lands on a known cell of the other agrees when the other has an occupied
    cell within ``tol`` cells, and conflicts when it lands on free space with none there."""
    import cv2
    h, w = parent.shape
    warped = cv2.warpAffine(child, B[:2], (w, h), flags=cv2.INTER_NEAREST,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    k = np.ones((2 * tol + 1, 2 * tol + 1), np.uint8)
    occ_p, occ_c = parent == OCCUPIED, warped == OCCUPIED
    near_p = cv2.dilate(occ_p.astype(np.uint8), k) > 0
    near_c = cv2.dilate(occ_c.astype(np.uint8), k) > 0
    overlap = int(np.count_nonzero((parent > 0) & (warped > 0)))
    agree = np.count_nonzero(occ_p & near_c) + np.count_nonzero(occ_c & near_p)
    conflict = (np.count_nonzero(occ_p & (warped == FREE) & ~near_c)
                + np.count_nonzero(occ_c & (parent == FREE) & ~near_p))
    return (agree / float(agree + conflict) if agree + conflict else 0.0), overlap


@pytest.mark.parametrize('seed', range(4))
def test_agreement_with_the_parents_walls_derived_once_is_as_specified(seed):
    parent, child, A = _room_grids(seed)
    boxes = (known_bbox(parent), known_bbox(child))
    walls = verify.Walls.of(parent, 2)
    for B in (A, A @ se2(3, -2, 0.05), A @ se2(40, 0, 0.0), A @ se2(0, 0, 1.0)):
        want_ag, want_overlap = _agreement_reference(parent, child, B, 2)
        # (the score warps the child onto a window of the parent: OpenCV's fixed-point
        # sampling can then pick the other cell of a tie, a few cells in ten thousand)
        for got_ag, got_overlap in (verify.agreement(parent, child, B, 2, boxes, walls),
                                    verify.agreement(parent, child, B, 2)):
            assert got_ag == pytest.approx(want_ag, abs=0.005)
            assert got_overlap == pytest.approx(want_overlap, rel=0.002)
    ag, overlap = verify.agreement(parent, child, A, 2, boxes, walls)
    assert ag > 0.95 and overlap > 5000
    assert verify.agreement(parent, child, A @ se2(40, 0, 0.0), 2, boxes, walls)[0] < 0.8


def _blas_threads_after(setup: str, call: str) -> str:
    """OpenBLAS's thread count in a fresh Python after ``setup`` (imports) and ``call`` (with
    the thread count first set to 2), or 'no openblas' where numpy's BLAS is another."""
    code = ('import ctypes, sys\n'
            'sys.path.insert(0, %r)\n'
            'import numpy\n'
            '%s\n'
            'try:\n'
            '    lib = ctypes.CDLL("libblas.so.3")\n'
            '    get = lib.openblas_get_num_threads\n'
            '    lib.openblas_set_num_threads(2)\n'
            'except (OSError, AttributeError):\n'
            '    print("no openblas"); sys.exit(0)\n'
            '%s\n'
            'print(get())\n' % (SRC, setup, call))
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    if out.stdout.strip() == 'no openblas':
        pytest.skip('numpy\'s BLAS here is not OpenBLAS')
    return out.stdout.strip()


def test_workers_run_blas_on_one_thread():
    """Where numpy's BLAS is OpenBLAS, a worker's initialiser leaves it one thread."""
    assert _blas_threads_after('from multi_map_merge.runtime.process import worker_init', 'worker_init()') == '1'


@pytest.mark.parametrize('seed', range(3))
def test_wall_field_offsets_name_the_labelled_nearest_walls(seed):
    """The wall field keeps each cell's offset to its nearest wall (int8) instead of the
    distance transform's label (int32): the wall found is the labelled one, for every cell."""
    import cv2

    from multi_map_merge.core.refine import WallField
    parent, _, _ = _room_grids(seed)
    f = WallField(parent)
    r0, c0 = int(f.offset[1]), int(f.offset[0])
    h, w = f.shape
    occ = parent[r0:r0 + h, c0:c0 + w] == OCCUPIED
    _, labels = cv2.distanceTransformWithLabels(np.where(occ, 0, 255).astype(np.uint8), cv2.DIST_L2, 5,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    rr, cc = np.nonzero(occ)
    idx = np.arange(h * w)
    wx, wy = f.walls(idx)
    near = f.dist_flat[:-1] <= 20
    assert near.sum() > 0.5 * h * w
    lab = labels.ravel()[near] - 1
    assert np.array_equal(wx[near], cc[lab] + c0)
    assert np.array_equal(wy[near], rr[lab] + r0)
    # the cells of those walls are walls of the grid, at the distance the field gives
    assert np.all(parent[wy[near].astype(int), wx[near].astype(int)] == OCCUPIED)
    d = np.hypot(wx[near] - (idx[near] % w + c0), wy[near] - (idx[near] // w + r0))
    assert np.allclose(d, f.dist_flat[:-1][near], atol=0.05 * d.max())


def test_wall_field_of_a_box_wider_than_32767_cells():
    """A box over 2^15 cells a side packs a wall's (col, row) in 64 bits: the offsets still
    name the nearest walls (a corridor 33000 cells long, walls along both sides)."""
    from multi_map_merge.core.refine import WallField
    levels = np.full((12, 33000), FREE, np.uint8)
    levels[1, :] = OCCUPIED
    levels[10, ::7] = OCCUPIED
    f = WallField(levels, margin=0)
    assert f.shape == (12, 33000)
    idx = np.arange(12 * 33000)
    wx, wy = f.walls(idx)
    assert np.all(levels[wy.astype(int), wx.astype(int)] == OCCUPIED)
    d = np.hypot(wx - idx % 33000, wy - idx // 33000)
    assert np.allclose(d, f.dist_flat[:-1], atol=0.05 * max(1.0, d.max()))
    assert wx[5 * 33000 + 32990] > 32000      # the far end's walls, not wrapped


@pytest.mark.parametrize('factor', [1, 2, 3, 5])
def test_maxpool_keeps_the_highest_level_of_each_block(factor):
    """Pooling for a coarse description: each pixel is the highest level of its factor x factor
    block of cells (blocks past the grid's edge count as unknown), on odd shapes too."""
    from multi_map_merge.core.features import _maxpool
    rng = np.random.default_rng(factor)
    for shape in [(1, 1), (7, 3), (64, 65), (301, 257)]:
        levels = rng.integers(0, 3, shape).astype(np.uint8)
        h, w = shape
        H, W = -(-h // factor), -(-w // factor)
        padded = np.zeros((H * factor, W * factor), np.uint8)
        padded[:h, :w] = levels
        expect = np.array([[padded[i * factor:(i + 1) * factor, j * factor:(j + 1) * factor].max()
                            for j in range(W)] for i in range(H)], np.uint8)
        got = _maxpool(levels, factor)
        assert got.dtype == np.uint8 and np.array_equal(got, expect)


def test_cost_table_in_16_bits_is_the_truncated_squared_distance():
    """covariance.CostField's uint16 table: min(distance, TRUNCATE)^2 to 1/COST_SCALE."""
    import cv2

    from multi_map_merge.core import covariance
    parent, _, _ = _room_grids(0)
    field = covariance.CostField(parent)
    box = known_bbox(parent)
    occ = parent[box[0]:box[1], box[2]:box[3]] == OCCUPIED
    dist = cv2.distanceTransform(np.where(occ, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)
    pad = int(box[2] - field.offset[0])
    got = field.cost[pad:pad + occ.shape[0], pad:pad + occ.shape[1]] / covariance.COST_SCALE
    want = np.minimum(dist, covariance.TRUNCATE) ** 2
    assert field.cost.dtype == np.uint16
    assert np.abs(got - want).max() <= 0.5 / covariance.COST_SCALE + 1e-6
    assert want.max() == covariance.TRUNCATE ** 2   # (the truncation is exercised)
    # the padding costs the truncation
    assert field.cost[0, 0] == field.big and field.big / covariance.COST_SCALE == pytest.approx(9.0, abs=1e-3)


def test_the_process_starting_the_pool_runs_blas_on_one_thread():
    """The node's own process (it places the robots: the pose graph's small solves) also runs
    OpenBLAS on one thread once it starts its worker pool."""
    assert _blas_threads_after('from multi_map_merge.core.workers import start_pool', 'start_pool(1)') == '1'
