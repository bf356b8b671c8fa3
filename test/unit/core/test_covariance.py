"""How well a link is pinned (core/covariance.py): a corridor pins across, not along; a corner
pins both; on a real map the true pose is found and covered."""
import math

import numpy as np
import pytest
from conftest import truth

from multi_map_merge.core import covariance as cv
from multi_map_merge.core.grid import FREE, OCCUPIED
from multi_map_merge.core.transforms import pose_to_image, se2, xyyaw
from multi_map_merge.lab.pieces import cut_piece, split_rects


def corridor(c0, c1, width=30, end_wall=False):
    """Levels of a straight corridor along the columns c0..c1 (rows 100..100 + width)."""
    lv = np.zeros((300, 400), np.uint8)
    lv[100:100 + width, c0:c1] = FREE
    lv[100, c0:c1] = OCCUPIED
    lv[100 + width, c0:c1] = OCCUPIED
    if end_wall:
        lv[100:101 + width, c1] = OCCUPIED
    return lv


def test_a_corridor_pins_across_not_along():
    # the child saw the middle of a corridor the parent saw longer: it may slide along it
    p = cv.pinning(corridor(20, 380), corridor(100, 300), se2(0.0, 0.0, 0.0))
    along, across = math.sqrt(p.cov[0, 0]), math.sqrt(p.cov[1, 1])
    assert along > 5.0 and across < 1.0, (along, across)
    assert math.degrees(math.sqrt(p.cov[2, 2])) < 0.5
    # of equally good poses the given one is kept
    assert np.allclose(p.A, np.eye(3))


def test_a_corridor_end_pins_both():
    p = cv.pinning(corridor(20, 380, end_wall=True), corridor(100, 380, end_wall=True), se2(0.0, 0.0, 0.0))
    sx, sy = math.sqrt(p.cov[0, 0]), math.sqrt(p.cov[1, 1])
    assert sx < 1.0 and sy < 1.0, (sx, sy)


def test_a_pose_off_along_the_corridor_end_is_found_and_covered():
    # the link is 3 cells short along the corridor, 1 across: the walls' end says where it is
    A = se2(-3.0, 1.0, 0.0)
    p = cv.pinning(corridor(20, 380, end_wall=True), corridor(100, 380, end_wall=True), A)
    assert np.allclose(p.A[:2, 2], 0.0, atol=0.6), p.A
    e = np.array([3.0, -1.0, 0.0])               # truth minus the given pose, in the parent's cells
    # about the best pose the given one is clearly off; the moments about the given pose count
    # the offset in, so its covariance still covers the truth
    assert e @ np.linalg.solve(p.cov_best, e) > 7.81
    assert e @ np.linalg.solve(p.cov, e) < 7.81
    assert p.cost_best < p.cost


def test_real_map_offset_covered(intel):
    """Two overlapping pieces of the Intel lab at known poses: a link a little off (2 cells, half
    a degree) is brought back within a cell of the truth, and its error is inside the
    covariance's 95% ellipse."""
    rs = split_rects(intel, 2, 0.3)
    (ga, Ta), (gb, Tb) = cut_piece(intel, rs[0], (1.0, 2.0, 0.4)), cut_piece(intel, rs[1], (-2.0, 0.5, -1.2))
    A_true = pose_to_image(truth(Ta, Tb), ga.resolution, ga.origin, gb.resolution, gb.origin)
    off = se2(2.0, -1.0, math.radians(0.5))
    p = cv.pinning(ga.levels(), gb.levels(), off @ A_true)
    d = p.A @ np.linalg.inv(A_true)
    assert math.hypot(d[0, 2], d[1, 2]) < 1.5 and abs(math.degrees(math.atan2(d[1, 0], d[0, 0]))) < 0.3
    # the truth as a perturbation of the given pose (a shift of the walls' centre, a turn about
    # it: cov's terms) lies inside the 95% ellipse (chi-square, 3 dof)
    P = A_true @ np.linalg.inv(off @ A_true)
    c = np.append(p.centre, 1.0)
    e = np.array([*(P @ c - c)[:2], math.atan2(P[1, 0], P[0, 0])])
    assert float(e @ np.linalg.solve(p.cov, e)) < 7.81, (e, p.cov)
    # at the truth itself the truth is inside the 95% ellipse
    p0 = cv.pinning(ga.levels(), gb.levels(), A_true)
    assert p0.cost <= p0.cost_best + 1e-9 or np.allclose(p0.A, A_true, atol=1.0)
    assert math.sqrt(p0.cov[0, 0]) < 2.0 and math.sqrt(p0.cov[1, 1]) < 2.0


def test_no_overlap_says_nothing():
    lv = corridor(20, 380)
    assert cv.pinning(lv, lv, se2(1000.0, 0.0, 0.0)) is None
    assert cv.pinning(np.zeros_like(lv), lv, np.eye(3)) is None


def test_metric_covariance_units_and_lever():
    res = 0.05
    # a translation-only covariance in cells becomes metres^2 (a map origin's yaw turns it)
    c = np.diag([4.0, 1.0, 0.0])
    m = cv.metric_covariance(c, np.zeros(2), se2(0.0, 0.0, 0.0), res, (0.0, 0.0, 0.0))
    assert np.allclose(np.diag(m), [4 * res ** 2, res ** 2, 0.0])
    m = cv.metric_covariance(c, np.zeros(2), se2(0.0, 0.0, 0.0), res, (0.0, 0.0, math.pi / 2))
    assert np.allclose(np.diag(m), [res ** 2, 4 * res ** 2, 0.0])
    # a turn about the walls' centre, 10 m from the child frame's origin along y, moves that
    # origin along x by 10 m x the turn
    s = math.radians(0.5)
    W_centre = np.array([0.0, 0.0])            # cell (0, 0): metres (res/2, res/2)
    T = se2(res / 2, res / 2 + 10.0, 0.3)
    m = cv.metric_covariance(np.diag([0.0, 0.0, s ** 2]), W_centre, T, res, (0.0, 0.0, 0.0))
    assert m[0, 0] == pytest.approx((10.0 * s) ** 2) and m[1, 1] == pytest.approx(0.0, abs=1e-12)
    assert m[2, 2] == pytest.approx(s ** 2) and m[0, 2] == pytest.approx(-10.0 * s ** 2)
    assert cv.position_sigma(m) == pytest.approx(10.0 * s)
    assert xyyaw(T)[2] == pytest.approx(0.3)


def test_kept_links_carry_their_covariance(intel):
    """A merger's kept links carry the covariance computed on the grids, in status and in the
    exported state, and a restored link takes it back."""
    from multi_map_merge.core.config import MergeConfig
    from multi_map_merge.core.merger import MapMerger
    rs = split_rects(intel, 2, 0.3)
    ps = [cut_piece(intel, r, p) for r, p in zip(rs, [(1.0, 2.0, 0.4), (-2.0, 0.5, -1.2)])]
    m = MapMerger(MergeConfig(workers=1))
    m.update_map('a', ps[0][0])
    m.update_map('b', ps[1][0])
    m.estimate()
    st = m.status()
    assert st['b'].link_covariances and st['b'].link_covariances == st['a'].link_covariances
    a, b, C = st['b'].link_covariances[0]
    assert (a, b) == ('a', 'b') and C.shape == (3, 3) and np.all(np.linalg.eigvalsh(C) > 0)
    # the link is placed within 0.1 m: its 2-sigma is of that order, not metres nor microns
    assert 0.01 < 2 * cv.position_sigma(C) < 0.3
    e = m.export_state()['edges'][0]
    assert np.allclose(np.array(e['cov']).reshape(3, 3), C)
    assert e['sigma_position'] == pytest.approx(cv.position_sigma(C))
    m2 = MapMerger(MergeConfig(workers=1))
    assert m2.restore_state(m.export_state()) == 1
    assert np.allclose(m2._linker.ledger.restored[('a', 'b')].cov, C)


def _input(name, levels):
    from multi_map_merge.core.pair import PairInput
    return PairInput(name, 1, levels, 0.05, (0.0, 0.0, 0.0), None, owner='test_covariance')


@pytest.mark.parametrize('dx', [0.0, -4.0])
def test_a_better_pose_found_by_the_search_is_taken(dx):
    """An accepted link 4 cells short along a corridor whose end both maps saw (and off by a
    fraction of a cell across) is moved to where the walls meet; a right link stays as it is."""
    from multi_map_merge.core import pair, verify
    from multi_map_merge.core.config import MergeConfig
    c = MergeConfig()
    pa = _input('pa%d' % dx, corridor(20, 380, end_wall=True))
    ch = _input('ch%d' % dx, corridor(100, 380, end_wall=True))
    A = se2(dx, 0.0, 0.0)
    ag, ov = verify.agreement(pa.levels, ch.levels, A, c.agreement_tolerance)
    r = pair.PairResult(A.copy(), agreement=ag, overlap=ov, accepted=True)
    pair._pin(c, pa, ch, r)
    assert np.allclose(r.A, np.eye(3), atol=1e-6), r.A
    assert r.agreement >= ag and r.cov is not None
    # the taken pose's covariance is about the pose taken: the 4 cells are not in it
    assert 2 * cv.position_sigma(r.cov) < 0.1
