
import numpy as np
import pytest

from multi_map_merge.core.grid import (
    FREE,
    OCCUPIED,
    UNKNOWN,
    Grid,
    GridError,
    apply_update,
    classify,
    make_grid,
    rescale,
    validate,
)
from multi_map_merge.core.mapio import MapFileError, grid_to_pgm, load_map, save_map


def test_classification_thresholds():
    v = np.array([-1, 0, 19, 20, 64, 65, 100], np.int8)
    assert list(classify(v)) == [UNKNOWN, FREE, FREE, UNKNOWN, UNKNOWN, OCCUPIED, OCCUPIED]


@pytest.mark.parametrize('kw, reason', [
    (dict(data=np.zeros(5)), r'data length 5 != width\*height'),
    (dict(width=0, height=0, data=np.zeros(0)), 'empty grid'),
    (dict(width=0, data=np.zeros(0)), 'empty grid: width=0'),
    (dict(height=0, data=np.zeros(0)), 'empty grid: width=4 height=0'),
    (dict(width=-4, height=-3), 'empty grid'),
    (dict(resolution=0.0), 'resolution must be'),
    (dict(resolution=-0.05), 'resolution must be'),
    (dict(resolution=float('nan')), 'resolution must be'),
    (dict(origin=(float('nan'), 0, 0)), 'origin is not finite'),
    (dict(origin=(0, float('inf'), 0)), 'origin is not finite'),
    (dict(origin=(0, 0, float('-inf'))), 'origin is not finite'),
    (dict(resolution=float('inf')), 'resolution must be'),
    (dict(data=np.array([0] * 11 + [101])), r'outside -1..100 \(min 0, max 101\)'),
    (dict(data=np.full(12, 120)), 'outside -1..100'),
    (dict(data=np.full(12, -5)), 'outside -1..100'),
    (dict(max_cells=10), 'too large: 4x3 = 12 cells > max_cells 10'),
])
def test_validate_rejects_with_reason(kw, reason):
    args = dict(data=np.zeros(12, np.int8), width=4, height=3, resolution=0.05, origin=(0, 0, 0))
    args.update(kw)
    with pytest.raises(GridError, match=reason):
        make_grid(**args)


def test_validate_accepts_the_edges():
    validate(np.array([-1, 0, 100, 50], np.int8).reshape(2, 2), 2, 2, 1e-3, (0, 0, 0), 4)


def test_make_grid_reshapes_row_major():
    g = make_grid(np.arange(12) % 2 * 100, 4, 3, 0.05, (1.0, 2.0, 0.0), 'tb3_1/map')
    assert g.data.shape == (3, 4) and g.data[0, 1] == 100 and g.data[1, 0] == 0
    assert g.frame_id == 'tb3_1/map' and g.origin == (1.0, 2.0, 0.0)


def test_pgm_round_trip_and_orientation(tmp_path):
    data = np.full((5, 7), -1, np.int8)
    data[0, 0] = 100          # row 0 = the origin row = the BOTTOM of the picture
    data[4, 6] = 0
    data[2, 1:4] = 100
    g = Grid(data, 0.1, (-1.5, 2.25, 0.0))
    save_map(g, str(tmp_path / 'm.yaml'))
    img = grid_to_pgm(g)
    assert img[4, 0] == 0 and img[0, 6] == 254 and img[0, 0] == 205
    back = load_map(str(tmp_path / 'm.yaml'))
    assert np.array_equal(back.data, data)
    assert back.resolution == pytest.approx(0.1) and back.origin[:2] == pytest.approx((-1.5, 2.25))


def test_load_real_map_orientation(tmp_path):
    """The intel map read back equals itself after a save (no double flip)."""
    from conftest import INTEL_MAP, shared_file
    g = load_map(shared_file(INTEL_MAP))
    save_map(g, str(tmp_path / 'i.yaml'))
    assert np.array_equal(load_map(str(tmp_path / 'i.yaml')).data, g.data)
    assert (g.data == 100).sum() > 10000 and (g.data == 0).sum() > 100000


def test_rescale_keeps_walls():
    data = np.zeros((40, 40), np.int8)
    data[:, 21] = 100                     # one-cell wall
    g = Grid(data, 0.05, (0, 0, 0))
    coarse = rescale(g, 0.1)
    assert coarse.data.shape == (20, 20) and coarse.resolution == 0.1
    assert (coarse.data == 100).any(axis=0).sum() >= 1 and (coarse.data == 100).all(axis=0).any()
    fine = rescale(coarse, 0.05)
    assert fine.data.shape == (40, 40)
    assert (fine.data[:, 20:22] == 100).all()


def test_apply_update():
    g = Grid(np.full((4, 5), -1, np.int8), 0.05)
    g2 = apply_update(g, 1, 2, 3, 2, np.array([0, 100, 0, 100, 0, 100]))
    assert g2.data[2, 1] == 0 and g2.data[2, 2] == 100 and g2.data[3, 3] == 100
    assert (g.data == -1).all()           # the original is untouched
    with pytest.raises(GridError):
        apply_update(g, 4, 0, 3, 1, np.zeros(3))
    with pytest.raises(GridError):
        apply_update(g, 0, 0, 2, 2, np.zeros(3))


def test_load_map_errors_name_the_file(tmp_path):
    with pytest.raises(MapFileError, match='nope.yaml'):
        load_map(str(tmp_path / 'nope.yaml'))
    (tmp_path / 'bad.yaml').write_text('image: missing.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n')
    with pytest.raises(MapFileError, match='bad.yaml.*cannot read image'):
        load_map(str(tmp_path / 'bad.yaml'))


def test_rescale_real_map_never_loses_a_wall():
    """intel at 0.05 m -> 0.1 m -> 0.05 m: every wall cell stays a wall (max-pooling), free
    space stays mostly free, and the origin corner does not move."""
    from conftest import INTEL_MAP, shared_file
    g = load_map(shared_file(INTEL_MAP))
    coarse = rescale(g, 0.1)
    assert coarse.origin == g.origin and coarse.resolution == 0.1
    assert coarse.data.shape == ((g.height + 1) // 2, (g.width + 1) // 2)
    rr, cc = np.nonzero(g.data == 100)
    assert (coarse.data[rr // 2, cc // 2] == 100).all()
    fine = rescale(coarse, 0.05)
    assert fine.data.shape == g.data.shape
    assert (fine.data[rr, cc] == 100).all()
    free = g.data == 0
    assert (fine.data[free] == 0).mean() > 0.8


def test_rescale_keeps_cells_in_place_and_edges():
    """Shrinking keeps the origin corner: fine cell (r, c) at 0.05 m lies in coarse cell
    (r // 2, c // 2) at 0.1 m, walls on the first and last rows/columns included (an odd size
    rounds up so nothing is cut off)."""
    d = np.zeros((5, 7), np.int8)
    d[0, :] = 100          # first row
    d[:, 6] = 100          # last column (odd width)
    d[4, 0] = 100          # last row (odd height)
    d[2, 3] = 100          # metric centre (0.175, 0.125) -> coarse cell (1, 1)
    c = rescale(Grid(d, 0.05, (1.0, 2.0, 0.0)), 0.1)
    assert c.data.shape == (3, 4)
    expect = np.zeros((3, 4), np.int8)
    expect[0, :] = 100
    expect[:, 3] = 100
    expect[2, 0] = 100
    expect[1, 1] = 100
    assert np.array_equal(c.data, expect), c.data
    # a non-integer factor: every wall still lands in the coarse cell containing its centre
    c = rescale(Grid(d, 0.05, (0, 0, 0)), 0.08)
    rr, cc = np.nonzero(d == 100)
    assert (c.data[((rr + 0.5) * 0.05 / 0.08).astype(int), ((cc + 0.5) * 0.05 / 0.08).astype(int)] == 100).all()
