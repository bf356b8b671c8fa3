"""lab/drives.py's planned drive (issue 22's sweeps on the maps with no log): it tours the whole
free space clear of walls, and its simulated ranges end on walls."""
import math

import cv2
import numpy as np
import pytest

from multi_map_merge.core.grid import FREE
from multi_map_merge.core.transforms import cell_to_metric, inverse
from multi_map_merge.lab import drives


@pytest.fixture(scope='module')
def house_drive(house):
    return drives.planned_drive(house)


def test_a_planned_drive_tours_the_house_clear_of_walls_and_its_ranges_end_on_walls(house, house_drive):
    poses, ranges, angles = house_drive
    lv = house.levels()
    Winv = inverse(cell_to_metric(house.resolution, house.origin))

    def cells(xy):
        c = np.rint(xy @ Winv[:2, :2].T + Winv[:2, 2]).astype(int)
        return c[:, 1], c[:, 0]
    # every pose on free space, CLEARANCE from anything not free; steps of STEP or less
    far = np.ones(lv.shape, np.uint8)
    far[lv != FREE] = 0
    dist = cv2.distanceTransform(far, cv2.DIST_L2, 5) * house.resolution
    assert dist[cells(poses[:, :2])].min() >= drives.CLEARANCE - house.resolution
    steps = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    assert steps.max() <= drives.STEP + 2 * house.resolution and steps.min() > 0
    # its scans see nearly all of the house
    seen = drives.seen(house, poses, ranges, angles)
    assert seen[lv > 0].mean() > 0.95, seen[lv > 0].mean()
    # a return ends on a cell that is not free, the beam ran through free space up to it, and
    # a beam with no return saw only free space as far as it could
    k = np.nonzero(ranges > 0)
    p, r = poses[k[0]], ranges[k].astype(float)
    u = np.stack([np.cos(p[:, 2] + angles[k[1]]), np.sin(p[:, 2] + angles[k[1]])], 1)
    assert np.mean(lv[cells(p[:, :2] + r[:, None] * u)] != FREE) > 0.995   # (float32 ranges: a few
    # end on a cell boundary and round the other way)
    for f in (0.25, 0.5, 0.9):
        assert np.mean(lv[cells(p[:, :2] + (f * r - 0.5 * house.resolution)[:, None] * u)] == FREE) > 0.995
    assert np.mean(ranges > 0) > 0.9
    assert len(poses) > 100 and math.isclose(angles[-1] - angles[0], math.pi)


def known_in_world(house, piece):
    """Boolean mask over ``house``'s cells of a chain piece's known cells (its frame moved back)."""
    g, T = piece
    M = inverse(cell_to_metric(g.resolution, g.origin)) @ inverse(T) @ cell_to_metric(house.resolution,
                                                                                      house.origin)
    lv = cv2.warpAffine(g.levels(), M[:2], house.data.shape[::-1], flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP)
    return lv > 0


def test_a_strict_chain_overlaps_only_neighbours(house, house_drive, monkeypatch):
    # robots seeing 3 m: at 8 m every stretch of a tour of this small house sees most of it
    monkeypatch.setattr(drives, 'MAX_RANGE', 3.0)
    n = 5
    loose = [known_in_world(house, p) for p in drives.chain(house, *house_drive, n, 0)]
    strict = [known_in_world(house, p) for p in drives.chain(house, *house_drive, n, 0, strict=True)]

    def shared(ms, i, j):
        return int((ms[i] & ms[j]).sum())
    far = [(i, j) for i in range(n) for j in range(i + 2, n)]
    # the tour comes back to places: the plain chain's far-apart stretches overlap, the strict one's do not
    assert max(shared(loose, i, j) for i, j in far) > 1000
    assert max(shared(strict, i, j) for i, j in far) < 50          # (a cell's rounding at the cut)
    assert min(shared(strict, i, i + 1) for i in range(n - 1)) > 1000
    # every robot keeps part of its stretch, and nothing it did not see
    assert all(m.sum() > 0.05 * lm.sum() and (m & ~lm).sum() < 50 for m, lm in zip(strict, loose))
