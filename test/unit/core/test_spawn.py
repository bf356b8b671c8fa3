"""m-explore's init_pose_* read against the grids (core/spawn.py): ROBOTIS's Gazebo set-up (spawn
poses of robots whose maps all start in the world frame) is told apart from priors that are the
poses of the map frames, and only then does the merger place the robots at identity."""
import math

import numpy as np
import pytest
from conftest import merged, pose_error

from multi_map_merge.core.config import MergeConfig
from multi_map_merge.core.grid import Grid
from multi_map_merge.core.spawn import NOT_ONE_FRAME, spawn_point_free, spawn_poses_in_one_frame
from multi_map_merge.core.transforms import se2, xyyaw
from multi_map_merge.core.verify import pose_on_grids
from multi_map_merge.lab.pieces import cut_piece, in_world_frame

# ROBOTIS's multi_map_merge.launch: init_pose_* = the spawn positions (yaw written 0)
SPAWN = {'tb3_0': [-7.0, -1.0, 0.0], 'tb3_1': [7.0, -1.0, 0.0], 'tb3_2': [0.5, 3.0, 0.0]}
# what each robot mapped around its spawn point in the AWS small house (x0, x1, y0, y1)
MAPPED = {'tb3_0': (-9.6, 0.5, -6.0, 6.0), 'tb3_1': (1.5, 9.8, -6.0, 6.0), 'tb3_2': (-3.5, 5.0, -2.5, 6.0)}


@pytest.fixture(scope='module')
def gazebo(house):
    """The three robots' maps as ROBOTIS's Gazebo robots make them: all in the world frame."""
    return {r: in_world_frame(house, MAPPED[r], frame_id='%s/map' % r) for r in MAPPED}


def test_in_world_frame_keeps_the_world_where_it_is(house, gazebo):
    g = gazebo['tb3_2']
    assert g.origin == (-10.0, -10.0, 0.0) and g.data.shape == (400, 400)
    for x, y in [(0.5, 3.0), (-3.0, -2.0), (4.9, 5.9)]:
        r, c = int((y + 10.0) / 0.05), int((x + 10.0) / 0.05)
        rw, cw = int((y - house.origin[1]) / 0.05), int((x - house.origin[0]) / 0.05)
        assert g.levels()[r, c] == house.levels()[rw, cw]
    assert (g.levels()[:, :int((-3.5 + 10) / 0.05)] == 0).all()   # west of its box: unknown


def test_spawn_poses_of_maps_in_one_frame_are_detected(gazebo):
    v = spawn_poses_in_one_frame(MergeConfig(), gazebo, SPAWN)
    assert v is not None
    assert v.robots == ['tb3_0', 'tb3_1', 'tb3_2']
    # the overlapping pairs, each agreeing at identity; tb3_0 and tb3_1 do not overlap
    assert sorted((a, b) for a, b, *_ in v.pairs) == [('tb3_0', 'tb3_2'), ('tb3_1', 'tb3_2')]
    assert all(agr >= 0.95 and ovl > 5000 for _, _, agr, ovl, _ in v.pairs), v.pairs
    assert {round(off, 2) for *_, off in v.pairs} == {8.5, 7.63}
    assert 'agree where they are' in v.message()


def test_priors_that_are_map_frames_are_left_alone(house):
    """m-explore's meaning: each prior is the pose of its robot's map frame (the robot starts at
    its map's origin); maps in frames of their own do not agree at identity: no verdict."""
    poses = {'tb3_0': (-7.0, -1.0, 0.0), 'tb3_2': (0.5, 3.0, 0.0)}
    grids, priors = {}, {}
    for r, (x, y, yaw) in poses.items():
        x0, x1, y0, y1 = MAPPED[r]
        rect = (int((y0 + 12.5) / 0.05), int((y1 + 12.5) / 0.05), int((x0 + 12.5) / 0.05), int((x1 + 12.5) / 0.05))
        grids[r], _ = cut_piece(house, rect, (x, y, yaw), '%s/map' % r)
        priors[r] = [x, y, yaw]
    assert spawn_poses_in_one_frame(MergeConfig(), grids, priors) is None
    # and the merger places them by those priors, as m-explore would
    m = merged(grids, initial_poses=priors, map_drift=0.0)
    d, a = pose_error(m.placements()['tb3_2'].T, np.linalg.inv(se2(*poses['tb3_0'])) @ se2(*poses['tb3_2']))
    assert d < 0.1 and a < 1.0


def test_no_verdict_without_the_grids_saying_so(gazebo):
    cfg = MergeConfig()
    # a spawn point on a wall or outside the map: not where a robot stood
    wall = dict(SPAWN, tb3_2=[0.5, -6.0, 0.0])
    assert not spawn_point_free(cfg, gazebo['tb3_2'], 0.5, -6.0)
    assert spawn_poses_in_one_frame(cfg, gazebo, wall) is None
    assert not spawn_point_free(cfg, gazebo['tb3_0'], 50.0, 0.0)
    # only the two robots that do not overlap: nothing to tell
    assert spawn_poses_in_one_frame(cfg, {r: gazebo[r] for r in ('tb3_0', 'tb3_1')},
                                    {r: SPAWN[r] for r in ('tb3_0', 'tb3_1')}) is None
    # a robot with a prior but no map yet: wait
    assert spawn_poses_in_one_frame(cfg, {r: gazebo[r] for r in ('tb3_0', 'tb3_2')}, SPAWN) is None
    # priors that say identity already: nothing to correct
    assert spawn_poses_in_one_frame(cfg, gazebo, {r: [0.0, 0.0, 0.0] for r in SPAWN}) is None
    # one map moved out of the shared frame (1.5 m): it plainly disagrees at identity with the
    # map it overlaps, though tb3_0's and tb3_2's still agree
    moved = dict(gazebo)
    g = gazebo['tb3_1']
    moved['tb3_1'] = Grid(g.data, g.resolution, (g.origin[0] + 1.5, g.origin[1], 0.0), g.frame_id)
    assert pose_on_grids(cfg, moved['tb3_2'], moved['tb3_1'], np.eye(3))[0] < NOT_ONE_FRAME
    assert spawn_point_free(cfg, moved['tb3_1'], *SPAWN['tb3_1'][:2])
    assert spawn_poses_in_one_frame(cfg, moved, SPAWN) is None


def drifting_maps(house_team, in_world):
    """The four simulated robots' drifting maps of the house (conftest.house_team: robots started
    within 1 m of each other, headings apart) and their true starts: in their own frames, or,
    ``in_world``, carried into the house's frame by their starts (as Gazebo's robots' maps are)."""
    maps, starts = house_team
    grids = {}
    for r, start in starts.items():
        g = maps[r]
        origin = tuple(xyyaw(se2(*start) @ se2(*g.origin))) if in_world else g.origin
        grids[r] = Grid(g.data, g.resolution, origin, r + '/map')
    return grids, starts


@pytest.mark.slow
def test_drifting_maps_in_one_frame_despite_their_drift(house_team):
    """Drifting maps in one frame do not agree perfectly at identity (0.77-1.00, one pair under
    min_agreement): drift is not taken for maps in frames of their own."""
    cfg = MergeConfig()
    grids, starts = drifting_maps(house_team, in_world=True)
    v = spawn_poses_in_one_frame(cfg, grids, starts)
    assert v is not None and v.robots == sorted(starts)
    m = merged(grids, initial_poses={r: [0.0, 0.0, 0.0] for r in starts})
    for r in starts:
        d, a = pose_error(m.placements()[r].T, np.eye(3))
        assert d < 0.25 and a < 3.0, (r, d, a)


@pytest.mark.slow
def test_drifting_maps_in_their_own_frames_keep_their_priors(house_team):
    """The same maps in their own frames with their starts as priors (m-explore's meaning, and
    right): they disagree at identity (0.11-0.30), the priors stay."""
    grids, starts = drifting_maps(house_team, in_world=False)
    assert spawn_poses_in_one_frame(MergeConfig(), grids, starts) is None


def test_merged_at_identity_once_the_priors_are_read_as_spawn_poses(gazebo):
    """Read as map frames they reject the right links (ROBOTIS's launch with our node, issue 32);
    [0, 0, 0] for each, as the verdict says, merges them where they are."""
    m = merged(gazebo, initial_poses=SPAWN, map_drift=0.0)
    assert set(m.placements()) == {'tb3_0'}
    assert 'contradicts initial poses' in m.status()['tb3_1'].last_attempt.reason
    m = merged(gazebo, initial_poses={r: [0.0, 0.0, 0.0] for r in SPAWN}, map_drift=0.0)
    for r in ('tb3_1', 'tb3_2'):
        d, a = pose_error(m.placements()[r].T, np.eye(3))
        assert d < 0.02 and a < math.degrees(0.005), (r, d, a)


def test_the_merger_gives_spawn_poses_its_zero_priors_and_keeps_its_config(gazebo):
    """MapMerger.add_init_pose / check_spawn_poses (the node's init_pose_* and its check before
    each cycle): once the grids say the priors are spawn poses in one frame, every such robot's
    prior is [0, 0, 0], those read later too; the configuration stays as loaded."""
    from multi_map_merge.core.merger import MapMerger
    cfg = MergeConfig(known_init_poses=True, workers=1)
    m = MapMerger(cfg)
    for r in ('tb3_0', 'tb3_2'):
        assert m.wants_init_pose(r) and m.add_init_pose(r, SPAWN[r]) is False
    assert m.priors() == {r: SPAWN[r] for r in ('tb3_0', 'tb3_2')}
    assert m.check_spawn_poses() is None          # no map yet
    m.update_map('tb3_0', gazebo['tb3_0'])
    m.update_map('tb3_2', gazebo['tb3_2'])
    changed, verdict, events = m.check_spawn_poses()
    assert changed == ['tb3_0', 'tb3_2'] and verdict.robots == changed and events == []
    assert m.priors() == {'tb3_0': [0.0, 0.0, 0.0], 'tb3_2': [0.0, 0.0, 0.0]}
    assert m.check_spawn_poses() is None          # decided: not again
    assert m.add_init_pose('tb3_1', SPAWN['tb3_1']) is True
    assert m.priors()['tb3_1'] == [0.0, 0.0, 0.0]
    assert cfg.initial_poses == {}
