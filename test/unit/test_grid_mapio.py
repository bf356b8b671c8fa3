
import numpy as np
import pytest

from multi_map_merge.grid import (FREE, OCCUPIED, UNKNOWN, Grid, GridError, apply_update, classify,
                                  make_grid, rescale)
from multi_map_merge.mapio import MapFileError, grid_to_pgm, load_map, save_map


def test_classification_thresholds():
    v = np.array([-1, 0, 19, 20, 64, 65, 100], np.int8)
    assert list(classify(v)) == [UNKNOWN, FREE, FREE, UNKNOWN, UNKNOWN, OCCUPIED, OCCUPIED]


@pytest.mark.parametrize('kw, reason', [
    (dict(data=np.zeros(5)), r'data length 5 != width\*height'),
    (dict(width=0, height=0, data=np.zeros(0)), 'empty grid'),
    (dict(resolution=0.0), 'resolution must be'),
    (dict(resolution=-0.05), 'resolution must be'),
    (dict(resolution=float('nan')), 'resolution must be'),
    (dict(origin=(float('nan'), 0, 0)), 'origin is not finite'),
    (dict(origin=(0, float('inf'), 0)), 'origin is not finite'),
    (dict(data=np.full(12, 120)), 'outside -1..100'),
    (dict(data=np.full(12, -5)), 'outside -1..100'),
    (dict(max_cells=10), 'too large'),
])
def test_validate_rejects_with_reason(kw, reason):
    args = dict(data=np.zeros(12, np.int8), width=4, height=3, resolution=0.05, origin=(0, 0, 0))
    args.update(kw)
    with pytest.raises(GridError, match=reason):
        make_grid(**args)


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
    """The shipped intel map read back equals itself after a save (no double flip)."""
    import os
    from conftest import DATA
    g = load_map(os.path.join(DATA, 'intel.yaml'))
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
