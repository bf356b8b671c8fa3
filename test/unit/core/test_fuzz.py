"""Hundreds of bad and strange inputs into the core: clear errors, no crash, no false merge."""

import numpy as np
import pytest
from conftest import INTEL_MAP, shared_file

from multi_map_merge.core.grid import Grid, GridError, apply_update, make_grid
from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.merger import MapMerger
from multi_map_merge.lab.pieces import bad_grids, cut_piece, random_poses, split_rects


def test_every_bad_grid_gets_a_reason():
    rng = np.random.default_rng(7)
    reasons = set()
    for data, w, h, res, origin in bad_grids(rng, 600):
        with pytest.raises(GridError) as e:
            make_grid(data, w, h, res, origin, max_cells=25_000_000)
        assert str(e.value)
        reasons.add(str(e.value).split(' ')[0])
    assert len(reasons) >= 5   # the reasons say different things for different faults


def test_bad_updates_raise():
    rng = np.random.default_rng(3)
    g = Grid(np.zeros((20, 30), np.int8), 0.05)
    for _ in range(300):
        x, y = int(rng.integers(-5, 35)), int(rng.integers(-5, 25))
        w, h = int(rng.integers(0, 40)), int(rng.integers(0, 30))
        n = w * h + int(rng.choice([0, 0, -1, 1]))
        data = rng.integers(-3, 105, max(0, n))
        ok = (0 <= x and 0 <= y and x + w <= 30 and y + h <= 20 and data.size == w * h
              and (data.size == 0 or (data.min() >= -1 and data.max() <= 100)))
        if ok:
            assert apply_update(g, x, y, w, h, data).data.shape == (20, 30)
        else:
            with pytest.raises(GridError):
                apply_update(g, x, y, w, h, data)
    assert (g.data == 0).all()


def strange_valid_grids(rng, n):
    """Valid grids no robot would make: noise, empty, 1x1, all walls, stripes."""
    for k in range(n):
        w, h = int(rng.integers(1, 300)), int(rng.integers(1, 300))
        kind = k % 6
        if kind == 0:
            d = rng.choice(np.array([-1, 0, 100], np.int8), size=(h, w))
        elif kind == 1:
            d = np.full((h, w), -1, np.int8)
        elif kind == 2:
            d = np.full((1, 1), int(rng.choice([-1, 0, 100])), np.int8)
        elif kind == 3:
            d = np.full((h, w), 100, np.int8)
        elif kind == 4:
            d = np.zeros((h, w), np.int8)
            d[:, ::7] = 100
        else:
            d = (rng.random((h, w)) < 0.02).astype(np.int8) * 100
        yield Grid(d, float(rng.choice([0.05, 0.1, 0.025])),
                   (float(rng.uniform(-50, 50)), float(rng.uniform(-50, 50)), float(rng.uniform(-3, 3))))


@pytest.mark.slow
def test_strange_maps_never_crash_or_merge():
    world = load_map(shared_file(INTEL_MAP))
    ps = [cut_piece(world, r, p)[0] for r, p in zip(split_rects(world, 2, 0.3), random_poses(2, 1))]
    m = MapMerger()
    m.update_map('a', ps[0])
    m.update_map('b', ps[1])
    m.estimate()
    assert set(m.placements()) == {'a', 'b'}
    before = m.compose()
    rng = np.random.default_rng(11)
    for i, g in enumerate(strange_valid_grids(rng, 60)):
        m.update_map('z%02d' % i, g)
    m.estimate()
    assert set(m.placements()) == {'a', 'b'}, 'a nonsense map was merged'
    after = m.compose()
    assert np.array_equal(before.data, after.data) and before.origin == after.origin
