"""A map that bends across a link's overlap (core/bend.py): the overlap's halves fitted on their
own, how far apart they land, and the model error it adds to the link's covariance."""
import math

import numpy as np
import pytest

from multi_map_merge.core import bend
from multi_map_merge.core.grid import OCCUPIED
from multi_map_merge.core.refine import WallField
from multi_map_merge.core.transforms import apply, se2

WINDOW = (60, 260, 40, 140)     # cols c0:c1, rows r0:r1 of the house's map: 10.5 m x 5.2 m


@pytest.fixture(scope='module')
def parent(house):
    lv = house.levels()
    return lv, WallField(lv), house.resolution


def window_walls(lv):
    c0, c1, r0, r1 = WINDOW
    rr, cc = np.nonzero(lv[r0:r1, c0:c1] == OCCUPIED)
    return np.stack([cc + c0, rr + r0], 1).astype(np.float64)


def bent(pts, degrees):
    """``pts`` with the part right of the window's middle turned by ``degrees`` about the
    middle: a map whose far half came out turned."""
    c0, c1, r0, r1 = WINDOW
    mid = np.array([(c0 + c1) / 2.0, (r0 + r1) / 2.0])
    R = se2(mid[0], mid[1], 0.0) @ se2(0.0, 0.0, math.radians(degrees)) @ se2(-mid[0], -mid[1], 0.0)
    out = pts.copy()
    right = pts[:, 0] > mid[0]
    out[right] = apply(R, pts[right])
    return out


def test_a_rigid_overlap_does_not_bend(parent):
    lv, field, res = parent
    b = bend.across_halves(field, window_walls(lv), np.eye(3), res)
    assert b is not None
    assert b.metres < 0.05                               # within a cell
    assert 2.0 * math.sqrt(max(b.cov_cells()[0, 0], b.cov_cells()[1, 1])) * res < 0.05


def test_a_bent_overlap_is_measured_and_widens_the_covariance(parent):
    lv, field, res = parent
    pts = window_walls(lv)
    # the far half turned by 1.5 degrees: its walls at the window's corners land
    # (half-diagonal) x 1.5 deg apart from where the near half's pose puts them
    c0, c1, r0, r1 = WINDOW
    expected = math.hypot((c1 - c0) / 2.0, (r1 - r0) / 2.0) * math.radians(1.5) * res
    b = bend.across_halves(field, bent(pts, 1.5), np.eye(3), res)
    assert b is not None
    assert 0.5 * expected < b.metres < 1.6 * expected, (b.metres, expected)
    assert abs(math.degrees(b.d[2])) > 0.7                # the halves' fits differ by the turn
    rigid = bend.across_halves(field, pts, np.eye(3), res)
    assert np.trace(b.cov_cells()) > 10 * np.trace(rigid.cov_cells()) + 1e-12


def test_too_few_walls_say_nothing(parent):
    lv, field, res = parent
    pts = window_walls(lv)
    assert bend.across_halves(field, pts[:bend.MIN_HALF_POINTS], np.eye(3), res) is None
    # a few cells across: too narrow to split
    narrow = pts[(pts[:, 0] >= 100) & (pts[:, 0] < 110) & (pts[:, 1] >= 40) & (pts[:, 1] < 50)]
    assert bend.across_halves(field, narrow, np.eye(3), res) is None
