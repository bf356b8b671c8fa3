"""core/scans.normalise_scan: LDS-02 driver-shaped scans (ld08_driver: length varying per
revolution, zeros, range 0-100 m, angles from the data) resampled onto one fixed grid for
gmapping; scans in that form already pass unchanged. No ROS, no numpy."""
import math

from multi_map_merge.core.scans import NO_RETURN, Scan, ScanGrid, describe_change, in_fixed_form, normalise_scan

INC = 2 * math.pi / 360


def fixed_scan(ranges):
    return Scan(0.0, 359 * INC, INC, 0.2 / 360, 0.2, 0.16, 8.0, list(ranges), [])


def driver_like(n, a0, reading, zeros=()):
    """n points over a revolution from a0 (angle_min a0, angle_max from the last point), 0 at
    the indices in zeros, range 0-100 m as ld08_driver says."""
    inc = 2 * math.pi / n
    ranges = [0.0 if i in zeros else reading(a0 + i * inc) for i in range(n)]
    return Scan(a0, a0 + (n - 1) * inc, inc, 0.2 / n, 0.2, 0.0, 100.0, ranges, [7.0] * n)


def wall(a):
    """A square room 4 m across around the scanner: the range at angle a."""
    return 2.0 / max(abs(math.cos(a)), abs(math.sin(a)))


def test_a_fixed_scan_passes_unchanged():
    s = fixed_scan([1.0 + 0.01 * i if i % 7 else NO_RETURN for i in range(360)])
    assert in_fixed_form(s, ScanGrid())
    assert normalise_scan(s) is s
    assert describe_change(s) is None


def test_driver_scans_of_any_length_become_360_beams_at_one_degree():
    for n, a0 in ((451, 0.004), (468, -0.01), (437, 0.0135), (360, 0.0)):
        s = driver_like(n, a0, wall)
        out = normalise_scan(s)
        assert len(out.ranges) == 360 and len(out.intensities) == 360
        assert out.angle_min == 0.0 and abs(out.angle_increment - INC) < 1e-12
        assert abs(out.angle_max - 359 * INC) < 1e-12
        assert (out.range_min, out.range_max) == (0.16, 8.0)
        # every beam took the nearest reading within half a driver step of its angle
        for k, r in enumerate(out.ranges):
            assert r != NO_RETURN
            assert abs(r - wall(k * INC)) < 0.05, (n, k, r)


def test_zeros_and_out_of_range_readings_are_no_return():
    s = driver_like(360, 0.0, lambda a: 3.0, zeros={10, 11, 200})
    ranges = list(s.ranges)
    ranges[50], ranges[60], ranges[70], ranges[80] = 0.1, 9.5, float('nan'), 100.0
    s = s._replace(ranges=ranges)
    out = normalise_scan(s)
    assert [k for k, r in enumerate(out.ranges) if r == NO_RETURN] == [10, 11, 50, 60, 70, 80, 200]
    assert all(r == 3.0 for k, r in enumerate(out.ranges) if r != NO_RETURN)
    assert out.intensities[10] == 0.0 and out.intensities[12] == 7.0
    assert '3 readings of 0' in describe_change(s) and '4 outside 0.16-8.00 m' in describe_change(s)


def test_beams_no_reading_reached_are_no_return_and_the_nearest_reading_wins():
    # 180 points, 2 degrees apart: every other beam empty
    s = driver_like(180, 0.0, lambda a: 2.0)
    out = normalise_scan(s)
    assert sum(r == NO_RETURN for r in out.ranges) == 180
    # two readings for one beam: the nearer
    s = Scan(0.0, 0.001, 0.001, 0.0, 0.2, 0.0, 100.0, [5.0, 4.0], [])
    assert normalise_scan(s).ranges[0] == 4.0


def test_angles_wrap_around_a_full_turn_and_a_partial_grid_drops_what_is_outside():
    # a revolution from -pi (as some drivers give it): beam 0 (angle 0) takes the reading at 0
    s = driver_like(400, -math.pi, lambda a: 1.0 + abs(math.atan2(math.sin(a), math.cos(a))))
    out = normalise_scan(s)
    assert abs(out.ranges[0] - 1.0) < 0.01 and abs(out.ranges[180] - (1.0 + math.pi)) < 0.02
    front = ScanGrid(beams=90, angle_min=-math.pi / 4, span=math.pi / 2)
    out = normalise_scan(s, front)
    assert len(out.ranges) == 90 and abs(out.angle_min + math.pi / 4) < 1e-12
    assert all(r != NO_RETURN and r < 1.0 + math.pi / 4 + 0.02 for r in out.ranges)


def test_a_decreasing_scan_and_one_without_increment():
    inc = 2 * math.pi / 400
    ranges = [1.0 + 0.001 * i for i in range(400)]
    down = Scan(2 * math.pi - inc, 0.0, -inc, 0.0, 0.2, 0.0, 100.0, ranges, [])
    out = normalise_scan(down)
    assert abs(out.ranges[359] - ranges[1]) < 0.002          # angle 359 deg: the second reading
    flat = Scan(0.0, 399 * inc, 0.0, 0.0, 0.2, 0.0, 100.0, ranges, [])
    assert abs(normalise_scan(flat).ranges[180] - ranges[200]) < 0.002
    empty = Scan(0.0, 0.0, 0.0, 0.0, 0.2, 0.0, 100.0, [], [])
    assert normalise_scan(empty).ranges == [NO_RETURN] * 360


def test_a_scan_whose_angles_say_nothing_passes_unchanged_and_says_so():
    s = Scan(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, [0.2 + 0.01 * i for i in range(360)], [])
    assert normalise_scan(s) is s
    assert 'passed on unchanged' in describe_change(s)
