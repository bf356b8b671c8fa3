"""A SLAM map's drift from its frame's origin in a placement's covariance (core/drift.py)."""
import math

import cv2
import numpy as np
import pytest
from conftest import merged

from multi_map_merge.core import drift
from multi_map_merge.core.grid import FREE, OCCUPIED
from multi_map_merge.core.transforms import se2, xyyaw

RATE, YAW_RATE = 0.02, math.radians(0.4)


def test_the_drift_grows_with_the_overlaps_distance_from_both_origins():
    T = se2(10.0, 0.0, 0.5)                 # the child's origin 10 m from the parent's
    near_parent = drift.link_covariance((1.0, 0.0), T, RATE, YAW_RATE)      # 1 m and 9 m away
    midway = drift.link_covariance((5.0, 0.0), T, RATE, YAW_RATE)           # 5 m and 5 m
    assert np.allclose(near_parent, near_parent.T) and np.all(np.linalg.eigvalsh(near_parent) > 0)
    assert near_parent[2, 2] == pytest.approx(YAW_RATE ** 2 * 10.0)        # heading: a random walk
    assert midway[2, 2] == pytest.approx(YAW_RATE ** 2 * 10.0)
    # along the ways: each map's stretch only
    assert near_parent[0, 0] == pytest.approx(RATE ** 2 * (1.0 + 81.0))
    # across: the parent's turn swings the child's origin about the overlap (lever 9 m) and its
    # shift moves the overlap (q L^3 / 3, correlated); the child's turn and shift, undone about
    # the overlap, leave what its heading did along the way (q L^3 / 3 for its 9 m)
    q = YAW_RATE ** 2
    parent = q * (1.0 * 81.0 + 2.0 * 9.0 * 1.0 / 2.0 + 1.0 / 3.0)
    child = q * 729.0 / 3.0
    assert near_parent[1, 1] == pytest.approx(RATE ** 2 * 82.0 + parent + child)
    assert midway[1, 1] < near_parent[1, 1]
    assert np.allclose(drift.link_covariance((0.0, 0.0), se2(0.0, 0.0, 0.0), RATE, YAW_RATE), 0.0)
    assert np.allclose(drift.link_covariance((3.0, 4.0), T, 0.0, 0.0), 0.0)


def drawn_along(end, n, rng, yaw_rate, runs):
    """``runs`` maps drawn along a straight way from (0, 0) to ``end`` (metres) in ``n`` steps,
    their heading a random walk of ``yaw_rate`` radians per sqrt(metre): per run the heading
    turned at the way's end (radians) and the end's drawn place (metres)."""
    end = np.asarray(end, np.float64)
    length = float(np.hypot(*end))
    step = length / n
    walk = np.cumsum(rng.normal(0.0, yaw_rate * math.sqrt(step), (runs, n)), axis=1)
    heading = math.atan2(end[1], end[0]) + np.hstack([np.zeros((runs, 1)), walk[:, :-1]])
    drawn_end = step * np.stack([np.cos(heading).sum(1), np.sin(heading).sum(1)], axis=1)
    return walk[:, -1], drawn_end


def test_the_drift_is_what_maps_drawn_with_a_heading_walk_give_a_link():
    """Monte Carlo: two maps drawn along straight ways with heading random walks, the link
    fitted on their drawn overlap; its error's covariance is the model's."""
    rng = np.random.default_rng(3)
    true = se2(12.0, -4.0, 0.7)
    centre = np.array([6.0, 5.0])                          # the overlap, in the parent's frame
    centre_child = (np.linalg.inv(true) @ np.r_[centre, 1.0])[:2]
    yaw_rate, runs = math.radians(0.4), 4000
    turn_p, end_p = drawn_along(centre, 300, rng, yaw_rate, runs)
    turn_c, end_c = drawn_along(centre_child, 300, rng, yaw_rate, runs)
    errors = []
    for k in range(runs):
        # each map draws the overlap turned about its centre and moved to its drawn end; the link
        # maps the child's drawing onto the parent's
        drawn_parent = se2(*end_p[k], turn_p[k]) @ se2(*(-centre), 0.0)
        drawn_child = se2(*end_c[k], turn_c[k]) @ se2(*(-centre_child), 0.0)
        link = drawn_parent @ true @ np.linalg.inv(drawn_child)
        e = np.array(xyyaw(link)) - np.array(xyyaw(true))
        errors.append(e)
    empirical = np.cov(np.array(errors).T)
    model = drift.link_covariance(centre, true, 0.0, yaw_rate)
    scale = np.sqrt(np.outer(np.diag(model), np.diag(model)))
    assert np.all(np.abs(empirical - model) / scale < 0.08), (empirical, model)


@pytest.mark.slow
def test_drifting_maps_placements_are_within_their_ellipse_of_the_true_starts(house_team):
    """The house, seed 2, four simulated robots' drifting maps (conftest.house_team): every
    placement's error against where the robots really started lies within its 95% ellipse (x, y,
    yaw) with the maps' drift, and the walls alone would make every error at least twice as far
    (squared Mahalanobis distance): their ellipse is too narrow for maps that bend."""
    maps, starts = house_team

    def d2s(**cfg):
        m = merged(maps, reference_robot='tb3_0', workers=1, **cfg)
        out = {}
        for r, pl in m.placements().items():
            if r == 'tb3_0':
                continue
            true = np.linalg.inv(se2(*starts['tb3_0'])) @ se2(*starts[r])
            e = np.array(xyyaw(pl.T)) - np.array(xyyaw(true))
            e[2] = (e[2] + math.pi) % (2 * math.pi) - math.pi
            out[r] = (float(e @ np.linalg.solve(pl.cov, e)), pl.T)
        return out
    with_drift, walls_only = d2s(), d2s(map_drift=0.0, map_drift_yaw=0.0)
    assert set(with_drift) == set(walls_only) == {'tb3_1', 'tb3_2', 'tb3_3'}
    assert all(d2 < 7.81 for d2, _ in with_drift.values()), with_drift
    assert all(walls_only[r][0] > 2.0 * with_drift[r][0] for r in with_drift), (walls_only, with_drift)
    # the drift widens what the placement is known to; it does not move it
    for r in with_drift:
        assert np.allclose(with_drift[r][1], walls_only[r][1])


RES = 0.05


def rooms(levels, centre, turn_deg, size_m=8.0, spacing_m=2.0):
    """Walls of a square of rooms (``spacing_m`` apart) around ``centre`` (col, row), drawn
    turned by ``turn_deg`` counter-clockwise in the grid's cells."""
    c, s = math.cos(math.radians(turn_deg)), math.sin(math.radians(turn_deg))
    half = size_m / RES / 2.0
    for k in np.arange(-half, half + 1e-9, spacing_m / RES):
        for (a, b) in (((k, -half), (k, half)), ((-half, k), (half, k))):
            p = [(int(round(centre[0] + c * x - s * y)), int(round(centre[1] + s * x + c * y))) for x, y in (a, b)]
            cv2.line(levels, p[0], p[1], int(OCCUPIED), 1)


@pytest.fixture
def turned_map():
    """A map whose rooms at its origin (cell (100, 100)) are drawn square and whose rooms 20 m
    away are drawn turned by 12 degrees: its heading turned on the way."""
    levels = np.full((600, 600), FREE, np.uint8)
    rooms(levels, (100, 100), 0.0)
    rooms(levels, (500, 100), 12.0)
    return levels


def test_a_maps_turn_is_read_off_its_walls(turned_map):
    t = drift.turn(turned_map, RES, (100, 100), (500, 100))
    assert t is not None and abs(math.degrees(t) - 12.0) < 1.0, t
    assert abs(drift.turn(turned_map, RES, (500, 100), (100, 100)) + t) < 1e-9        # the way back turns back
    assert abs(math.degrees(drift.turn(turned_map, RES, (100, 100), (120, 110)))) < 0.5   # the same rooms


def test_walls_of_every_direction_or_none_say_nothing(turned_map):
    levels = turned_map.copy()
    rng = np.random.default_rng(0)
    for a in rng.uniform(0.0, math.pi, 40):        # a far place of walls in every direction
        p0 = (300 + int(70 * math.cos(a)), 500 + int(70 * math.sin(a)))
        p1 = (300 - int(70 * math.cos(a)), 500 - int(70 * math.sin(a)))
        cv2.line(levels, p0, p1, int(OCCUPIED), 1)
    assert drift.wall_direction(levels, RES, (300, 500)) is None
    assert drift.turn(levels, RES, (100, 100), (300, 500)) is None
    assert drift.wall_direction(levels, RES, (300, 300)) is None                 # no walls there
    assert drift.wall_direction(levels, RES, (-500, -500)) is None               # off the map


def test_a_turn_near_45_degrees_is_not_told_from_its_opposite():
    levels = np.full((600, 600), FREE, np.uint8)
    rooms(levels, (100, 100), 0.0)
    rooms(levels, (500, 100), 40.0)
    assert drift.turn(levels, RES, (100, 100), (500, 100)) is None


def test_a_measured_turn_widens_the_heading_and_the_position():
    T = se2(10.0, 0.0, 0.5)
    base = drift.link_covariance((4.0, 0.0), T, RATE, YAW_RATE)
    assert np.allclose(drift.link_covariance((4.0, 0.0), T, RATE, YAW_RATE, None, None), base)
    tp, tc = math.radians(20.0), math.radians(2.0)
    both = drift.link_covariance((4.0, 0.0), T, RATE, YAW_RATE, tp, tc)
    assert both[2, 2] == pytest.approx(base[2, 2] + (tp - tc) ** 2)
    # the overlap 4 m from the parent's origin and 6 m from the child's: shifted by a turn
    # anywhere on the longer way
    assert both[0, 0] == pytest.approx(base[0, 0] + ((tp - tc) * 6.0) ** 2 / 3.0)
    assert drift.link_turn(tp, None) == tp and drift.link_turn(None, None) == 0.0
    # both maps read alike (a building's wing, or a turn both made): nothing added
    assert np.allclose(drift.link_covariance((4.0, 0.0), T, RATE, YAW_RATE, tp, tp), base)


def test_the_status_names_what_each_robots_map_turned_against_the_others():
    from multi_map_merge.core.links import Link
    from multi_map_merge.core.status import _turns_apart

    def link(parent, child, parent_turn, child_turn):
        return Link(parent, child, np.eye(3), 0.5, 0.9, 30, 60, 0.0,
                    parent_turn=math.radians(parent_turn), child_turn=math.radians(child_turn))
    edges = {('a', 'b'): link('a', 'b', 22.0, 0.5), ('a', 'c'): link('a', 'c', 1.0, -2.0),
             ('b', 'c'): link('b', 'c', 3.0, -4.0),
             ('c', 'd'): Link('c', 'd', np.eye(3), 0.5, 0.9, 30, 60, 0.0, parent_turn=0.3)}   # d's unread
    degrees = {r: [(o, round(math.degrees(t), 1)) for o, t in _turns_apart(r, edges)] for r in 'abcd'}
    assert degrees['a'] == [('b', 21.5)]                 # a 3 degree turn apart is under REPORT_TURN
    assert degrees['b'] == [('a', -21.5), ('c', 7.0)]        # its own turn less the other's, largest first
    assert degrees['c'] == [('b', -7.0)]
    assert degrees['d'] == []
