"""Robots driving through a real building's map: LDS-02 scans, wheel odometry, and the map their
gmapping would publish, with the errors a real robot has. The data behind ``make_robot_bags``.

Frames (per robot k, as on a real Turtlebot3 running gmapping):

- ``world``: the ground-truth map's frame. Never seen by a robot.
- ``tb3_k/map``: robot k's SLAM frame, origin at its start pose (``start`` = pose of
  ``tb3_k/map`` in ``world``). Its published grid and its SLAM poses are in this frame.
- ``tb3_k/odom``: its wheel odometry frame, also at the start pose, drifting away from the map
  frame as odometry errs (gmapping publishes ``map -> odom`` to correct it).

Error model (all deterministic for a seed):

- Range noise of the LDS-02 datasheet (accuracy +-10 mm under 0.3 m, +-3 % to 6 m, +-5 % to
  8 m), each bound taken as 3 sigma of a Gaussian; no return beyond 8 m or into unmapped space.
- Odometry as a Burger's OpenCR firmware computes it (``turtlebot3_core``, ``calcOdometry``):
  the distance from the wheels, the heading from the IMU. The wheels' distance errs in
  proportion to the distance driven (variance ``odom_trans_var``) and slips now and then
  (``slip_*``: metres are counted that were not driven). The heading is the integrated gyro
  (the firmware takes the yaw of its IMU filter, which no magnetometer corrects), which errs by
  a scale factor (``gyro_scale_sigma``, per robot), a residual rate bias left after the
  firmware's calibration at start-up (``gyro_bias_sigma``, per robot) and white rate noise
  (``gyro_noise_density``); the figures and their sources are in docs/measurements.md
  ("A Burger's odometry").
- SLAM (gmapping): the pose the map is built with drifts from the truth: a random walk that
  grows with the distance travelled and the angle turned (variances ``slam_*_var``, far below
  odometry's), plus a steady heading drift per metre drawn once per robot (``slam_bias``), so
  the error grows with the distance: a robot that drives four times as far ends about four
  times as rotated, and where it comes back its new walls land beside its old ones.
- The map: gmapping's counting model (a cell is occupied when more than ``occ_thresh`` of the
  beams that reached it ended in it), beams used up to ``max_urange``; a scan is processed
  after ``linear_update`` m, ``angular_update`` rad or ``temporal_update`` s, the map published
  every ``map_update_interval`` s. Values as in config/gmapping_lds02.yaml (ROBOTIS' settings).

Units: metres, radians, seconds; grids in OccupancyGrid order (see :mod:`multi_map_merge.core.grid`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..core.grid import FREE, OCCUPIED, Grid
from ..core.transforms import compose, relative, wrap_angle

LDS02_OFFSET = (-0.032, 0.0, 0.172)   # base_footprint -> base_scan on a Burger, metres


@dataclass
class SimConfig:
    """Every knob of the simulation; defaults are a Turtlebot3 Burger with an LDS-02."""
    robots: int = 4
    seed: int = 1
    # driving
    speed: float = 0.22                 # m/s (the Burger's top speed)
    turn_rate: float = 1.5              # rad/s, turning on the spot
    clearance: float = 0.22             # m: keep this far from walls (Burger radius 0.105 m)
    viewpoint_spacing: float = 1.6      # m between places a robot visits while exploring
    start_spread: float = 0.3           # m: robots start on a circle this size (paper: close together)
    # sensors
    odom_rate: float = 20.0             # Hz, /odom and odom -> base_footprint
    scan_rate: float = 5.0              # Hz (LDS-02: 5 Hz, 360 beams, 1 degree apart)
    beams: int = 360
    range_min: float = 0.16
    range_max: float = 8.0
    # errors (variances grow linearly with distance / angle: a random walk)
    odom_trans_var: float = 0.02 ** 2   # m^2 per m driven (wheels)
    # the IMU's gyro (MPU-9250 on the OpenCR 1.0), which gives a Burger's odometry its heading
    gyro_scale_sigma: float = 0.01      # relative: sensitivity tolerance +-3 % as 3 sigma
    gyro_bias_sigma: float = math.radians(0.005)   # rad/s left after the start-up calibration (assumed)
    gyro_noise_density: float = math.radians(0.01)  # rad/s/sqrt(Hz): rate noise spectral density
    # the heading from the wheels instead (a robot without an IMU; not a Burger): set
    # ``wheel_heading`` to use these
    wheel_heading: bool = False
    odom_rot_var: float = math.radians(2.0) ** 2   # rad^2 per m driven
    odom_turn_var: float = 0.05 ** 2    # rad^2 per rad turned
    slip_rate: float = 0.05             # slip events per second of driving
    slip_gain: float = 0.3              # extra counted distance during a slip (fraction)
    slip_duration: float = 0.6          # s
    slam_trans_var: float = 0.003 ** 2  # m^2 per m driven
    slam_rot_var: float = math.radians(0.05) ** 2  # rad^2 per m driven
    slam_turn_var: float = 0.002 ** 2   # rad^2 per rad turned
    slam_bias: float = math.radians(0.03)  # rad per m: sigma of each robot's steady heading drift
    # gmapping (config/gmapping_lds02.yaml)
    resolution: float = 0.05
    max_urange: float = 3.0
    occ_thresh: float = 0.25
    linear_update: float = 1.0
    angular_update: float = 0.2
    temporal_update: float = 0.5
    map_update_interval: float = 2.0
    map_half_size: float = 10.0         # xmin/ymin = -10, xmax/ymax = 10: the map grows past it
    hold: float = 10.0                  # s every robot stands still at the end (last maps settle)


@dataclass
class Scans:
    """Laser scans of one robot: ``ranges[i]`` taken at ``steps[i]`` (an index into the robot's
    pose arrays). Ranges in metres, ``inf`` = no return, angles in the base_scan frame."""
    steps: np.ndarray
    ranges: np.ndarray                  # (S, B) float32
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float
    offset: Tuple[float, float, float] = LDS02_OFFSET   # base_footprint -> scanner, m

    @property
    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(self.ranges.shape[1])

    def scan(self, k: int) -> Tuple[float, float, np.ndarray]:
        """Scan ``k`` as a LaserScan holds it: (angle_min, angle_increment, ranges)."""
        return self.angle_min, self.angle_increment, self.ranges[k]


@dataclass
class DriverScans:
    """Laser scans of one robot as ROBOTIS's LDS-02 driver for Noetic (``ld08_driver``)
    publishes them (:func:`ld08_driver_scans`): one revolution each, of its own length, angles
    from its first and last point, 0 where no point, ``range_min`` 0, ``range_max`` 100."""
    steps: np.ndarray
    scans: List[Tuple[float, float, np.ndarray]]   # per scan (angle_min, angle_increment, ranges float32)
    range_min: float = 0.0
    range_max: float = 100.0
    offset: Tuple[float, float, float] = LDS02_OFFSET

    def scan(self, k: int) -> Tuple[float, float, np.ndarray]:
        return self.scans[k]


# The LDS-02 samples at a fixed 2.3 kHz and turns at about 5 Hz ("Scan Frequency 5Hz or above",
# "may vary by each product"; ROBOTIS e-Manual, LDS-02): about 460 points a revolution, their
# count following the motor's speed from revolution to revolution.
LDS02_SAMPLE_RATE = 2300.0


def ld08_driver_scans(scans: Scans, rng: np.random.Generator, scan_rate: float = 5.0,
                      speed_sigma: float = 0.02, angle_jitter: float = 0.3, dropout: float = 0.02) -> DriverScans:
    """``scans`` (fixed beams, ``inf`` for no return) as ``ld08_driver`` would have published
    them, written from what the driver is documented and seen to do, not from its code:

    - each revolution turns at ``scan_rate`` Hz times (1 + N(0, ``speed_sigma``)), so it has
      ``LDS02_SAMPLE_RATE / rate`` points: the length varies from scan to scan;
    - the points' angles start anywhere within the first point's step and wander by
      ``angle_jitter`` of a step (the sensor's encoder); each point is put in the bin of its angle
      among as many bins as points between the first and the last point's angle
      (``angle_min``/``angle_max`` from the data), a bin without a point reads 0 (two points in a
      bin: the later one);
    - a point reads the nearest fixed beam's range; no return (``inf``) and a random
      ``dropout`` share of points read 0, as the sensor reports them;
    - ``range_min`` 0, ``range_max`` 100 (m)."""
    B = scans.ranges.shape[1]
    beam_inc = scans.angle_increment
    out = []
    for k in range(len(scans.steps)):
        rate = scan_rate * (1.0 + speed_sigma * rng.standard_normal())
        n = max(2, int(round(LDS02_SAMPLE_RATE / max(rate, 1e-3))))
        step = 2.0 * math.pi / n
        angles = scans.angle_min + rng.uniform(0.0, step) + step * (np.arange(n) + angle_jitter * rng.uniform(
            -0.5, 0.5, n))
        beam = np.rint((angles - scans.angle_min) / beam_inc).astype(np.int64) % B
        reading = scans.ranges[k][beam].astype(np.float64)
        reading[~np.isfinite(reading) | (rng.random(n) < dropout)] = 0.0
        a0, a1 = float(angles[0]), float(angles[-1])
        inc = (a1 - a0) / (n - 1)
        bins = np.clip(np.rint((angles - a0) / inc).astype(np.int64), 0, n - 1)
        ranges = np.zeros(n, np.float32)
        ranges[bins] = reading          # numpy: the last of equal indices wins
        out.append((a0, inc, ranges))
    return DriverScans(scans.steps, out, offset=scans.offset)


@dataclass
class RobotRun:
    """Everything one robot did and published. Poses are (x, y, yaw) of base_footprint:
    ``true`` in ``world``, ``odom`` in ``tb3_k/odom``, ``slam`` in ``tb3_k/map``."""
    name: str
    t: np.ndarray                       # (K,) seconds from the start of the run
    true: np.ndarray                    # (K, 3)
    odom: np.ndarray                    # (K, 3)
    slam: np.ndarray                    # (K, 3)
    scans: Scans                        # or DriverScans (make_robot_bags --lds02-driver)
    maps: List[Tuple[float, Grid]] = field(default_factory=list)   # (time, map in tb3_k/map)
    start: Tuple[float, float, float] = (0.0, 0.0, 0.0)             # tb3_k/map in world

    @property
    def distance(self) -> float:
        return float(np.sum(np.hypot(*np.diff(self.true[:, :2], axis=0).T)))

    @property
    def turned(self) -> float:
        return float(np.sum(np.abs(wrap_angle(np.diff(self.true[:, 2])))))


# ---------------------------------------------------------------------------------------- poses

def integrate(increments: np.ndarray) -> np.ndarray:
    """Poses from the identity by composing (K-1, 3) increments: (K, 3)."""
    out = np.zeros((len(increments) + 1, 3))
    for i, d in enumerate(increments):     # sequential by nature; K is a few thousand
        out[i + 1] = compose(out[i], d)
    return out


def noisy_increments(inc: np.ndarray, rng: np.random.Generator, trans_var: float, rot_var: float,
                     turn_var: float, slip: Optional[np.ndarray] = None) -> np.ndarray:
    """Increments as a sensor or estimator measures them: errors whose variance grows with the
    distance (m) and the angle (rad) of each increment. ``slip`` multiplies the counted distance."""
    d = np.hypot(inc[:, 0], inc[:, 1])
    a = np.abs(inc[:, 2])
    out = inc.copy()
    if slip is not None:
        out[:, :2] *= slip[:, None]
    out[:, 0] += rng.normal(0.0, 1.0, len(inc)) * np.sqrt(trans_var * d)
    out[:, 1] += rng.normal(0.0, 1.0, len(inc)) * np.sqrt(trans_var * d)
    out[:, 2] += rng.normal(0.0, 1.0, len(inc)) * np.sqrt(rot_var * d + turn_var * a)
    return out


# ---------------------------------------------------------------------------------- the world

class World:
    """A ground-truth map ready for ray casting and path planning."""

    def __init__(self, grid: Grid):
        self.grid = grid
        self.res = grid.resolution
        if abs(grid.origin[2]) > 1e-9:
            raise ValueError('world map with a rotated origin is not supported')
        self.ox, self.oy = grid.origin[0], grid.origin[1]
        lv = grid.levels()
        self.occupied = lv == OCCUPIED
        self.free = lv == FREE
        # distance (cells) from each cell centre to the nearest cell a beam cannot cross
        opaque = ~self.free
        self.edt = cv2.distanceTransform((~opaque).astype(np.uint8), cv2.DIST_L2, 5).astype(np.float32)
        self.h, self.w = lv.shape

    def to_cell(self, x, y):
        return (np.asarray(x) - self.ox) / self.res - 0.5, (np.asarray(y) - self.oy) / self.res - 0.5

    def to_metric(self, col, row):
        return self.ox + (np.asarray(col) + 0.5) * self.res, self.oy + (np.asarray(row) + 0.5) * self.res

    def raycast(self, poses: np.ndarray, angles: np.ndarray, range_max: float) -> np.ndarray:
        """Ranges (m) from each scanner pose (S, 3) in ``world`` along each angle (B,): the
        distance to the first occupied cell, ``inf`` when nothing occupied is met within
        ``range_max`` or the beam enters unmapped space. Sphere tracing on the distance
        transform, then bisection to the cell's face."""
        S, B = len(poses), len(angles)
        th = (poses[:, 2:3] + angles[None, :]).ravel()
        dx, dy = np.cos(th), np.sin(th)
        c0, r0 = self.to_cell(np.repeat(poses[:, 0], B), np.repeat(poses[:, 1], B))
        tmax = range_max / self.res
        t = np.zeros(S * B)
        result = np.full(S * B, np.inf)
        active = np.arange(S * B)
        for _ in range(2000):
            if active.size == 0:
                break
            c = c0[active] + t[active] * dx[active]
            r = r0[active] + t[active] * dy[active]
            ci, ri = np.rint(c).astype(np.int64), np.rint(r).astype(np.int64)
            out = (ci < 0) | (ri < 0) | (ci >= self.w) | (ri >= self.h)
            ci, ri = np.clip(ci, 0, self.w - 1), np.clip(ri, 0, self.h - 1)
            blocked = ~self.free[ri, ci] | out
            hit = blocked & ~out & self.occupied[ri, ci]
            if hit.any():
                idx = active[hit]
                result[idx] = self._face(c0[idx], r0[idx], dx[idx], dy[idx], t[idx])
            far = t[active] > tmax
            done = blocked | far
            step = np.maximum(self.edt[ri, ci] - 1.5, 0.4)
            t[active] += step
            active = active[~done]
        result = result * self.res
        result[result > range_max] = np.inf
        return result.reshape(S, B)

    def _face(self, c0, r0, dx, dy, t_in):
        """Bisection between a free point 0.4..step cells before ``t_in`` and ``t_in``."""
        lo = np.maximum(t_in - 3.0, 0.0)
        hi = t_in.copy()
        for _ in range(8):
            mid = 0.5 * (lo + hi)
            ci = np.clip(np.rint(c0 + mid * dx).astype(np.int64), 0, self.w - 1)
            ri = np.clip(np.rint(r0 + mid * dy).astype(np.int64), 0, self.h - 1)
            f = self.free[ri, ci]
            lo = np.where(f, mid, lo)
            hi = np.where(f, hi, mid)
        return hi

    # ------------------------------------------------------------------------------ planning
    def navigable(self, clearance: float) -> np.ndarray:
        """Cells whose centre is at least ``clearance`` m from anything a robot cannot enter,
        in the largest connected region."""
        ok = (self.edt * self.res >= clearance) & self.free
        n, lab = cv2.connectedComponents(ok.astype(np.uint8), connectivity=8)
        if n <= 1:
            raise ValueError('no navigable space in the world map at clearance %.2f m' % clearance)
        sizes = np.bincount(lab.ravel())
        sizes[0] = 0
        return lab == int(np.argmax(sizes))


class Planner:
    """Shortest paths on the navigable cells (8-connected, cells of clearance-weighted cost)."""

    def __init__(self, world: World, nav: np.ndarray):
        from scipy.sparse import csr_matrix
        self.world, self.nav = world, nav
        rows, cols = np.nonzero(nav)
        self.index = -np.ones(nav.shape, np.int64)
        self.index[rows, cols] = np.arange(len(rows))
        self.rows, self.cols = rows, cols
        # prefer the middle of corridors: a cell near walls costs a little more
        clear = world.edt[rows, cols] * world.res
        penalty = 1.0 + 0.5 / np.maximum(clear, 0.05)
        src, dst, wgt = [], [], []
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            r2, c2 = rows + dr, cols + dc
            ok = (r2 >= 0) & (r2 < nav.shape[0]) & (c2 >= 0) & (c2 < nav.shape[1])
            ok[ok] = nav[r2[ok], c2[ok]]
            a = np.nonzero(ok)[0]
            b = self.index[r2[ok], c2[ok]]
            w = math.hypot(dr, dc) * 0.5 * (penalty[a] + penalty[b])
            src += [a, b]
            dst += [b, a]
            wgt += [w, w]
        n = len(rows)
        self.graph = csr_matrix((np.concatenate(wgt), (np.concatenate(src), np.concatenate(dst))), shape=(n, n))

    def distances(self, node: int):
        from scipy.sparse.csgraph import dijkstra
        return dijkstra(self.graph, indices=node, return_predecessors=True)

    def path(self, pred: np.ndarray, goal: int) -> List[int]:
        out = [goal]
        while pred[out[-1]] >= 0:
            out.append(int(pred[out[-1]]))
        return out[::-1]

    def node_of(self, x: float, y: float) -> int:
        """The navigable cell nearest to a metric point."""
        c, r = self.world.to_cell(x, y)
        d = (self.cols - c) ** 2 + (self.rows - r) ** 2
        return int(np.argmin(d))

    def xy(self, nodes) -> np.ndarray:
        x, y = self.world.to_metric(self.cols[nodes], self.rows[nodes])
        return np.stack([x, y], axis=-1)


def viewpoints(world: World, nav: np.ndarray, spacing: float) -> np.ndarray:
    """Places to visit so that the whole navigable space is seen: in each square of
    ``spacing`` m, its navigable cell farthest from walls. (P, 2) metres in ``world``."""
    k = max(1, int(round(spacing / world.res)))
    score = np.where(nav, world.edt, -1.0)
    H, W = nav.shape
    Hp, Wp = -(-H // k) * k, -(-W // k) * k
    s = np.full((Hp, Wp), -1.0, np.float32)
    s[:H, :W] = score
    blocks = s.reshape(Hp // k, k, Wp // k, k).transpose(0, 2, 1, 3).reshape(Hp // k, Wp // k, k * k)
    best = blocks.argmax(axis=2)
    val = blocks.max(axis=2)
    bi, bj = np.nonzero(val > 0)
    r = bi * k + best[bi, bj] // k
    c = bj * k + best[bi, bj] % k
    x, y = world.to_metric(c, r)
    return np.stack([x, y], axis=-1)


def kmeans(points: np.ndarray, k: int, iters: int = 50) -> np.ndarray:
    """Deterministic k-means (farthest-point initialisation): a label per point."""
    centres = [points[np.argmin(points[:, 0] + points[:, 1])]]
    for _ in range(1, k):
        d = np.min([np.sum((points - c) ** 2, axis=1) for c in centres], axis=0)
        centres.append(points[int(np.argmax(d))])
    C = np.array(centres, float)
    lab = np.zeros(len(points), int)
    for _ in range(iters):
        lab = np.argmin(((points[:, None, :] - C[None]) ** 2).sum(-1), axis=1)
        newC = np.array([points[lab == j].mean(0) if np.any(lab == j) else C[j] for j in range(k)])
        if np.allclose(newC, C):
            break
        C = newC
    return lab


def tour(planner: Planner, start_node: int, goals: Sequence[int]) -> List[int]:
    """Visit every goal, always the nearest unvisited one along the paths: a node list."""
    path = [start_node]
    todo = list(goals)
    cur = start_node
    while todo:
        dist, pred = planner.distances(cur)
        reach = [g for g in todo if np.isfinite(dist[g])]
        if not reach:
            break
        g = min(reach, key=lambda n: dist[n])
        seg = planner.path(pred, g)
        path += seg[1:]
        cur = g
        todo = [n for n in todo if n != g and not (np.isfinite(dist[n]) and n in seg)]
    return path


def drive(route: np.ndarray, start: Tuple[float, float, float], cfg: SimConfig) -> np.ndarray:
    """True poses (K, 3) at ``cfg.odom_rate`` of a robot following ``route`` (metres) from
    ``start``: pure pursuit, turning on the spot when the route bends sharply."""
    dt = 1.0 / cfg.odom_rate
    # route resampled every 5 cm
    seg = np.hypot(*np.diff(route, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] < 1e-6:
        return np.array([start], float)
    ss = np.arange(0.0, s[-1], 0.05)
    pts = np.stack([np.interp(ss, s, route[:, 0]), np.interp(ss, s, route[:, 1])], axis=1)
    pts = np.vstack([pts, route[-1]])
    pose = np.array(start, float)
    out = [pose.copy()]
    i = 0
    look = 0.25
    for _ in range(int(1e6)):
        while i < len(pts) - 1 and np.hypot(*(pts[i] - pose[:2])) < look:
            i += 1
        tgt = pts[i]
        d = np.hypot(*(tgt - pose[:2]))
        if i == len(pts) - 1 and d < 0.05:
            break
        e = float(wrap_angle(math.atan2(tgt[1] - pose[1], tgt[0] - pose[0]) - pose[2]))
        w = float(np.clip(3.0 * e, -cfg.turn_rate, cfg.turn_rate))
        v = 0.0 if abs(e) > 0.5 else cfg.speed * math.cos(e) * min(1.0, d / 0.1 + 0.3)
        pose = compose(pose, np.array([v * dt, 0.0, w * dt]))
        out.append(pose.copy())
    return np.array(out)


# -------------------------------------------------------------------------------- the mapper

class GmappingMap:
    """gmapping's occupancy counting on a fixed canvas in a robot's map frame."""

    def __init__(self, bounds: Tuple[float, float, float, float], cfg: SimConfig):
        res = cfg.resolution
        x0, y0, x1, y1 = bounds
        self.x0 = math.floor(x0 / res) * res
        self.y0 = math.floor(y0 / res) * res
        self.w = int(math.ceil((x1 - self.x0) / res))
        self.h = int(math.ceil((y1 - self.y0) / res))
        self.res, self.cfg = res, cfg
        self.visits = np.zeros(self.h * self.w, np.int32)
        self.hits = np.zeros(self.h * self.w, np.int32)

    def _cells(self, x, y):
        c = np.floor((x - self.x0) / self.res).astype(np.int64)
        r = np.floor((y - self.y0) / self.res).astype(np.int64)
        ok = (c >= 0) & (r >= 0) & (c < self.w) & (r < self.h)
        return np.where(ok, r * self.w + c, -1)

    def add(self, poses: np.ndarray, ranges: np.ndarray, angles: np.ndarray, range_min: float = 0.0) -> None:
        """Scans taken from scanner poses (S, 3) in the map frame: cells along each beam are
        visited, the end cell of a beam shorter than ``max_urange`` is also hit."""
        if len(poses) == 0:
            return
        mu = self.cfg.max_urange
        valid = ranges >= range_min
        r = np.where(valid, np.minimum(ranges, mu), 0.0)          # inf -> free up to max_urange
        hit = valid & (ranges < mu)
        th = poses[:, 2:3] + angles[None, :]
        ox, oy = poses[:, 0:1], poses[:, 1:2]
        ex, ey = ox + r * np.cos(th), oy + r * np.sin(th)
        end = self._cells(ex, ey)
        step = 0.5 * self.res
        L = int(math.ceil(mu / step))
        d = np.arange(L) * step                                     # (L,)
        # a beam's cells, in order, each counted once; the end cell is not "passed"
        for k in range(0, len(poses), 64):
            sl = slice(k, k + 64)
            rr = r[sl][..., None]
            px = ox[sl][..., None] + d * np.cos(th[sl])[..., None]
            py = oy[sl][..., None] + d * np.sin(th[sl])[..., None]
            cells = self._cells(px, py)
            keep = (d < rr) & (cells >= 0) & (cells != end[sl][..., None])
            keep[..., 1:] &= cells[..., 1:] != cells[..., :-1]
            self._count(self.visits, cells[keep])
        e = end[hit]
        e = e[e >= 0]
        self._count(self.hits, e)
        self._count(self.visits, e)

    @staticmethod
    def _count(acc: np.ndarray, cells: np.ndarray) -> None:
        if cells.size == 0:
            return
        lo, hi = int(cells.min()), int(cells.max()) + 1   # only the window the scans touched
        acc[lo:hi] += np.bincount(cells - lo, minlength=hi - lo).astype(np.int32)

    def grid(self, frame_id: str, stamp: float = 0.0) -> Grid:
        """The map as gmapping publishes it: -1 never seen, 100 occupied, 0 free."""
        data = np.full(self.h * self.w, -1, np.int8)
        seen = self.visits > 0
        occ = np.zeros_like(seen)
        occ[seen] = self.hits[seen] > self.cfg.occ_thresh * self.visits[seen]
        data[seen] = 0
        data[occ] = 100
        return Grid(data.reshape(self.h, self.w), self.res, (round(self.x0, 6), round(self.y0, 6), 0.0),
                    frame_id, stamp)


def processed_scans(poses: np.ndarray, t: np.ndarray, cfg: SimConfig) -> np.ndarray:
    """Which scans gmapping would process (mask): after moving ``linear_update``, turning
    ``angular_update`` or waiting ``temporal_update`` since the last processed one."""
    keep = np.zeros(len(poses), bool)
    last = None
    for i in range(len(poses)):
        if last is None:
            keep[i], last = True, i
            continue
        d = relative(poses[last], poses[i])
        if (math.hypot(d[0], d[1]) >= cfg.linear_update or abs(d[2]) >= cfg.angular_update
                or t[i] - t[last] >= cfg.temporal_update):
            keep[i], last = True, i
    return keep


def build_maps(name: str, t: np.ndarray, slam: np.ndarray, scans: Scans,
               cfg: SimConfig) -> List[Tuple[float, Grid]]:
    """The maps a robot's gmapping publishes (frame ``<name>/map``), built from the processed
    scans at their SLAM poses: (time s, map) every ``map_update_interval`` or more."""
    scan_t = t[scans.steps]
    scanner = compose(slam[scans.steps], np.array([scans.offset[0], scans.offset[1], 0.0]))
    keep = processed_scans(scanner, scan_t, cfg)
    ang = scans.angles
    # canvas: gmapping's initial square, grown to everything the robot will map
    reach = np.minimum(np.where(np.isfinite(scans.ranges), scans.ranges, cfg.max_urange), cfg.max_urange)
    ex = scanner[:, 0:1] + reach * np.cos(scanner[:, 2:3] + ang)
    ey = scanner[:, 1:2] + reach * np.sin(scanner[:, 2:3] + ang)
    hs = cfg.map_half_size
    bounds = (min(-hs, ex.min() - 0.5), min(-hs, ey.min() - 0.5), max(hs, ex.max() + 0.5), max(hs, ey.max() + 0.5))
    gm = GmappingMap(bounds, cfg)
    frame = '%s/map' % name
    out: List[Tuple[float, Grid]] = []
    # as gmapping: the map is redrawn when a scan is processed at least
    # map_update_interval after the last redraw
    idx = np.nonzero(keep)[0]
    last, done = -np.inf, 0
    for j, i in enumerate(idx):
        if scan_t[i] - last < cfg.map_update_interval and j != 0:
            continue
        sel = idx[done:j + 1]
        gm.add(scanner[sel], scans.ranges[sel], ang, scans.range_min)
        done, last = j + 1, float(scan_t[i])
        out.append((last, gm.grid(frame, last)))
    return out


# ------------------------------------------------------------------------- the whole scenario

def lds02_noise(r: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Ranges with the LDS-02's datasheet accuracy as 3 sigma: 10 mm below 0.3 m, 3 % to 6 m,
    5 % beyond."""
    sigma = np.where(r < 0.3, 0.010, np.where(r < 6.0, 0.03 * r, 0.05 * r)) / 3.0
    out = r + rng.normal(0.0, 1.0, r.shape) * np.where(np.isfinite(sigma), sigma, 0.0)
    return out


def errors(true: np.ndarray, cfg: SimConfig, rng: np.random.Generator) -> Tuple[np.ndarray, np.ndarray]:
    """(odom, slam) poses of a true trajectory, each from the identity at the start."""
    inc = relative(true[:-1], true[1:])
    dt = 1.0 / cfg.odom_rate
    moving = np.hypot(inc[:, 0], inc[:, 1]) > 1e-4
    slip = np.ones(len(inc))
    n_slip = rng.poisson(cfg.slip_rate * moving.sum() * dt)
    span = max(1, int(cfg.slip_duration * cfg.odom_rate))
    for s in rng.choice(np.nonzero(moving)[0], size=min(n_slip, int(moving.sum())), replace=False) \
            if moving.any() else []:
        slip[s:s + span] += cfg.slip_gain
    odom_inc = noisy_increments(inc, rng, cfg.odom_trans_var, cfg.odom_rot_var, cfg.odom_turn_var, slip)
    slam_inc = noisy_increments(inc, rng, cfg.slam_trans_var, cfg.slam_rot_var, cfg.slam_turn_var)
    # what scan matching does not see leaves a steady heading drift: it grows with the distance
    # (linearly, on top of the random walk), so a robot driving four times as far ends four
    # times as rotated and its late walls land beside its early ones
    slam_inc[:, 2] += rng.normal(0.0, cfg.slam_bias) * np.hypot(inc[:, 0], inc[:, 1])
    slam = integrate(slam_inc)
    if not cfg.wheel_heading:
        # drawn after the rest, so that the SLAM poses (and the simulated maps) of a seed stay
        # what they were with the wheels' heading
        odom_inc[:, 2] = gyro_heading(inc[:, 2], dt, cfg, rng)
    return integrate(odom_inc), slam


def gyro_heading(turned: np.ndarray, dt: float, cfg: SimConfig, rng: np.random.Generator) -> np.ndarray:
    """Heading increments (rad) that a robot's integrated gyro reports for the true ones
    ``turned`` (rad, one per odometry step of ``dt`` s): a scale error and a rate bias drawn once
    for the robot, plus white rate noise. The bias accrues while the robot stands still too."""
    scale = 1.0 + rng.normal(0.0, cfg.gyro_scale_sigma)
    bias = rng.normal(0.0, cfg.gyro_bias_sigma)
    noise = rng.normal(0.0, 1.0, len(turned)) * cfg.gyro_noise_density * math.sqrt(dt)
    return turned * scale + bias * dt + noise


def run_robot(name: str, world: World, true: np.ndarray, cfg: SimConfig, rng: np.random.Generator) -> RobotRun:
    """Sensors, errors and maps of a robot driving the true trajectory ``true`` (world)."""
    K = len(true)
    t = np.arange(K) / cfg.odom_rate
    every = max(1, int(round(cfg.odom_rate / cfg.scan_rate)))
    steps = np.arange(0, K, every)
    inc = cfg.beams
    angle_inc = 2 * math.pi / inc
    angles = np.arange(inc) * angle_inc
    scanner_true = compose(true[steps], np.array([LDS02_OFFSET[0], LDS02_OFFSET[1], 0.0]))
    ranges = world.raycast(scanner_true, angles, cfg.range_max)
    ranges = lds02_noise(ranges, rng)
    ranges[ranges > cfg.range_max] = np.inf
    ranges[ranges < cfg.range_min] = np.inf       # too close to measure: no return
    scans = Scans(steps, ranges.astype(np.float32), 0.0, angle_inc, cfg.range_min, cfg.range_max)
    odom, slam = errors(true, cfg, rng)
    start = tuple(float(v) for v in true[0])
    run = RobotRun(name, t, true, odom, slam, scans, start=start)
    run.maps = build_maps(name, t, slam, scans, cfg)
    return run


def plan_team(world: World, cfg: SimConfig) -> Tuple[List[np.ndarray], List[Tuple[float, float, float]],
                                                     np.ndarray, Tuple[float, float, float]]:
    """Routes of ``cfg.robots`` robots that start together near the middle of the building and
    explore different regions, and of one robot exploring all of it alone.
    Returns (team routes, team start poses, lone route, lone start pose), metres in ``world``."""
    nav = world.navigable(cfg.clearance)
    planner = Planner(world, nav)
    vp = viewpoints(world, nav, cfg.viewpoint_spacing)
    # start: the most open navigable place near the middle of the navigable space
    rows, cols = np.nonzero(nav)
    cx, cy = world.to_metric(cols.mean(), rows.mean())
    open_ = world.edt[rows, cols] * world.res
    x, y = world.to_metric(cols, rows)
    d = np.hypot(x - cx, y - cy)
    score = d - 2.0 * np.minimum(open_, 1.0)
    score[open_ < cfg.start_spread + cfg.clearance] = np.inf
    i0 = int(np.argmin(score)) if np.isfinite(score).any() else int(np.argmax(open_))
    sx, sy = float(x[i0]), float(y[i0])
    n = cfg.robots
    goals = np.array([planner.node_of(px, py) for px, py in vp])
    lab = kmeans(planner.xy(goals), n)
    # robot k explores the region whose centre lies k-th around the start (counter-clockwise)
    cent = np.array([planner.xy(goals[lab == j]).mean(0) for j in range(n)])
    order = np.argsort(np.arctan2(cent[:, 1] - sy, cent[:, 0] - sx))
    routes, starts = [], []
    for k, j in enumerate(order):
        a = 2 * math.pi * k / n
        px, py = sx + cfg.start_spread * math.cos(a), sy + cfg.start_spread * math.sin(a)
        heading = math.atan2(cent[j, 1] - py, cent[j, 0] - px)
        node = planner.node_of(px, py)
        path = tour(planner, node, list(goals[lab == j]))
        routes.append(np.vstack([[px, py], planner.xy(np.array(path))]))
        starts.append((px, py, heading))
    node = planner.node_of(sx, sy)
    lone = tour(planner, node, list(goals))
    lone_start = (sx, sy, starts[0][2])
    return routes, starts, np.vstack([[sx, sy], planner.xy(np.array(lone))]), lone_start


def simulate_world(world_grid: Grid, cfg: SimConfig, lone: bool = True) -> Tuple[List[RobotRun], Optional[RobotRun]]:
    """The paper's experiment in a ground-truth map: ``cfg.robots`` robots starting together and
    exploring different regions, and (``lone``, else None) one robot exploring everything alone.
    The team's runs are the same with or without the lone robot."""
    world = World(world_grid)
    routes, starts, lone_route, lone_start = plan_team(world, cfg)
    seeds = np.random.SeedSequence(cfg.seed).spawn(len(routes) + 1)
    trues = [drive(r, s, cfg) for r, s in zip(routes, starts)]
    end = max(len(tr) for tr in trues) / cfg.odom_rate + cfg.hold
    team = []
    for k, tr in enumerate(trues):
        # a robot done exploring stays where it is until the last one is done
        pad = int(round(end * cfg.odom_rate)) - len(tr)
        tr = np.vstack([tr, np.repeat(tr[-1:], max(pad, 0), axis=0)])
        team.append(run_robot('tb3_%d' % k, world, tr, cfg, np.random.default_rng(seeds[k])))
    if not lone:
        return team, None
    lone_true = drive(lone_route, lone_start, cfg)
    lone_true = np.vstack([lone_true, np.repeat(lone_true[-1:], int(cfg.hold * cfg.odom_rate), axis=0)])
    return team, run_robot('tb3_0', world, lone_true, cfg, np.random.default_rng(seeds[-1]))


# ------------------------------------------------------------------- real scans: CARMEN logs

@dataclass
class CarmenLog:
    """Laser scans of a CARMEN log: ``ranges[i]`` (m) taken at ``t[i]`` (s) from the
    SLAM-corrected laser pose ``poses[i]`` (x, y, yaw in the log's frame = the ground-truth
    map's frame). Beams spread over 180 degrees from -90 to +90 around the heading."""
    t: np.ndarray
    poses: np.ndarray
    ranges: np.ndarray

    @property
    def angles(self) -> np.ndarray:
        n = self.ranges.shape[1]
        # 180/360 beams: one every 180/n degrees from -90; 181/361: both ends included
        step = math.pi / (n - 1) if n % 2 == 1 else math.pi / n
        return -math.pi / 2 + step * np.arange(n)


def read_carmen(path: str) -> CarmenLog:
    """FLASER records of a CARMEN log (``.gz`` or plain). Raises ValueError naming the file."""
    import gzip
    opener = gzip.open if path.endswith('.gz') else open
    t, poses, ranges = [], [], []
    try:
        with opener(path, 'rt') as f:
            for line in f:
                if not line.startswith('FLASER'):
                    continue
                v = line.split()
                n = int(v[1])
                r = [float(x) for x in v[2:2 + n]]
                x, y, th = (float(a) for a in v[2 + n:5 + n])
                ts = float(v[8 + n])
                if ranges and len(r) != len(ranges[0]):
                    continue
                t.append(ts)
                poses.append((x, y, th))
                ranges.append(r)
    except (OSError, ValueError, IndexError) as e:
        raise ValueError('%s: cannot read CARMEN log: %s' % (path, e)) from None
    if len(t) < 2:
        raise ValueError('%s: fewer than 2 FLASER records' % path)
    # logger timestamps sometimes step back a little: keep the record order, never the clock back
    t = np.maximum.accumulate(np.array(t))
    return CarmenLog(t, np.array(poses), np.array(ranges, np.float32))


def interpolate_poses(t_src: np.ndarray, poses: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Poses at times ``t``, linear in x, y and in the unwrapped yaw."""
    yaw = np.unwrap(poses[:, 2])
    return np.stack([np.interp(t, t_src, poses[:, 0]), np.interp(t, t_src, poses[:, 1]),
                     wrap_angle(np.interp(t, t_src, yaw))], axis=1)


def simulate_carmen(log: CarmenLog, cfg: SimConfig, overlap: float = 0.25,
                    max_range: float = 40.0) -> List[RobotRun]:
    """A real laser log cut into ``cfg.robots`` consecutive stretches, one per robot, each
    grown by ``overlap`` of its length at both ends so that neighbours share some building.
    Every robot starts at time 0 of the bag. Scans are the log's real ones (readings at or
    beyond ``max_range`` are no return); true poses the log's corrected ones; odometry and
    SLAM errors as in :func:`errors` on top of them."""
    n = cfg.robots
    S = len(log.t)
    seeds = np.random.SeedSequence(cfg.seed).spawn(n)
    runs = []
    for k in range(n):
        a = max(0, int(round((k - overlap) * S / n)))
        b = min(S, int(round((k + 1 + overlap) * S / n)))
        ts = log.t[a:b] - log.t[a]
        K = int(ts[-1] * cfg.odom_rate) + 1
        t = np.arange(K) / cfg.odom_rate
        true = interpolate_poses(ts, log.poses[a:b], t)
        steps = np.minimum(np.rint(ts * cfg.odom_rate).astype(int), K - 1)
        r = log.ranges[a:b].astype(np.float32).copy()
        r[(r >= max_range) | (r <= 0.0)] = np.inf
        ang = log.angles
        scans = Scans(steps, r, float(ang[0]), float(ang[1] - ang[0]), 0.0, max_range, (0.0, 0.0, 0.0))
        rng = np.random.default_rng(seeds[k])
        odom, slam = errors(true, cfg, rng)
        name = 'tb3_%d' % k
        run = RobotRun(name, t, true, odom, slam, scans, start=tuple(float(v) for v in true[0]))
        run.maps = build_maps(name, t, slam, scans, cfg)
        runs.append(run)
    return runs
