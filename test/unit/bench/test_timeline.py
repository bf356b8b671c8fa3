"""bench/timeline.py's pure parts: the coverage of a ground truth by a map placed on it, the time
to a level, the snapshot period."""
import os
import sys

import numpy as np

BENCH = os.path.join(os.path.dirname(__file__), '..', '..', '..', 'bench')
sys.path.insert(0, os.path.abspath(BENCH))

from timeline import coverage, snapshot_every, time_to  # noqa: E402

from multi_map_merge.core.grid import Grid  # noqa: E402
from multi_map_merge.core.transforms import se2  # noqa: E402


def room(h=40, w=60):
    """A 2 x 3 m room at 0.05 m: a wall ring 2 cells thick around free floor (values -1/0/100)."""
    d = np.full((h, w), 100, np.int8)
    d[2:-2, 2:-2] = 0
    return d


def test_the_truth_covers_itself_and_a_half_map_covers_half():
    truth = Grid(room(), 0.05, (0.0, 0.0, 0.0))
    full = coverage(truth, truth, np.eye(3))
    assert full == {'free': 1.0, 'walls': 1.0}
    half = room()
    half[:, 30:] = -1                                 # the right half unknown
    c = coverage(Grid(half, 0.05, (0.0, 0.0, 0.0)), truth, np.eye(3))
    assert 0.45 < c['free'] < 0.55, c
    assert 0.35 < c['walls'] < 0.65, c


def test_the_wall_surface_not_its_inside():
    truth = Grid(room(), 0.05, (0.0, 0.0, 0.0))
    seen = room()
    seen[:1, :] = -1                                  # the outer row of the thick wall never seen
    seen[-1:, :] = -1
    seen[:, :1] = -1
    seen[:, -1:] = -1
    assert coverage(Grid(seen, 0.05, (0.0, 0.0, 0.0)), truth, np.eye(3))['walls'] == 1.0


def test_a_misplaced_map_covers_less_and_its_pose_restores_it():
    truth = Grid(room(), 0.05, (0.0, 0.0, 0.0))
    # the same room in a frame 1 m to the right: placed by its true pose it covers everything
    shifted = Grid(room(), 0.05, (-1.0, 0.0, 0.0))
    assert coverage(shifted, truth, se2(1.0, 0.0, 0.0)) == {'free': 1.0, 'walls': 1.0}
    off = coverage(shifted, truth, np.eye(3))
    assert off['free'] < 0.7 and off['walls'] < 0.7, off
    # the tolerance: 0.05 m off (one cell) is still within 0.10 m, 0.30 m is not
    assert coverage(shifted, truth, se2(1.05, 0.0, 0.0))['walls'] == 1.0
    assert coverage(shifted, truth, se2(1.30, 0.0, 0.0))['walls'] < 0.9


def test_time_to_a_level():
    series = [(5, 0.2), (10, 0.85), (15, 0.91), (20, 0.995)]
    assert time_to(series, 0.90) == 15.0
    assert time_to(series, 0.99) == 20.0
    assert time_to(series[:3], 0.99) is None
    assert time_to([], 0.9) is None


def test_snapshot_period():
    assert snapshot_every(460.6) == 5.0          # the home's lone robot
    assert snapshot_every(2182.6) == 20.0        # the Intel lab's: about 100 snapshots
    assert snapshot_every(10.0) == 5.0           # never below 5 s
