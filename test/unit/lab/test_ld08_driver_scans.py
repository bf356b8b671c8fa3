"""lab/simulate.ld08_driver_scans: fixed simulated LDS-02 scans reshaped as ROBOTIS's Noetic
driver sends them (lengths varying, 0 for no point, range 0-100 m, angles from the data), and
core/scans.normalise_scan bringing them back to the fixed form."""
import math

import numpy as np

from multi_map_merge.core.scans import NO_RETURN, Scan, normalise_scan
from multi_map_merge.lab.simulate import Scans, ld08_driver_scans


def fixed_scans(n=60):
    inc = 2 * math.pi / 360
    a = np.arange(360) * inc
    r = np.tile((2.0 + np.sin(3 * a)).astype(np.float32), (n, 1))
    r[:, 100:110] = np.inf
    return Scans(np.arange(n), r, 0.0, inc, 0.16, 8.0)


def test_driver_scans_vary_in_length_and_carry_zeros_and_their_own_angles():
    sc = fixed_scans()
    d = ld08_driver_scans(sc, np.random.default_rng(3))
    assert (d.range_min, d.range_max) == (0.0, 100.0) and len(d.scans) == len(sc.steps)
    lengths = [len(r) for _, _, r in d.scans]
    assert 420 <= min(lengths) and max(lengths) <= 500 and len(set(lengths)) > 10
    assert len({a0 for a0, _, _ in d.scans}) == len(d.scans)
    for a0, inc, r in d.scans:
        assert -math.pi / 400 <= a0 < 2 * math.pi / 400 and abs(a0 + inc * (len(r) - 1) - 2 * math.pi) < 0.03
        assert np.all(np.isfinite(r)) and np.mean(r == 0.0) > 10 / 360      # the 10 no-return beams, and dropouts


def test_normalised_driver_scans_are_the_fixed_scans_but_for_a_few_lost_beams():
    sc = fixed_scans()
    d = ld08_driver_scans(sc, np.random.default_rng(4))
    for k, (a0, inc, r) in enumerate(d.scans):
        out = normalise_scan(Scan(a0, a0 + inc * (len(r) - 1), inc, 0.0, 0.2, d.range_min, d.range_max,
                                  [float(v) for v in r]))
        o = np.array(out.ranges)
        assert len(o) == 360 and out.range_min == 0.16 and out.range_max == 8.0
        assert np.all(o[101:109] == NO_RETURN)          # (its edges may take a neighbour's point)
        same = o == sc.ranges[k]
        assert same.sum() >= 320, same.sum()            # lost: dropouts and empty bins, as inf
        # the driver's angle of a point is its bin's, not its own: at most a beam off
        near = same | (o == np.roll(sc.ranges[k], 1)) | (o == np.roll(sc.ranges[k], -1))
        assert np.all((o == NO_RETURN) | near)
