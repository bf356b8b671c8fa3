"""The demo's own world (lab/home.py): the home's size, closed walls, rooms joined by doors, no
rotational symmetry, the rasterised values, its map_server form; and make_robot_bags in it
(lab/robot_bags.py, lab/worlds.py): the team's true poses in free space and the floor they cover."""
import math
import os

import cv2
import numpy as np
import pytest
import yaml

from multi_map_merge.core.grid import FREE, Grid
from multi_map_merge.core.mapio import load_map
from multi_map_merge.core.transforms import inverse, se2
from multi_map_merge.lab import home as H
from multi_map_merge.lab import simulate as sim
from multi_map_merge.lab import worlds

PAPER_AREA = 117.0      # m2, the paper's experiment
BURGER_RADIUS = 0.105   # m


@pytest.fixture(scope='module')
def grid():
    return H.rasterise()


def value_at(grid, x, y):
    """The grid's value at the metric point (x, y) (frame home)."""
    c = int(math.floor((x - grid.origin[0]) / grid.resolution))
    r = int(math.floor((y - grid.origin[1]) / grid.resolution))
    return int(grid.data[r, c])


def test_free_floor_is_the_papers_117_m2(grid):
    area = H.free_area(grid)
    assert abs(area - PAPER_AREA) <= 0.1 * PAPER_AREA, area
    # the rooms' floor (between the walls' centre lines) is more: walls and furniture take some
    rooms = sum((r.x1 - r.x0) * (r.y1 - r.y0) for r in H.the_home().rooms if r.name != 'closet')
    assert area < rooms < area + 45.0


def test_walls_are_closed(grid):
    """No free cell is reachable from outside through cells that are not walls (8-connected,
    so not even through a diagonal chink a beam could pass)."""
    passable = (grid.data != 100).astype(np.uint8)
    _, label = cv2.connectedComponents(passable, connectivity=8)
    outside = label[0, 0]
    assert grid.data[0, 0] == -1
    assert not np.any((label == outside) & (grid.data == 0))
    # and the unknown cells are only outside
    assert np.all(label[grid.data == -1] == outside)


def test_doors_join_every_room(grid):
    """The floor is one piece (4-connected), and a Burger (the simulator's clearance) can drive
    into every room but the walk-in closet from one connected navigable space."""
    n, label = cv2.connectedComponents((grid.data == 0).astype(np.uint8), connectivity=4)
    assert n == 2, 'the floor is in %d pieces' % (n - 1)
    world = sim.World(grid)
    nav = world.navigable(sim.SimConfig().clearance)
    for room in H.the_home().rooms:
        c0, r0 = (int(v) for v in world.to_cell(room.x0, room.y0))
        c1, r1 = (int(v) for v in world.to_cell(room.x1, room.y1))
        reached = nav[r0:r1, c0:c1].sum() * grid.resolution ** 2
        assert reached > (0.1 if room.name == 'closet' else 1.0), (room.name, reached)


def best_overlap(a: np.ndarray, b: np.ndarray) -> float:
    """Largest share of ``a``'s cells that ``b`` covers, over every shift of ``b`` (FFT)."""
    h, w = a.shape[0] + b.shape[0], a.shape[1] + b.shape[1]
    corr = np.fft.irfft2(np.fft.rfft2(a, (h, w)) * np.conj(np.fft.rfft2(b, (h, w))), (h, w))
    return float(corr.max() / a.sum())


def test_no_rotation_maps_the_home_onto_itself(grid):
    """Its walls and furniture rotated by 90, 180 or 270 degrees overlap themselves at best about
    half as well as unrotated (each cell counted with a cell of slack): a rotated copy is no
    second answer for map alignment. A rectangle of rooms would score near 1."""
    occ = (grid.data == 100).astype(np.float64)
    assert best_overlap(occ, occ) == pytest.approx(1.0, abs=1e-6)
    for k in (1, 2, 3):
        turned = cv2.dilate(np.rot90(occ, k).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(np.float64)
        assert best_overlap(occ, turned) < 0.6, k * 90
    # the check sees symmetry: a home mirrored onto itself by its 180-degree turn scores high
    half = occ[:, :occ.shape[1] // 2]
    symmetric = np.hstack([half, np.rot90(half, 2)])
    assert best_overlap(symmetric, np.rot90(symmetric, 2)) > 0.99


def test_rasterised_values(grid):
    home = H.the_home()
    assert set(np.unique(grid.data).tolist()) == {-1, 0, 100}
    assert grid.resolution == H.RESOLUTION and grid.origin[2] == 0.0 and grid.frame_id == 'home'
    # the margin: unknown all round, the walls within MARGIN of the grid's edge
    for edge in (grid.data[0], grid.data[-1], grid.data[:, 0], grid.data[:, -1]):
        assert np.all(edge == -1)
    assert grid.origin[0] == pytest.approx(-H.MARGIN - H.OUTER_WALL / 2, abs=grid.resolution)
    assert value_at(grid, -0.6, 5.0) == -1                  # outside, west
    assert value_at(grid, 7.0, 0.0) == 100                  # the south wall's centre line
    assert value_at(grid, 7.0, 0.08) == 100                 # still in it (0.2 m thick)
    assert value_at(grid, 7.0, 0.14) == 0                   # the main bedroom's floor beyond it
    assert value_at(grid, 6.6, 3.5) == 100                  # a partition (0.1 m)
    assert value_at(grid, 9.0, 5.85) == 0                   # the corridor
    corridor_south = next(w for w in home.walls if w.start == (0.0, 5.2))
    offset, width = corridor_south.doors[1]                 # living room <-> corridor
    assert value_at(grid, offset + width / 2, 5.2) == 0     # a door is a gap in its wall
    assert value_at(grid, offset - 0.1, 5.2) == 100         # its jamb
    table = next(f for f in home.furniture if f.name == 'dining table')
    leg = np.mean(table.parts[0], axis=0)
    assert value_at(grid, *leg) == 100                      # a table's leg is seen ...
    assert value_at(grid, 2.6, 7.3) == 0                    # ... not its top, above the lidar
    assert value_at(grid, 9.0, 1.0) == 100                  # the double bed, solid to the floor


def test_wall_pieces_leave_the_doors_open():
    w = H.Wall((0.0, 0.0), (4.0, 0.0), 0.1, doors=((1.0, 0.9), (3.0, 0.5)))
    assert np.allclose(w.pieces(), [(-0.05, 1.0), (1.9, 3.0), (3.5, 4.05)])
    poly = w.polygons()[1]
    assert poly[:, 0].min() == pytest.approx(1.9) and poly[:, 1].max() == pytest.approx(0.05)
    # a door at a wall's end leaves only the half thickness that closes the corner
    assert np.allclose(H.Wall((0.0, 0.0), (0.0, 2.0), 0.1, doors=((1.2, 0.8),)).pieces(),
                       [(-0.05, 1.2), (2.0, 2.05)])


def test_map_server_files_round_trip(tmp_path, grid):
    pgm, path = H.write_home_map(str(tmp_path / 'home.yaml'), grid)
    assert os.path.exists(pgm)
    back = load_map(path)
    assert np.array_equal(back.data, grid.data)
    assert back.origin == pytest.approx(grid.origin) and back.resolution == grid.resolution
    # the world a tool asks for by name is the same map, written where it is told
    p, g = worlds.world_map(worlds.HOME, str(tmp_path / 'out'))
    assert p == str(tmp_path / 'out' / 'home.yaml') and np.array_equal(load_map(p).data, grid.data)


def test_aws_small_house_is_read_in_place_or_said_missing(tmp_path):
    from multi_map_merge.core.mapio import MapFileError
    path = worlds.aws_small_house()
    if path is None:
        with pytest.raises(MapFileError, match='shared/data'):
            worlds.world_map(worlds.AWS_SMALL_HOUSE, str(tmp_path))
    else:
        p, g = worlds.world_map(worlds.AWS_SMALL_HOUSE, str(tmp_path))
        assert p == path and g.data.shape[0] > 100 and not os.listdir(str(tmp_path))


def seen_free(run: sim.RobotRun, truth: Grid) -> np.ndarray:
    """Which of the truth's free cells the robot's last map knows as free (its map frame put
    at its true start: the SLAM model's small drift is ignored)."""
    rows, cols = np.nonzero(truth.levels() == FREE)
    x = truth.origin[0] + (cols + 0.5) * truth.resolution
    y = truth.origin[1] + (rows + 0.5) * truth.resolution
    T = inverse(se2(*run.start))
    px, py = T[0, 0] * x + T[0, 1] * y + T[0, 2], T[1, 0] * x + T[1, 1] * y + T[1, 2]
    g = run.maps[-1][1]
    c = np.floor((px - g.origin[0]) / g.resolution).astype(np.int64)
    r = np.floor((py - g.origin[1]) / g.resolution).astype(np.int64)
    inside = (c >= 0) & (r >= 0) & (c < g.width) & (r < g.height)
    out = np.zeros(len(x), bool)
    out[inside] = g.levels()[r[inside], c[inside]] == FREE
    return out


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    """make_robot_bags in the home, 4 robots, seed 3, the team only (about 8 s): (output
    directory, the team's runs as simulated for the bag)."""
    pytest.importorskip('rosbag')
    from multi_map_merge.lab import robot_bags
    out = tmp_path_factory.mktemp('home_bags')
    captured = []

    def simulate_and_keep(*args, **kw):
        result = sim.simulate_world(*args, **kw)
        captured.append(result)
        return result

    # (pytest 4.6, focal's, has no MonkeyPatch for a module-scoped fixture)
    robot_bags.simulate_world = simulate_and_keep
    try:
        rc = robot_bags.main(['-o', str(out / 'house.bag'), '--robots', '4', '--seed', '3', '--no-single',
                              '--sensors-only'])
    finally:
        robot_bags.simulate_world = sim.simulate_world
    assert rc == 0
    team, lone = captured[0]
    assert lone is None
    return out, team


@pytest.mark.filterwarnings('ignore:tostring.. is deprecated:DeprecationWarning')
def test_make_robot_bags_in_the_home(bags, grid):
    out, team = bags
    assert sorted(os.listdir(str(out))) == ['home.pgm', 'home.yaml', 'house.bag', 'house.truth.yaml']
    with open(str(out / 'house.truth.yaml')) as f:
        truth = yaml.safe_load(f)
    assert truth['world'] == 'home.yaml' and sorted(truth['robots']) == ['tb3_0', 'tb3_1', 'tb3_2', 'tb3_3']
    assert np.array_equal(load_map(str(out / 'home.yaml')).data, grid.data)
    world = sim.World(grid)
    for r in team:
        assert truth['robots'][r.name]['start'] == pytest.approx(list(r.start), abs=1e-6)
        # every true pose on free floor, the Burger's body clear of walls and furniture
        c, rr = world.to_cell(r.true[:, 0], r.true[:, 1])
        c, rr = np.rint(c).astype(int), np.rint(rr).astype(int)
        assert np.all(world.free[rr, c]), r.name
        assert world.edt[rr, c].min() * grid.resolution > BURGER_RADIUS, r.name
    # they start together (the paper) and end apart, each in a region of its own
    starts = np.array([r.start[:2] for r in team])
    ends = np.array([r.true[-1, :2] for r in team])
    assert np.max(np.hypot(*(starts - starts.mean(0)).T)) < 0.5
    assert min(np.hypot(*(ends[i] - ends[j])) for i in range(4) for j in range(i)) > 2.0


def test_the_team_covers_the_home(bags, grid):
    """Each robot maps a real part of the home (a quarter or more), some of it seen by no
    other; together they map most of it."""
    _, team = bags
    seen = np.array([seen_free(r, grid) for r in team])
    assert np.all(seen.mean(axis=1) > 0.25), seen.mean(axis=1)
    only = seen & (seen.sum(axis=0) == 1)
    assert np.all(only.mean(axis=1) > 0.03), only.mean(axis=1)
    assert seen.any(axis=0).mean() > 0.9


@pytest.mark.slow
def test_the_lone_robot_covers_the_home(grid):
    """One robot exploring the home alone (about 15 s) maps most of it."""
    team, lone = sim.simulate_world(grid, sim.SimConfig(robots=4, seed=3))
    assert seen_free(lone, grid).mean() > 0.85
    assert lone.distance > 0.8 * sum(r.distance for r in team)
