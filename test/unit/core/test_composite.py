"""Step 5 by hand: warping onto the reference's lattice and compositing, cell by cell."""
import math

import numpy as np

from multi_map_merge.core.composite import Lattice, composite, lattice_for, warp_patch
from multi_map_merge.core.grid import Grid
from multi_map_merge.core.transforms import se2

RES = 0.5


def patch(grid: Grid, T: np.ndarray, lattice: Lattice):
    kv = grid.known_values()
    return None if kv is None else warp_patch(kv[1], kv[0], grid.resolution, grid.origin, T, lattice, 10**6)


def test_occupied_beats_free_beats_unknown_and_unsure_cells_are_unknown():
    # Reference: 3x4 cells, all free but one wall at row 1, col 2 and one unknown at row 0, col 0.
    a = Grid(np.zeros((3, 4), np.int8), RES, (0.0, 0.0, 0.0), 'a')
    a.data[1, 2] = 100
    a.data[0, 0] = -1
    # The other map: 2x2 cells at a whole-cell offset of (1, 1) cells from a's: a wall over a's
    # free cell (row 1, col 1), a free cell over a's wall (row 1, col 2), and a gmapping "not
    # sure" 50, which is unknown: over a's free cell (row 2, col 1) it adds nothing.
    b = Grid(np.array([[100, 0], [50, 0]], np.int8), RES, (0.0, 0.0, 0.0), 'b')
    lat = lattice_for(a)
    merged = composite([patch(a, np.eye(3), lat), patch(b, se2(RES, RES, 0.0), lat)], lat, 'map', 10**6)
    assert merged.data.dtype == np.int8
    assert merged.origin == (0.0, 0.0, 0.0) and merged.data.shape == (3, 4)
    expected = np.array([[-1, 0, 0, 0],
                         [0, 100, 100, 0],
                         [0, 0, 0, 0]], np.int8)
    assert (merged.data == expected).all()
    alone = composite([patch(b, np.eye(3), lattice_for(b))], lattice_for(b), 'map', 10**6)
    assert (alone.data == [[100, 0], [-1, 0]]).all()


def test_a_turned_map_lands_on_the_cells_it_covers_and_grows_the_canvas():
    a = Grid(np.zeros((2, 2), np.int8), RES, (0.0, 0.0, 0.0), 'a')
    # b: one row of three cells, a wall at its far end, turned a quarter to the left about its
    # frame's origin and moved 2 cells right: its cells run up the lattice's column 2, from row 0.
    b = Grid(np.array([[0, 0, 100]], np.int8), RES, (0.0, 0.0, 0.0), 'b')
    T = se2(3 * RES, 0.0, math.pi / 2)
    lat = lattice_for(a)
    merged = composite([patch(a, np.eye(3), lat), patch(b, T, lat)], lat, 'map', 10**6)
    assert merged.data.shape == (3, 3) and merged.origin == (0.0, 0.0, 0.0)
    assert (merged.data[:, 2] == [0, 0, 100]).all()          # b, turned
    assert (merged.data[:2, :2] == 0).all()                  # a
    assert (merged.data[2, :2] == -1).all()                  # nobody's


def test_a_map_with_nothing_known_adds_no_patch():
    a = Grid(np.full((3, 3), -1, np.int8), RES, (0.0, 0.0, 0.0), 'a')
    assert patch(a, np.eye(3), lattice_for(a)) is None
    assert composite([None], lattice_for(a), 'map', 10**6) is None
