"""Laser scans made fit for gmapping, without ROS and without numpy (the robot-side relay imports
this; see :mod:`multi_map_merge.ros.relays`).

ROBOTIS's LDS-02 driver for Noetic (``ld08_driver``) publishes each revolution as it comes:
``ranges`` sized to that revolution's points (the length varies from scan to scan),
``angle_min``/``angle_max`` taken from the data, 0 where a bin has no point, ``range_min`` 0 and
``range_max`` 100. slam_gmapping takes the beam count of its first scan and silently drops every
later scan of another length (``SlamGMapping::addScan``: ``if(scan.ranges.size() !=
gsp_laser_beam_count_) return false;``), and keeps readings of 0 m (they are not below
``range_min``). :func:`normalise_scan` resamples a scan onto one fixed angular grid.

What gmapping does with "no return" (openslam_gmapping ``ScanMatcher::computeActiveArea`` and
``registerScan``, slam_gmapping ``addScan``): a reading below the scan's ``range_min`` becomes the
scan's ``range_max``; a reading above ``maxRange`` (``inf`` included) is skipped altogether; one
at or below ``maxRange`` is clipped to ``maxUrange`` and clears free space along the beam. So the
no-return value here is ``inf`` (REP 117's "no return"): never a wall, never free space made up
from a reading the sensor did not make. (``range_max`` itself would clear free space up to
``maxUrange`` with config/gmapping_lds02.yaml's ``maxRange`` 8.)
"""
from __future__ import annotations

import math
from typing import List, NamedTuple, Optional, Sequence

# The LDS-02's datasheet (ROBOTIS e-Manual, "LDS-02" appendix, Measurement Performance
# Specifications): distance range 160 ~ 8,000 mm, angular range 360 deg, angular resolution
# 1 deg (5 Hz; "may vary by the scan frequency": 2.3 kHz fixed sampling).
LDS02_RANGE_MIN = 0.16
LDS02_RANGE_MAX = 8.0
LDS02_BEAMS = 360
FULL_TURN = 2.0 * math.pi
NO_RETURN = float('inf')


class ScanGrid(NamedTuple):
    """The fixed form a scan is resampled onto: ``beams`` beams from ``angle_min`` over
    ``span`` radians (beam k at ``angle_min + k * span / beams``; a full turn wraps), readings
    valid in [``range_min``, ``range_max``] m. Defaults: an LDS-02 (datasheet figures)."""
    beams: int = LDS02_BEAMS
    angle_min: float = 0.0
    span: float = FULL_TURN
    range_min: float = LDS02_RANGE_MIN
    range_max: float = LDS02_RANGE_MAX

    @property
    def increment(self) -> float:
        return self.span / self.beams

    @property
    def full_turn(self) -> bool:
        return abs(self.span - FULL_TURN) < 1e-6


LDS02 = ScanGrid()


class Scan(NamedTuple):
    """The fields of a sensor_msgs/LaserScan that the resampling reads and writes."""
    angle_min: float
    angle_max: float
    angle_increment: float
    time_increment: float
    scan_time: float
    range_min: float
    range_max: float
    ranges: Sequence[float]
    intensities: Sequence[float] = ()


def _close(a: float, b: float, tol: float) -> bool:
    return abs(a - b) <= tol


def in_fixed_form(scan: Scan, grid: ScanGrid) -> bool:
    """Whether ``scan`` already has ``grid``'s beams, angles and range limits (then
    :func:`normalise_scan` returns it unchanged)."""
    inc = grid.increment
    return (len(scan.ranges) == grid.beams and _close(scan.angle_increment, inc, 1e-6 * max(1.0, inc))
            and _close(scan.angle_min, grid.angle_min, 1e-5)
            and _close(scan.range_min, grid.range_min, 1e-6) and _close(scan.range_max, grid.range_max, 1e-6))


def scan_increment(scan: Scan) -> Optional[float]:
    """The angle between a scan's readings: its ``angle_increment``, or where that is 0 or not
    finite, its angles' span over its readings; None when neither places the readings (a scan of
    two or more readings with no span: nothing to resample it by)."""
    inc = scan.angle_increment
    n = len(scan.ranges)
    if n > 1 and (inc == 0.0 or not math.isfinite(inc)):
        inc = (scan.angle_max - scan.angle_min) / (n - 1)
        if inc == 0.0 or not math.isfinite(inc):
            return None
    return inc if math.isfinite(inc) else 0.0


def normalise_scan(scan: Scan, grid: ScanGrid = LDS02) -> Scan:
    """``scan`` resampled onto ``grid``: each reading goes to the beam nearest its angle
    (``angle_min + i * angle_increment``; outside the span of a partial ``grid`` it is left out),
    the nearest valid reading wins where several meet, readings of 0, below ``grid.range_min``,
    above ``grid.range_max`` or not finite are no return (``inf``), and so is a beam no reading
    reached. ``range_min``/``range_max`` become ``grid``'s. Intensities follow their readings
    (0 where none) when there is one per reading, else are dropped. A scan in the fixed form
    already (:func:`in_fixed_form`) whose readings are all valid or ``inf`` is returned as is,
    and so is one whose angles say nothing (:func:`scan_increment` None)."""
    n = len(scan.ranges)
    lo, hi = grid.range_min, grid.range_max
    if in_fixed_form(scan, grid) and all(lo <= r <= hi or r == NO_RETURN for r in scan.ranges):
        return scan
    inc = scan_increment(scan)
    if inc is None:
        return scan
    step = grid.increment
    beams = grid.beams
    out = [NO_RETURN] * beams
    with_intensities = len(scan.intensities) == n and n > 0
    inten: List[float] = [0.0] * beams if with_intensities else []
    for i, r in enumerate(scan.ranges):
        if not (lo <= r <= hi):          # 0, too close, too far, nan, inf: no return
            continue
        k = int(math.floor((scan.angle_min + i * inc - grid.angle_min) / step + 0.5))
        if grid.full_turn:
            k %= beams
        elif not 0 <= k < beams:
            continue
        if r < out[k]:
            out[k] = r
            if with_intensities:
                inten[k] = scan.intensities[i]
    time_increment = scan.time_increment * n / beams if n else 0.0
    return Scan(grid.angle_min, grid.angle_min + (beams - 1) * step, step, time_increment,
                scan.scan_time, lo, hi, out, inten)


def describe_change(scan: Scan, grid: ScanGrid = LDS02) -> Optional[str]:
    """One line saying what :func:`normalise_scan` changes in ``scan`` (None: nothing), for the
    relay's log."""
    n = len(scan.ranges)
    lo, hi = grid.range_min, grid.range_max
    zeros = sum(1 for r in scan.ranges if r == 0.0)
    bad = sum(1 for r in scan.ranges if r != 0.0 and not (lo <= r <= hi) and r != NO_RETURN)
    if in_fixed_form(scan, grid) and zeros == 0 and bad == 0:
        return None
    if scan_increment(scan) is None:
        return ('%d readings with no angle between them (angle_increment %g, angle_min = angle_max = %g): '
                'passed on unchanged, not resampled' % (n, scan.angle_increment, scan.angle_min))
    return ('%d beams over [%.3f, %.3f] rad (increment %.5f), range %.2f-%.2f m, %d readings of 0 and %d '
            'outside %.2f-%.2f m -> %d beams over [%.3f, %.3f) rad, range %.2f-%.2f m, those as no return '
            '(inf)' % (n, scan.angle_min, scan.angle_max, scan.angle_increment, scan.range_min, scan.range_max,
                       zeros, bad, lo, hi, grid.beams, grid.angle_min, grid.angle_min + grid.span, lo, hi))
