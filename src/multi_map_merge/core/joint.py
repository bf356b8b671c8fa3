"""Placement by what all the overlaps say: every robot's placement refined against
every placed map it overlaps, after the pose graph.

A link is fitted on its pair's overlap, which on gmapping maps lies mostly near where the robots
met; a gmapping map bends, so a robot placed by its links (chained or averaged by the pose
graph) fits its partners' start area and can sit walls apart from them elsewhere. Here each
non-reference robot's pose is searched, the others held where they are (block coordinates over
the robots, the reference fixed), for the pose whose walls best meet the walls of *all* the
other placed maps at once: a correlative search (:func:`covariance.search`) of its wall cells
against the truncated squared distance to the nearest wall of the union of the other maps,
warped onto the merged lattice; then ICP (:func:`refine.refine`) on that union's walls, with a
tight gate, for what a cell's lattice cannot resolve. Every wall cell of the robot that lands on
a cell another robot knows counts once, so an overlap with more walls counts more.

Near its start first: a SLAM map is most exact where its robot started (its map frame's origin,
as gmapping, slam_toolbox and Cartographer have it) and its error grows with the path driven from
there. The walls a robot is refined on are thinned, deterministically, to a share
``1 / (1 + (d / START_SCALE)^2)`` of those at distance ``d`` from its origin, relative to its
nearest wall that meets another map (:func:`near_start_first`): the walls near its start weigh
most, every part of its overlap still counts, and a robot whose start lies far from every other
map keeps most of its walls.

Bounds: the search stays within ``SEARCH_WINDOW`` of the pose the links gave (the *anchor*,
:attr:`placement.Placement.graph_T`), measured at the centre of the robot's walls (at its map
frame's origin, metres away, a small turn looks like a jump); a result beyond it, one whose
walls do not meet clearly better than the anchor's (``covariance.BETTER_COST``) or one that verifies
(:func:`verify.agreement_counts`, summed over the robot's overlaps) worse than the anchor keeps
the anchor. The window is centred on the anchor, not on the robot's current pose, so the result
is a function of the maps, the anchors and the other robots' poses only: refining again what
was refined gives the same poses (no drift, no jitter). Deterministic: no random sampling, the
robots in name order.

Frames: poses are 3x3 SE(2) matrices of a robot's map frame in the merged frame (metres,
radians); the search works in cells of the merged lattice (:func:`composite.lattice_for` of
the reference's grid).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Protocol, Tuple

import cv2
import numpy as np

from . import covariance, verify
from .composite import Lattice
from .grid import FREE, OCCUPIED, UNKNOWN, Grid
from .refine import WallField, occupied_points, refine
from .transforms import apply, cell_to_metric, inverse, pose_to_image, turn_between

# how far a placement may move from the pose its links gave: metres (at the centre of its
# walls), radians
SEARCH_WINDOW = (0.5, math.radians(9.0))
# a refined pose within this of the robot's current one (metres, radians) leaves its placement
# as it is: a map that grew by a few cells does not move its TF
SAME_POSE = (0.02, math.radians(0.2))
# block-coordinate rounds over the robots at most (each robot against the others' latest poses)
ROUNDS = 3
# ICP after the search: its pairing gate (cells) shrinks from this to one cell
ICP_GATE = 2.0
# wall cells of the robot that must land on cells another robot knows for it to be refined
MIN_WALLS = 100
# metres from a robot's start (its map frame's origin) at which its walls count half as much in
# the refinement as those at its start (:func:`near_start_first`)
START_SCALE = 2.0
# wall cells per map used (evenly thinned): the search scores at most covariance.MAX_POINTS
MAX_WALLS = 4000
# placed maps a robot is refined against at most: those whose placed known boxes meet its own
# most (in a large team a map overlaps a few others much and the rest little or not at all)
NEIGHBOURS = 8
# refinements of a round shipped to the worker processes in this many chunks per worker: a
# chunk carries the maps it needs once (neighbours overlap), several per worker even out their
# lengths
CHUNKS_PER_WORKER = 2
# robots to refine in a round from which they go to the workers: a chunk ships the maps its
# robots meet (megabytes with maps of 100,000 known cells), which a few refinements do not repay
AHEAD_FROM = 16
# metres a robot's placed known box is grown by when looking for the maps it may meet: beyond
# the window its union is warped on (the search's window and the cost field's pad)
NEAR = 2.0


class Runner(Protocol):
    """Runs calls in worker processes: ``runner(fn, [args, ...])`` returns ``[fn(*args), ...]``
    in order; ``workers``: how many run at once."""

    workers: int

    def __call__(self, fn: Callable, calls: List[tuple]) -> list: ...


@dataclass
class Robot:
    """What the refinement needs of one placed robot: its grid's geometry and levels (at the
    merged resolution), the classified values of its known part and its wall cells. Plain
    arrays: it goes to the worker processes as it is."""

    resolution: float                   # metres per cell
    origin: Tuple[float, float, float]  # (x, y, yaw) of cell (0, 0)'s corner in its map frame
    levels: np.ndarray
    box: Tuple[int, int, int, int]      # known box (rows r0:r1, cols c0:c1)
    values: np.ndarray                  # int8 -1/0/100 of the cells in box
    walls: np.ndarray                   # (N, 2) col, row of occupied cells (thinned)
    W: np.ndarray                       # cells -> metres in its map frame

    @classmethod
    def of(cls, grid: Grid, levels: np.ndarray, box_values) -> Optional['Robot']:
        if box_values is None:
            return None
        box, values = box_values
        walls = occupied_points(levels, box, MAX_WALLS)
        return cls(grid.resolution, tuple(grid.origin), levels, box, values, walls,
                   cell_to_metric(grid.resolution, grid.origin))


# classified OccupancyGrid values (as uint8: 255 unknown, 0 free, 100 occupied) -> levels
_LEVELS_LUT = np.full(256, UNKNOWN, np.uint8)
_LEVELS_LUT[0] = FREE
_LEVELS_LUT[100] = OCCUPIED


def _placed_box(r: Robot, T: np.ndarray, grow: float) -> Tuple[float, float, float, float]:
    """(x0, y0, x1, y1) metres: the axis-aligned box in the merged frame of the robot's known
    box placed at ``T``, grown by ``grow`` metres."""
    r0, r1, c0, c1 = r.box
    p = apply(T @ r.W, np.array([[c0, r0], [c1, r0], [c0, r1], [c1, r1]], np.float64))
    return (float(p[:, 0].min()) - grow, float(p[:, 1].min()) - grow,
            float(p[:, 0].max()) + grow, float(p[:, 1].max()) + grow)


Box = Tuple[float, float, float, float]     # (x0, y0, x1, y1) metres, merged frame


def placed_boxes(robots: Dict[str, Robot], poses: Dict[str, np.ndarray]) -> Dict[str, Box]:
    """Per robot of ``poses`` (and ``robots``): its known box placed in the merged frame
    (:func:`_placed_box`, not grown)."""
    return {o: _placed_box(robots[o], T, 0.0) for o, T in poses.items() if o in robots}


def neighbours(robots: Dict[str, Robot], poses: Dict[str, np.ndarray], n: str,
               most: int = NEIGHBOURS, boxes: Optional[Dict[str, Box]] = None) -> List[str]:
    """The robots of ``poses`` (robot -> pose in the merged frame) that robot ``n`` is refined
    against: those whose placed known boxes meet its own grown by NEAR (the others land
    nowhere in its union's window), the ``most`` whose boxes meet it most; by name. ``boxes``:
    :func:`placed_boxes` of ``poses``, when the caller has them."""
    if boxes is None:
        boxes = placed_boxes(robots, poses)
    x0, y0, x1, y1 = boxes[n]
    a = (x0 - NEAR, y0 - NEAR, x1 + NEAR, y1 + NEAR)
    met = []
    for o in sorted(poses):
        if o == n or o not in robots:
            continue
        b = boxes[o]
        w, h = min(a[2], b[2]) - max(a[0], b[0]), min(a[3], b[3]) - max(a[1], b[1])
        if w > 0 and h > 0:
            met.append((-w * h, o))
    return sorted(o for _, o in sorted(met)[:most])


def refine_placements(robots: Dict[str, Robot], anchors: Dict[str, np.ndarray], ref: str,
                      lattice: Lattice, tolerance: int, current: Optional[Dict[str, np.ndarray]] = None,
                      moving: Optional[List[str]] = None, run: Optional[Runner] = None) -> Dict[str, np.ndarray]:
    """The pose of every robot of ``anchors`` (3x3, its map frame in the merged frame) refined
    against the placed robots it overlaps (module docstring: its :func:`neighbours`); the
    reference and robots without walls on another's known cells keep their anchor. ``robots``:
    every placed robot (the reference included), ``tolerance``: verification's wall tolerance
    (cells). ``moving``: the robots refined (default: every one); the others stay at their pose
    of ``current`` (default: their anchor). ``run``: runs a list of calls in worker processes
    (:data:`Runner`); the robots of a round (AHEAD_FROM or more) are then refined there ahead,
    against the poses the round starts from, and a robot whose neighbours moved earlier in the
    round is refined again here: the same poses as without it. Returns robot -> pose, for
    every robot of ``anchors``."""
    start = {n: T.copy() for n, T in anchors.items()}
    movable = [n for n in sorted(anchors) if n != ref and n in robots]
    if moving is not None:
        movable = [n for n in movable if n in moving]
        for n in start:
            if n not in movable and current is not None and n in current:
                start[n] = current[n].copy()
    poses = {n: T.copy() for n, T in start.items()}
    if len(poses) < 2 or not movable:
        return poses
    boxes = placed_boxes(robots, start)
    near = {n: neighbours(robots, start, n, boxes=boxes) for n in movable}
    seen: Dict[str, list] = {}      # per robot: the others' poses it was last refined against
    # (a few robots refined against many held: one round; their moves barely touch each other)
    for _ in range(ROUNDS if moving is None else 1):
        moved = False
        ahead = _ahead(robots, [n for n in movable if not _same_inputs(seen, n, poses, near[n])],
                       anchors, poses, near, lattice, tolerance, run)
        for n in movable:
            others = {o: poses[o] for o in near[n]}
            if _same_inputs(seen, n, poses, near[n]):
                continue                 # the same inputs give the same pose
            seen[n] = list(others.values())
            if n in ahead and _same_inputs(seen, n, ahead[n][0], near[n]):
                T = ahead[n][1]
            else:
                T = _refine_one(robots, n, anchors[n], others, lattice, tolerance)
            if not np.array_equal(T, poses[n]):
                poses[n] = T
                moved = True
        if not moved:
            break
    # all together no worse than the links' placements, or the links' placements stand (over
    # the overlaps of the robots refined)
    pairs = sorted({tuple(sorted((n, o))) for n in movable for o in near[n]
                    if not (np.array_equal(poses[n], start[n]) and np.array_equal(poses[o], start[o]))})
    if _agreement_over(robots, poses, pairs, tolerance) < _agreement_over(robots, start, pairs, tolerance):
        return start
    return poses


def _same_inputs(seen: Dict[str, list], n: str, poses: Dict[str, np.ndarray], near: List[str]) -> bool:
    """Robot ``n`` was last refined against its neighbours ``near`` at these ``poses``."""
    return n in seen and all(np.array_equal(a, poses[o]) for a, o in zip(seen[n], near))


def _ahead(robots: Dict[str, Robot], todo: List[str], anchors: Dict[str, np.ndarray],
           poses: Dict[str, np.ndarray], near: Dict[str, List[str]], lattice: Lattice, tolerance: int,
           run: Optional[Runner]) -> Dict[str, Tuple[Dict[str, np.ndarray], np.ndarray]]:
    """Per robot of ``todo`` (robot -> (its neighbours' poses it was refined against, its
    pose)), refined in worker processes by ``run``, in ``CHUNKS_PER_WORKER`` chunks per worker
    (a chunk carries the robots its refinements need once); none without ``run`` or with fewer
    than AHEAD_FROM robots (the shipping would cost more than the workers save)."""
    if run is None or len(todo) < AHEAD_FROM:
        return {}
    k = min(len(todo), CHUNKS_PER_WORKER * run.workers)
    chunks = [todo[i::k] for i in range(k)]
    calls = []
    for chunk in chunks:
        jobs = [(n, anchors[n], {o: poses[o] for o in near[n]}) for n in chunk]
        needed = set(chunk) | {o for n in chunk for o in near[n]}
        calls.append(({o: robots[o] for o in needed}, jobs, lattice, tolerance))
    out = {}
    for (_, jobs, _, _), poses_of in zip(calls, run(refine_chunk, calls)):
        for (n, _, others), T in zip(jobs, poses_of):
            out[n] = (others, T)
    return out


def refine_chunk(robots: Dict[str, Robot], jobs: List[Tuple[str, np.ndarray, Dict[str, np.ndarray]]],
                 lattice: Lattice, tolerance: int) -> List[np.ndarray]:
    """:func:`_refine_one` of each job (robot, anchor, its neighbours' poses): a worker's task."""
    return [_refine_one(robots, n, anchor, others, lattice, tolerance) for n, anchor, others in jobs]


def _refine_one(robots: Dict[str, Robot], n: str, anchor: np.ndarray, others: Dict[str, np.ndarray],
                lattice: Lattice, tolerance: int) -> np.ndarray:
    """Robot ``n``'s pose searched around ``anchor`` against the union of ``others`` (robot ->
    pose) warped onto ``lattice``; ``anchor`` when nothing better is found within the bounds."""
    r = robots[n]
    if r.walls.shape[0] < MIN_WALLS:
        return anchor
    res = lattice.resolution
    half_cells = int(math.ceil(SEARCH_WINDOW[0] / res))
    # a window of the lattice around where the robot's known box lands, wide enough for the
    # search's steps (and covariance.CostField's own pad) around it
    to_lattice = inverse(cell_to_metric(res, (lattice.x0, lattice.y0, 0.0)))
    r0, r1, c0, c1 = r.box
    corners = apply(to_lattice @ anchor @ r.W, np.array([[c0, r0], [c1, r0], [c0, r1], [c1, r1]], np.float64))
    m = 2 * half_cells + 8
    i0, j0 = int(math.floor(corners[:, 0].min())) - m, int(math.floor(corners[:, 1].min())) - m
    i1, j1 = int(math.ceil(corners[:, 0].max())) + m, int(math.ceil(corners[:, 1].max())) + m
    union = _union(robots, others, lattice, i0, j0, i1 - i0, j1 - j0)
    if union is None:
        return anchor
    # the robot's cells -> cells of the window
    to_window = np.array([[1.0, 0.0, -i0], [0.0, 1.0, -j0], [0.0, 0.0, 1.0]]) @ to_lattice
    A0 = to_window @ anchor @ r.W
    # its walls that land on (or within the tolerance of) a cell another robot knows: only
    # those say where it belongs
    known = cv2.dilate((union > UNKNOWN).view(np.uint8), np.ones((2 * tolerance + 1,) * 2, np.uint8)) > 0
    at = np.rint(apply(A0, r.walls)).astype(np.int64)
    h, w = union.shape
    inside = (at[:, 0] >= 0) & (at[:, 0] < w) & (at[:, 1] >= 0) & (at[:, 1] < h)
    seen = np.zeros(len(at), bool)
    seen[inside] = known[at[inside, 1], at[inside, 0]]
    pts = r.walls[seen]
    if pts.shape[0] < MIN_WALLS:
        return anchor
    pts = near_start_first(pts, r.W)
    wf = WallField(union, margin=0)
    if not wf.ok:
        return anchor
    field = covariance.CostField(union, wf.dist_flat[:-1].reshape(wf.shape),
                                 (int(wf.offset[0]), int(wf.offset[1])), pad=2 * half_cells + 8)
    pivot = pts.mean(axis=0)
    found = covariance.search(field, pts, A0, half_cells, math.degrees(SEARCH_WINDOW[1]), pivot)
    if found is None:
        return anchor
    A, _ = found
    cost0 = _cost(field, pts, A0)
    # ICP on the union's walls, from the search's pose: the lattice's cells are the search's
    # resolution; kept when its walls meet at least as well
    A_icp = refine(wf, pts, A, max_distance=ICP_GATE)
    candidates = [A] if A_icp is None else [A_icp, A]
    before = None
    for cand in candidates:
        if _cost(field, pts, cand) > cost0 - covariance.BETTER_COST or not _within(A0, cand, pivot, res):
            continue
        T = inverse(to_window) @ cand @ inverse(r.W)
        if before is None:
            before = _agreement_of(robots, n, anchor, others, tolerance)
        if _agreement_of(robots, n, T, others, tolerance) >= before:
            return T
    return anchor


def near_start_first(walls: np.ndarray, W: np.ndarray, scale: float = START_SCALE,
                     least: int = MIN_WALLS) -> np.ndarray:
    """``walls`` (N x 2 cells of a robot's grid; ``W``: its cells -> metres in its map frame)
    thinned to a share ``(1 + (d0/scale)^2) / (1 + (d/scale)^2)`` of those at ``d`` metres from
    the map frame's origin (``d0``: the nearest wall's), in a fixed low-discrepancy order: the
    same walls give the same points. ``walls`` as they are when fewer than ``least`` would
    remain."""
    if walls.shape[0] == 0:
        return walls
    xy = apply(W, walls.astype(np.float64))
    d2 = (xy * xy).sum(axis=1) / (scale * scale)
    share = (1.0 + d2.min()) / (1.0 + d2)
    # the golden ratio's multiples modulo 1 spread evenly over [0, 1) in any stretch of the walls
    keep = (np.arange(walls.shape[0]) * _GOLDEN) % 1.0 < share
    return walls[keep] if int(keep.sum()) >= least else walls


_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def _union(robots: Dict[str, Robot], poses: Dict[str, np.ndarray], lattice: Lattice,
           i0: int, j0: int, w: int, h: int) -> Optional[np.ndarray]:
    """Levels (UNKNOWN / FREE / OCCUPIED) of the robots ``poses`` places, warped onto the
    ``w`` x ``h`` cells of ``lattice`` from cell (i0, j0) and composited as the merged map is
    (occupied over free over unknown); None where none of them lands."""
    res = lattice.resolution
    W_window = cell_to_metric(res, (lattice.x0 + i0 * res, lattice.y0 + j0 * res, 0.0))
    out = None
    for o, T in poses.items():
        r = robots[o]
        r0, _, c0, _ = r.box
        # window cells -> cells of o's known box
        M = np.array([[1.0, 0.0, -c0], [0.0, 1.0, -r0], [0.0, 0.0, 1.0]]) @ inverse(r.W) @ inverse(T) @ W_window
        warped = cv2.warpAffine(r.values.view(np.uint8), M[:2], (w, h),
                                flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=255).view(np.int8)
        out = warped if out is None else cv2.max(out, warped)
    if out is None or not (out >= 0).any():
        return None
    return _LEVELS_LUT[out.view(np.uint8)]


def _cost(field: covariance.CostField, pts: np.ndarray, A: np.ndarray) -> float:
    """Mean truncated squared distance (cells^2) of the points ``pts`` (cells of the robot)
    under ``A`` to the field's walls; a point off the table costs the truncation."""
    idx, ok = field.flat_index(apply(A, pts), 0)
    total = field.flat.take(idx[ok]).sum(dtype=np.float64) + (len(pts) - int(ok.sum())) * field.big
    return float(total) / (len(pts) * covariance.COST_SCALE)


def _within(A0: np.ndarray, A: np.ndarray, pivot: np.ndarray, res: float) -> bool:
    """``A`` (robot cells -> lattice cells) within SEARCH_WINDOW of ``A0``, measured at the
    robot's cell ``pivot`` (the centre of its walls)."""
    d = apply(A, pivot[None])[0] - apply(A0, pivot[None])[0]
    return math.hypot(d[0], d[1]) * res <= SEARCH_WINDOW[0] + 1e-9 and turn_between(A0, A) <= SEARCH_WINDOW[1] + 1e-9


def _agreement_of(robots: Dict[str, Robot], n: str, T: np.ndarray, others: Dict[str, np.ndarray],
                  tolerance: int) -> float:
    """Robot ``n`` at ``T`` against every one of ``others``: verification's agreement
    (:func:`verify.agreement_counts`), its walls meeting theirs and theirs meeting its, summed
    over the overlaps (an overlap with more walls counts more); 0 without any."""
    agree = conflict = 0
    for o, To in others.items():
        a, c = _counts(robots[o], robots[n], inverse(To) @ T, tolerance)
        agree += a
        conflict += c
    return agree / float(agree + conflict) if agree + conflict else 0.0


def joint_agreement(robots: Dict[str, Robot], poses: Dict[str, np.ndarray], tolerance: int) -> float:
    """Verification's agreement summed over every pair of placed robots of ``poses`` (robot ->
    pose in the merged frame): 0..1, 0 when no walls overlap."""
    names = [n for n in sorted(poses) if n in robots]
    return _agreement_over(robots, poses, [(a, b) for i, a in enumerate(names) for b in names[i + 1:]], tolerance)


def _agreement_over(robots: Dict[str, Robot], poses: Dict[str, np.ndarray], pairs, tolerance: int) -> float:
    """Verification's agreement summed over ``pairs`` of robots at ``poses``: 0..1, 0 when no
    walls overlap."""
    agree = conflict = 0
    for a, b in pairs:
        ag, co = _counts(robots[a], robots[b], inverse(poses[a]) @ poses[b], tolerance)
        agree += ag
        conflict += co
    return agree / float(agree + conflict) if agree + conflict else 0.0


def _counts(parent: Robot, child: Robot, T: np.ndarray, tolerance: int) -> Tuple[int, int]:
    A = pose_to_image(T, parent.resolution, parent.origin, child.resolution, child.origin)
    agree, conflict, _ = verify.agreement_counts(parent.levels, child.levels, A, tolerance, (parent.box, child.box))
    return agree, conflict

