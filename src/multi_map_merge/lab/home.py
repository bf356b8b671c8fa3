"""The demo's own world: a one-storey home drawn by the project as geometry, and its
rasteriser to an occupancy grid (ground truth for the simulator and the evaluation).

    python3 -m multi_map_merge.lab.home [--yaml OUT/home.yaml] [--png OUT/home.png]

The paper's experiment ran four Turtlebot3s in a home of about 117 m2. This home is ours, drawn
from scratch: an L-shaped house of seven rooms, a corridor and a walk-in closet (living room,
kitchen with its dining table, study, three bedrooms, bathroom), described as plain data:

- walls: centre-line segments with a thickness; a door is a gap along its wall;
- furniture and clutter: polygons of what a lidar at 0.17 m above the floor meets: solid for
  beds, sofas, cabinets, shelves, the bathtub; only the legs for tables and chairs (their tops
  are above the scan plane);
- rooms: named rectangles (the areas the doors join), for tests and the docs.

Frame ``home``: metres, x east, y north, origin at the outer south-west wall corner's centre
line; the grid's origin is ``MARGIN`` m beyond the walls. :func:`rasterise` draws it with
OpenCV at 0.05 m per cell: walls and furniture occupied (100), the floor inside the walls free
(0), outside unknown (-1), as :func:`multi_map_merge.core.mapio.load_map` reads a map_server map.
"""
from __future__ import annotations

import argparse
import math
import os
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import cv2
import numpy as np

from ..core.grid import Grid

Point = Tuple[float, float]

RESOLUTION = 0.05       # m per cell, as gmapping's maps (config/gmapping_lds02.yaml)
MARGIN = 1.0            # m of unknown around the outer walls
OUTER_WALL = 0.20       # m thick: exterior walls
INNER_WALL = 0.10       # m thick: partitions
LEG = 0.05              # m: side of a table or chair leg
FRAME_ID = 'home'


@dataclass(frozen=True)
class Wall:
    """A straight wall: centre line from ``start`` to ``end`` (m, frame ``home``), ``thickness``
    m, and doors as (offset of the door's first jamb from ``start`` along the wall, width), m.
    The wall is drawn past both ends by half its thickness, so walls that meet close the corner."""
    start: Point
    end: Point
    thickness: float = INNER_WALL
    doors: Tuple[Tuple[float, float], ...] = ()

    @property
    def length(self) -> float:
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])

    def pieces(self) -> List[Tuple[float, float]]:
        """The solid stretches between the doors: (from, to) offsets along the wall, m."""
        out, at = [], -0.5 * self.thickness
        for offset, width in sorted(self.doors):
            if offset > at:
                out.append((at, offset))
            at = offset + width
        end = self.length + 0.5 * self.thickness
        if end > at:
            out.append((at, end))
        return out

    def polygons(self) -> List[np.ndarray]:
        """Each solid stretch as a rectangle (4, 2), m."""
        (x0, y0), (x1, y1) = self.start, self.end
        ux, uy = (x1 - x0) / self.length, (y1 - y0) / self.length
        nx, ny = -uy * 0.5 * self.thickness, ux * 0.5 * self.thickness
        out = []
        for a, b in self.pieces():
            ax, ay, bx, by = x0 + ux * a, y0 + uy * a, x0 + ux * b, y0 + uy * b
            out.append(np.array([[ax + nx, ay + ny], [bx + nx, by + ny], [bx - nx, by - ny], [ax - nx, ay - ny]]))
        return out


@dataclass(frozen=True)
class Furniture:
    """One thing on the floor as the scan plane cuts it: ``parts`` are polygons (m, frame
    ``home``), several for a table's legs."""
    name: str
    parts: Tuple[Tuple[Point, ...], ...]


@dataclass(frozen=True)
class Room:
    """A room's floor between its walls' centre lines (m, frame ``home``)."""
    name: str
    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def centre(self) -> Point:
        return 0.5 * (self.x0 + self.x1), 0.5 * (self.y0 + self.y1)


@dataclass(frozen=True)
class Home:
    """A home as geometry: the outer walls' centre-line polygon, every wall, the furniture."""
    outline: Tuple[Point, ...]
    walls: Tuple[Wall, ...]
    furniture: Tuple[Furniture, ...]
    rooms: Tuple[Room, ...]


# ----------------------------------------------------------------------- shapes of furniture

def box(x0: float, y0: float, x1: float, y1: float) -> Tuple[Point, ...]:
    """An axis-aligned rectangle (m)."""
    return ((x0, y0), (x1, y0), (x1, y1), (x0, y1))


def turned_box(cx: float, cy: float, width: float, depth: float, angle_deg: float) -> Tuple[Point, ...]:
    """A rectangle ``width`` x ``depth`` m centred on (cx, cy), turned ``angle_deg`` degrees."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    return tuple((cx + c * dx - s * dy, cy + s * dx + c * dy)
                 for dx, dy in ((-width / 2, -depth / 2), (width / 2, -depth / 2),
                                (width / 2, depth / 2), (-width / 2, depth / 2)))


def disc(cx: float, cy: float, radius: float, sides: int = 12) -> Tuple[Point, ...]:
    """A round thing (a pot, a bin, a chair's column) as a polygon of ``sides``."""
    return tuple((cx + radius * math.cos(2 * math.pi * k / sides), cy + radius * math.sin(2 * math.pi * k / sides))
                 for k in range(sides))


def legs(cx: float, cy: float, width: float, depth: float, angle_deg: float = 0.0,
         size: float = LEG) -> Tuple[Tuple[Point, ...], ...]:
    """The four legs (squares of ``size`` m) of a table or chair whose top is ``width`` x
    ``depth`` m centred on (cx, cy), turned ``angle_deg``; legs set in by half their size."""
    a = math.radians(angle_deg)
    c, s = math.cos(a), math.sin(a)
    hx, hy = width / 2 - size / 2, depth / 2 - size / 2
    return tuple(turned_box(cx + c * dx - s * dy, cy + s * dx + c * dy, size, size, angle_deg)
                 for dx, dy in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)))


def solid(name: str, *polygon: Point) -> Furniture:
    return Furniture(name, (tuple(polygon),))


def on_legs(name: str, parts: Sequence[Tuple[Point, ...]]) -> Furniture:
    return Furniture(name, tuple(parts))


# -------------------------------------------------------------------------------- the home

def the_home() -> Home:
    """The demo's home (see the module docstring and docs/demo.md for its plan).

    Main block 14.2 x 9.6 m between the outer walls' centre lines, with the study added on the
    north-west (6.6 x 2.8 m) and a bay window in the living room: no rotation maps the home onto
    itself. South of the
    corridor: living room, main bedroom, bathroom; north: kitchen with dining (open to the living
    room through a wide opening), bedroom 1, bedroom 2 with its walk-in closet; the study opens
    off the kitchen. Furniture against a wall reaches into it, so no sliver of floor is left
    between them."""
    W, D = 14.2, 9.6                 # main block, m
    SX, SD = 6.6, 2.8                # study wing: width (from x = 0), depth north of the block
    KX = 4.6                         # kitchen's east wall
    CS, CN = 5.2, 6.5                # corridor between y = CS and y = CN
    # the living room's bay window: a trapezoid 0.6 m out of the south wall
    bay = ((2.8, 0.0), (3.2, -0.6), (4.6, -0.6), (5.0, 0.0))
    outline = ((0.0, 0.0),) + bay + ((W, 0.0), (W, D), (SX, D), (SX, D + SD), (0.0, D + SD))
    o = OUTER_WALL
    walls = [Wall(outline[k], outline[(k + 1) % len(outline)], o) for k in range(len(outline))]
    walls += [
        # south side of the corridor, west to east: living room <-> kitchen (a 2.2 m opening),
        # living room <-> corridor, main bedroom, bathroom
        Wall((0.0, CS), (W, CS), doors=((0.9, 2.2), (5.3, 0.9), (7.2, 0.9), (12.2, 0.8))),
        # north side of the corridor: bedroom 1, bedroom 2
        Wall((KX, CN), (W, CN), doors=((1.0, 0.9), (5.4, 0.9))),
        # kitchen <-> corridor (the corridor's west end)
        Wall((KX, CS), (KX, D), doors=((0.2, 0.9),)),
        Wall((6.6, 0.0), (6.6, CS)),                 # living room | main bedroom
        Wall((11.4, 0.0), (11.4, CS)),               # main bedroom | bathroom
        Wall((9.2, CN), (9.2, D)),                   # bedroom 1 | bedroom 2
        Wall((0.0, D), (SX, D), doors=((3.2, 0.9),)),   # study | kitchen (door), bedroom 1
        # bedroom 2's walk-in closet in its north-east corner, its door facing west
        Wall((12.8, 8.2), (W, 8.2)),
        Wall((12.8, 8.2), (12.8, D), doors=((0.3, 0.8),)),
    ]
    F: List[Furniture] = [
        # living room (0..6.6, 0..5.2)
        solid('corner sofa', (0.0, 0.45), (2.7, 0.45), (2.7, 1.35), (0.95, 1.35), (0.95, 3.1), (0.0, 3.1)),
        on_legs('coffee table', legs(1.95, 2.3, 1.0, 0.55)),
        solid('armchair', *turned_box(4.5, 1.25, 0.8, 0.8, -25.0)),
        on_legs('side table', legs(5.4, 0.8, 0.45, 0.45, 10.0)),
        solid('tv cabinet', *box(6.0, 1.2, 6.6, 3.0)),
        solid('bookshelf', *box(5.1, 0.0, 6.4, 0.38)),
        solid('plant pot', *disc(0.45, 4.75, 0.2)),
        solid('floor lamp', *disc(3.1, 0.5, 0.12, 8)),
        solid('toy basket', *disc(5.3, 4.1, 0.22, 10)),
        # kitchen and dining (0..4.6, 5.2..9.6)
        solid('fridge', *box(0.0, 5.2, 0.75, 5.9)),
        solid('kitchen counter', (0.0, 5.9), (0.65, 5.9), (0.65, 8.95), (2.9, 8.95), (2.9, 9.6), (0.0, 9.6)),
        on_legs('dining table', legs(2.6, 7.3, 1.6, 0.9)),
        on_legs('chair', legs(2.15, 6.55, 0.42, 0.42)),
        on_legs('chair', legs(3.05, 6.55, 0.42, 0.42)),
        on_legs('chair', legs(2.25, 8.05, 0.42, 0.42, 10.0)),
        on_legs('chair', legs(3.7, 7.35, 0.42, 0.42, 80.0)),
        solid('bin', *disc(4.25, 9.3, 0.18, 10)),
        # study (0..6.6, 9.6..12.4)
        solid('bookcase', *box(0.0, 9.9, 0.4, 12.0)),
        solid('desk drawers', *box(1.0, 11.8, 1.45, 12.4)),
        on_legs('desk', legs(1.7, 12.1, 1.45, 0.6)[1:3]),
        solid('office chair column', *disc(1.75, 11.35, 0.05, 8)),
        solid('boxes', *turned_box(3.4, 10.5, 0.5, 0.4, 20.0)),
        solid('boxes', *turned_box(3.9, 10.15, 0.4, 0.35, -10.0)),
        solid('upright piano', *box(4.4, 11.85, 5.9, 12.4)),
        solid('reading chair', *turned_box(5.85, 10.35, 0.75, 0.75, 30.0)),
        # main bedroom (6.6..11.4, 0..5.2)
        solid('double bed', *box(8.2, 0.0, 9.8, 2.1)),
        solid('night stand', *box(7.7, 0.0, 8.15, 0.45)),
        solid('night stand', *box(9.85, 0.0, 10.3, 0.45)),
        solid('wardrobe', *box(6.6, 0.6, 7.25, 2.8)),
        solid('dresser', *box(10.85, 2.6, 11.4, 3.9)),
        solid('laundry basket', *disc(10.85, 0.55, 0.2)),
        solid('armchair', *turned_box(10.6, 4.5, 0.7, 0.7, 15.0)),
        # bathroom (11.4..14.2, 0..5.2)
        solid('bathtub', *box(12.4, 0.0, 14.2, 0.8)),
        solid('washing machine', *box(11.4, 0.0, 12.05, 0.65)),
        solid('toilet', (14.2, 1.95), (13.75, 1.95), (13.55, 2.05), (13.5, 2.2), (13.55, 2.35),
              (13.75, 2.45), (14.2, 2.45)),
        solid('sink cabinet', *box(11.4, 2.6, 11.95, 3.6)),
        solid('linen cabinet', *box(13.7, 3.7, 14.2, 4.6)),
        # corridor (4.6..14.2, 5.2..6.5)
        solid('shoe rack', *box(13.75, 5.2, 14.2, 6.3)),
        solid('console', *box(7.9, 6.2, 9.0, 6.5)),
        # bedroom 1 (4.6..9.2, 6.5..9.6)
        solid('bed', *box(7.0, 8.65, 9.2, 9.6)),
        on_legs('desk', legs(5.3, 9.3, 1.2, 0.6)),
        on_legs('chair', legs(5.35, 8.65, 0.4, 0.4, -15.0)),
        solid('bookshelf', *box(8.7, 6.6, 9.2, 7.8)),
        solid('toy box', *turned_box(6.9, 7.3, 0.5, 0.4, 15.0)),
        # bedroom 2 (9.2..14.2, 6.5..9.6, the closet in its corner)
        solid('bed', *box(9.2, 7.5, 10.15, 9.6)),
        solid('desk', *box(13.6, 6.5, 14.2, 7.9)),
        on_legs('chair', legs(13.2, 7.2, 0.42, 0.42, 5.0)),
        solid('bean bag', *disc(11.6, 8.95, 0.35)),
        solid('closet shelves', *box(13.75, 8.2, 14.2, 9.6)),
    ]
    rooms = (
        Room('living room', 0.0, 0.0, 6.6, CS),
        Room('kitchen', 0.0, CS, KX, D),
        Room('study', 0.0, D, SX, D + SD),
        Room('corridor', KX, CS, W, CN),
        Room('main bedroom', 6.6, 0.0, 11.4, CS),
        Room('bathroom', 11.4, 0.0, W, CS),
        Room('bedroom 1', KX, CN, 9.2, D),
        Room('bedroom 2', 9.2, CN, W, D),             # an L: the closet takes its corner
        Room('closet', 12.8, 8.2, W, D),
    )
    return Home(outline, tuple(walls), tuple(F), rooms)


# ---------------------------------------------------------------------------- rasterising

def _mark(img: np.ndarray, polygon: np.ndarray, value: int, origin: Point, resolution: float) -> None:
    """Set ``img``'s cells whose centre lies inside ``polygon`` (m, (N, 2)) to ``value`` (an
    even-odd crossing test on the cell centres of the polygon's bounding box); a polygon that
    holds no centre (a leg thinner than a cell) marks the cell holding its centroid."""
    poly = np.asarray(polygon, np.float64)
    (x0, y0), (x1, y1) = poly.min(0), poly.max(0)
    h, w = img.shape
    c0 = max(int(math.floor((x0 - origin[0]) / resolution)), 0)
    r0 = max(int(math.floor((y0 - origin[1]) / resolution)), 0)
    c1 = min(int(math.ceil((x1 - origin[0]) / resolution)), w)
    r1 = min(int(math.ceil((y1 - origin[1]) / resolution)), h)
    xs = origin[0] + (np.arange(c0, c1) + 0.5) * resolution
    ys = origin[1] + (np.arange(r0, r1) + 0.5) * resolution
    X, Y = np.meshgrid(xs, ys)
    inside = np.zeros(X.shape, bool)
    for (ax, ay), (bx, by) in zip(poly, np.roll(poly, -1, axis=0)):
        if ay == by:
            continue                         # a horizontal edge crosses no horizontal ray
        crosses = (ay > Y) != (by > Y)
        x_at = ax + (Y - ay) * (bx - ax) / (by - ay)
        inside ^= crosses & (X < x_at)
    img[r0:r1, c0:c1][inside] = value
    if not inside.any():
        cx, cy = poly.mean(0)
        img[int((cy - origin[1]) // resolution), int((cx - origin[0]) // resolution)] = value


def rasterise(home: Optional[Home] = None, resolution: float = RESOLUTION, margin: float = MARGIN) -> Grid:
    """The home as an occupancy grid in frame ``home`` (OccupancyGrid order, row 0 south):
    walls and furniture 100, the floor inside the outer walls 0, outside -1. A cell takes a
    shape's value when its centre is inside the shape; a shape that holds no cell centre (a
    leg) marks the cell holding its centroid. The origin is on the resolution's lattice."""
    home = home or the_home()
    corners = np.array([p for w in home.walls for poly in w.polygons() for p in poly])
    lo = np.floor((corners.min(0) - margin) / resolution) * resolution
    hi = corners.max(0) + margin
    width, height = (int(v) for v in np.ceil((hi - lo) / resolution))
    origin = (float(lo[0]), float(lo[1]))
    img = np.zeros((height, width), np.uint8)   # 0 unknown, 1 floor, 2 solid
    _mark(img, np.array(home.outline), 1, origin, resolution)
    for poly in [poly for w in home.walls for poly in w.polygons()] + \
            [np.array(part) for f in home.furniture for part in f.parts]:
        _mark(img, poly, 2, origin, resolution)
    data = np.full((height, width), -1, np.int8)
    data[img == 1] = 0
    data[img == 2] = 100
    return Grid(data, resolution, (round(origin[0], 6), round(origin[1], 6), 0.0), FRAME_ID)


_GRID: List[Grid] = []


def home_grid() -> Grid:
    """:func:`rasterise` of :func:`the_home` at the default resolution, made once per process
    (the grid is not modified by its users)."""
    if not _GRID:
        _GRID.append(rasterise())
    return _GRID[0]


def free_area(grid: Grid) -> float:
    """m2 of free cells (the floor a robot can see: furniture and walls excluded)."""
    return float(np.count_nonzero(grid.data == 0)) * grid.resolution ** 2


def write_home_map(yaml_path: str, grid: Optional[Grid] = None) -> Tuple[str, str]:
    """The home as a map_server map (``<stem>.pgm`` + ``yaml_path``); returns both paths."""
    from ..core.mapio import save_map
    return save_map(grid or home_grid(), yaml_path)


def picture(grid: Grid, home: Optional[Home] = None, scale: int = 4) -> np.ndarray:
    """BGR picture of the grid, north up, ``scale`` pixels per cell, each room named."""
    from ..core.mapio import grid_to_pgm
    img = cv2.resize(grid_to_pgm(grid), None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    for room in (home or the_home()).rooms:
        if room.name == 'closet':
            continue
        x, y = room.centre
        c = (x - grid.origin[0]) / grid.resolution * scale
        r = (grid.height - (y - grid.origin[1]) / grid.resolution) * scale
        size = cv2.getTextSize(room.name, cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)[0]
        cv2.putText(img, room.name, (int(c - size[0] / 2), int(r + size[1] / 2)), cv2.FONT_HERSHEY_SIMPLEX,
                    0.6, (40, 90, 200), 1, cv2.LINE_AA)
    # a 1 m scale bar at the bottom left
    r0, c0 = img.shape[0] - int(0.4 / grid.resolution * scale), int(0.4 / grid.resolution * scale)
    cv2.line(img, (c0, r0), (c0 + int(1.0 / grid.resolution * scale), r0), (0, 0, 0), 3)
    cv2.putText(img, '1 m', (c0, r0 - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog='python3 -m multi_map_merge.lab.home', description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--yaml', help='write the home as a map_server map (YAML; the .pgm beside it)')
    ap.add_argument('--png', help='write a picture of the home (rooms named)')
    a = ap.parse_args(argv)
    grid = home_grid()
    print('home: %d x %d cells of %.2f m, free floor %.1f m2, occupied %.1f m2' % (
        grid.width, grid.height, grid.resolution, free_area(grid),
        np.count_nonzero(grid.data == 100) * grid.resolution ** 2))
    if a.yaml:
        print('map: %s %s' % write_home_map(a.yaml, grid))
    if a.png:
        os.makedirs(os.path.dirname(os.path.abspath(a.png)), exist_ok=True)
        cv2.imwrite(a.png, picture(grid))
        print('picture: %s' % a.png)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
